"""Resampling an image through per-pixel source maps (``cv2.remap``), the one routine the sensor's
lens distortion (rig/sensor.py) and the views' undistortion (recon/undistort.py) share."""
from __future__ import annotations

import numpy as np

__all__ = ["remap_image", "INTERPOLATIONS"]

#: interpolation names: "linear" for radiance, "nearest" for depth and masks (no new values)
INTERPOLATIONS = ("linear", "nearest")


def remap_image(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, interpolation: str = "linear") -> np.ndarray:
    """``out[i, j] = image(map_y[i, j], map_x[i, j])`` (pixel coordinates, OpenCV's: centre of
    the top-left pixel at 0, 0), 0 (False) where the source lies outside the image.

    image: (H, W) or (H, W, C) array (float32, float64, uint8, uint16 or bool), any C (OpenCV
    interpolates at most 4 channels at once: more are remapped one by one). map_x, map_y:
    (H', W') float32. Returns (H', W'[, C]) of the image's dtype. Bilinear weights in
    ``cv2.remap`` are quantized to 1/32 px.
    """
    import cv2  # here, not at import: the stages that load this module start without OpenCV

    flags = {"linear": cv2.INTER_LINEAR, "nearest": cv2.INTER_NEAREST}
    if interpolation not in flags:
        raise ValueError(f"interpolation must be one of {sorted(flags)}, got {interpolation!r}")
    a = np.asarray(image)
    src = a.view(np.uint8) if a.dtype == np.bool_ else a
    flag = flags[interpolation]

    def one(s: np.ndarray) -> np.ndarray:
        out = cv2.remap(np.ascontiguousarray(s), map_x, map_y, flag, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return out.reshape(map_x.shape + s.shape[2:])  # cv2 drops a trailing channel axis of size 1

    out = np.stack([one(src[..., c]) for c in range(src.shape[2])], axis=-1) if src.ndim == 3 and src.shape[2] > 4 \
        else one(src)
    return out.view(np.bool_) if a.dtype == np.bool_ else out
