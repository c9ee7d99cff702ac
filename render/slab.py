"""Two-plane light slabs (Levoy and Hanrahan 1996): geometry, ray lookup, interpolation.

A light slab stores the radiance of the oriented lines that cross two parallel rectangles, the
*uv* quad (where the eyes are) and the *st* quad (the focal plane, through the object). Pure
functions over arrays: nothing here knows files or stages (:mod:`render.slab_io` reads and
writes slab sets).

Conventions (tested in ``tests/render/test_slab.py``):

* A quad is given by four world corners ``(4, 3)`` float64 in the order (0, 0), (1, 0), (1, 1),
  (0, 1) of its parameters: ``u`` (resp. ``s``) runs along corner 1 - corner 0 and ``v`` (resp.
  ``t``) along corner 3 - corner 0. Both quads are rectangles with the same edge directions.
* Seen from the uv quad looking at the st quad, ``s`` runs to the right and ``t`` downwards, as
  an image's x and y in OpenCV axes: ``forward = e_s x e_t`` points from the uv plane to the
  st plane. A slab stores the radiance *seen by an eye ray travelling along +forward*, i.e. of
  light leaving the object towards the uv side.
* Sample (i, j) of an axis of N samples sits at the cell centre ``(i + 0.5) / N`` (pixel centres
  at +0.5), so the st samples of a uv sample are exactly the pixels of the sheared-perspective
  camera :func:`sheared_camera` (image plane = the st quad).
* ``radiance`` is ``(Nv, Nu, Nt, Ns, 3)`` float32 linear RGB: an Nv x Nu grid of Nt x Ns
  images, row-major like images (memory-mappable). ``depth`` (optional) is ``(Nv, Nu, Nt, Ns)``
  float32: the distance along ``forward`` from the uv plane to the first surface on that ray
  (the sheared camera's z-depth), 0 where the ray hits nothing.

Interpolation modes (the paper's Fig. 13): ``nearest``; ``uv`` (bilinear in u, v, nearest in
s, t); ``st`` (nearest in u, v, bilinear in s, t); ``quadrilinear``; and ``depth``, the depth-
corrected variant of the Lumigraph (Gortler et al. 1996) and of dynamically reparameterized
light fields (Isaksen et al. 2000): the eye ray is intersected with a focal surface (the slab's
depth where it has one, else the focal plane ``focal_depth``), and each of the four nearest uv
samples is looked up bilinearly where *its* ray through that focal point crosses st.
Coordinates outside a quad mean the ray misses the slab; inside, interpolation clamps to the
edge samples.
"""
from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .camera import Camera, Intrinsics

__all__ = ["MODES", "SlabGeometry", "LightSlab", "SlabHits", "slab_coordinates", "lookup",
           "select_slabs", "render_rays", "render_view", "camera_hits", "sheared_camera"]

MODES = ("nearest", "uv", "st", "quadrilinear", "depth")

#: rays whose direction makes |cos| below this with a slab's normal are treated as parallel
#: to its planes (the plane-intersection denominator would be near zero): they miss the slab
MIN_COS = 1e-6


def _corners(c, what: str) -> np.ndarray:
    a = np.asarray(c, dtype=np.float64)
    if a.shape != (4, 3) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: expected finite (4, 3) corners, got shape {a.shape}")
    return a


@dataclass(frozen=True)
class SlabGeometry:
    """Two parallel rectangles and sample counts ``shape = (Nu, Nv, Ns, Nt)``.

    uv_corners, st_corners: (4, 3) float64 world corners, order (0,0), (1,0), (1,1), (0,1).
    """

    uv_corners: np.ndarray
    st_corners: np.ndarray
    shape: tuple[int, int, int, int]
    name: str = "slab"
    # derived, set in __post_init__
    rotation: np.ndarray = field(init=False, repr=False)  # (3, 3) rows e_s, e_t, forward
    distance: float = field(init=False)  # from the uv plane to the st plane along forward
    uv_size: tuple[float, float] = field(init=False)  # (Wu, Hv) edge lengths
    st_size: tuple[float, float] = field(init=False)  # (Ws, Ht)
    st_offset: tuple[float, float] = field(init=False)  # st corner 0 in the uv frame (x, y)

    def __post_init__(self) -> None:
        uv = _corners(self.uv_corners, f"slab {self.name!r} uv_corners")
        st = _corners(self.st_corners, f"slab {self.name!r} st_corners")
        shape = tuple(int(n) for n in self.shape)
        if len(shape) != 4 or min(shape) < 1:
            raise ValueError(f"slab {self.name!r}: shape must be four positive counts (Nu, Nv, Ns, Nt), got {self.shape}")
        frames = []
        for q, what in ((uv, "uv"), (st, "st")):
            a, b = q[1] - q[0], q[3] - q[0]
            la, lb = np.linalg.norm(a), np.linalg.norm(b)
            if la < 1e-12 or lb < 1e-12:
                raise ValueError(f"slab {self.name!r}: degenerate {what} quad (zero-length edge)")
            scale = max(la, lb)
            if abs(a @ b) > 1e-6 * la * lb or np.linalg.norm(q[2] - (q[1] + q[3] - q[0])) > 1e-6 * scale:
                raise ValueError(f"slab {self.name!r}: {what} corners are not a rectangle in order (0,0), (1,0), (1,1), (0,1)")
            frames.append((a / la, b / lb, la, lb))
        (eu, ev, wu, hv), (es, et, ws, ht) = frames
        if not (np.allclose(eu, es, atol=1e-6) and np.allclose(ev, et, atol=1e-6)):
            raise ValueError(f"slab {self.name!r}: uv and st quads must be parallel with the same edge directions")
        fwd = np.cross(eu, ev)
        dist = float((st[0] - uv[0]) @ fwd)
        if not dist > 1e-9:
            raise ValueError(f"slab {self.name!r}: the st plane must lie in front of the uv plane along e_s x e_t "
                             "(s right, t down seen from the uv side)")
        rot = np.stack([eu, ev, fwd])
        off = rot[:2] @ (st[0] - uv[0])
        object.__setattr__(self, "uv_corners", uv)
        object.__setattr__(self, "st_corners", st)
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "distance", dist)
        object.__setattr__(self, "uv_size", (float(wu), float(hv)))
        object.__setattr__(self, "st_size", (float(ws), float(ht)))
        object.__setattr__(self, "st_offset", (float(off[0]), float(off[1])))

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit normal from the uv plane towards the st plane (eye-ray direction)."""
        return self.rotation[2].copy()

    @property
    def array_shape(self) -> tuple[int, int, int, int, int]:
        """Shape of the radiance array: (Nv, Nu, Nt, Ns, 3)."""
        nu, nv, ns, nt = self.shape
        return (nv, nu, nt, ns, 3)

    @property
    def n_rays(self) -> int:
        return int(np.prod(self.shape))

    def uv_point(self, u, v) -> np.ndarray:
        """World point(s) (..., 3) of uv parameters ``u, v`` (arrays broadcast; [0, 1] on the quad)."""
        u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
        c = self.uv_corners
        return c[0] + u[..., None] * (c[1] - c[0]) + v[..., None] * (c[3] - c[0])

    def uv_sample_points(self) -> np.ndarray:
        """(Nv, Nu, 3) float64 world positions of the uv sample centres."""
        nu, nv = self.shape[:2]
        v, u = np.meshgrid((np.arange(nv) + 0.5) / nv, (np.arange(nu) + 0.5) / nu, indexing="ij")
        return self.uv_point(u, v)

    def to_dict(self) -> dict:
        return {"name": self.name, "uv_corners": self.uv_corners.tolist(), "st_corners": self.st_corners.tolist(),
                "shape": list(self.shape)}

    @classmethod
    def from_dict(cls, d: dict) -> "SlabGeometry":
        return cls(np.array(d["uv_corners"], dtype=np.float64), np.array(d["st_corners"], dtype=np.float64),
                   tuple(int(n) for n in d["shape"]), str(d.get("name", "slab")))


@dataclass
class LightSlab:
    """A slab's geometry and samples.

    radiance: (Nv, Nu, Nt, Ns, 3) float32 linear RGB (a numpy array or memmap).
    depth: optional (Nv, Nu, Nt, Ns) float32 distance along ``forward`` from the uv plane to the
    first surface (0 = nothing). focal_depth: distance from the uv plane of the focal plane the
    ``depth`` mode uses where there is no depth (None: the st plane, i.e. ``distance``).
    """

    geometry: SlabGeometry
    radiance: np.ndarray
    depth: np.ndarray | None = None
    focal_depth: float | None = None

    def __post_init__(self) -> None:
        g = self.geometry
        if self.radiance.shape != g.array_shape or self.radiance.dtype != np.float32:
            raise ValueError(f"slab {g.name!r}: radiance must be {g.array_shape} float32, "
                             f"got {self.radiance.shape} {self.radiance.dtype}")
        if self.depth is not None and (self.depth.shape != g.array_shape[:4] or self.depth.dtype != np.float32):
            raise ValueError(f"slab {g.name!r}: depth must be {g.array_shape[:4]} float32, "
                             f"got {self.depth.shape} {self.depth.dtype}")
        if self.focal_depth is not None and not (np.isfinite(self.focal_depth) and self.focal_depth > 0):
            raise ValueError(f"slab {g.name!r}: focal_depth must be a positive distance, got {self.focal_depth}")

    @property
    def nbytes(self) -> int:
        return int(self.radiance.nbytes + (0 if self.depth is None else self.depth.nbytes))


@dataclass
class SlabHits:
    """Where rays cross one slab. All arrays have N rows.

    ``uv``, ``st``: (N, 2) float64 plane coordinates in the uv frame (world units, x along e_s,
    y along e_t; st relative to the uv quad's corner 0, like uv). ``coords``: (N, 4) float64
    (u, v, s, t) in [0, 1] for valid rays. ``valid``: (N,) bool, the ray travels along +forward,
    its origin is not beyond the st plane, and it crosses both quads. ``cos``: (N,) float64
    cosine between the ray and ``forward`` (how steeply it crosses).
    """

    uv: np.ndarray
    st: np.ndarray
    coords: np.ndarray
    valid: np.ndarray
    cos: np.ndarray


def _check_rays(origins, dirs) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError(f"origins and dirs must have the same shape, got {o.shape} and {d.shape}")
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise ValueError("ray origins and directions must be finite")
    return o, d


def slab_coordinates(geom: SlabGeometry, origins: np.ndarray, dirs: np.ndarray) -> SlabHits:
    """Intersect rays with both planes of a slab.

    origins, dirs: (N, 3) float64 world rays (dirs need not be unit; zero ones miss). Rays
    parallel to the planes (|cos| < :data:`MIN_COS`), travelling against ``forward``, starting
    beyond the st plane, or crossing outside either quad are invalid; every output is finite.
    """
    o, d = _check_rays(origins, dirs)
    R = geom.rotation
    op = (o - geom.uv_corners[0]) @ R.T
    dp = d @ R.T
    norm = np.linalg.norm(dp, axis=1)
    cos = np.divide(dp[:, 2], norm, out=np.zeros(len(dp)), where=norm > 0)
    ok = cos > MIN_COS
    dz = np.where(ok, dp[:, 2], 1.0)  # guard: never divide by a near-zero denominator
    lam_uv = -op[:, 2] / dz
    lam_st = (geom.distance - op[:, 2]) / dz
    ok &= lam_st > 0  # the origin must not lie beyond the st plane
    lam_uv, lam_st = np.where(ok, lam_uv, 0.0), np.where(ok, lam_st, 0.0)
    uv = op[:, :2] + lam_uv[:, None] * dp[:, :2]
    st = op[:, :2] + lam_st[:, None] * dp[:, :2]
    coords = np.stack([uv[:, 0] / geom.uv_size[0], uv[:, 1] / geom.uv_size[1],
                       (st[:, 0] - geom.st_offset[0]) / geom.st_size[0],
                       (st[:, 1] - geom.st_offset[1]) / geom.st_size[1]], axis=1)
    ok &= np.all((coords >= 0.0) & (coords <= 1.0), axis=1)
    coords = np.where(ok[:, None], coords, 0.5)
    return SlabHits(np.where(ok[:, None], uv, 0.0), np.where(ok[:, None], st, 0.0), coords, ok, np.where(ok, cos, 0.0))


def _taps(x: np.ndarray, n: int, linear: bool) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Sample indices and weights along one axis of ``n`` cell-centred samples for parameters
    ``x`` (N,) in [0, 1]: one nearest tap (weight None = 1) or two linear taps, edge-clamped."""
    c = np.clip(x * n - 0.5, 0.0, n - 1.0)
    if not linear or n == 1:
        return [(np.minimum(np.floor(c + 0.5), n - 1).astype(np.int64), None)]
    i0 = np.minimum(np.floor(c), n - 2).astype(np.int64)
    f = (c - i0).astype(np.float32)
    return [(i0, 1.0 - f), (i0 + 1, f)]


def _mul(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return a * b


def _gather(flat: np.ndarray, taps_v, taps_u, taps_t, taps_s, shape) -> np.ndarray:
    """Sum of weighted samples over the product of per-axis taps; flat (Nv*Nu*Nt*Ns, C)."""
    nu, nv, ns, nt = shape
    uv = [(iv * nu + iu, _mul(wv, wu)) for (iv, wv), (iu, wu) in itertools.product(taps_v, taps_u)]
    st = [(it * ns + is_, _mul(wt, ws)) for (it, wt), (is_, ws) in itertools.product(taps_t, taps_s)]
    out = None
    for (a, wa), (b, wb) in itertools.product(uv, st):
        vals = np.take(flat, a * (nt * ns) + b, axis=0)
        w = _mul(wa, wb)
        if w is not None:
            vals *= w[:, None]
        if out is None:
            out = vals.astype(np.float32, copy=False)
        else:
            out += vals
    return out


def lookup(slab: LightSlab, hits_or_coords, mode: str = "quadrilinear") -> np.ndarray:
    """Interpolate a slab at valid ray coordinates.

    hits_or_coords: :class:`SlabHits` (required by ``depth`` mode) restricted to valid rays, or
    (N, 4) float64 (u, v, s, t) in [0, 1]. Returns (N, 3) float32 radiance.
    """
    if mode not in MODES:
        raise ValueError(f"unknown interpolation mode {mode!r}; known: {list(MODES)}")
    g = slab.geometry
    nu, nv, ns, nt = g.shape
    hits = hits_or_coords if isinstance(hits_or_coords, SlabHits) else None
    coords = hits.coords if hits is not None else np.asarray(hits_or_coords, dtype=np.float64).reshape(-1, 4)
    flat = slab.radiance.reshape(-1, 3)
    if len(coords) == 0:
        return np.zeros((0, 3), np.float32)
    u, v, s, t = coords.T
    if mode != "depth":
        lin_uv = mode in ("uv", "quadrilinear")
        lin_st = mode in ("st", "quadrilinear")
        return _gather(flat, _taps(v, nv, lin_uv), _taps(u, nu, lin_uv), _taps(t, nt, lin_st), _taps(s, ns, lin_st),
                       g.shape)
    if hits is None:
        raise ValueError("depth mode needs SlabHits (the rays' plane crossings), not bare coordinates")
    return _lookup_depth(slab, hits)


def _lookup_depth(slab: LightSlab, hits: SlabHits) -> np.ndarray:
    """Depth-corrected lookup: focal point on the eye ray at the focal surface, re-projected
    from each of the four nearest uv samples onto st (Gortler et al. 1996; Isaksen et al. 2000)."""
    g = slab.geometry
    nu, nv, ns, nt = g.shape
    D = g.distance
    u, v, s, t = hits.coords.T
    zeta = np.full(len(u), D if slab.focal_depth is None else float(slab.focal_depth))
    if slab.depth is not None:
        near = [_taps(x, n, False)[0][0] for x, n in ((v, nv), (u, nu), (t, nt), (s, ns))]
        z = np.asarray(slab.depth.reshape(-1)[((near[0] * nu + near[1]) * nt + near[2]) * ns + near[3]], np.float64)
        zeta = np.where(z > 1e-6 * D, z, zeta)  # 0 = no surface: keep the focal plane
    # focal point F (uv frame, x y) on the eye ray at depth zeta; the ray crosses z=0 at hits.uv, z=D at hits.st
    F = hits.uv + (zeta / D)[:, None] * (hits.st - hits.uv)
    scale = (D / zeta)[:, None]
    flat = slab.radiance.reshape(-1, 3)
    out = np.zeros((len(u), 3), np.float32)
    for (iv, wv), (iu, wu) in itertools.product(_taps(v, nv, True), _taps(u, nu, True)):
        # this uv sample's ray through F crosses st at P = U + (D / zeta) (F - U)
        U = np.stack([(iu + 0.5) / nu * g.uv_size[0], (iv + 0.5) / nv * g.uv_size[1]], axis=1)
        P = U + scale * (F - U)
        sp = np.clip((P[:, 0] - g.st_offset[0]) / g.st_size[0], 0.0, 1.0)
        tp = np.clip((P[:, 1] - g.st_offset[1]) / g.st_size[1], 0.0, 1.0)
        w = _mul(wv, wu)
        vals = _gather(flat, [(iv, None)], [(iu, None)], _taps(tp, nt, True), _taps(sp, ns, True), g.shape)
        out += vals if w is None else vals * w[:, None]
    return out


def select_slabs(slabs: Sequence[LightSlab], origins: np.ndarray, dirs: np.ndarray
                 ) -> tuple[np.ndarray, list[SlabHits]]:
    """For each ray, the slab it crosses at the steepest angle (largest cos with ``forward``).

    Returns ``(index (N,) int64, -1 where no slab is crossed; hits per slab)``.
    """
    o, d = _check_rays(origins, dirs)
    best = np.full(len(o), -1, dtype=np.int64)
    score = np.zeros(len(o))
    all_hits = []
    for k, slab in enumerate(slabs):
        h = slab_coordinates(slab.geometry, o, d)
        better = h.valid & (h.cos > score)
        best[better], score[better] = k, h.cos[better]
        all_hits.append(h)
    return best, all_hits


def _subset(h, sel: np.ndarray) -> SlabHits:
    if isinstance(h, _LazyHits):
        return h.subset(sel)
    return SlabHits(h.uv[sel], h.st[sel], h.coords[sel], h.valid[sel], h.cos[sel])


def render_rays(slabs: Sequence[LightSlab], origins: np.ndarray, dirs: np.ndarray, mode: str = "quadrilinear",
                background=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Radiance (N, 3) float32 of eye rays looked up in a slab set; rays missing every slab get
    ``background`` (3,) linear RGB. origins, dirs: (N, 3) world rays (eye -> scene)."""
    if mode not in MODES:
        raise ValueError(f"unknown interpolation mode {mode!r}; known: {list(MODES)}")
    o, d = _check_rays(origins, dirs)
    return _render_hits(slabs, [slab_coordinates(s.geometry, o, d) for s in slabs], mode, background)


def camera_hits(geom: SlabGeometry, camera: Camera) -> "_LazyHits":
    """:func:`slab_coordinates` of every pixel-centre ray of an undistorted pinhole ``camera``
    (row-major, N = H * W), computed in float32 from the two plane homographies: a pinhole's ray
    through pixel p = (x, y, 1) has direction A p in the slab frame (A = R_slab R_cam K^-1), so
    each coordinate is a ratio of affine functions of x and y (no per-ray matrix products)."""
    k = camera.intrinsics
    if k.has_distortion:
        o, d = camera.pixel_rays()
        h = slab_coordinates(geom, o, d)
        return _LazyHits([h.uv[:, 0], h.uv[:, 1], h.st[:, 0], h.st[:, 1], *h.coords.T], h.valid, h.cos)
    Kinv = np.linalg.inv(k.K)
    A = geom.rotation @ camera.cam_to_world[:3, :3] @ Kinv
    oc = geom.rotation @ (camera.center - geom.uv_corners[0])
    x = (np.arange(k.width, dtype=np.float32) + np.float32(0.5))[None, :]
    y = (np.arange(k.height, dtype=np.float32) + np.float32(0.5))[:, None]
    A32 = A.astype(np.float32)
    dx, dy, dz = (A32[i, 0] * x + (A32[i, 1] * y + A32[i, 2]) for i in range(3))
    norm = np.sqrt(dx * dx + dy * dy + dz * dz)
    cos = dz / norm  # norm > 0: K^-1 p has z = 1
    ok = cos > MIN_COS
    if not oc[2] < geom.distance:  # the eye is beyond the st plane: every ray misses
        ok[:] = False
    dzs = np.where(ok, dz, np.float32(1.0))
    D = geom.distance
    f_uv, f_st = np.float32(-oc[2]) / dzs, np.float32(D - oc[2]) / dzs
    ox, oy = np.float32(oc[0]), np.float32(oc[1])
    ux, uy = ox + f_uv * dx, oy + f_uv * dy
    sx, sy = ox + f_st * dx, oy + f_st * dy
    cu = ux * np.float32(1 / geom.uv_size[0])
    cv = uy * np.float32(1 / geom.uv_size[1])
    cs = (sx - np.float32(geom.st_offset[0])) * np.float32(1 / geom.st_size[0])
    ct = (sy - np.float32(geom.st_offset[1])) * np.float32(1 / geom.st_size[1])
    for c in (cu, cv, cs, ct):
        ok &= (c >= 0) & (c <= 1)
    ok = ok.reshape(-1)
    return _LazyHits([a.reshape(-1) for a in (ux, uy, sx, sy, cu, cv, cs, ct)], ok, np.where(ok, cos.reshape(-1), 0))


class _LazyHits:
    """SlabHits of a whole image kept as flat components; stacked only for the rays a slab serves."""

    def __init__(self, comps: list[np.ndarray], valid: np.ndarray, cos: np.ndarray):
        self.comps, self.valid, self.cos = comps, valid, cos

    def subset(self, sel: np.ndarray) -> SlabHits:
        c = [a[sel] for a in self.comps]
        return SlabHits(np.stack(c[0:2], 1), np.stack(c[2:4], 1), np.stack(c[4:8], 1), self.valid[sel], self.cos[sel])

    def full(self) -> SlabHits:
        return self.subset(slice(None))


def _render_hits(slabs: Sequence[LightSlab], hits: list[SlabHits], mode: str, background) -> np.ndarray:
    bg = np.asarray(background, dtype=np.float32).reshape(-1)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ValueError(f"background must be three finite numbers, got {background!r}")
    n = len(hits[0].valid) if hits else 0
    best = np.full(n, -1, dtype=np.int64)
    score = np.zeros(n, dtype=np.float32)
    for k, h in enumerate(hits):
        better = h.valid & (h.cos > score)
        best[better], score[better] = k, h.cos[better]
    out = np.empty((n, 3), np.float32)
    out[:] = bg
    for k, slab in enumerate(slabs):
        sel = np.flatnonzero(best == k)
        if len(sel):
            out[sel] = lookup(slab, _subset(hits[k], sel), mode)
    return out


def _band(camera: Camera, row0: int, row1: int) -> Camera:
    """The same camera restricted to pixel rows [row0, row1) (principal point shifted)."""
    k = camera.intrinsics
    return Camera(Intrinsics(k.width, row1 - row0, k.fx, k.fy, k.cx, k.cy - row0, k.dist), camera.cam_to_world,
                  camera.name)


def render_view(slabs: Sequence[LightSlab], camera: Camera, mode: str = "quadrilinear",
                background=(0.0, 0.0, 0.0), threads: int = 2) -> np.ndarray:
    """(H, W, 3) float32 linear image of ``camera`` rendered from a slab set (every pixel centre);
    each pixel's ray is looked up in the slab it crosses most steeply, else gets ``background``.
    ``threads`` bands of rows are rendered concurrently (NumPy releases the GIL in its kernels)."""
    if mode not in MODES:
        raise ValueError(f"unknown interpolation mode {mode!r}; known: {list(MODES)}")
    k = camera.intrinsics
    if k.has_distortion:
        threads = 1  # distorted rays are computed for the whole image
    threads = max(1, min(int(threads), k.height))

    def band(rows: tuple[int, int]) -> np.ndarray:
        cam = camera if rows == (0, k.height) else _band(camera, *rows)
        hits = [camera_hits(s.geometry, cam) for s in slabs]
        return _render_hits(slabs, hits, mode, background)

    edges = np.linspace(0, k.height, threads + 1).astype(int)
    bands = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
    if threads == 1:
        return band(bands[0]).reshape(k.height, k.width, 3)
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(threads) as pool:
        parts = list(pool.map(band, bands))
    return np.concatenate(parts).reshape(k.height, k.width, 3)


def sheared_camera(geom: SlabGeometry, u: float, v: float, st_supersample: int = 1, name: str | None = None) -> Camera:
    """The sheared-perspective camera at uv parameters (u, v) whose image is exactly the st quad.

    Its optical axis is ``forward`` (x along e_s, y along e_t, OpenCV axes) and its principal
    point is shifted so that pixel (row i, col j) is st sample (t = (i + 0.5) / H, s = (j + 0.5) / W),
    with W x H = (Ns, Nt) times ``st_supersample``. Its z-depth is the slab's depth convention.
    """
    if st_supersample < 1:
        raise ValueError(f"st_supersample must be >= 1, got {st_supersample}")
    nu, nv, ns, nt = geom.shape
    W, H = ns * st_supersample, nt * st_supersample
    ws, ht = geom.st_size
    x_u, y_v = u * geom.uv_size[0], v * geom.uv_size[1]
    D = geom.distance
    fx, fy = W * D / ws, H * D / ht
    cx, cy = W * (x_u - geom.st_offset[0]) / ws, H * (y_v - geom.st_offset[1]) / ht
    pose = np.eye(4)
    pose[:3, :3] = geom.rotation.T  # columns e_s, e_t, forward
    pose[:3, 3] = geom.uv_point(u, v)
    return Camera(Intrinsics(W, H, fx, fy, cx, cy), pose, name or f"{geom.name}_u{u:.4f}_v{v:.4f}")
