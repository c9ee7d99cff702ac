"""Two-plane light slabs (Levoy and Hanrahan 1996): geometry and the ray-to-slab mapping.

A light slab stores the radiance of the oriented lines that cross two parallel rectangles, the
*uv* quad (where the eyes are) and the *st* quad (the focal plane, through the object). Pure
functions over arrays: nothing here knows files or stages (:mod:`render.lightfield.storage`
reads and writes slab sets; :mod:`render.lightfield.rendering` looks rays up and interpolates).

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
* ``radiance`` is ``(Nv, Nu, Nt, Ns, 3)`` float32 (or float16) linear RGB: an Nv x Nu grid of
  Nt x Ns images, row-major like images (memory-mappable). ``depth`` (optional) is ``(Nv, Nu, Nt, Ns)``
  float32 (or float16): the distance along ``forward`` from the uv plane to the first surface on that ray
  (the sheared camera's z-depth), 0 where the ray hits nothing.

Compression: ``radiance`` may be a :class:`VQRadiance` (2 x 2 x 2 x 2 ray tiles coded against a
codebook, Levoy and Hanrahan's section 4); the renderers look rays up through the codebook, so a
compressed slab renders without being decoded.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera, Intrinsics

__all__ = ["SlabGeometry", "VQRadiance", "LightSlab", "SlabHits", "MIN_COS", "EMPTY_DEPTH", "FAR_DEPTH",
           "DEPTH_SEARCH_STEPS", "VISIBILITY_TOL", "SAMPLE_DTYPES", "check_rays", "slab_coordinates",
           "sheared_camera"]

#: rays whose direction makes |cos| below this with a slab's normal are treated as parallel
#: to its planes (the plane-intersection denominator would be near zero): they miss the slab
MIN_COS = 1e-6

#: the depth mode's depth search (:mod:`render.lightfield.rendering`): a depth sample below
#: EMPTY_DEPTH x D (D: the slab's uv -> st distance) means the ray hit nothing, and is read as a
#: surface at FAR_DEPTH x D (background "at infinity": rays parallel to the eye ray, shift -0.9999)
EMPTY_DEPTH = 1e-6
FAR_DEPTH = 1e4
#: fixed-point steps per uv tap when searching the eye ray's depth
DEPTH_SEARCH_STEPS = 3
#: a uv tap sees the eye ray's surface when its depth agrees in D / depth within this (2% of the
#: depth near the st plane): looser loses occlusion, tighter rejects slanted surfaces' taps
VISIBILITY_TOL = 0.02


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


#: sample dtypes a slab's radiance and depth arrays may have: float16 halves the memory of a slab
#: set sized to the capture's pixels (a relative rounding of 2^-11, far below 8-bit display steps)
SAMPLE_DTYPES = (np.dtype(np.float32), np.dtype(np.float16))


@dataclass
class LightSlab:
    """A slab's geometry and samples.

    radiance: (Nv, Nu, Nt, Ns, 3) float32 or float16 linear RGB (a numpy array or memmap), or the
    same vector-quantized (:class:`VQRadiance`).
    depth: optional (Nv, Nu, Nt, Ns) float32 or float16 distance along ``forward`` from the uv
    plane to the first surface (0 = nothing). focal_depth: distance from the uv plane of the focal
    plane the ``depth`` mode uses where there is no depth (None: the st plane, i.e. ``distance``).
    Renderers read float16 samples as the float32 values they round-trip to.
    """

    geometry: SlabGeometry
    radiance: np.ndarray | VQRadiance
    depth: np.ndarray | None = None
    focal_depth: float | None = None

    def __post_init__(self) -> None:
        g = self.geometry
        if tuple(self.radiance.shape) != g.array_shape or self.radiance.dtype not in SAMPLE_DTYPES:
            raise ValueError(f"slab {g.name!r}: radiance must be {g.array_shape} float32 or float16, "
                             f"got {self.radiance.shape} {self.radiance.dtype}")
        if self.depth is not None and (self.depth.shape != g.array_shape[:4] or self.depth.dtype not in SAMPLE_DTYPES):
            raise ValueError(f"slab {g.name!r}: depth must be {g.array_shape[:4]} float32 or float16, "
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


def check_rays(origins, dirs) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float64 origins and directions from any (..., 3) arrays; ValueError when their shapes
    differ or a value is not finite."""
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
    o, d = check_rays(origins, dirs)
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
