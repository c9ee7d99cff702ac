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
perceptual error: Andersson et al. 2020, LDR; 2021, HDR) is scored by a torch port of NVIDIA's own
code (:func:`flip_map`; its C++ ``flip-evaluator`` package is kept as the oracle it is tested
against, and selectable): LDR-ꟻLIP on the display images, HDR-ꟻLIP on linear radiance. :func:`score_images` scores a pair on the whole image
and, given the subject's mask, on the subject's pixels, and :func:`black_image_scores` gives the
all-black image's scores beside them, so an empty background cannot carry a figure.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import torch
import torch.nn.functional as F
import kornia.metrics

from .color import linear_to_srgb

__all__ = ["psnr", "ssim", "rmse", "flip", "mse_to_psnr", "PSNR_MAX_DB", "MSE_FLOOR", "to_display", "flip_map",
           "score_images", "black_image_scores", "SCORE_NAMES", "FLIP_NAMES", "display_slope", "display_noise_mse",
           "rounding_excess", "flip_means", "score_order", "FLIP_PPD", "FLIP_IMPLEMENTATIONS", "flip_exposure_schedule"]

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


# ----------------------------------------------------------------------------------------- ꟻLIP
# A port of NVIDIA's ꟻLIP (NVlabs/flip, BSD-3-Clause: the PyTorch version's formulas with the C++
# flip_evaluator's separable filters, float32 constants and HDR exposure schedule), vectorized in
# torch: both images of a pair and every HDR exposure go through the same batched convolutions.
# It gives flip_evaluator's maps to float32 rounding (tests/render/test_metrics.py compares them).

#: ꟻLIP's observer in pixels per degree: 0.7 m from a 0.7 m wide, 3840-pixel display (its default;
#: float32 as flip_evaluator computes it: 67.0206)
FLIP_PPD = float(np.float32(0.7) * (np.float32(3840.0) / np.float32(0.7)) * np.float32(math.pi / 180.0))
# ꟻLIP's constants (Andersson et al. 2020): colour exponent q_c, redistribution point p_c and its
# target p_t, feature exponent q_f, the edge detector's peak-to-trough width w in degrees
_FLIP_QC, _FLIP_PC, _FLIP_PT, _FLIP_QF, _FLIP_W = 0.7, 0.4, 0.95, 0.5, 0.082
# contrast sensitivity functions as Gaussians a sqrt(pi / b) exp(-pi^2 x^2 / b), x in degrees:
# achromatic, red-green, and blue-yellow (a sum of two)
_CSF_A, _CSF_RG, _CSF_BY = (1.0, 0.0047), (1.0, 0.0053), ((34.1, 0.04), (13.5, 0.025))
_D65 = np.array([0.950428545, 1.0, 1.088900371])
_LINRGB_TO_XYZ = np.array([[10135552 / 24577794, 8788810 / 24577794, 4435075 / 24577794],
                           [2613072 / 12288897, 8788810 / 12288897, 887015 / 12288897],
                           [1425312 / 73733382, 8788810 / 73733382, 70074185 / 73733382]])
_XYZ_TO_LINRGB = np.array([[3.241003275, -1.537398934, -0.498615861],
                           [-0.969224334, 1.875930071, 0.041554224],
                           [0.055639423, -0.204011202, 1.057148933]])
# HDR-ꟻLIP's tone mapper: Narkowicz's ACES fit (0.6 pre-exposure cancelled),
# (c0 x^2 + c1 x + c2) / (c3 x^2 + c4 x + c5), coefficients as flip_evaluator's float32 constants
_ACES = tuple(float(c) for c in (np.float32(0.6) * np.float32(0.6) * np.float32(2.51), np.float32(0.6) * np.float32(0.03),
                                 0.0, np.float32(0.6) * np.float32(0.6) * np.float32(2.43),
                                 np.float32(0.6) * np.float32(0.59), np.float32(0.14)))
#: flip_map's implementations: this module's torch port, or NVIDIA's C++ flip_evaluator (the test oracle)
FLIP_IMPLEMENTATIONS = ("torch", "flip_evaluator")


@functools.lru_cache(maxsize=None)
def _flip_filters(ppd: float) -> tuple[np.ndarray, np.ndarray, int]:
    """ꟻLIP's 1-D filter factors at ``ppd`` pixels per degree, zero-padded to one radius r (the
    CSFs' ceil(3 sqrt(b_max / (2 pi^2)) ppd) = 10 at 67 ppd; the feature filters' ceil(3 sd) = 9):
    ``csf`` (4, 2r+1) float64: achromatic, red-green, and the blue-yellow kernel's two Gaussians
    (that kernel is a sum of two rank-one terms: each factor carries the square root of its
    Gaussian's amplitude, the pair normalized together so the 2-D kernel sums to 1, as
    flip_evaluator separates it); ``feature`` (3, 2r+1): a Gaussian of sd = w ppd / 2 (sum 1),
    its first and second derivatives (positive weights summing to 1, negative to -1)."""
    r_csf = int(math.ceil(3.0 * math.sqrt(max(_CSF_A[1], _CSF_RG[1], _CSF_BY[0][1], _CSF_BY[1][1])
                                          / (2.0 * math.pi ** 2)) * ppd))
    sd = 0.5 * _FLIP_W * ppd
    r_feature = int(math.ceil(3.0 * sd))
    r = max(r_csf, r_feature)
    x2 = (np.arange(-r_csf, r_csf + 1) / ppd) ** 2

    def gaussian(a: float, b: float, amplitude_root: bool = False) -> np.ndarray:
        amplitude = a * math.sqrt(math.pi / b)
        return (math.sqrt(amplitude) if amplitude_root else amplitude) * np.exp(-math.pi ** 2 * x2 / b)

    achromatic, red_green = gaussian(*_CSF_A), gaussian(*_CSF_RG)
    by1, by2 = gaussian(*_CSF_BY[0], True), gaussian(*_CSF_BY[1], True)
    by_norm = math.hypot(by1.sum(), by2.sum())
    csf = np.zeros((4, 2 * r + 1))
    csf[:, r - r_csf:r + r_csf + 1] = [achromatic / achromatic.sum(), red_green / red_green.sum(),
                                       by1 / by_norm, by2 / by_norm]
    j = np.arange(-r_feature, r_feature + 1, dtype=np.float64)
    g = np.exp(-j * j / (2.0 * sd * sd))

    def signed_unit(k: np.ndarray) -> np.ndarray:
        return np.where(k > 0, k / k[k > 0].sum(), k / -k[k < 0].sum())

    feature = np.zeros((3, 2 * r + 1))
    feature[:, r - r_feature:r + r_feature + 1] = [g / g.sum(), signed_unit(-j * g), signed_unit((j * j / (sd * sd) - 1.0) * g)]
    return csf, feature, r


@functools.lru_cache(maxsize=None)
def _flip_convolutions(ppd: float) -> dict:
    """ꟻLIP's filtering as four float32 conv2d weight sets (the colour transforms folded into the
    colour filters, which are linear): linear RGB -> the x-filtered opponent channels (Y, Cx and
    Cz twice, ``color_x`` (4, 3, 1, k) + ``color_x_bias``), those -> filtered linear RGB
    (``color_y`` (3, 4, k, 1) + ``color_y_bias``); the luminance -> its x-filtered Gaussian,
    first and second derivative (``feature_x`` (3, 1, 1, k)), those -> (d/dx, d2/dx2, d/dy,
    d2/dy2) (``feature_y`` (4, 3, k, 1)); ``r`` the padding every filter needs."""
    csf, feature, r = _flip_filters(ppd)
    k = 2 * r + 1
    rgb_to_ycxcz = np.array([[0.0, 116.0, 0.0], [500.0, -500.0, 0.0], [0.0, 200.0, -200.0]]) @ np.diag(1.0 / _D65) \
        @ _LINRGB_TO_XYZ  # Y = 116 y - 16, Cx = 500 (x - y), Cz = 200 (y - z) of D65-normalized XYZ
    component = (0, 1, 2, 2)  # the opponent channel each CSF factor filters
    color_x = np.stack([np.outer(rgb_to_ycxcz[c], csf[i]) for i, c in enumerate(component)])
    color_x_bias = np.array([-16.0 * csf[0].sum(), 0.0, 0.0, 0.0])
    ycxcz_to_xyz = np.array([[1 / 116, 1 / 500, 0.0], [1 / 116, 0.0, 0.0], [1 / 116, 0.0, -1 / 200]])
    to_rgb = _XYZ_TO_LINRGB @ np.diag(_D65)
    ycxcz_to_rgb = to_rgb @ ycxcz_to_xyz
    color_y = np.stack([np.stack([ycxcz_to_rgb[o, c] * csf[i] for i, c in enumerate(component)]) for o in range(3)])
    feature_y = np.zeros((4, 3, k))
    # x-filtered (Gaussian, d/dx, d2/dx2) -> d/dx and d2/dx2 through the Gaussian in y; the
    # Gaussian through d/dy and d2/dy2
    feature_y[0, 1], feature_y[1, 2], feature_y[2, 0], feature_y[3, 0] = feature[0], feature[0], feature[1], feature[2]

    def f32(a: np.ndarray, *shape: int) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, np.float32)).reshape(shape)

    return {"color_x": f32(color_x, 4, 3, 1, k), "color_x_bias": f32(color_x_bias, 4),
            "color_y": f32(color_y, 3, 4, k, 1), "color_y_bias": f32(to_rgb @ np.full(3, 16.0 / 116.0), 3),
            "feature_x": f32(feature, 3, 1, 1, k), "feature_y": f32(feature_y, 4, 3, k, 1),
            "luminance": f32(_LINRGB_TO_XYZ[1], 1, 3, 1, 1), "to_lab": f32(np.diag(1.0 / _D65) @ _LINRGB_TO_XYZ, 3, 3),
            "r": r}


def _hunt_lab(rgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Hunt-adjusted CIE L*a*b* (D65; a and b scaled by L / 100) of linear RGB (M, 3, H, W):
    three (M, H, W) tensors."""
    m, _, h, w = rgb.shape
    t = torch.matmul(_flip_convolutions(FLIP_PPD)["to_lab"].to(rgb.device), rgb.reshape(m, 3, h * w))
    delta3 = (6.0 / 29.0) ** 3
    f = torch.where(t > delta3, t.clamp(min=delta3).pow(1.0 / 3.0), t * (1.0 / (3.0 * (6.0 / 29.0) ** 2)) + 4.0 / 29.0)
    lightness = 116.0 * f[:, 1] - 16.0
    a = (f[:, 0] - f[:, 1]).mul_(5.0 * lightness)  # 500 (fx - fy) x L / 100
    b = (f[:, 1] - f[:, 2]).mul_(2.0 * lightness)  # 200 (fy - fz) x L / 100
    return lightness.view(m, h, w), a.view(m, h, w), b.view(m, h, w)


@functools.lru_cache(maxsize=None)
def _flip_cmax() -> float:
    """ꟻLIP's largest colour difference: HyAB^q_c of pure green against pure blue, Hunt-adjusted."""
    lightness, a, b = _hunt_lab(torch.tensor([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).view(2, 3, 1, 1))
    return float((abs(lightness[0] - lightness[1]) + torch.hypot(a[0] - a[1], b[0] - b[1])) ** _FLIP_QC)


def _ldr_flip_pairs(ref: torch.Tensor, test: torch.Tensor, ppd: float = FLIP_PPD) -> torch.Tensor:
    """LDR-ꟻLIP error maps (N, H, W) float32 of N pairs of linear RGB images (N, 3, H, W) in
    [0, 1]: the colour difference (CSF-filtered, clamped to the RGB cube, Hunt-adjusted HyAB^q_c,
    redistributed to [0, 1]) raised to 1 - the feature difference (edges and points of the
    luminance). Edges are replicated (flip_evaluator's clamp to the border)."""
    conv = {k: (v.to(ref.device) if isinstance(v, torch.Tensor) else v) for k, v in _flip_convolutions(ppd).items()}
    r, n = conv["r"], ref.shape[0]
    # pointwise transforms commute with replicated borders: pad once, then filter with no padding
    both = F.pad(torch.cat([ref, test], 0), (r, r, r, r), mode="replicate").contiguous(memory_format=torch.channels_last)
    rgb = F.conv2d(F.conv2d(both, conv["color_x"], conv["color_x_bias"]), conv["color_y"], conv["color_y_bias"])
    rgb = rgb.contiguous().clamp_(0.0, 1.0)
    luminance = (both * conv["luminance"]).sum(1, keepdim=True)  # ꟻLIP's (Y + 16) / 116 = CIE y
    del both
    features = F.conv2d(F.conv2d(luminance, conv["feature_x"]), conv["feature_y"]).contiguous()
    del luminance
    lightness, a, b = _hunt_lab(rgb)
    del rgb
    hyab = (lightness[:n] - lightness[n:]).abs_().add_(torch.hypot(a[:n] - a[n:], b[:n] - b[n:]))
    cmax = _flip_cmax()
    pccmax = _FLIP_PC * cmax
    powered = hyab.pow_(_FLIP_QC)
    color = torch.where(powered < pccmax, powered * (_FLIP_PT / pccmax),
                        (powered - pccmax).mul_((1.0 - _FLIP_PT) / (cmax - pccmax)).add_(_FLIP_PT))
    edge = torch.hypot(features[:, 0], features[:, 2])
    point = torch.hypot(features[:, 1], features[:, 3])
    feature = torch.maximum((edge[:n] - edge[n:]).abs_(), (point[:n] - point[n:]).abs_())
    return color.pow_(feature.mul_(1.0 / math.sqrt(2.0)).pow_(_FLIP_QF).neg_().add_(1.0))


def _aces(img: torch.Tensor) -> torch.Tensor:
    """HDR-ꟻLIP's tone mapper of exposed linear radiance, clamped to [0, 1]. The input is capped
    at 1e4, where the curve is already above 1 (it crosses 1 near 17), so the cap changes no
    value and the squares stay finite (flip_evaluator's overflow past ~1.8e19 to inf / inf = NaN,
    which its clamp turns into 0: such a pixel is black there and white here)."""
    x = img.clamp(max=1e4)
    c0, c1, c2, c3, c4, c5 = _ACES
    numerator = (x * c0).add_(c1).mul_(x).add_(c2)
    return numerator.div_((x * c3).add_(c4).mul_(x).add_(c5)).clamp_(0.0, 1.0)


def flip_exposure_schedule(start: float, stop: float) -> np.ndarray:
    """HDR-ꟻLIP's exposures (float32, as flip_evaluator computes them): max(2, ceil(stop -
    start)) equally spaced stops from ``start`` to ``stop``."""
    start32, stop32 = np.float32(start), np.float32(stop)
    count = int(max(2.0, math.ceil(float(stop32 - start32))))
    step = np.float32((stop32 - start32) / np.float32(count - 1))
    return np.array([start32 + np.float32(i) * step for i in range(count)], np.float32)


def _flip_map_torch(pred: np.ndarray, ref: np.ndarray, hdr: bool, exposures: dict | None,
                    device: str | torch.device, exposure_batch: int = 3) -> np.ndarray:
    """(H, W) float32 ꟻLIP map by the torch port: LDR of display (sRGB-encoded) (H, W, 3) images,
    HDR of linear ones over ``exposures`` (startExposure, stopExposure), ``exposure_batch``
    exposures (both images each) per batched pass (memory: ~0.3 GB per exposure at 1280x960)."""
    dev = torch.device(device)
    with torch.no_grad():
        test = torch.from_numpy(np.ascontiguousarray(pred, np.float32)).permute(2, 0, 1)[None].to(dev)
        reference = torch.from_numpy(np.ascontiguousarray(ref, np.float32)).permute(2, 0, 1)[None].to(dev)
        if not hdr:
            def srgb_to_linear(s: torch.Tensor) -> torch.Tensor:
                return torch.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4).clamp_(0.0, 1.0)
            return _ldr_flip_pairs(srgb_to_linear(reference), srgb_to_linear(test))[0].cpu().numpy()
        stops = flip_exposure_schedule(exposures["startExposure"], exposures["stopExposure"])
        worst = None
        for i in range(0, len(stops), exposure_batch):
            scale = torch.from_numpy(np.exp2(stops[i:i + exposure_batch])).to(dev).view(-1, 1, 1, 1)
            err = _ldr_flip_pairs(_aces(reference * scale), _aces(test * scale)).amax(0)
            worst = err if worst is None else torch.maximum(worst, err)
        return worst.cpu().numpy()


@functools.lru_cache(maxsize=None)
def _flip_x_max() -> float:
    """HDR-ꟻLIP's tone-mapper point x_max: the larger root of ACES(x) = t, t = 0.85, solved in
    float32 as flip_evaluator solves it (its start exposure of a unit-luminance image is
    log2(x_max))."""
    f32 = np.float32
    t = f32(0.85)
    c = [f32(k) for k in _ACES]
    a, b, c0 = c[0] - t * c[3], c[1] - t * c[4], c[2] - t * c[5]
    half = f32(-0.5) * (b / a)
    return float(half + np.sqrt(half * half - c0 / a))


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


def flip_map(pred: np.ndarray, ref: np.ndarray, hdr: bool = False, implementation: str = "torch",
             device: str | torch.device = "cpu") -> np.ndarray:
    """ꟻLIP error map (H, W) float32 in [0, 1] of linear (H, W, 3) images: LDR-ꟻLIP of their
    :func:`to_display` images, or (``hdr``) HDR-ꟻLIP of the linear radiance (negative values
    clipped to 0) with the exposure range of :func:`_hdr_exposures`. 67 pixels per degree
    (ꟻLIP's default: a 0.7 m viewing distance on a 0.7 m wide 4K display). ``implementation``:
    "torch" (this module's port, on ``device``; ~2-3x faster than flip_evaluator on 2 cores) or
    "flip_evaluator" (NVIDIA's C++ package, the oracle; CPU only)."""
    if implementation not in FLIP_IMPLEMENTATIONS:
        raise ValueError(f"ꟻLIP implementation must be one of {FLIP_IMPLEMENTATIONS}, got {implementation!r}")
    if np.shape(pred) != np.shape(ref) or np.ndim(ref) != 3 or np.shape(ref)[2] != 3:
        raise ValueError(f"ꟻLIP needs two (H, W, 3) images, got {np.shape(pred)} and {np.shape(ref)}")
    a = np.asarray(pred, dtype=np.float64)
    b = np.asarray(ref, dtype=np.float64)
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("ꟻLIP of an image with NaN or Inf")
    if hdr:
        a, b = np.maximum(a, 0.0), np.maximum(b, 0.0)
        exposures = _hdr_exposures(b, a)
    else:
        a, b, exposures = to_display(a), to_display(b), None
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    if implementation == "torch":
        err = _flip_map_torch(a32, b32, hdr, exposures, device)
    else:
        import flip_evaluator
        err, _, _ = flip_evaluator.evaluate(b32, a32, "HDR" if hdr else "LDR", applyMagma=False,
                                            **({"parameters": exposures} if hdr else {}))
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


def flip_means(maps: dict[str, np.ndarray], mask: np.ndarray | None = None) -> dict[str, float]:
    """Mean ꟻLIP error (float64) of each (H, W) map in ``maps`` over every pixel (``name``) and,
    given a (H, W) bool ``mask``, over its pixels (``name_subject``). The mask must select a pixel
    (the caller checks, as :func:`score_images` does through ``_check_mask``)."""
    out = {}
    for name, err in maps.items():
        out[name] = float(err.mean(dtype=np.float64))
        if mask is not None:
            out[name + "_subject"] = float(err[mask].mean(dtype=np.float64))
    return out


def score_order(scores: dict) -> dict:
    """``scores`` with the figures of :data:`SCORE_NAMES` first in its order (headline first, each
    ``name_subject`` after ``name``), then every other key in its own order."""
    head = sorted((k for k in scores if k.removesuffix("_subject") in SCORE_NAMES),
                  key=lambda k: (SCORE_NAMES.index(k.removesuffix("_subject")), k))
    return {**{k: scores[k] for k in head}, **{k: v for k, v in scores.items() if k not in head}}


def score_images(pred: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None,
                 with_flip: bool = True, maps: dict | None = None) -> dict[str, float]:
    """The field's figures of a linear (H, W, 3) render ``pred`` against ``ref``: display PSNR
    and SSIM (8-bit sRGB, :func:`to_display`), LDR- and HDR-ꟻLIP, linear PSNR, each on the whole
    image (``name``) and, given the subject's (H, W) mask, on its pixels (``name_subject``),
    in :func:`score_order`. ``with_flip=False`` leaves ꟻLIP out (about 1 s per megapixel each).
    ``maps``, a dict, receives the (H, W) float32 ꟻLIP error maps under "flip_ldr" and
    "flip_hdr" (for the report's images)."""
    da, db = to_display(pred), to_display(ref)
    subject = None if mask is None else _check_mask(mask, np.shape(ref))
    masks = {"": None} if subject is None else {"": None, "_subject": subject}
    out = {}
    for suffix, m in masks.items():
        out["display_psnr" + suffix] = psnr(da, db, mask=m)
        out["display_ssim" + suffix] = ssim(da, db, mask=m)
        out["linear_psnr" + suffix] = psnr(pred, ref, mask=m)
    if with_flip:
        errs = {name: flip_map(pred, ref, hdr) for name, hdr in FLIP_NAMES}
        if maps is not None:
            maps.update(errs)
        out.update(flip_means(errs, subject))
    return score_order(out)


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
