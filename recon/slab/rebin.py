"""Rebinning calibrated captures into light slabs through a depth proxy.

Each slab ray (u, v, s, t) is filled from the captured views that saw it, as the Lumigraph
(Gortler et al. 1996) and the unstructured lumigraph (Buehler et al. 2001) do:

1. Depth proxy: the views' z-depth maps are back-projected into one point cloud (pixels on a
   depth discontinuity are dropped: their depth mixes two surfaces), thinned on a voxel grid,
   and z-buffered into every uv sample's sheared camera, so each slab ray gets the distance
   ``z`` (along ``forward``, from the uv plane) of the first surface point it meets, or 0. Single
   interior holes of the splat are closed from their neighbours.
2. Blending: the surface point P of a ray is projected into the ``candidates`` views whose
   direction to P is closest to the ray's; a view *sees* P when its depth map agrees with P's
   depth within ``depth_tolerance``. The ``cameras_per_ray`` best visible views are blended with
   the unstructured lumigraph's angular weights w = (1 - a / a_k) / a (a: angle between the
   ray and the view's ray to P, a_k: the next-best angle), sampled bilinearly.

Coverage = filled rays / rays that hit the proxy; rays that hit nothing or that no view saw get
the background (and depth 0 when they hit nothing).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from render.camera import Camera
from render.lightfield import LightSlab, SlabGeometry, create_slab_arrays, write_slab_index

from .rebin_kernels import blend_rays, splat_depth_images

__all__ = ["SourceView", "RebinConfig", "RebinStats", "point_cloud", "splat_depth", "rebin_slabs"]


@dataclass
class SourceView:
    """A calibrated view the rebinning draws rays from (a capture's train view, not
    :class:`rig.capture.CapturedView`, which recon never sees): ``rgb`` (H, W, 3) float32 linear, ``depth`` (H, W) float32 z-depth
    (0 = nothing), camera-to-world OpenCV pose in ``camera``."""

    camera: Camera
    rgb: np.ndarray
    depth: np.ndarray


@dataclass(frozen=True)
class RebinConfig:
    """cameras_per_ray: views blended per ray (k of the unstructured lumigraph); candidates: views
    tested for visibility per ray; depth_tolerance: relative z agreement for visibility; voxel:
    point-cloud grid spacing in units of the finest st sample spacing; edge_jump: relative
    depth step that marks a pixel as a discontinuity."""

    cameras_per_ray: int = 3
    candidates: int = 8
    depth_tolerance: float = 0.01
    voxel: float = 0.4
    edge_jump: float = 0.02

    def __post_init__(self):
        if not (1 <= self.cameras_per_ray <= self.candidates) or self.depth_tolerance <= 0 or self.voxel <= 0:
            raise ValueError(f"bad rebinning config {self}")


@dataclass
class RebinStats:
    """Ray counts per slab name: all rays, rays that hit the proxy, rays filled from a view."""

    rays: dict[str, int] = field(default_factory=dict)
    surface: dict[str, int] = field(default_factory=dict)
    filled: dict[str, int] = field(default_factory=dict)

    @property
    def coverage(self) -> float:
        """Fraction of slab rays that hit the proxy and got radiance from at least one view."""
        s = sum(self.surface.values())
        return float(sum(self.filled.values()) / s) if s else 0.0

    @property
    def surface_fraction(self) -> float:
        n = sum(self.rays.values())
        return float(sum(self.surface.values()) / n) if n else 0.0

    def to_dict(self) -> dict:
        return {"coverage": self.coverage, "surface_fraction": self.surface_fraction,
                "per_slab": {k: {"rays": self.rays[k], "surface_rays": self.surface[k], "filled_rays": self.filled[k],
                                 "coverage": self.filled[k] / self.surface[k] if self.surface[k] else 0.0}
                             for k in self.rays}}


def _check_views(views: Sequence[SourceView]) -> None:
    if not views:
        raise ValueError("rebinning needs at least one captured view")
    shapes = {(v.camera.intrinsics.height, v.camera.intrinsics.width) for v in views}
    if len(shapes) != 1:
        raise ValueError(f"captured views must share one image size, got {sorted(shapes)}")
    h, w = shapes.pop()
    for v in views:
        if v.rgb.shape != (h, w, 3) or v.depth.shape != (h, w):
            raise ValueError(f"view {v.camera.name!r}: rgb {v.rgb.shape} / depth {v.depth.shape} do not match {w}x{h}")
        if not (np.all(np.isfinite(v.rgb)) and np.all(np.isfinite(v.depth))):
            raise ValueError(f"view {v.camera.name!r}: non-finite pixels")


def _edge_free(depth: np.ndarray, jump: float) -> np.ndarray:
    """(H, W) bool: pixels with depth whose 4-neighbours all have depth within ``jump`` relative."""
    ok = depth > 0
    z = np.pad(depth, 1, mode="edge")
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        n = z[dy:dy + depth.shape[0], dx:dx + depth.shape[1]]
        ok &= (n > 0) & (np.abs(n - depth) <= jump * depth)
    return ok


def point_cloud(views: Sequence[SourceView], voxel: float, edge_jump: float = 0.02) -> np.ndarray:
    """(P, 3) float64 world surface points from the views' depth maps, one per occupied voxel."""
    pts = []
    for v in views:
        ok = _edge_free(np.asarray(v.depth, np.float64), edge_jump)
        ii, jj = np.nonzero(ok)
        if len(ii) == 0:
            continue
        o, d = v.camera.pixel_rays(np.stack([jj + 0.5, ii + 0.5], axis=1))
        axis = v.camera.cam_to_world[:3, 2]
        z = v.depth[ii, jj].astype(np.float64)
        pts.append(o + d * (z / (d @ axis))[:, None])  # z-depth -> distance along the unit ray
    if not pts:
        raise ValueError("no captured view has depth: nothing to rebin")
    p = np.concatenate(pts)
    return p[np.sort(_first_per_voxel(np.floor(p / voxel).astype(np.int64)))]


def _first_per_voxel(cells: np.ndarray) -> np.ndarray:
    """Index of the first row of each distinct (N, 3) int64 voxel coordinate, as
    ``np.unique(cells, axis=0, return_index=True)[1]``: the rows packed into one int64 key each
    (a 1-D sort; the row-wise unique sorts void records and took 60% of a rebin at st 192)."""
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0 ** 62:  # keys would overflow: the row-wise way
        return np.unique(cells, axis=0, return_index=True)[1]
    c = cells - lo
    keys = (c[:, 0] * span[1] + c[:, 1]) * span[2] + c[:, 2]
    return np.unique(keys, return_index=True)[1]


def _fill_single_holes(z: np.ndarray) -> np.ndarray:
    """Close empty pixels of a (H, W) depth image that have at least 6 of 8 non-empty neighbours
    (with the nearest of them)."""
    H, W = z.shape
    zp = np.pad(z, 1)
    neigh = np.stack([zp[1 + dy:1 + dy + H, 1 + dx:1 + dx + W] for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                      if (dy, dx) != (0, 0)])
    count = (neigh > 0).sum(0)
    nearest = np.where(neigh > 0, neigh, np.inf).min(0)
    fill = (z == 0) & (count >= 6)
    return np.where(fill, nearest, z)


def splat_depth(geom: SlabGeometry, points: np.ndarray) -> np.ndarray:
    """(Nv, Nu, Nt, Ns) float32 proxy depth of every slab ray (z-buffered point splats, 0 = none;
    compiled: :func:`recon.slab.rebin_kernels.splat_depth_images`, :func:`splat_depth_numpy` is its reference)."""
    q = _slab_frame_points(geom, points)
    return splat_depth_images(q, geom.shape, geom.uv_size, geom.distance, geom.st_offset, geom.st_size)


def _slab_frame_points(geom: SlabGeometry, points: np.ndarray) -> np.ndarray:
    """(P', 3) float64 ``points`` in the slab's frame, those in front of the uv plane, nearest first."""
    q = (np.asarray(points, np.float64) - geom.uv_corners[0]) @ geom.rotation.T
    q = q[q[:, 2] > 1e-6 * geom.distance]
    return q[np.argsort(q[:, 2], kind="stable")]       # nearest first: the first splat per pixel wins


def splat_depth_numpy(geom: SlabGeometry, points: np.ndarray) -> np.ndarray:
    """:func:`splat_depth` in numpy, one uv sample at a time: the reference the kernel is tested against."""
    nu, nv, ns, nt = geom.shape
    q = _slab_frame_points(geom, points)
    D = geom.distance
    (sx0, sy0), (ws, ht) = geom.st_offset, geom.st_size
    mag = (D / q[:, 2])[:, None]
    out = np.zeros((nv, nu, nt, ns), np.float32)
    for j in range(nv):
        for i in range(nu):
            U = np.array([(i + 0.5) / nu * geom.uv_size[0], (j + 0.5) / nv * geom.uv_size[1]])
            S = U + mag * (q[:, :2] - U)
            col = np.floor((S[:, 0] - sx0) / ws * ns)
            row = np.floor((S[:, 1] - sy0) / ht * nt)
            inside = (col >= 0) & (col < ns) & (row >= 0) & (row < nt)
            idx = (row[inside] * ns + col[inside]).astype(np.int64)
            uniq, first = np.unique(idx, return_index=True)
            img = np.zeros(nt * ns, np.float32)
            img[uniq] = q[inside][first, 2]
            out[j, i] = _fill_single_holes(img.reshape(nt, ns))
    return out


def _bilinear(images: np.ndarray, which: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample (M, H, W, C) ``images[which]`` bilinearly at pixel coordinates (x, y) (centres at
    +0.5), edge-clamped. Returns (N, C) float32."""
    _, H, W, _ = images.shape
    fx, fy = np.clip(x - 0.5, 0, W - 1), np.clip(y - 0.5, 0, H - 1)
    x0, y0 = np.minimum(np.floor(fx), W - 2).astype(np.int64), np.minimum(np.floor(fy), H - 2).astype(np.int64)
    ax, ay = (fx - x0)[:, None].astype(np.float32), (fy - y0)[:, None].astype(np.float32)
    g = lambda yy, xx: images[which, yy, xx]  # noqa: E731
    return ((1 - ay) * ((1 - ax) * g(y0, x0) + ax * g(y0, x0 + 1)) + ay * ((1 - ax) * g(y0 + 1, x0) + ax * g(y0 + 1, x0 + 1)))


class _Views:
    """The captures stacked for vectorized projection and sampling."""

    def __init__(self, views: Sequence[SourceView]):
        self.rgb = np.stack([np.asarray(v.rgb, np.float32) for v in views])
        self.depth = np.stack([np.asarray(v.depth, np.float32) for v in views])
        self.centres = np.stack([v.camera.center for v in views])
        w2c = np.stack([v.camera.world_to_cam[:3] for v in views])   # (M, 3, 4)
        k = views[0].camera.intrinsics
        self.w2c, self.k = w2c, k

    def project(self, which: np.ndarray, P: np.ndarray):
        """which (N,), P (N, 3) -> pixel x, y and camera z (N,) each (ideal pinhole)."""
        M = self.w2c[which]
        pc = np.einsum("nij,nj->ni", M[:, :, :3], P) + M[:, :, 3]
        z = pc[:, 2]
        zs = np.where(z > 1e-9, z, 1.0)
        return self.k.fx * pc[:, 0] / zs + self.k.cx, self.k.fy * pc[:, 1] / zs + self.k.cy, z


def _blend_rays(views: _Views, P: np.ndarray, r: np.ndarray, cfg: RebinConfig, tol_abs: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Radiance (N, 3) float32 and filled (N,) bool for rays of unit direction r reaching P
    (the compiled kernel; :func:`_blend_rays_numpy` is its tested reference)."""
    k = views.k
    return blend_rays(P, r, views.rgb, views.depth, views.centres, views.w2c, (k.fx, k.fy, k.cx, k.cy),
                      cfg.candidates, cfg.cameras_per_ray, cfg.depth_tolerance, tol_abs)


def _blend_rays_numpy(views: _Views, P: np.ndarray, r: np.ndarray, cfg: RebinConfig, tol_abs: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_blend_rays` in numpy, over (N, views, 3) arrays: the reference the kernel is tested against."""
    n, M = len(P), len(views.centres)
    m = min(cfg.candidates, M)
    to_p = P[:, None, :] - views.centres[None]                   # (N, M, 3) view -> P
    cos = np.einsum("nmc,nc->nm", to_p, r) / np.maximum(np.linalg.norm(to_p, axis=2), 1e-12)
    cand = np.argpartition(-cos, m - 1, axis=1)[:, :m] if m < M else np.tile(np.arange(M), (n, 1))
    ccos = np.take_along_axis(cos, cand, axis=1)
    order = np.argsort(-ccos, axis=1)
    cand, ccos = np.take_along_axis(cand, order, 1), np.take_along_axis(ccos, order, 1)
    angle = np.arccos(np.clip(ccos, -1.0, 1.0))                  # (N, m) ascending
    H, W = views.depth.shape[1:]
    visible = np.zeros((n, m), bool)
    for c in range(m):
        x, y, z = views.project(cand[:, c], P)
        inside = (z > 0) & (x >= 0) & (x < W) & (y >= 0) & (y < H)
        xi, yi = np.clip(x.astype(np.int64), 0, W - 1), np.clip(y.astype(np.int64), 0, H - 1)
        dm = views.depth[cand[:, c], yi, xi]
        visible[:, c] = inside & (dm > 0) & (np.abs(dm - z) <= cfg.depth_tolerance * z + tol_abs)
    # keep visible candidates first (stable, by angle), then the unstructured lumigraph weights
    key = np.argsort(~visible, axis=1, kind="stable")
    cand, angle, visible = (np.take_along_axis(a, key, 1) for a in (cand, angle, visible))
    k = cfg.cameras_per_ray
    if m > k:
        thresh = np.where(visible[:, k], angle[:, k], np.pi)
    else:
        thresh = np.full(n, np.pi)
    a = angle[:, :k]
    w = visible[:, :k] * np.clip(1.0 - a / thresh[:, None], 0.0, None) / np.maximum(a, 1e-4)
    total = w.sum(1)
    filled = visible[:, 0]
    lone = filled & (total <= 0)            # all at the threshold angle: take the best view
    w[lone, 0], total[lone] = 1.0, 1.0
    w = np.where(filled[:, None], w / np.where(total > 0, total, 1.0)[:, None], 0.0).astype(np.float32)
    out = np.zeros((n, 3), np.float32)
    for c in range(k):
        sel = w[:, c] > 0
        if sel.any():
            x, y, _ = views.project(cand[sel, c], P[sel])
            out[sel] += w[sel, c, None] * _bilinear(views.rgb, cand[sel, c], x, y)
    return out, filled


def rebin_slabs(geometries: Sequence[SlabGeometry], views: Sequence[SourceView], folder,
                config: RebinConfig = RebinConfig(), background=(0.0, 0.0, 0.0),
                progress: Callable[[int], None] | None = None,
                dtype=np.float32) -> tuple[list[LightSlab], RebinStats]:
    """Fill slabs from captures into memory-mapped arrays of ``dtype`` (float32 or float16) in
    ``folder`` (and its slabs.json).

    ``progress(1)`` is called after each uv sample. Returns the slabs and their coverage.
    """
    _check_views(views)
    bg = np.asarray(background, np.float32).reshape(3)
    spacing = min(min(g.st_size[0] / g.shape[2], g.st_size[1] / g.shape[3]) for g in geometries)
    cloud = point_cloud(views, config.voxel * spacing, config.edge_jump)
    stacked = _Views(views)
    stats, slabs = RebinStats(), []
    for geom in geometries:
        nu, nv, ns, nt = geom.shape
        rad, depth = create_slab_arrays(Path(folder), geom, with_depth=True, dtype=dtype)
        depth[:] = splat_depth(geom, cloud)
        D = geom.distance
        st_pts = np.stack(np.meshgrid(geom.st_offset[0] + (np.arange(ns) + 0.5) / ns * geom.st_size[0],
                                      geom.st_offset[1] + (np.arange(nt) + 0.5) / nt * geom.st_size[1]), -1)
        st_world = geom.uv_corners[0] + st_pts.reshape(-1, 2) @ geom.rotation[:2] + D * geom.rotation[2]
        # the splat quantizes a surface point to its st sample: allow a few samples of depth slack
        tol_abs = 2.0 * spacing
        surface = filled = 0
        for j in range(nv):
            for i in range(nu):
                U = geom.uv_point((i + 0.5) / nu, (j + 0.5) / nv)
                z = np.asarray(depth[j, i], np.float64).reshape(-1)
                hit = np.flatnonzero(z > 0)
                img = np.empty((nt * ns, 3), np.float32)
                img[:] = bg
                if len(hit):
                    r = st_world[hit] - U
                    P = U + (z[hit] / D)[:, None] * r
                    r /= np.linalg.norm(r, axis=1, keepdims=True)
                    col, ok = _blend_rays(stacked, P, r, config, tol_abs)
                    img[hit[ok]] = col[ok]
                    surface += len(hit)
                    filled += int(ok.sum())
                rad[j, i] = img.reshape(nt, ns, 3)
                if progress is not None:
                    progress(1)
        stats.rays[geom.name], stats.surface[geom.name], stats.filled[geom.name] = geom.n_rays, surface, filled
        slabs.append(LightSlab(geom, rad, depth))
    write_slab_index(folder, slabs)
    return slabs, stats
