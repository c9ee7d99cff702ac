"""First-hit buffers through Embree: z-depth and subject mask at pixel centres.

What a path-traced capture writes beside its radiance, matching the rasterizer's outputs:
depth is z-depth along the optical axis (0 where no surface), never ray length.
"""
from __future__ import annotations

import numpy as np

from .accel import Accel
from .camera import Camera
from .scene import Scene

__all__ = ["first_hit_buffers"]


def first_hit_buffers(scene: Scene, camera: Camera, accel: Accel | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Depth and mask of ``camera``'s view of ``scene``, one ray per pixel centre.

    Returns ``(depth (H, W) float32 z-depth, 0 = miss; mask (H, W) bool, pixels whose first hit
    belongs to an object with is_subject)``.
    """
    k = camera.intrinsics
    own = accel is None
    accel = accel or Accel(scene)
    try:
        origins, dirs = camera.pixel_rays()
        hits = accel.intersect(origins, dirs)
    finally:
        if own:
            accel.close()
    hit = hits.tri >= 0
    axis = camera.cam_to_world[:3, 2]
    depth = np.where(hit, hits.t, 0.0) * (dirs @ axis)  # t is inf on a miss: select before multiplying
    subject = np.array([o.is_subject for o in scene.objects] + [False])
    obj = np.full(len(hits.tri), -1, dtype=np.int64)
    obj[hit] = accel.geometry.obj[hits.tri[hit]]
    mask = subject[obj]  # index -1 (miss) picks the trailing False
    return depth.reshape(k.height, k.width).astype(np.float32), mask.reshape(k.height, k.width)
