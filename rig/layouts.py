"""Camera layouts: turntable rings, a Levoy-Hanrahan planar gantry, explicit views.

All poses are camera-to-world (4, 4) float64 in OpenCV axes (render.poses.look_at).
"""
from __future__ import annotations

import numpy as np

from render.camera import Camera, Intrinsics
from render.poses import look_at

from .spec import GantryLayout, IntrinsicsSpec, LayoutSpec, RingLayout, ViewLayout, view_names

__all__ = ["make_intrinsics", "ring_poses", "gantry_poses", "layout_cameras"]


def make_intrinsics(spec: IntrinsicsSpec) -> Intrinsics:
    if spec.fov_y_deg is not None:  # focal from the field of view; a given principal point is kept
        k = Intrinsics.from_fov(spec.width, spec.height, spec.fov_y_deg)
        cx, cy = spec.principal_point()
        return Intrinsics(k.width, k.height, k.fx, k.fy, cx, cy, spec.dist)
    fy = spec.fy if spec.fy is not None else spec.fx
    cx = spec.cx if spec.cx is not None else spec.width / 2
    cy = spec.cy if spec.cy is not None else spec.height / 2
    return Intrinsics(spec.width, spec.height, spec.fx, fy, cx, cy, spec.dist)


def _frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal (a, b, up) with a, b spanning the plane perpendicular to ``up``."""
    up = up / np.linalg.norm(up)
    helper = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    a = np.cross(up, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(up, a), up


def ring_poses(ring: RingLayout, up: np.ndarray) -> list[np.ndarray]:
    """``count`` poses at equal azimuth steps, counter-clockwise seen from above."""
    a, b, up = _frame(np.asarray(up, float))
    target = np.asarray(ring.target, float)
    el = np.radians(ring.elevation_deg)
    poses = []
    for k in range(ring.count):
        az = np.radians(ring.azimuth_offset_deg) + 2 * np.pi * k / ring.count
        direction = np.cos(el) * (np.cos(az) * a + np.sin(az) * b) + np.sin(el) * up
        poses.append(look_at(target + ring.distance * direction, target, up))
    return poses


def gantry_poses(g: GantryLayout, up: np.ndarray) -> list[np.ndarray]:
    """A grid of cameras in the plane through ``center`` perpendicular to center -> look_at,
    all sharing the orientation of the central camera; row-major from the top-left."""
    centre_pose = look_at(g.center, g.look_at, _unit(g.up if g.up is not None else up))
    right, down = centre_pose[:3, 0], centre_pose[:3, 1]
    us = (np.arange(g.nu) - (g.nu - 1) / 2) * (g.extent[0] / max(g.nu - 1, 1))
    vs = (np.arange(g.nv) - (g.nv - 1) / 2) * (g.extent[1] / max(g.nv - 1, 1))
    poses = []
    for v in vs:
        for u in us:
            p = centre_pose.copy()
            p[:3, 3] = centre_pose[:3, 3] + u * right + v * down
            poses.append(p)
    return poses


def layout_cameras(layouts: list[LayoutSpec], intrinsics: Intrinsics, up, prefix: str) -> list[Camera]:
    """Expand a split's layouts into named cameras (:func:`rig.spec.view_names`: a view's own name,
    else ``<prefix>_<index:03d>``). A view's or gantry's ``up`` is normalized before use, so only
    its direction matters (the spec has checked it is non-zero and not along the view)."""
    up = np.asarray(up, float)
    poses: list[np.ndarray] = []
    for layout in layouts:
        if layout.ring is not None:
            poses += ring_poses(layout.ring, up)
        elif layout.gantry is not None:
            poses += gantry_poses(layout.gantry, up)
        else:
            v: ViewLayout = layout.view
            poses.append(look_at(v.eye, v.target, _unit(v.up if v.up is not None else up)))
    return [Camera(intrinsics, pose, name) for pose, name in zip(poses, view_names(layouts, prefix), strict=True)]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)
