"""Image metrics: PSNR (closed form), SSIM (kornia) and RMSE, one convention for the project.

PSNR convention: PSNR = 10 log10(peak^2 / max(MSE, MSE_FLOOR x peak^2)) dB on images clipped to
[0, peak], so identical images (MSE 0) give the finite cap PSNR_MAX_DB = 100 dB, never +inf:
every metrics.json stays valid JSON (no Infinity) and means over views stay finite. An MSE
below 1e-10 of peak^2 is beyond float32 images' resolution anyway (their relative rounding is
6e-8, i.e. an MSE of ~4e-15 near 1). Validate, the slab and NeRF stages and NeRF training
(:func:`mse_to_psnr`) all use these two functions.

Every metric of identical images is finite and documented: psnr PSNR_MAX_DB, ssim 1, rmse 0.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import kornia.metrics

__all__ = ["psnr", "ssim", "rmse", "mse_to_psnr", "PSNR_MAX_DB", "MSE_FLOOR"]

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


def psnr(pred: np.ndarray, ref: np.ndarray, max_val: float = 1.0) -> float:
    """PSNR in dB of same-shape (H, W[, C]) images clipped to [0, max_val] (float64 MSE over
    every pixel and channel); identical images give PSNR_MAX_DB (see :func:`mse_to_psnr`)."""
    if np.shape(pred) != np.shape(ref):
        raise ValueError(f"shape mismatch {np.shape(pred)} vs {np.shape(ref)}")
    a = np.clip(np.asarray(pred, dtype=np.float64), 0.0, max_val)
    b = np.clip(np.asarray(ref, dtype=np.float64), 0.0, max_val)
    return mse_to_psnr(float(np.mean((a - b) ** 2)), max_val)


def ssim(pred: np.ndarray, ref: np.ndarray, window: int = 11) -> float:
    """Mean SSIM of (H, W[, C]) images clipped to [0, 1] (kornia, Gaussian window ``window``);
    images identical after clipping give exactly 1 (kornia's 1e-12 in the denominator would
    give 1 - 1e-12 / (C1 C2) = 0.99999 on flat images)."""
    if np.shape(pred) != np.shape(ref):
        raise ValueError(f"shape mismatch {np.shape(pred)} vs {np.shape(ref)}")
    a, b = _to_tensor(pred), _to_tensor(ref)
    if torch.equal(a, b):
        return 1.0
    # kornia pads by reflection, which needs the window smaller than the image
    window = min(window, (min(np.shape(pred)[:2]) - 1) | 1)
    return float(kornia.metrics.ssim(a, b, window).mean())
