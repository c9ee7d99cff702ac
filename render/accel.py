"""Ray intersection through Embree (embreex): scene triangles, first hits, occlusion, ray offsets.

All objects' triangles go into one Embree geometry; a hit's ``tri`` is the global triangle index
into :class:`Geometry`'s arrays (objects concatenated in scene order). Vertices are rounded to
float32 once, and the float64 shading math uses those same rounded vertices, so the surface we
shade is exactly the surface Embree intersects.

Degenerate (zero-area or non-finite) triangles are kept in the arrays (so indices stay aligned
with the meshes) but never given to Embree: they are never hit, never sampled as lights, and
their normal is the zero vector rather than NaN.

Embree's tnear is 0: callers offset new ray origins with :func:`spawn_origin`, which moves a
point along the geometric normal, to the side the new ray leaves on, by an error bound that
scales with the point's magnitude (pbrt's approach; float32 intersection error grows with |p|).

embreex releases the GIL, so large batches are split over threads.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

import embreex.mesh_construction as _emesh
import embreex.rtcore_scene as _escene

from . import embree_lib as _elib
from . import path_aot as _aot
from .scene import Scene

__all__ = ["Geometry", "Hits", "Accel", "spawn_origin", "offset_eps", "OFFSET_REL"]

#: relative ray-offset error bound: float32 rounding of a ray origin is 6e-8 |p|, Embree's
#: watertight test adds a few ulps more; 1e-6 |p| is ~16 ulps (tests probe it at mm scale)
OFFSET_REL = 1e-6
_MIN_SPLIT = 16384  # smallest batch worth splitting over threads


def _ray_kernels(*rays):
    """The compiled Embree queries for these rays (render.path_aot: the ahead-of-time extension's
    when it is loaded and the rays have the types it was compiled for, else numba's)."""
    k = _aot.kernels()
    return k if not k.aot or _aot.rays_ok(*rays) else _aot.jit_kernels()


@dataclass
class Geometry:
    """Flat triangle arrays of a scene (T triangles over all objects, float64 unless stated).

    v0, e1, e2: (T, 3) first vertex and edges v1 - v0, v2 - v0. normal: (T, 3) unit geometric
    normal cross(e1, e2) (right-hand rule on the face winding; zero for degenerate triangles).
    area: (T,). obj: (T,) int64 object index. uv: (T, 3, 2) per-corner texture coordinates
    (zeros where the mesh has none). valid: (T,) bool non-degenerate. extent: scene bounding-box
    diagonal (scene units), used for scale-relative epsilons.
    """

    v0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    obj: np.ndarray
    uv: np.ndarray
    valid: np.ndarray
    extent: float

    @classmethod
    def from_scene(cls, scene: Scene) -> "Geometry":
        tris, objs, uvs = [], [], []
        for i, o in enumerate(scene.objects):
            v = np.asarray(o.mesh.vertices, dtype=np.float32).astype(np.float64)
            f = np.asarray(o.mesh.faces, dtype=np.int64).reshape(-1, 3)
            tris.append(v[f])
            objs.append(np.full(len(f), i, dtype=np.int64))
            uv = o.uv
            if uv is not None and len(uv) == len(v):
                uvs.append(uv[f])
            else:
                uvs.append(np.zeros((len(f), 3, 2)))
        if tris:
            t = np.concatenate(tris)
            obj = np.concatenate(objs)
            uv = np.concatenate(uvs)
        else:
            t, obj, uv = np.zeros((0, 3, 3)), np.zeros(0, np.int64), np.zeros((0, 3, 2))
        v0 = t[:, 0]
        e1 = t[:, 1] - v0
        e2 = t[:, 2] - v0
        c = np.cross(e1, e2)
        a2 = np.linalg.norm(c, axis=1)
        finite = np.all(np.isfinite(t.reshape(len(t), -1)), axis=1)
        if len(t) and np.any(finite):
            lo, hi = t[finite].reshape(-1, 3).min(0), t[finite].reshape(-1, 3).max(0)
            extent = float(np.linalg.norm(hi - lo))
        else:
            extent = 1.0
        extent = extent if extent > 0 else 1.0
        valid = finite & (a2 > 1e-14 * extent * extent)
        normal = np.zeros_like(c)
        np.divide(c, a2[:, None], out=normal, where=valid[:, None])
        area = np.where(valid, 0.5 * a2, 0.0)
        return cls(v0, e1, e2, normal, area, obj, uv, valid, extent)

    def point(self, tri: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N, 3) points at barycentrics (u, v) (Embree's: p = v0 + u e1 + v e2) of triangles ``tri``."""
        return self.v0[tri] + u[:, None] * self.e1[tri] + v[:, None] * self.e2[tri]

    def point_normal(self, tri: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(points (N, 3), unit geometric normals (N, 3)) at barycentrics (u, v): one gather."""
        if getattr(self, "_packed", None) is None:
            self._packed = np.concatenate([self.v0, self.e1, self.e2, self.normal], axis=1)
        q = self._packed[tri]
        return q[:, 0:3] + u[:, None] * q[:, 3:6] + v[:, None] * q[:, 6:9], q[:, 9:12]

    def texcoords(self, tri: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N, 2) interpolated texture coordinates at barycentrics (u, v)."""
        c = self.uv[tri]
        return (1.0 - u - v)[:, None] * c[:, 0] + u[:, None] * c[:, 1] + v[:, None] * c[:, 2]


@dataclass
class Hits:
    """First hits of N rays. t: (N,) float64 distance along the (unit) ray, inf on a miss.
    tri: (N,) int64 global triangle index, -1 on a miss. u, v: (N,) float64 barycentrics."""

    t: np.ndarray
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray


def offset_eps(p: np.ndarray, extent: float) -> np.ndarray:
    """(N,) ray-offset error bound OFFSET_REL * (max_k |p_k| + 1e-2 * extent) at points p (N, 3)."""
    a = np.abs(p)
    return OFFSET_REL * (np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2]) + 1e-2 * extent)


def spawn_origin(p: np.ndarray, ng: np.ndarray, w: np.ndarray, extent: float) -> np.ndarray:
    """Offset ray origins off a surface, to the side direction ``w`` leaves on.

    p, ng, w: (N, 3) hit points, unit geometric normals, new ray directions. The offset is
    :func:`offset_eps` along +ng or -ng. Returns (N, 3) float64.
    """
    eps = offset_eps(p, extent)
    side = np.where(w[:, 0] * ng[:, 0] + w[:, 1] * ng[:, 1] + w[:, 2] * ng[:, 2] >= 0.0, eps, -eps)
    return p + side[:, None] * ng


class Accel:
    """Embree BVH over a scene's valid triangles.

    threads: how many threads a large batch is split over (embreex releases the GIL).
    subset: optional (T,) bool mask: build over those triangles only (hits still report global
    triangle indices), e.g. the emitters alone.
    """

    def __init__(self, scene: Scene, threads: int = 2, geometry: Geometry | None = None,
                 subset: np.ndarray | None = None):
        self.geometry = geometry if geometry is not None else Geometry.from_scene(scene)
        g = self.geometry
        self.threads = max(1, int(threads))
        keep = g.valid if subset is None else g.valid & np.asarray(subset, bool)
        self._ids = np.nonzero(keep)[0].astype(np.int64)  # embree primID -> global tri
        self._scene = None
        #: the same triangles as a scene the compiled kernels query directly (render.embree_lib),
        #: or None (embreex's library not found, or no triangles)
        self.direct = None
        if len(self._ids):
            tv = np.stack([g.v0, g.v0 + g.e1, g.v0 + g.e2], axis=1)[self._ids].astype(np.float32)
            self._scene = _escene.EmbreeScene()
            _emesh.TriangleMesh(self._scene, np.ascontiguousarray(tv))
            if _elib.AVAILABLE:
                self.direct = _elib.DirectScene(tv)
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        if self.direct is not None:
            self.direct.close()
            self.direct = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    def _split(self, fn, n: int, threads: int | None):
        k = self.threads if threads is None else max(1, int(threads))
        if k == 1 or n < _MIN_SPLIT or self._pool is None:
            return [fn(0, n)]
        bounds = np.linspace(0, n, k + 1).astype(int)
        return list(self._pool.map(lambda i: fn(bounds[i], bounds[i + 1]), range(k)))

    @staticmethod
    def _prep(origins, dirs, tmax, n):
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(dirs, dtype=np.float32)
        if tmax is None:
            tf = None
        else:
            tf = np.ascontiguousarray(np.broadcast_to(np.minimum(tmax, 3e38), (n,)), dtype=np.float32)
        return o, d, tf

    def intersect(self, origins: np.ndarray, dirs: np.ndarray, tmax=None, threads: int | None = None) -> Hits:
        """First hits of rays (N, 3) origins and unit dirs, optional (N,) or scalar tmax.

        Hits at t in (0, tmax) only: offset origins yourself (:func:`spawn_origin`).
        """
        n = len(origins)
        if self._scene is None or n == 0:
            return Hits(np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros(n), np.zeros(n))
        o, d, tf = self._prep(origins, dirs, tmax, n)

        def run(a, b):
            out = self._scene.run(o[a:b], d[a:b], dists=None if tf is None else tf[a:b], output=True)
            return out["primID"], out["tfar"], out["u"], out["v"]

        parts = self._split(run, n, threads)
        if len(parts) == 1:
            prim, tf32, u32, v32 = parts[0]
        else:
            prim, tf32, u32, v32 = (np.concatenate([p[i] for p in parts]) for i in range(4))
        hit = prim >= 0
        tri = self._ids[np.maximum(prim, 0)]
        t = tf32.astype(np.float64)
        u = u32.astype(np.float64)
        v = v32.astype(np.float64)
        if not hit.all():
            miss = ~hit
            tri[miss] = -1
            t[miss] = np.inf
            u[miss] = 0.0
            v[miss] = 0.0
        return Hits(t, tri, u, v)

    @property
    def ids(self) -> np.ndarray:
        """(P,) int64 global triangle index of each Embree primID of this BVH."""
        return self._ids

    def intersect_raw(self, o32: np.ndarray, d32: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Embree's own first-hit output for (N, 3) C-contiguous float32 origins and unit dirs,
        on the calling thread (what the wavefront kernels read): (primID (N,) int32, -1 on a
        miss, index into :attr:`ids`; tfar (N,) float32; u, v (N,) float32 barycentrics)."""
        n = len(o32)
        if self._scene is None or n == 0:
            z = np.zeros(n, np.float32)
            return np.full(n, -1, np.int32), np.full(n, np.inf, np.float32), z, z
        out = self._scene.run(o32, d32, dists=None, output=True)
        return out["primID"], out["tfar"], out["u"], out["v"]

    def intersect_fast(self, o32: np.ndarray, d32: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`intersect_raw`, through compiled code calling Embree directly when possible."""
        if self.direct is None or len(o32) == 0:
            return self.intersect_raw(o32, d32)
        n = len(o32)
        prim, tfar = np.empty(n, np.int32), np.empty(n, np.float32)
        u, v = np.empty(n, np.float32), np.empty(n, np.float32)
        _ray_kernels(o32, d32).intersect_many(self.direct.handle, o32, d32, prim, tfar, u, v)
        return prim, tfar, u, v

    def occluded_fast(self, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray) -> np.ndarray:
        """:meth:`occluded_raw`, through compiled code calling Embree directly when possible."""
        if self.direct is None or len(o32) == 0:
            return self.occluded_raw(o32, d32, t32)
        occ = np.empty(len(o32), np.int32)
        _ray_kernels(o32, d32, t32).occluded_many(self.direct.handle, o32, d32, t32, occ)
        return occ

    def occluded_raw(self, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray) -> np.ndarray:
        """Embree's occlusion output for float32 rays (N, 3) and tmax (N,), on the calling
        thread: (N,) int32, -1 where nothing lies on the ray at t in (0, tmax)."""
        n = len(o32)
        if self._scene is None or n == 0:
            return np.full(n, -1, np.int32)
        return self._scene.run(o32, d32, dists=t32, query="OCCLUDED")

    def occluded(self, origins: np.ndarray, dirs: np.ndarray, tmax, threads: int | None = None) -> np.ndarray:
        """(N,) bool: does anything lie on the ray at t in (0, tmax)? tmax (N,) or scalar."""
        n = len(origins)
        if self._scene is None or n == 0:
            return np.zeros(n, dtype=bool)
        o, d, tf = self._prep(origins, dirs, tmax, n)

        def run(a, b):
            return self._scene.run(o[a:b], d[a:b], dists=tf[a:b], query="OCCLUDED")

        parts = self._split(run, n, threads)
        # embreex reports -1 for unoccluded rays
        return np.concatenate(parts) != -1
