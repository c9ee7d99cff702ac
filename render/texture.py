"""Texture lookup shared by every renderer, so they agree texel for texel.

Convention (OpenGL's, which trimesh and pyrender follow): ``u`` runs left to right across the
image, ``v`` bottom to top; texel centres sit at ((j + 0.5) / W, 1 - (i + 0.5) / H) for image row
i, column j. Lookup is bilinear with repeat wrapping (GL_LINEAR, GL_REPEAT), in linear albedo:
texels are decoded from sRGB before filtering, as GL does for SRGB8 textures.
"""
from __future__ import annotations

import numpy as np

from .color import srgb_to_linear

__all__ = ["decode_texture", "sample_bilinear"]


def decode_texture(texture_srgb8: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 sRGB -> (H, W, 3) float32 linear albedo."""
    lut = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)
    return lut[np.asarray(texture_srgb8)]


def sample_bilinear(texture_linear: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with repeat wrapping.

    texture_linear: (H, W, C) float32. uv: (N, 2) float64 texture coordinates.
    Returns (N, C) float64.
    """
    h, w = texture_linear.shape[:2]
    x = np.asarray(uv[:, 0], dtype=np.float64) * w - 0.5
    y = (1.0 - np.asarray(uv[:, 1], dtype=np.float64)) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0 = x0.astype(np.int64) % w
    y0 = y0.astype(np.int64) % h
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    t = texture_linear
    return ((1 - fx) * (1 - fy) * t[y0, x0] + fx * (1 - fy) * t[y0, x1]
            + (1 - fx) * fy * t[y1, x0] + fx * fy * t[y1, x1])
