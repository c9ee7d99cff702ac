"""Fixtures for the rig's tests: tiny scenes built from render.scene types, exact ray casts.

Helpers reach tests through the ``geo`` fixture (several test folders have a conftest.py, so
``import conftest`` would be ambiguous).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from render.camera import Camera, Intrinsics
from render.poses import look_at


def quad_mesh(x0, x1, y0, y1, z=0.0, uv=None) -> trimesh.Trimesh:
    """Axis-aligned rectangle in the plane z = ``z``, normal +z, as two triangles.

    uv: optional (4, 2) texture coordinates of the corners (x0,y0), (x1,y0), (x1,y1), (x0,y1).
    """
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=np.float64)
    visual = None if uv is None else trimesh.visual.TextureVisuals(uv=np.asarray(uv, dtype=np.float64))
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], visual=visual, process=False)


def sphere_mesh(center, radius, subdivisions=4) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m.apply_translation(center)
    return m


def box_mesh(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def camera_at(eye, target, width=160, height=120, fov_y=50.0, up=(0, 0, 1), **intrinsics) -> Camera:
    """Camera (OpenCV axes) at ``eye`` looking at ``target``; ``intrinsics`` override fx, fy, cx, cy."""
    k = Intrinsics.from_fov(width, height, fov_y)
    if intrinsics:
        k = Intrinsics(width, height, intrinsics.get("fx", k.fx), intrinsics.get("fy", k.fy),
                       intrinsics.get("cx", k.cx), intrinsics.get("cy", k.cy), intrinsics.get("dist", k.dist))
    return Camera(k, look_at(eye, target, up))


# -- exact ray casts (vectorized over pixel rays) ---------------------------------------------

def ray_plane_z(origins, dirs, z=0.0):
    """Ray parameter t where rays meet the plane z = ``z`` (inf when parallel or behind)."""
    dz = dirs[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (z - origins[:, 2]) / dz
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def ray_box(origins, dirs, lo, hi):
    """Slab test: (t_enter, hit) for rays against the box [lo, hi]; hit requires t_exit > max(t_enter, 0)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        t0 = (lo - origins) * inv
        t1 = (hi - origins) * inv
    t0 = np.where(np.isnan(t0), -np.inf, t0)
    t1 = np.where(np.isnan(t1), np.inf, t1)
    tmin = np.minimum(t0, t1).max(axis=1)
    tmax = np.maximum(t0, t1).min(axis=1)
    return tmin, tmax > np.maximum(tmin, 0.0)


def ray_sphere(origins, dirs, center, radius):
    """Whether unit-direction rays hit the sphere."""
    oc = origins - np.asarray(center, float)
    b = np.einsum("ij,ij->i", oc, dirs)
    c = np.einsum("ij,ij->i", oc, oc) - radius * radius
    disc = b * b - c
    return (disc >= 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 0)


@pytest.fixture
def geo():
    """Mesh builders, cameras and exact ray casts: geo.quad_mesh, geo.sphere_mesh, geo.box_mesh,
    geo.camera_at, geo.ray_plane_z, geo.ray_box, geo.ray_sphere."""
    return SimpleNamespace(quad_mesh=quad_mesh, sphere_mesh=sphere_mesh, box_mesh=box_mesh, camera_at=camera_at,
                           ray_plane_z=ray_plane_z, ray_box=ray_box, ray_sphere=ray_sphere)


@pytest.fixture
def render_scene():
    """render_scene(scene, camera, **renderer_kwargs) -> RasterFrame; renderers closed at teardown."""
    from rig.raster import RasterRenderer

    renderers = []

    def _render(scene, camera, **kwargs):
        k = camera.intrinsics
        r = RasterRenderer(scene, k.width, k.height, **kwargs)
        renderers.append(r)
        return r.render(camera)

    yield _render
    for r in renderers:
        r.close()
