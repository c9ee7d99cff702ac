"""A distorted view resampled into the ideal pinhole camera of the same K (Brown model forward).

Recon's consumers of captured pixels that project with an ideal pinhole (the slab's rebinning,
``recon.slab.rebin._Views.project``) take estimated cameras with lens distortion through
:func:`undistort_view`: the view's radiance (and z-depth, subject mask) resampled so that
pixel (i, j) holds what the ideal pinhole camera ``K`` (same fx, fy, cx, cy; ``dist`` all zero)
sees through that pixel's centre. The NeRF does not need it: its rays come from
``Camera.pixel_rays``, which inverts the distortion exactly per pixel (modelling the lens in ray
generation, no resampling).

Why the forward model and not its inverse: for the pinhole pixel centre (j + 0.5, i + 0.5) the
source position in the distorted image is closed form, ``K distort(K^-1 p)``
(:func:`render.camera.distort_normalized`), so no fixed-point inversion is involved; ``cv2.remap``
samples it (OpenCV's integer pixel centres: -0.5 at that call only, docs/architecture.md).

Conventions: pixel centres at +0.5 (COLMAP's), OpenCV/Brown ``(k1, k2, p1, p2, k3)`` on
normalized coordinates, z-depth (unchanged by distortion: the 3D point is the same, so depth and
mask are resampled with nearest-neighbour and no new values are invented at edges). A pinhole
pixel whose source falls outside the distorted image (beyond the bilinear footprint) gets
radiance 0, depth 0 (= nothing hit) and mask False: rebinning never draws from it, since a view
*sees* a point only where its depth agrees.
"""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from render.camera import Camera, Intrinsics, distort_normalized
from render.remap import INTERPOLATIONS, remap_image

__all__ = ["pinhole_of", "undistort_maps", "undistort_image", "undistort_view"]


def pinhole_of(intrinsics: Intrinsics) -> Intrinsics:
    """The same intrinsics without distortion (same size, fx, fy, cx, cy)."""
    return replace(intrinsics, dist=(0.0,) * 5)


@lru_cache(maxsize=16)
def _maps(k: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    xy = np.stack([(jj.ravel() - k.cx) / k.fx, (ii.ravel() - k.cy) / k.fy], axis=1)
    xy_d = distort_normalized(xy, k.dist)
    # source position in OpenCV's integer-centre pixel coordinates
    mx = (k.fx * xy_d[:, 0] + k.cx - 0.5).reshape(k.height, k.width)
    my = (k.fy * xy_d[:, 1] + k.cy - 0.5).reshape(k.height, k.width)
    # inside the image with its whole bilinear footprint: no black border mixed into radiance
    valid = (mx >= 0) & (mx <= k.width - 1) & (my >= 0) & (my <= k.height - 1)
    out = (mx.astype(np.float32), my.astype(np.float32), valid)
    for a in out:
        a.setflags(write=False)
    return out


def undistort_maps(intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(map_x, map_y, valid)`` for ``cv2.remap`` from the distorted image to its pinhole one.

    For pinhole pixel (i, j), ``(map_x[i, j], map_y[i, j])`` is where its ray meets the distorted
    image, in OpenCV's integer-centre coordinates; ``valid[i, j]`` is False when that is outside
    the image. Returns (H, W) float32, float32 and bool, read-only, cached per intrinsics.
    """
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"expected render.camera.Intrinsics, got {type(intrinsics).__name__}")
    return _maps(intrinsics)


def undistort_image(image: np.ndarray, intrinsics: Intrinsics, interpolation: str = "linear") -> np.ndarray:
    """Resample ``image`` seen through ``intrinsics`` (with distortion) into its pinhole camera.

    image: (H, W) or (H, W, C) array (float32, float64, uint8 or bool) of the intrinsics' size.
    interpolation: ``"linear"`` for radiance, ``"nearest"`` for z-depth and masks. Returns the
    same shape and dtype; pixels outside the distorted image are 0 (False). An exact copy when
    the intrinsics have no distortion.
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {sorted(INTERPOLATIONS)}, got {interpolation!r}")
    a = np.asarray(image)
    k = intrinsics
    if a.ndim not in (2, 3) or a.shape[:2] != (k.height, k.width):
        raise ValueError(f"image shape {a.shape} does not match the intrinsics' {k.height}x{k.width}")
    if not k.has_distortion:
        return a.copy()
    mx, my, valid = undistort_maps(k)
    out = remap_image(a, mx, my, interpolation)
    out[~valid] = 0
    return out


def undistort_view(camera: Camera, rgb: np.ndarray, depth: np.ndarray | None = None,
                   mask: np.ndarray | None = None) -> tuple[Camera, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A view through a distorting lens as its ideal pinhole view.

    camera: the view's camera (intrinsics with ``dist``); rgb: (H, W, 3) linear radiance; depth:
    (H, W) z-depth (0 = nothing) or None; mask: (H, W) bool subject mask or None. Returns
    ``(pinhole camera (same pose, name, K; dist zero), rgb, depth, mask)`` at the same size, dtypes
    kept; pixels whose ray leaves the distorted image get rgb 0, depth 0, mask False. A camera
    without distortion returns its inputs unchanged (no copy).
    """
    k = camera.intrinsics
    if not k.has_distortion:
        return camera, rgb, depth, mask
    pin = Camera(pinhole_of(k), camera.cam_to_world, camera.name)
    out_rgb = undistort_image(rgb, k, "linear")
    out_depth = None if depth is None else undistort_image(depth, k, "nearest")
    out_mask = None if mask is None else undistort_image(mask, k, "nearest")
    return pin, out_rgb, out_depth, out_mask
