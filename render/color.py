"""sRGB transfer functions (IEC 61966-2-1). Radiance is linear; sRGB exists only in previews."""
from __future__ import annotations

import numpy as np

__all__ = ["srgb_to_linear", "linear_to_srgb", "to_srgb8"]


def srgb_to_linear(c):
    """sRGB-encoded values in [0, 1] (any shape) -> linear, float64."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    """Linear values (any shape, clipped to [0, 1]) -> sRGB-encoded in [0, 1], float64."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    flat = c.reshape(-1)
    out = 12.92 * flat
    # the power only where it applies: a dark scene's background (most pixels) skips it, 2x faster
    bright = flat > 0.0031308
    out[bright] = 1.055 * flat[bright] ** (1 / 2.4) - 0.055
    return out.reshape(c.shape)


def to_srgb8(linear, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance (H, W, 3) -> (H, W, 3) uint8 sRGB preview after scaling by ``exposure``."""
    return np.round(linear_to_srgb(np.asarray(linear) * exposure) * 255.0).astype(np.uint8)
