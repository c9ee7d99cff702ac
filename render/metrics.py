"""Image metrics through kornia: PSNR and SSIM on linear images clipped to [0, 1]."""
from __future__ import annotations

import numpy as np
import torch
import kornia.metrics

__all__ = ["psnr", "ssim", "rmse"]


def _to_tensor(img: np.ndarray) -> torch.Tensor:
    a = np.asarray(img, dtype=np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3:
        raise ValueError(f"expected (H, W) or (H, W, C) image, got {a.shape}")
    return torch.from_numpy(np.clip(a, 0.0, 1.0)).permute(2, 0, 1)[None]


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root-mean-square difference of two same-shape float arrays (unclipped)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"shape mismatch {a.shape} vs {b.shape}")
    return float(np.sqrt(np.mean((a - b) ** 2)))


def psnr(pred: np.ndarray, ref: np.ndarray, max_val: float = 1.0) -> float:
    """PSNR in dB of (H, W, C) images in [0, max_val] (kornia). Identical images give +inf."""
    if np.shape(pred) != np.shape(ref):
        raise ValueError(f"shape mismatch {np.shape(pred)} vs {np.shape(ref)}")
    mse = np.mean((np.clip(pred, 0, max_val) - np.clip(ref, 0, max_val)) ** 2)
    if mse == 0:
        return float("inf")
    return float(kornia.metrics.psnr(_to_tensor(pred / max_val), _to_tensor(ref / max_val), 1.0))


def ssim(pred: np.ndarray, ref: np.ndarray, window: int = 11) -> float:
    """Mean SSIM of (H, W, C) images in [0, 1] (kornia, Gaussian window ``window``)."""
    if np.shape(pred) != np.shape(ref):
        raise ValueError(f"shape mismatch {np.shape(pred)} vs {np.shape(ref)}")
    # kornia pads by reflection, which needs the window smaller than the image
    window = min(window, (min(np.shape(pred)[:2]) - 1) | 1)
    return float(kornia.metrics.ssim(_to_tensor(pred), _to_tensor(ref), window).mean())
