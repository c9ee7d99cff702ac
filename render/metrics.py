"""Image metrics: PSNR (closed form), SSIM (kornia) and RMSE, one convention for the project.

PSNR convention: PSNR = 10 log10(peak^2 / max(MSE, MSE_FLOOR x peak^2)) dB on images clipped to
[0, peak], so identical images (MSE 0) give the finite cap PSNR_MAX_DB = 100 dB, never +inf:
every metrics.json stays valid JSON (no Infinity) and means over views stay finite. An MSE
below 1e-10 of peak^2 is beyond float32 images' resolution anyway (their relative rounding is
6e-8, i.e. an MSE of ~4e-15 near 1). Validate, the slab and NeRF stages and NeRF training
(:func:`mse_to_psnr`) all use these two functions.

Every metric of identical images is finite and documented: psnr PSNR_MAX_DB, ssim 1, rmse 0,
flip 0.

Display metrics (the field's headline: NeRF, TensoRF and Instant-NGP report PSNR/SSIM of 8-bit
sRGB images) score :func:`to_display` images: linear radiance clipped to [0, 1], sRGB-encoded and
quantized to 8 bits. Linear PSNR stays available and is always named as linear. ꟻLIP (NVIDIA's
``flip-evaluator``: Andersson et al. 2020, LDR; 2021, HDR) is the perceptual error: LDR-ꟻLIP on the
display images, HDR-ꟻLIP on linear radiance. :func:`score_images` scores a pair on the whole image
and, given the subject's mask, on the subject's pixels, and :func:`black_image_scores` gives the
all-black image's scores beside them, so an empty background cannot carry a figure.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import torch
import kornia.metrics

from .color import linear_to_srgb

__all__ = ["psnr", "ssim", "rmse", "flip", "mse_to_psnr", "PSNR_MAX_DB", "MSE_FLOOR", "to_display", "flip_map",
           "score_images", "black_image_scores", "SCORE_NAMES", "FLIP_NAMES", "display_slope", "display_noise_mse", "rounding_excess"]

#: PSNR of identical images (dB): the cap every PSNR in the project shares
PSNR_MAX_DB = 100.0
#: MSE floor as a fraction of peak^2: 10 log10(1 / MSE_FLOOR) = PSNR_MAX_DB
MSE_FLOOR = 1e-10


def _to_tensor(img: np.ndarray) -> torch.Tensor:
    a = np.asarray(img, dtype=np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3:
        raise ValueError(f"expected (H, W) or (H, W, C) image, got {a.shape}")
    return torch.from_numpy(np.clip(a, 0.0, 1.0)).permute(2, 0, 1)[None]


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root-mean-square difference of two same-shape float arrays (unclipped); 0 when identical."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"shape mismatch {a.shape} vs {b.shape}")
    return float(np.sqrt(np.mean((a - b) ** 2)))


def mse_to_psnr(mse: float, peak: float = 1.0) -> float:
    """PSNR in dB of a mean squared error of images in [0, peak]: 10 log10(peak^2 / mse), with
    mse floored at MSE_FLOOR x peak^2, so at most PSNR_MAX_DB (mse 0: exactly PSNR_MAX_DB)."""
    peak2 = float(peak) * float(peak)
    return float(10.0 * math.log10(peak2 / max(float(mse), MSE_FLOOR * peak2)))


def _check_mask(mask: np.ndarray | None, shape: tuple) -> np.ndarray | None:
    """``mask`` as a (H, W) bool array matching ``shape``'s first two axes; refuses an empty one
    (a mean over no pixel is no figure)."""
    if mask is None:
        return None
    m = np.asarray(mask)
    if m.shape != tuple(shape[:2]):
        raise ValueError(f"mask shape {m.shape} does not match the image's {tuple(shape[:2])}")
    m = m.astype(bool)
    if not m.any():
        raise ValueError("mask selects no pixel: a masked metric needs at least one")
    return m


def psnr(pred: np.ndarray, ref: np.ndarray, max_val: float = 1.0, mask: np.ndarray | None = None) -> float:
    """PSNR in dB of same-shape (H, W[, C]) images clipped to [0, max_val] (float64 MSE over
    every pixel and channel, or over the (H, W) ``mask``'s pixels); identical images give
    PSNR_MAX_DB (see :func:`mse_to_psnr`). An empty mask raises ValueError."""
    if np.shape(pred) != np.shape(ref):
        raise ValueError(f"shape mismatch {np.shape(pred)} vs {np.shape(ref)}")
    m = _check_mask(mask, np.shape(ref))
    a = np.clip(np.asarray(pred, dtype=np.float64), 0.0, max_val)
    b = np.clip(np.asarray(ref, dtype=np.float64), 0.0, max_val)
    sq = (a - b) ** 2
    return mse_to_psnr(float(np.mean(sq if m is None else sq[m])), max_val)


def ssim(pred: np.ndarray, ref: np.ndarray, window: int = 11, mask: np.ndarray | None = None) -> float:
    """Mean SSIM of (H, W[, C]) images clipped to [0, 1] (kornia, Gaussian window ``window``),
    over every pixel or over the (H, W) ``mask``'s pixels of the SSIM map (the windows still see
    their whole neighbourhood); images identical after clipping give exactly 1 (kornia's 1e-12 in
    the denominator would give 1 - 1e-12 / (C1 C2) = 0.99999 on flat images)."""
    if np.shape(pred) != np.shape(ref):
        raise ValueError(f"shape mismatch {np.shape(pred)} vs {np.shape(ref)}")
    m = _check_mask(mask, np.shape(ref))
    # float32: 6.5x faster than float64 at 1280x960 and within 3e-8 of it (the variances' float32
    # rounding, ~1e-7, is far below SSIM's C2 = 9e-4)
    a, b = _to_tensor(pred).float(), _to_tensor(ref).float()
    if torch.equal(a, b):
        return 1.0
    # kornia pads by reflection, which needs the window smaller than the image
    window = min(window, (min(np.shape(pred)[:2]) - 1) | 1)
    ssim_map = kornia.metrics.ssim(a, b, window)[0].mean(0)  # (H, W), channels averaged
    return float(ssim_map.mean() if m is None else ssim_map[torch.from_numpy(m)].mean())


def to_display(linear: np.ndarray) -> np.ndarray:
    """Linear radiance (H, W[, C]) -> the 8-bit sRGB display image as float64 in [0, 1] (clipped
    to [0, 1], sRGB-encoded, rounded to 1/255): what the field's display PSNR/SSIM score."""
    return np.round(linear_to_srgb(linear) * 255.0) / 255.0


def _luminance(img: np.ndarray) -> np.ndarray:
    """ꟻLIP's luminance of linear RGB (H, W, 3) (Rec. 709 weights)."""
    return img @ np.array([0.2126, 0.7152, 0.0722])


@functools.lru_cache(maxsize=None)
def _flip_x_max() -> float:
    """ꟻLIP's tone-mapper point x_max (ACES, t = 0.85), read from the package itself: its start
    exposure of a unit-luminance image is log2(x_max)."""
    import flip_evaluator
    _, _, params = flip_evaluator.evaluate(np.ones((8, 8, 3), np.float32), np.ones((8, 8, 3), np.float32), "HDR",
                                           applyMagma=False)
    return float(2.0 ** params["startExposure"])


def _hdr_exposures(ref: np.ndarray, test: np.ndarray) -> dict:
    """HDR-ꟻLIP's exposure range (start log2(x_max / Y_max), stop log2(x_max / Y_median)) with
    the median over the reference's lit pixels, not all of them. ꟻLIP's own choice takes the median
    over every pixel: on a mostly black frame (the turntable's background) that median is 0, its
    stop exposure runs to +24 stops, and with an all-black reference it calls exit() from C++
    ("Start exposure must be smaller than stop exposure") and takes the process with it."""
    lum = _luminance(ref)
    lit = lum[lum > 0]
    if lit.size == 0:  # black reference: expose for the test image, or for 1 if both are black
        lum = _luminance(test)
        lit = lum[lum > 0] if (lum > 0).any() else np.ones(1)
    x_max = _flip_x_max()
    start = math.log2(x_max / float(lit.max()))
    stop = max(start, math.log2(x_max / float(np.median(lit))))
    return {"startExposure": start, "stopExposure": stop}


def flip_map(pred: np.ndarray, ref: np.ndarray, hdr: bool = False) -> np.ndarray:
    """ꟻLIP error map (H, W) float32 in [0, 1] of linear (H, W, 3) images: LDR-ꟻLIP of their
    :func:`to_display` images, or (``hdr``) HDR-ꟻLIP of the linear radiance (negative values
    clipped to 0) with the exposure range of :func:`_hdr_exposures`. 67 pixels per degree
    (ꟻLIP's default: a 0.7 m viewing distance on a 24-inch 4K display)."""
    import flip_evaluator
    if np.shape(pred) != np.shape(ref) or np.ndim(ref) != 3 or np.shape(ref)[2] != 3:
        raise ValueError(f"ꟻLIP needs two (H, W, 3) images, got {np.shape(pred)} and {np.shape(ref)}")
    a = np.asarray(pred, dtype=np.float64)
    b = np.asarray(ref, dtype=np.float64)
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("ꟻLIP of an image with NaN or Inf")
    if hdr:
        a, b = np.maximum(a, 0.0), np.maximum(b, 0.0)
        err, _, _ = flip_evaluator.evaluate(b.astype(np.float32), a.astype(np.float32), "HDR", applyMagma=False,
                                            parameters=_hdr_exposures(b, a))
    else:
        err, _, _ = flip_evaluator.evaluate(to_display(b).astype(np.float32), to_display(a).astype(np.float32), "LDR",
                                            applyMagma=False)
    return np.asarray(err, dtype=np.float32).reshape(np.shape(ref)[:2])


def flip(pred: np.ndarray, ref: np.ndarray, hdr: bool = False, mask: np.ndarray | None = None) -> float:
    """Mean ꟻLIP error (0 identical, 1 the largest: pure green against pure blue) of linear
    (H, W, 3) images over every pixel or the (H, W) ``mask``'s pixels; see :func:`flip_map`."""
    m = _check_mask(mask, np.shape(ref))
    err = flip_map(pred, ref, hdr)
    return float(err.mean(dtype=np.float64) if m is None else err[m].mean(dtype=np.float64))


#: the figures :func:`score_images` writes, headline first
SCORE_NAMES = ("display_psnr", "display_ssim", "flip_ldr", "flip_hdr", "linear_psnr")
#: the ꟻLIP figures of SCORE_NAMES, with whether each is HDR-ꟻLIP
FLIP_NAMES = (("flip_ldr", False), ("flip_hdr", True))


def score_images(pred: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None,
                 with_flip: bool = True, maps: dict | None = None) -> dict[str, float]:
    """The field's figures of a linear (H, W, 3) render ``pred`` against ``ref``: display PSNR
    and SSIM (8-bit sRGB, :func:`to_display`), LDR- and HDR-ꟻLIP, linear PSNR, each on the whole
    image (``name``) and, given the subject's (H, W) mask, on its pixels (``name_subject``).
    ``with_flip=False`` leaves ꟻLIP out (about 2-3 s per megapixel each). ``maps``, a dict, receives
    the (H, W) float32 ꟻLIP error maps under "flip_ldr" and "flip_hdr" (for the report's images)."""
    da, db = to_display(pred), to_display(ref)
    masks = {"": None} if mask is None else {"": None, "_subject": _check_mask(mask, np.shape(ref))}
    out = {}
    for suffix, m in masks.items():
        out["display_psnr" + suffix] = psnr(da, db, mask=m)
        out["display_ssim" + suffix] = ssim(da, db, mask=m)
        out["linear_psnr" + suffix] = psnr(pred, ref, mask=m)
    if with_flip:
        for name, hdr in FLIP_NAMES:
            err = flip_map(pred, ref, hdr)
            if maps is not None:
                maps[name] = err
            for suffix, m in masks.items():
                out[name + suffix] = float(err.mean(dtype=np.float64) if m is None else err[m].mean(dtype=np.float64))
    return {k: out[k] for k in sorted(out, key=lambda k: (SCORE_NAMES.index(k.removesuffix("_subject")), k))}


def display_slope(linear: np.ndarray) -> np.ndarray:
    """d(sRGB encoding)/d(linear) at each value (any shape, float64): 12.92 on the linear segment
    (<= 0.0031308), (1.055 / 2.4) x^(1/2.4 - 1) above it, 0 outside [0, 1] where the display
    clips (a small change there does not move the displayed value)."""
    x = np.asarray(linear, dtype=np.float64)
    power = (1.055 / 2.4) * np.maximum(x, 0.0031308) ** (1.0 / 2.4 - 1.0)
    slope = np.where(x <= 0.0031308, 12.92, power)
    return np.where((x < 0.0) | (x > 1.0), 0.0, slope)


@functools.lru_cache(maxsize=None)
def _rounding_table() -> tuple[np.ndarray, np.ndarray]:
    """(sigma, g(sigma)) on a log grid: g(s) = E[{x}(1 - {x})], x ~ N(0, s^2), by its Fourier
    series 1/6 - sum_k exp(-2 pi^2 k^2 s^2) / (pi^2 k^2) (4000 terms)."""
    s = np.geomspace(1e-4, 4.0, 400)
    k = np.arange(1, 4001, dtype=np.float64)
    g = 1.0 / 6.0 - (np.exp(-2.0 * np.pi ** 2 * np.outer(s * s, k * k)) / (np.pi ** 2 * k * k)).sum(axis=1)
    return s, g


def rounding_excess(sigma_lsb: np.ndarray) -> np.ndarray:
    """Expected extra squared difference (in LSB^2) that rounding both a value and the value plus
    N(0, sigma^2) noise (sigma in LSB) to integers adds to sigma^2, over a uniform position on
    the grid: E[(Q(a + x) - Q(a))^2] = E[x^2] + E[{x}(1 - {x})] (Q's difference is the piecewise
    linear interpolation of n^2); 0 at sigma 0, ~ sigma sqrt(2 / pi) below 1e-4, 1/6 above 4."""
    s = np.asarray(sigma_lsb, dtype=np.float64)
    grid, g = _rounding_table()
    return np.where(s < grid[0], s * math.sqrt(2.0 / math.pi), np.interp(s, grid, g, right=1.0 / 6.0))


def display_noise_mse(ref: np.ndarray, var: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Display-space (8-bit sRGB in [0, 1]) MSE a perfect model is expected to score against a
    Monte Carlo reference ``ref`` (H, W, 3) linear with per-pixel variance ``var`` of its mean,
    over every pixel or the (H, W) ``mask``'s: the delta method's display_slope(ref)^2 var plus
    the excess of rounding both images to 8 bits (:func:`rounding_excess` of the display sigma in
    1/255 steps). The display noise ceiling is mse_to_psnr of it. First order: the noise small
    against the sRGB curve's bend."""
    m = _check_mask(mask, np.shape(ref))
    v = display_slope(ref) ** 2 * np.maximum(np.asarray(var, dtype=np.float64), 0.0)
    v = v + rounding_excess(255.0 * np.sqrt(v)) / 255.0 ** 2
    return float(np.mean(v if m is None else v[m]))


def black_image_scores(ref: np.ndarray, mask: np.ndarray | None = None, with_flip: bool = True) -> dict[str, float]:
    """:func:`score_images` of the all-black image against ``ref``: the floor any figure on a
    dark scene must be read against."""
    return score_images(np.zeros_like(np.asarray(ref, dtype=np.float64)), ref, mask, with_flip)
