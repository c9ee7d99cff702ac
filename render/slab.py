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
edge samples. The focal surface is the depth of the *nearest* sample: at a silhouette it may
belong to the background (0: the focal plane is used) or to the other surface.

Two implementations of the same math: :func:`render_rays` / :func:`lookup` for arbitrary rays
(numpy, float64 coordinates, all taps of a ray gathered at once), and :func:`render_view` for
pinhole cameras (the compiled kernels of :mod:`render.slab_kernels`, one pass per pixel, bands
of rows on several threads); tests check one against the other.

Compression: ``radiance`` may be a :class:`VQRadiance` (2 x 2 x 2 x 2 ray tiles coded against a
codebook, Levoy and Hanrahan's section 4); both paths look rays up through the codebook, so a
compressed slab renders without being decoded.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .camera import Camera, Intrinsics

__all__ = ["MODES", "SlabGeometry", "VQRadiance", "LightSlab", "SlabHits", "slab_coordinates", "lookup",
           "select_slabs", "render_rays", "render_view", "sheared_camera"]

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


#: codeword indices of up to 2**16 entries are stored as uint16, larger codebooks as uint32
_CODE_DTYPES = (np.uint16, np.uint32)


@dataclass
class VQRadiance:
    """Slab radiance vector-quantized in tiles of 2 x 2 x 2 x 2 rays (Levoy and Hanrahan 1996, 4.1).

    codes: (Tv, Tu, Tt, Ts) uint16 (uint32 for codebooks beyond 65536 entries) with T = ceil(N / 2)
    per axis: each tile's codeword. codebook: (K, 2, 2, 2, 2, 3) float32, one tile's rays in axis
    order (v, u, t, s), linear RGB. Ray (iv, iu, it, is) of the slab is
    ``codebook[codes[iv // 2, iu // 2, it // 2, is // 2], iv % 2, iu % 2, it % 2, is % 2]``.
    shape: the decoded array's (Nv, Nu, Nt, Ns, 3); with an odd count the last tile is half used.
    The renderer looks rays up through the codebook directly (two gathers instead of one).
    """

    codes: np.ndarray
    codebook: np.ndarray
    shape: tuple[int, int, int, int, int]

    def __post_init__(self) -> None:
        self.shape = tuple(int(n) for n in self.shape)
        if len(self.shape) != 5 or self.shape[4] != 3 or min(self.shape) < 1:
            raise ValueError(f"VQ radiance shape must be (Nv, Nu, Nt, Ns, 3), got {self.shape}")
        tiles = tuple((n + 1) // 2 for n in self.shape[:4])
        if self.codes.shape != tiles or self.codes.dtype not in _CODE_DTYPES:
            raise ValueError(f"VQ codes must be {tiles} uint16/uint32, got {self.codes.shape} {self.codes.dtype}")
        cb = self.codebook
        if cb.ndim != 6 or cb.shape[1:] != (2, 2, 2, 2, 3) or cb.dtype != np.float32 or len(cb) < 1:
            raise ValueError(f"VQ codebook must be (K, 2, 2, 2, 2, 3) float32, got {cb.shape} {cb.dtype}")
        if self.codes.size and int(self.codes.max()) >= len(cb):
            raise ValueError(f"VQ codes index beyond the codebook's {len(cb)} entries")

    dtype = np.dtype(np.float32)

    @property
    def nbytes(self) -> int:
        return int(self.codes.nbytes + self.codebook.nbytes)

    def decode(self, out: np.ndarray | None = None) -> np.ndarray:
        """(Nv, Nu, Nt, Ns, 3) float32 radiance (into ``out`` when given, e.g. a memmap), decoded
        one row of uv tiles at a time (bounded memory)."""
        nv, nu, nt, ns, _ = self.shape
        if out is None:
            out = np.empty(self.shape, np.float32)
        elif out.shape != self.shape:
            raise ValueError(f"decode target must be {self.shape}, got {out.shape}")
        tv, tu, tt, ts = self.codes.shape
        for j in range(tv):
            tiles = self.codebook[self.codes[j]]                       # (Tu, Tt, Ts, 2, 2, 2, 2, 3)
            rows = tiles.transpose(3, 0, 4, 1, 5, 2, 6, 7).reshape(2, 2 * tu, 2 * tt, 2 * ts, 3)
            take = min(2, nv - 2 * j)
            out[2 * j:2 * j + take] = rows[:take, :nu, :nt, :ns]
        return out


@dataclass
class LightSlab:
    """A slab's geometry and samples.

    radiance: (Nv, Nu, Nt, Ns, 3) float32 linear RGB (a numpy array or memmap), or the same
    vector-quantized (:class:`VQRadiance`).
    depth: optional (Nv, Nu, Nt, Ns) float32 distance along ``forward`` from the uv plane to the
    first surface (0 = nothing). focal_depth: distance from the uv plane of the focal plane the
    ``depth`` mode uses where there is no depth (None: the st plane, i.e. ``distance``).
    """

    geometry: SlabGeometry
    radiance: np.ndarray | VQRadiance
    depth: np.ndarray | None = None
    focal_depth: float | None = None

    def __post_init__(self) -> None:
        g = self.geometry
        if tuple(self.radiance.shape) != g.array_shape or self.radiance.dtype != np.float32:
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

    @property
    def compressed(self) -> bool:
        return isinstance(self.radiance, VQRadiance)


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


def _axis(c: np.ndarray, n: int, linear: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Taps along one axis of ``n`` samples at continuous sample coordinates ``c`` (...) (sample i
    at c = i, i.e. c = x n - 0.5 for a parameter x in [0, 1]), edge-clamped.

    Returns ``(index (..., K) intp, weight (..., K) float32 or None)``: K = 1 nearest tap (weight
    None = 1), or K = 2 linear taps."""
    c = np.clip(c, 0.0, n - 1.0)
    if not linear or n == 1:
        return np.floor(c + 0.5).astype(np.intp)[..., None], None
    f0 = np.minimum(np.floor(c), n - 2.0)
    f = (c - f0).astype(np.float32)
    i0 = f0.astype(np.intp)
    return np.stack([i0, i0 + 1], -1), np.stack([1 - f, f], -1)


def _pairs(a: np.ndarray, b: np.ndarray, sa: int, sb: int) -> np.ndarray:
    """(N, A * B) index parts ``a * sa + b * sb`` of every outer tap ``a`` (N, A) with its inner
    taps ``b`` (N, A or 1, B)."""
    return (a[:, :, None] * sa + b * sb).reshape(len(a), -1)


def _pair_weights(wa: np.ndarray | None, wb: np.ndarray | None, n: int) -> np.ndarray | None:
    if wa is None and wb is None:
        return None
    w = wb if wa is None else (wa[:, :, None] if wb is None else wa[:, :, None] * wb)
    return w.reshape(n, -1)


def _fetch(radiance, iv, it, iu, is_) -> np.ndarray:
    """(N, K, 3) float32 samples of every tap combination: rows (v, t) taps ``iv`` (N, A),
    ``it`` (N, A|1, B) by columns (u, s) taps ``iu`` (N, C), ``is_`` (N, C|1, E); K = A B C E."""
    n = len(iv)
    if isinstance(radiance, VQRadiance):
        tv, tu, tt, ts = radiance.codes.shape
        tile = (_pairs(iv >> 1, it >> 1, tu * tt * ts, ts)[:, :, None]
                + _pairs(iu >> 1, is_ >> 1, tt * ts, 1)[:, None, :]).reshape(n, -1)
        off = (_pairs(iv & 1, it & 1, 8, 2)[:, :, None] + _pairs(iu & 1, is_ & 1, 4, 1)[:, None, :]).reshape(n, -1)
        code = radiance.codes.reshape(-1).take(tile).astype(np.intp)
        return radiance.codebook.reshape(-1, 3).take(code * 16 + off, axis=0)
    nv, nu, nt, ns = radiance.shape[:4]
    idx = (_pairs(iv, it, nu * nt * ns, ns)[:, :, None] + _pairs(iu, is_, nt * ns, 1)[:, None, :]).reshape(n, -1)
    return np.asarray(radiance).reshape(-1, 3).take(idx, axis=0)


def _interpolate(slab: "LightSlab", u, v, s, t, mode: str) -> np.ndarray:
    """(N, 3) float32 radiance at slab parameters u, v, s, t (N,) in [0, 1] (float32 or float64).

    Every mode gathers the product of per-axis taps in one indexing operation. In ``depth`` mode
    the s (t) taps depend on the u (v) tap: the ray of uv sample U through the focal point F on
    the eye ray crosses st at P = U + (D / zeta) (F - U); in sample units that is
    c_s' = c_s + (D / zeta - 1) (W_u n_s / (W_s n_u)) (c_u - i_u) with c_x = x n_x - 0.5."""
    g = slab.geometry
    nu, nv, ns, nt = g.shape
    n = len(u)
    if n == 0:
        return np.zeros((0, 3), np.float32)
    cu, cv, cs, ct = u * nu - 0.5, v * nv - 0.5, s * ns - 0.5, t * nt - 0.5
    lin_uv = mode in ("uv", "quadrilinear", "depth")
    lin_st = mode in ("st", "quadrilinear", "depth")
    iu, wu = _axis(cu, nu, lin_uv)
    iv, wv = _axis(cv, nv, lin_uv)
    if mode == "depth":
        D = g.distance
        zeta = np.full(n, D if slab.focal_depth is None else slab.focal_depth, np.float32)
        if slab.depth is not None:
            near = [_axis(c, m, False)[0][:, 0] for c, m in ((cv, nv), (cu, nu), (ct, nt), (cs, ns))]
            z = np.asarray(slab.depth).reshape(-1).take(((near[0] * nu + near[1]) * nt + near[2]) * ns + near[3])
            zeta = np.where(z > 1e-6 * D, z, zeta)  # 0 = no surface: keep the focal plane
        shift = D / zeta - 1.0
        ks = g.uv_size[0] * ns / (g.st_size[0] * nu)
        kt = g.uv_size[1] * nt / (g.st_size[1] * nv)
        is_, ws = _axis(cs[:, None] + (shift * ks)[:, None] * (cu[:, None] - iu), ns, True)  # (N, 2, 2)
        it, wt = _axis(ct[:, None] + (shift * kt)[:, None] * (cv[:, None] - iv), nt, True)
    else:
        is_, ws = _axis(cs, ns, lin_st)
        it, wt = _axis(ct, nt, lin_st)
        is_, it = is_[:, None], it[:, None]
        ws, wt = (None if w is None else w[:, None] for w in (ws, wt))
    vals = _fetch(slab.radiance, iv, it, iu, is_)
    w_row, w_col = _pair_weights(wv, wt, n), _pair_weights(wu, ws, n)
    if w_row is None and w_col is None:
        return vals[:, 0]
    if w_row is None:
        w = w_col
    elif w_col is None:
        w = w_row
    else:
        w = (w_row[:, :, None] * w_col[:, None, :]).reshape(n, -1)
    return np.einsum("nk,nkc->nc", w, vals)


def lookup(slab: LightSlab, hits_or_coords, mode: str = "quadrilinear") -> np.ndarray:
    """Interpolate a slab at valid ray coordinates.

    hits_or_coords: :class:`SlabHits` restricted to valid rays, or (N, 4) (u, v, s, t) in [0, 1]
    (float64 or float32). Returns (N, 3) float32 radiance.
    """
    if mode not in MODES:
        raise ValueError(f"unknown interpolation mode {mode!r}; known: {list(MODES)}")
    coords = hits_or_coords.coords if isinstance(hits_or_coords, SlabHits) else hits_or_coords
    coords = np.asarray(coords)
    if coords.dtype not in (np.float32, np.float64):
        coords = coords.astype(np.float64)
    coords = coords.reshape(-1, 4)
    return _interpolate(slab, *coords.T, mode).astype(np.float32, copy=False)


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


def _coords_of(h: SlabHits, sel: np.ndarray) -> list[np.ndarray]:
    """(u, v, s, t) arrays of the rays ``sel``."""
    return list(h.coords[sel].T)


def render_rays(slabs: Sequence[LightSlab], origins: np.ndarray, dirs: np.ndarray, mode: str = "quadrilinear",
                background=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Radiance (N, 3) float32 of eye rays looked up in a slab set; rays missing every slab get
    ``background`` (3,) linear RGB. origins, dirs: (N, 3) world rays (eye -> scene)."""
    if mode not in MODES:
        raise ValueError(f"unknown interpolation mode {mode!r}; known: {list(MODES)}")
    o, d = _check_rays(origins, dirs)
    return _render_hits(slabs, [slab_coordinates(s.geometry, o, d) for s in slabs], mode, background)


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
            out[sel] = _interpolate(slab, *_coords_of(hits[k], sel), mode)
    return out


def _kernel_params(slab: LightSlab, pix_to_world: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """(N_PARAMS,) float64 parameters of :mod:`render.slab_kernels` for a slab seen by a pinhole
    camera with pixel (x, y, 1) -> world direction map ``pix_to_world`` = R_cam K^-1 (3, 3) and
    centre ``eye`` (3,): the slab-frame direction map A = R_slab R_cam K^-1, the eye in the slab
    frame, the slab's sizes and its default focal distance."""
    g = slab.geometry
    A = g.rotation @ pix_to_world
    eye = g.rotation @ (eye - g.uv_corners[0])
    focal = g.distance if slab.focal_depth is None else float(slab.focal_depth)
    return np.concatenate([A.reshape(-1), eye, [g.distance], g.uv_size, g.st_size, g.st_offset, [focal]])


def _kernel_arrays(slab: LightSlab) -> tuple:
    """(dims, rad, depth, codes, codebook, tdims) of a slab as the kernels take them (views, no copies)."""
    nu, nv, ns, nt = slab.geometry.shape
    dims = np.array([nu, nv, ns, nt], np.int64)
    depth = np.zeros(0, np.float32) if slab.depth is None else np.asarray(slab.depth).reshape(-1)
    r = slab.radiance
    if isinstance(r, VQRadiance):
        return (dims, np.zeros((0, 3), np.float32), depth, r.codes.reshape(-1), r.codebook.reshape(-1, 3),
                np.array(r.codes.shape, np.int64))
    return (dims, np.asarray(r).reshape(-1, 3), depth, np.zeros(0, np.uint16), np.zeros((0, 3), np.float32),
            np.zeros(4, np.int64))


def render_view(slabs: Sequence[LightSlab], camera: Camera, mode: str = "quadrilinear",
                background=(0.0, 0.0, 0.0), threads: int = 2) -> np.ndarray:
    """(H, W, 3) float32 linear image of ``camera`` rendered from a slab set (every pixel centre);
    each pixel's ray is looked up in the slab it crosses most steeply, else gets ``background``.

    Pinhole cameras render through the compiled kernels of :mod:`render.slab_kernels` in
    ``threads`` bands of rows at once (the kernels release the GIL); cameras with lens distortion
    take the general per-ray path (:func:`render_rays`)."""
    if mode not in MODES:
        raise ValueError(f"unknown interpolation mode {mode!r}; known: {list(MODES)}")
    bg = np.asarray(background, dtype=np.float32).reshape(-1)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ValueError(f"background must be three finite numbers, got {background!r}")
    k = camera.intrinsics
    if k.has_distortion or not slabs:
        return render_rays(slabs, *camera.pixel_rays(), mode=mode, background=bg).reshape(k.height, k.width, 3)
    from . import slab_kernels as sk

    pix_to_world = camera.cam_to_world[:3, :3] @ np.linalg.inv(k.K)
    params = np.stack([_kernel_params(s, pix_to_world, camera.center) for s in slabs])
    arrays = [_kernel_arrays(s) for s in slabs]
    out = np.empty((k.height * k.width, 3), np.float32)
    out[:] = bg
    mode_id = sk.MODE_IDS[mode]

    def band(rows: tuple[int, int]) -> None:
        r0, r1 = rows
        best = np.empty((r1 - r0) * k.width, np.int64)
        sk.select_band(params, r0, r1, k.width, best)
        part = out[r0 * k.width:r1 * k.width]
        for i, arr in enumerate(arrays):
            sk.interpolate_band(params, *arr[:6], mode_id, best, i, r0, r1, k.width, part)

    threads = max(1, min(int(threads), k.height))
    edges = np.linspace(0, k.height, threads + 1).astype(int)
    bands = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
    if threads == 1:
        band(bands[0])
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(band, bands))
    return out.reshape(k.height, k.width, 3)


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
