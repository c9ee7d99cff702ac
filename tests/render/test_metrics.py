"""render.metrics: the project's one PSNR convention and the hard case of identical images."""
import json
import math

import numpy as np
import pytest

from render import metrics
from render.metrics import (MSE_FLOOR, PSNR_MAX_DB, black_image_scores, flip, flip_map, mse_to_psnr, psnr, rmse,
                            score_images, ssim, to_display)

#: the documented value of every image metric (render.metrics.__all__'s functions of two images)
#: on identical images
IDENTICAL = {"psnr": PSNR_MAX_DB, "ssim": 1.0, "rmse": 0.0, "flip": 0.0}


def _images():
    rng = np.random.default_rng(5)
    return {"black": np.zeros((12, 16, 3), np.float32), "constant": np.full((12, 16, 3), 0.25, np.float32),
            "random": rng.random((12, 16, 3)).astype(np.float32), "grey 2-D": rng.random((12, 16)),
            "over-range": rng.uniform(-1.0, 3.0, (12, 16, 3))}


def test_identical_images_through_every_metric():
    """Hard case: identical images through every metric of render.metrics (black, constant,
    random, 2-D, out of [0, 1]) give finite, documented values: psnr PSNR_MAX_DB = 100 dB (MSE
    floored at MSE_FLOOR = 1e-10 of peak^2), ssim 1, rmse 0; and those values are valid JSON
    (allow_nan=False, as stages write metrics.json). A metric added to render.metrics without
    a documented identical-image value here fails the first assertion."""
    image_metrics = {n for n in metrics.__all__ if callable(getattr(metrics, n))
                     and n not in ("mse_to_psnr", "to_display", "flip_map", "score_images", "black_image_scores",
                                "display_slope", "display_noise_mse", "rounding_excess", "flip_means", "score_order",
                                "flip_exposure_schedule")}
    assert image_metrics == set(IDENTICAL)
    assert PSNR_MAX_DB == 100.0 and 10 * math.log10(1 / MSE_FLOOR) == pytest.approx(PSNR_MAX_DB)
    for label, img in _images().items():
        names = [n for n in IDENTICAL if img.ndim == 3 or n != "flip"]  # ꟻLIP takes RGB only
        for name in names:
            got = getattr(metrics, name)(img, img.copy())
            assert math.isfinite(got) and got == pytest.approx(IDENTICAL[name], abs=1e-6), (label, name, got)
        if img.ndim == 3:
            assert flip(img, img.copy(), hdr=True) == 0.0, label
            assert score_images(img, img.copy(), mask=np.ones(img.shape[:2], bool)) == pytest.approx(
                {**{k + s: PSNR_MAX_DB for k in ("display_psnr", "linear_psnr") for s in ("", "_subject")},
                 **{"display_ssim" + s: 1.0 for s in ("", "_subject")},
                 **{k + s: 0.0 for k in ("flip_ldr", "flip_hdr") for s in ("", "_subject")}}), label
        json.dumps({name: getattr(metrics, name)(img, img) for name in names}, allow_nan=False)
    assert psnr(np.full((4, 4, 3), 2.0), np.full((4, 4, 3), 2.0), max_val=2.0) == PSNR_MAX_DB


def test_psnr_follows_its_closed_form_up_to_the_cap():
    """10 log10(peak^2 / MSE) below the cap, the cap at and beyond MSE = 1e-10 peak^2 (training's
    mse_to_psnr is the same function), never above it."""
    ref = np.full((8, 8, 3), 0.5)
    for d in (0.1, 1e-3, 1e-5 + 1e-9):
        assert psnr(ref + d, ref) == pytest.approx(-20 * math.log10(d), rel=1e-9)
    assert psnr(ref + 1e-6, ref) == pytest.approx(PSNR_MAX_DB, abs=1e-6)  # MSE 1e-12: capped
    assert mse_to_psnr(0.0) == mse_to_psnr(1e-300) == PSNR_MAX_DB
    assert mse_to_psnr(0.25, peak=2.0) == pytest.approx(10 * math.log10(16.0))
    from recon.nerf.train import mse_to_psnr as training_psnr
    assert training_psnr is mse_to_psnr
    assert rmse(ref + 0.1, ref) == pytest.approx(0.1) and ssim(ref + 0.1, ref) < 1.0


def _display_level(code: int) -> float:
    """The linear value whose 8-bit sRGB code is exactly ``code``."""
    from render.color import srgb_to_linear
    return float(srgb_to_linear(code / 255.0))


def test_display_psnr_of_a_constant_code_offset_follows_its_closed_form():
    """Display PSNR scores 8-bit sRGB codes: two flat images whose codes differ by 10 score
    20 log10(255 / 10) = 28.13 dB whatever their linear difference (which linear PSNR reports
    differently: dark codes are close in linear light), and values within half a code of each
    other score as identical (8-bit quantization)."""
    ref = np.full((16, 16, 3), _display_level(40))
    pred = np.full((16, 16, 3), _display_level(50))
    assert np.allclose(to_display(ref) * 255, 40) and np.allclose(to_display(pred) * 255, 50)
    got = score_images(pred, ref, with_flip=False)
    assert got["display_psnr"] == pytest.approx(20 * math.log10(255 / 10), abs=1e-9)
    assert got["linear_psnr"] == pytest.approx(psnr(pred, ref)) and got["linear_psnr"] > got["display_psnr"] + 5
    nudged = np.full((16, 16, 3), 0.7 * _display_level(40) + 0.3 * _display_level(41))  # 0.3 codes up
    assert score_images(nudged, ref, with_flip=False)["display_psnr"] == PSNR_MAX_DB


def test_masked_metrics_average_over_the_mask_and_refuse_an_empty_one():
    """With a mask, PSNR is the closed form over the mask's pixels only (the rest may be anything),
    and every masked metric refuses an empty mask or one of the wrong shape with ValueError."""
    ref = np.full((10, 12, 3), 0.5)
    pred = ref.copy()
    pred[:, :6] += 0.1  # the mask's half: error 0.1
    pred[:, 6:] = 0.0  # the other half: wildly wrong, outside the mask
    mask = np.zeros((10, 12), bool)
    mask[:, :6] = True
    assert psnr(pred, ref, mask=mask) == pytest.approx(20.0, abs=1e-9)
    assert ssim(pred, ref, mask=mask) > ssim(pred, ref)
    assert flip(pred, ref, mask=mask) < flip(pred, ref)
    for bad in (np.zeros((10, 12), bool), np.ones((12, 10), bool)):
        for call in (lambda m: psnr(pred, ref, mask=m), lambda m: ssim(pred, ref, mask=m),
                     lambda m: flip(pred, ref, mask=m), lambda m: score_images(pred, ref, mask=m)):
            with pytest.raises(ValueError, match="mask"):
                call(bad)


def test_flip_of_green_against_blue_is_its_maximum_one():
    """ꟻLIP's normalization (Andersson et al. 2020, eq. 3-4): the colour distance is scaled by that
    of pure green and pure blue, the largest in its colour space, so flat green against flat blue
    (no feature error) scores exactly 1; black against white scores below it; error grows with
    the difference."""
    green, blue = np.zeros((24, 24, 3)), np.zeros((24, 24, 3))
    green[..., 1], blue[..., 2] = 1.0, 1.0
    assert flip(green, blue) == pytest.approx(1.0, abs=1e-6)
    assert 0.5 < flip(np.zeros((24, 24, 3)), np.ones((24, 24, 3))) < 1.0
    ref = np.full((24, 24, 3), 0.2)
    errs = [flip(ref * (1 + d), ref) for d in (0.05, 0.2, 0.8)]
    assert 0.0 < errs[0] < errs[1] < errs[2]
    assert flip_map(ref * 1.2, ref).shape == (24, 24)


def _flip_pairs() -> dict:
    """(pred, ref, hdr) pairs at 96x128 for the torch ꟻLIP against flip_evaluator: LDR a constant
    offset, noise and a blurred edge; HDR a dark scene (4% lit, one highlight 100x its median:
    seven exposures), an offset and noise on a brighter one."""
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:96, 0:128]
    ramp = np.stack([0.2 + 0.6 * xx / 128, 0.3 + 0.4 * yy / 96, np.full((96, 128), 0.5)], -1)
    edge = np.where(xx < 64, 0.05, 0.8)[..., None] * np.array([1.0, 0.9, 0.7])
    kernel = np.exp(-0.5 * (np.arange(-4, 5) / 1.5) ** 2)
    blurred = np.apply_along_axis(lambda row: np.convolve(np.pad(row, 4, mode="edge"), kernel / kernel.sum(), "valid"),
                                  1, edge)
    dark = np.zeros((96, 128, 3))
    dark[30:60, 40:90] = 0.02 * (1.0 + rng.uniform(0.0, 1.0, (30, 50, 3)))
    dark[40:45, 50:55] = 3.0
    return {"offset": (ramp + 0.05, ramp, False),
            "noise": (np.clip(ramp + rng.normal(0.0, 0.05, ramp.shape), 0.0, 1.0), ramp, False),
            "blurred edge": (blurred, edge, False),
            "dark HDR": (dark * rng.uniform(0.8, 1.2, dark.shape), dark, True),
            "HDR offset": (4.0 * ramp + 0.1, 4.0 * ramp, True),
            "HDR noise": (np.abs(2.0 * ramp + rng.normal(0.0, 0.1, ramp.shape)), 2.0 * ramp, True)}


@pytest.mark.parametrize("case", list(_flip_pairs()))
def test_torch_flip_gives_flip_evaluators_maps(case):
    """The torch port of ꟻLIP (flip_map's default) against NVIDIA's flip_evaluator, the oracle, on
    the same inputs: per pixel within 1e-4 and the mean within 1e-6. Why 1e-4: both run in float32
    and sum their convolutions in different orders (~1e-7 relative), and ꟻLIP raises the feature
    difference to q_f = 0.5 and the colour distance to q_c = 0.7, powers with an infinite slope at
    0, so a rounding residue of ~1e-8 where the images barely differ becomes up to ~4e-5 of error
    (measured <= 1.4e-5 here; ~1e-3 on 0.2% of a 1280x960 turntable frame's near-black pixels,
    mean 1e-6). A wrong filter (e.g. the blue-yellow Gaussians' widths, off by sqrt(2)) moves
    pixels by 1e-2."""
    pred, ref, hdr = _flip_pairs()[case]
    got = flip_map(pred, ref, hdr)
    want = flip_map(pred, ref, hdr, implementation="flip_evaluator")
    assert got.dtype == np.float32 and got.shape == ref.shape[:2] and np.isfinite(got).all()
    assert np.abs(got - want).max() <= 1e-4, case
    assert abs(got.mean(dtype=np.float64) - want.mean(dtype=np.float64)) <= 1e-6, case
    assert want.mean() > 0.01  # a real difference, not two zero maps


def test_torch_flip_constants_are_flip_evaluators():
    """The port's observer (67.02 pixels per degree), tone-mapper point x_max (flip_evaluator's
    start exposure of a unit-luminance image is log2(x_max)) and exposure count are the package's;
    an unknown implementation is refused."""
    import flip_evaluator
    ones = np.ones((8, 8, 3), np.float32)
    _, _, params = flip_evaluator.evaluate(ones, ones, "HDR", applyMagma=False)
    assert metrics.FLIP_PPD == params["ppd"]
    assert math.log2(metrics._flip_x_max()) == pytest.approx(params["startExposure"], abs=1e-6)
    for start, stop in ((1.1444, 6.8595), (-2.0, -2.0), (0.3, 0.9), (-3.5, 9.25)):
        _, _, p = flip_evaluator.evaluate(ones, ones * 0.5, "HDR", applyMagma=False,
                                          parameters={"startExposure": start, "stopExposure": stop})
        schedule = metrics.flip_exposure_schedule(start, stop)
        assert len(schedule) == p["numExposures"] and schedule[0] == np.float32(start)
        assert schedule[-1] == pytest.approx(stop, abs=1e-5)
    with pytest.raises(ValueError, match="implementation"):
        flip_map(ones, ones, implementation="nvidia")


def test_hard_case_flip_of_radiance_past_float32_squares_is_white():
    """Hard case: HDR-ꟻLIP of a test image 1e30 times the reference (exposed, its square
    overflows float32). The tone mapper saturates it to white: the same map as an image 1e6 times
    the reference (already past the curve's 1 at every exposure), finite, in [0, 1]
    (flip_evaluator turns inf / inf into black instead)."""
    ref = np.full((16, 16, 3), 0.2)
    ref[4:12, 4:12] = 0.6
    huge = flip_map(ref * 1e30, ref, hdr=True)
    assert np.isfinite(huge).all() and 0.0 < huge.min() and huge.max() <= 1.0
    np.testing.assert_array_equal(huge, flip_map(ref * 1e6, ref, hdr=True))


def test_score_order_puts_the_headline_first_and_flip_means_average_each_map():
    """score_order: SCORE_NAMES' figures in its order, each name's subject figure after it, then
    other keys as they came (validate's rows and score_images share it); flip_means: each map's
    mean over the image and over the mask's pixels (closed form on a two-valued map)."""
    from render.metrics import flip_means, score_order
    scores = {"rmse": 1, "linear_psnr": 2, "flip_hdr_subject": 3, "display_psnr_subject": 4, "flip_ldr": 5,
              "display_psnr": 6, "scale": 7, "display_ssim": 8}
    assert list(score_order(scores)) == ["display_psnr", "display_psnr_subject", "display_ssim", "flip_ldr",
                                         "flip_hdr_subject", "linear_psnr", "rmse", "scale"]
    ref = np.full((8, 8, 3), 0.3)
    mask = np.zeros((8, 8), bool)
    mask[2:4] = True
    assert list(score_images(ref * 1.1, ref, mask)) == [n + s for n in metrics.SCORE_NAMES for s in ("", "_subject")]
    err = np.zeros((8, 8), np.float32)
    err[:, :2] = 1.0  # a quarter of the image, a quarter of the mask's rows
    err[2, 2:] = 0.5
    got = flip_means({"flip_ldr": err}, mask)
    assert got == {"flip_ldr": pytest.approx((16 + 3) / 64), "flip_ldr_subject": pytest.approx((4 + 3) / 16)}
    assert flip_means({"flip_hdr": err}) == {"flip_hdr": pytest.approx(19 / 64)}


def test_hard_case_hdr_flip_on_dark_references():
    """Hard case: HDR-ꟻLIP of a frame that is mostly or entirely black. ꟻLIP picks its exposure
    range from the reference's median luminance: 0 on the turntable's background (stop exposure
    +24 stops), and on an all-black reference it calls exit() and takes the process with it. The
    range comes from the lit pixels instead: finite errors in [0, 1], 0 for identical black images,
    and a larger error for a larger difference."""
    ref = np.zeros((32, 32, 3))
    ref[8:20, 8:20] = 0.03
    small, large = ref * 1.1, ref * 2.0
    e_small, e_large = flip(small, ref, hdr=True), flip(large, ref, hdr=True)
    assert 0.0 < e_small < e_large <= 1.0
    black = np.zeros((32, 32, 3))
    assert flip(black, black, hdr=True) == 0.0
    assert 0.0 < flip(ref, black, hdr=True) <= 1.0  # black reference, lit test image: no exit()


def test_black_image_scores_are_the_scores_of_black():
    """The all-black image's figures are score_images of zeros, and a render close to the
    reference beats them on every figure (higher PSNR/SSIM, lower ꟻLIP)."""
    rng = np.random.default_rng(3)
    ref = np.zeros((24, 32, 3))
    ref[6:18, 8:24] = rng.uniform(0.05, 0.4, (12, 16, 3))
    mask = ref.sum(-1) > 0
    black = black_image_scores(ref, mask)
    assert black == score_images(np.zeros_like(ref), ref, mask)
    good = score_images(ref * 1.02, ref, mask)
    for k in black:
        better = good[k] < black[k] if k.startswith("flip") else good[k] > black[k]
        assert better, (k, good[k], black[k])


def test_rounding_excess_closed_forms():
    """E[{x}(1 - {x})] for x ~ N(0, s^2): 0 at s = 0, s sqrt(2 / pi) as s -> 0 (E|x|), 1/6 for
    s >> 1 (a uniform fractional part), and a Monte Carlo estimate at s = 0.3 (seed 0, 1e6 draws:
    standard error < 3e-4, tolerance 5 of them)."""
    from render.metrics import rounding_excess

    assert rounding_excess(0.0) == 0.0
    assert rounding_excess(1e-3) == pytest.approx(1e-3 * math.sqrt(2 / math.pi), rel=1e-2)
    assert rounding_excess(10.0) == pytest.approx(1 / 6)
    x = np.random.default_rng(0).normal(0.0, 0.3, 1_000_000)
    frac = x - np.floor(x)
    assert rounding_excess(0.3) == pytest.approx(np.mean(frac * (1 - frac)), abs=1.5e-3)


@pytest.mark.parametrize("sigma", [3e-4, 3e-3])
def test_display_noise_mse_predicts_a_perfect_models_display_error(sigma):
    """A perfect model (the truth, uniform in [0.05, 0.9]) against truth + N(0, sigma^2) scores the
    display MSE display_noise_mse predicts (delta method + 8-bit rounding excess) within 3%: 196608
    channels, seed 3 (relative standard error of an MSE sqrt(2 / n) = 0.3%; the curve's bend and
    the grid's non-uniformity are the rest). Measured: +1.0% and -0.2%. Without the rounding term
    the prediction is 0.10 and 0.75 of the measured MSE."""
    from render.metrics import display_noise_mse

    rng = np.random.default_rng(3)
    truth = rng.uniform(0.05, 0.9, (256, 256, 3))
    ref = truth + rng.normal(0.0, sigma, truth.shape)
    measured = np.mean((to_display(truth) - to_display(ref)) ** 2)
    assert display_noise_mse(ref, np.full_like(ref, sigma ** 2)) == pytest.approx(measured, rel=0.03)
