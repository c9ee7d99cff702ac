"""Sensor effects: identity by default, distortion against Camera.project, Poisson-Gaussian
statistics (Pearson chi-square and moment Z-tests, alpha 0.01 Sidak-corrected), vignetting."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from render.camera import Camera, Intrinsics
from render.effects import SENSOR_EFFECTS
from render.poses import look_at
from rig.sensor import SensorConfig, apply_sensor, distort_map, distortion_maps, sensor_effects, vignetting_gain

DIST = (-0.12, 0.05, 0.0015, -0.001, -0.01)  # moderate barrel, every coefficient non-zero
PINCUSHION = (0.15, 0.02, -0.002, 0.001, 0.01)


def _intrinsics(dist=(0.0,) * 5, w=320, h=240) -> Intrinsics:
    return Intrinsics(w, h, 260.0, 258.0, w / 2 + 1.3, h / 2 - 2.1, dist)


def _image(k: Intrinsics, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.0, 3.0, (k.height, k.width, 3)).astype(np.float32)


# --------------------------------------------------------------------------- config


def test_default_config_is_the_identity_bit_exact():
    k = _intrinsics(DIST)  # distortion coefficients present, but not asked for
    img = _image(k)
    rng = np.random.default_rng(5)
    state = rng.bit_generator.state
    out = apply_sensor(img, k, SensorConfig(), rng)
    assert out.dtype == np.float32 and out.tobytes() == img.tobytes()
    assert out is not img
    assert rng.bit_generator.state == state  # nothing drawn
    assert sensor_effects(SensorConfig()) == frozenset()
    # neutral parameters are the identity too
    neutral = SensorConfig(exposure=1.0, vignetting=(0.0, 0.0), distortion=True)
    assert apply_sensor(img, _intrinsics(), neutral).tobytes() == img.tobytes()


def test_sensor_effects_names():
    cases = {
        "noise": SensorConfig(noise=(100.0, 2.0)),
        "distortion": SensorConfig(distortion=True),
        "vignetting": SensorConfig(vignetting=(-0.3, 0.0)),
        "exposure": SensorConfig(exposure=2.0 ** -1.5),
    }
    for name, cfg in cases.items():
        assert sensor_effects(cfg) == {name}
    everything = SensorConfig(exposure=2.0, vignetting=(-0.3, 0.1), noise=(10.0, 0.0), distortion=True)
    assert sensor_effects(everything) == {"noise", "distortion", "vignetting", "exposure"}
    assert sensor_effects(everything) <= set(SENSOR_EFFECTS)


@pytest.mark.parametrize("kwargs,match", [
    ({"exposure": 0.0}, "exposure"), ({"exposure": float("nan")}, "exposure"),
    ({"noise": (0.0, 1.0)}, "gain"), ({"noise": (10.0, -1.0)}, "read_sigma"), ({"noise": (1.0,)}, "two numbers"),
    ({"vignetting": (float("inf"), 0.0)}, "finite"), ({"distortion": "yes"}, "distortion"),
])
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SensorConfig(**kwargs)


def test_apply_sensor_rejects_bad_input():
    k = _intrinsics()
    img = _image(k)
    with pytest.raises(ValueError, match="Generator"):
        apply_sensor(img, k, SensorConfig(noise=(10.0, 1.0)), None)
    with pytest.raises(ValueError, match=r"\(240, 320, 3\)"):
        apply_sensor(img[:, :-1], k, SensorConfig())
    with pytest.raises(ValueError, match="float"):
        apply_sensor((img * 50).astype(np.uint8), k, SensorConfig())
    bad = img.copy()
    bad[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        apply_sensor(bad, k, SensorConfig())
    with pytest.raises(ValueError, match="negative gain"):
        apply_sensor(img, k, SensorConfig(vignetting=(-1.5, 0.0)))
    with pytest.raises(ValueError, match="interpolation"):
        distort_map(img, _intrinsics(DIST), "cubic")


# --------------------------------------------------------------------------- exposure, vignetting


def test_exposure_scales_radiance():
    k = _intrinsics()
    img = _image(k)
    for ev in (-2.0, 0.5, 3.0):
        out = apply_sensor(img, k, SensorConfig(exposure=2.0 ** ev))
        np.testing.assert_allclose(out, img.astype(np.float64) * 2.0 ** ev, rtol=1e-6)


@pytest.mark.parametrize("a2,a4", [(-0.35, 0.05), (-0.2, -0.1), (0.1, 0.0)])
def test_vignetting_equals_the_formula_at_corners(a2, a4):
    k = _intrinsics()
    c = np.float32(1.7)
    img = np.full((k.height, k.width, 3), c, dtype=np.float32)
    out = apply_sensor(img, k, SensorConfig(vignetting=(a2, a4)))
    half_diag = 0.5 * math.hypot(k.width, k.height)
    for i, j in [(0, 0), (0, k.width - 1), (k.height - 1, 0), (k.height - 1, k.width - 1)]:
        r = math.hypot(j + 0.5 - k.cx, i + 0.5 - k.cy) / half_diag
        expected = float(c) * (1 + a2 * r ** 2 + a4 * r ** 4)
        np.testing.assert_allclose(out[i, j], expected, rtol=1e-6)
        assert abs(r - 1.0) < 0.02  # the principal point is nearly centred: corners at r ~ 1
    # no falloff at the principal point; monotone darkening along a row when a2 < 0, a4 small
    i0, j0 = int(k.cy), int(k.cx)
    np.testing.assert_allclose(out[i0, j0], c, rtol=1e-4)
    np.testing.assert_allclose(vignetting_gain(k, a2, a4)[0, 0] * c, out[0, 0, 0], rtol=1e-6)


# --------------------------------------------------------------------------- distortion


def _blob(k: Intrinsics, u0: float, v0: float, sigma: float = 1.5) -> np.ndarray:
    """(H, W) float32 Gaussian centred at continuous pixel position (u0, v0), centres at +0.5."""
    jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    return np.exp(-((jj - u0) ** 2 + (ii - v0) ** 2) / (2 * sigma ** 2)).astype(np.float32)


def _centroid(img: np.ndarray, near: np.ndarray, radius: int = 9) -> np.ndarray:
    """Intensity-weighted centroid (u, v), pixel centres at +0.5, in a window around ``near``."""
    j0, i0 = int(near[0]), int(near[1])
    win = img[i0 - radius:i0 + radius + 1, j0 - radius:j0 + radius + 1].astype(np.float64)
    ii, jj = np.mgrid[i0 - radius:i0 + radius + 1, j0 - radius:j0 + radius + 1]
    return np.array([(win * (jj + 0.5)).sum(), (win * (ii + 0.5)).sum()]) / win.sum()


@pytest.mark.parametrize("dist", [DIST, PINCUSHION], ids=["barrel", "pincushion"])
def test_distortion_moves_a_dot_where_project_predicts(dist):
    k = _intrinsics(dist)
    ideal_k = Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    c2w = look_at((1.0, -4.0, 2.0), (0.0, 0.0, 0.3), (0, 0, 1))
    ideal_cam, real_cam = Camera(ideal_k, c2w), Camera(k, c2w)
    moved = 0.0
    for u0, v0 in [(40.3, 30.7), (280.2, 35.9), (45.6, 205.1), (270.8, 200.4), (160.2, 121.7), (100.5, 180.25)]:
        # the world point the ideal camera sees at (u0, v0) ...
        o, d = ideal_cam.pixel_rays(np.array([[u0, v0]]))
        point = o + 3.0 * d
        # ... is where the distorting camera projects it
        expected, _ = real_cam.project(point)
        ideal = np.repeat(_blob(k, u0, v0)[..., None], 3, axis=2)
        out = apply_sensor(ideal, k, SensorConfig(distortion=True))
        got = _centroid(out[..., 1], expected[0])
        np.testing.assert_allclose(got, expected[0], atol=0.1)
        moved = max(moved, np.abs(expected[0] - [u0, v0]).max())
    assert moved > 3.0  # the test exercises real displacement


def test_distort_map_nearest_for_depth_and_mask():
    k = _intrinsics(DIST)
    ideal_k = Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    rng = np.random.default_rng(3)
    depth = rng.uniform(1.0, 5.0, (k.height, k.width)).astype(np.float32)
    out = distort_map(depth, k, "nearest")
    assert out.shape == depth.shape and out.dtype == np.float32
    # nearest never invents values: every output is an input depth or 0 (outside)
    assert np.isin(out[out != 0], depth).all()
    # each output pixel takes the depth of the ideal pixel nearest to where its ray lands
    mx, my = distortion_maps(k)
    i, j = 17, 301
    src_j, src_i = int(np.floor(mx[i, j] + 0.5)), int(np.floor(my[i, j] + 0.5))
    assert out[i, j] == depth[src_i, src_j]
    # a mask disk moves with the distortion: its centroid follows the projected centre
    c2w = np.eye(4)
    u0, v0 = 60.3, 50.2
    o, d = Camera(ideal_k, c2w).pixel_rays(np.array([[u0, v0]]))
    expected, _ = Camera(k, c2w).project(o + d)
    jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    mask = (jj - u0) ** 2 + (ii - v0) ** 2 < 6.0 ** 2
    out_mask = distort_map(mask, k, "nearest")
    assert out_mask.dtype == np.bool_
    np.testing.assert_allclose(_centroid(out_mask.astype(np.float32), expected[0], 12), expected[0], atol=0.5)
    # masks as uint8 (what the capture passes) behave the same
    np.testing.assert_array_equal(distort_map(mask.astype(np.uint8), k, "nearest").astype(bool), out_mask)


def test_distort_map_barrel_corners_see_outside_and_pinhole_is_identity():
    k = _intrinsics((-0.35, 0.0, 0.0, 0.0, 0.0))
    ones = np.ones((k.height, k.width), np.float32)
    out = distort_map(ones, k, "linear")
    # barrel: the corners' rays fall outside the ideal image's field and get 0; the centre is kept
    assert out[0, 0] == 0 and out[k.height // 2, k.width // 2] == pytest.approx(1.0)
    assert np.all(np.isfinite(out)) and out.min() >= 0
    pin = _intrinsics()
    depth = _image(pin)[..., 0]
    np.testing.assert_array_equal(distort_map(depth, pin, "nearest"), depth)


def test_distortion_maps_are_cached_and_read_only():
    k = _intrinsics(DIST)
    a = distortion_maps(k)
    b = distortion_maps(Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy, DIST))  # equal, new object
    assert a[0] is b[0] and a[1] is b[1]
    assert not a[0].flags.writeable
    assert a[0].shape == (k.height, k.width) and a[0].dtype == np.float32


# --------------------------------------------------------------------------- noise

ALPHA = 0.01


def _poisson_gaussian_cell_probs(lam: float, sigma: float, edges: np.ndarray) -> np.ndarray:
    """P(max(N + E, 0) in each cell) for N ~ Poisson(lam), E ~ N(0, sigma^2), counts units.

    ``edges`` (M + 1,) increasing with edges[0] = -inf: the first cell holds the clipped zeros.
    """
    k = np.arange(max(0, int(lam - 12 * math.sqrt(lam + 1) - 10)), int(lam + 12 * math.sqrt(lam + 1) + 10))
    pk = stats.poisson.pmf(k, lam)
    cdf = stats.norm.cdf((edges[None, :] - k[:, None]) / sigma)  # (K, M + 1)
    return (pk[:, None] * np.diff(cdf, axis=1)).sum(axis=0)


def _clipped_moments(lam: float, sigma: float) -> tuple[float, float, float]:
    """Mean, variance and 4th central moment of max(N + E, 0) (electrons), by quadrature.

    The clip leaves a point mass at 0 (no contribution to raw moments) and the mixture density
    sum_k Poisson(k) phi((y - k) / sigma) / sigma on y > 0.
    """
    k = np.arange(0, int(lam + 15 * math.sqrt(lam + 1) + 10))
    pk = stats.poisson.pmf(k, lam)
    y = np.linspace(0.0, k[-1] + 10 * sigma, 40001)
    dens = (pk[:, None] * stats.norm.pdf((y[None, :] - k[:, None]) / sigma) / sigma).sum(axis=0)
    raw = [np.trapezoid(dens * y ** m, y) for m in (1, 2, 3, 4)]
    mean = raw[0]
    var = raw[1] - mean ** 2
    mu4 = raw[3] - 4 * mean * raw[2] + 6 * mean ** 2 * raw[1] - 3 * mean ** 4
    return mean, var, mu4


def _pearson_p_value(observed: np.ndarray, expected: np.ndarray) -> float:
    """Pearson chi-square p-value, cells with expected count < 5 pooled (Mitsuba's chi2 practice)."""
    order = np.argsort(expected)
    obs, exp = observed[order].astype(float), expected[order]
    pooled_o, pooled_e, acc_o, acc_e = [], [], 0.0, 0.0
    for o, e in zip(obs, exp):
        if e < 5:
            acc_o += o
            acc_e += e
        else:
            pooled_o.append(o)
            pooled_e.append(e)
    if acc_e > 0:
        pooled_o.append(acc_o)
        pooled_e.append(acc_e)
    pooled_o, pooled_e = np.array(pooled_o), np.array(pooled_e)
    chi2 = ((pooled_o - pooled_e) ** 2 / pooled_e).sum()
    return float(stats.chi2.sf(chi2, len(pooled_o) - 1))


def test_noise_matches_the_poisson_gaussian_model():
    gain, read = 40.0, 3.0  # photo-electrons per unit radiance, read noise in electrons
    levels = (0.25, 1.0, 4.0)  # radiance: 10, 40, 160 expected electrons
    k = _intrinsics(w=200, h=200)
    n_tests = 3 * len(levels)
    alpha = 1.0 - (1.0 - ALPHA) ** (1.0 / n_tests)  # Sidak
    rng = np.random.default_rng(20240611)
    for x in levels:
        img = np.full((k.height, k.width, 3), x, dtype=np.float32)
        out = apply_sensor(img, k, SensorConfig(noise=(gain, read)), rng)
        assert out.dtype == np.float32 and np.all(np.isfinite(out)) and out.min() >= 0
        e = out.ravel().astype(np.float64) * gain  # back to electrons
        n = e.size
        lam = gain * float(np.float32(x))
        # before the clip: mean lam, variance lam + read^2 (Poisson's cumulants all equal lam);
        # the clip at 0 matters at the lowest level (P(n + e < 0) ~ 1%), so use its exact moments
        mean, var, mu4 = _clipped_moments(lam, read)
        if x >= 1.0:
            assert mean == pytest.approx(lam, rel=1e-6) and var == pytest.approx(lam + read ** 2, rel=1e-4)
        z_mean = (e.mean() - mean) / math.sqrt(var / n)
        z_var = (e.var(ddof=1) - var) / math.sqrt((mu4 - var ** 2) / n)  # asymptotic law of s^2
        assert 2 * stats.norm.sf(abs(z_mean)) > alpha, f"mean at x={x}: z={z_mean:.2f}"
        assert 2 * stats.norm.sf(abs(z_var)) > alpha, f"variance at x={x}: z={z_var:.2f}"
        # the whole distribution: Pearson chi-square on unit-electron cells
        lo, hi = math.floor(lam - 6 * math.sqrt(var)), math.ceil(lam + 6 * math.sqrt(var))
        edges = np.concatenate([[-np.inf], np.arange(max(lo, 0), hi + 1) + 0.5, [np.inf]])
        expected = n * _poisson_gaussian_cell_probs(lam, read, edges)
        observed = np.histogram(e, bins=np.where(np.isinf(edges), np.sign(edges) * 1e12, edges))[0]
        assert observed.sum() == n
        p = _pearson_p_value(observed, expected)
        assert p > alpha, f"distribution at x={x}: p={p:.2g}"


def test_noise_at_zero_radiance_is_clipped_read_noise():
    gain, read = 20.0, 2.0
    k = _intrinsics(w=100, h=100)
    out = apply_sensor(np.zeros((k.height, k.width, 3), np.float32), k, SensorConfig(noise=(gain, read)),
                       np.random.default_rng(11))
    assert np.all(np.isfinite(out)) and out.min() == 0.0
    # Poisson(0) = 0, so the output is max(N(0, read^2), 0) / gain: half of it exactly 0
    zeros = int((out == 0).sum())
    assert stats.binomtest(zeros, out.size, 0.5).pvalue > ALPHA
    pos = out[out > 0].astype(np.float64) * gain  # half-normal
    assert stats.kstest(pos, stats.halfnorm(scale=read).cdf).pvalue > ALPHA


def test_noise_same_seed_same_bytes():
    k = _intrinsics(DIST)
    img = _image(k)
    cfg = SensorConfig(exposure=1.5, vignetting=(-0.3, 0.05), noise=(50.0, 2.5), distortion=True)
    a = apply_sensor(img, k, cfg, np.random.default_rng(7))
    b = apply_sensor(img, k, cfg, np.random.default_rng(7))
    c = apply_sensor(img, k, cfg, np.random.default_rng(8))
    assert a.dtype == np.float32 and a.shape == img.shape
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_noise_has_no_bias_after_exposure_and_vignetting():
    # the noise acts on the exposed, vignetted signal: average many frames of one pixel row
    k = _intrinsics(w=64, h=48)
    cfg = SensorConfig(exposure=2.0, vignetting=(-0.3, 0.0), noise=(30.0, 1.0))
    img = np.full((k.height, k.width, 3), 0.5, np.float32)
    clean = apply_sensor(img, k, SensorConfig(exposure=2.0, vignetting=(-0.3, 0.0)))
    rng = np.random.default_rng(99)
    frames = np.stack([apply_sensor(img, k, cfg, rng) for _ in range(400)]).astype(np.float64)
    var = clean / 30.0 + (1.0 / 30.0) ** 2
    z = (frames.mean(axis=0) - clean) / np.sqrt(var / len(frames))
    alpha = 1.0 - (1.0 - ALPHA) ** (1.0 / z.size)  # Sidak over all pixel channels
    assert (2 * stats.norm.sf(np.abs(z))).min() > alpha
