"""``irradiance_cache``: Ward's irradiance cache on the path tracer's kernels (biased, consistent).

Ward, Rubinstein and Clear 1988 ("A ray tracing solution for diffuse interreflection"): the
irradiance E(x) = \\int L_i(x, w) cos(theta) dw varies slowly over diffuse surfaces, so it is
computed accurately at sparse *records* x_i (normal n_i) and interpolated between them with the
weights

    w_i(x) = 1 / (|x - x_i| / R_i + sqrt(1 - n . n_i))

(R_i: the harmonic mean distance of the record's hemisphere rays to what they hit, clamped to
[min_spacing, max_spacing] x the scene's extent). A record serves x when its error estimate
1 / w_i(x) <= a (the error bound, Options.error_bound; w_i > 1/a in Ward's words), n . n_i > 0
(never across a normal flip: the two sides of a wall see different hemispheres) and x_i is not
in front of x (Ward's test (x - x_i) . (n + n_i) / 2 >= -0.01 R_i). E(x) = sum_i w_i E_i / sum_i w_i
over the records serving x (of its ``NEIGHBOURS`` nearest). No gradients (Ward and Heckbert
1992's translational / rotational gradients are not implemented): interpolation is the plain
weighted mean.

A record's irradiance is estimated from ``record_rays`` cosine-weighted hemisphere rays
(stratified in cos^2 theta), E_i = pi / K sum_k L_k; each ray's radiance L_k is the reference
path tracer's estimate, from the ray's first hit on (next-event estimation, MIS, Russian
roulette), by the same compiled kernels (:func:`render.integrators.path_kernels.shade_bounce`)
started at depth 1. With ``cache_direct`` False (the default, Ward's and Radiance's practice)
records hold *indirect* irradiance only (emission and background found by the first hemisphere
ray are dropped: the kernels' caustic-pruning flag does exactly that), and direct light at the
first diffuse vertex is computed per pixel sample by ``direct``'s kernels (emission seen by
the camera included), so shadows stay sharp; with True, records hold the total irradiance.

Record placement is wavefront, not a per-pixel loop (Ward places records lazily, pixel by
pixel): the query points are the first hits of all the camera samples of a group; in rounds,
the points no record serves are binned into cells of size a R / 2^round (R the previous
records' median spacing; one cell per normal direction class, so corners get records on each
wall), one random point per cell becomes a new record, and all new records of the round are
traced together. After ``ROUNDS`` rounds every point still unserved becomes a record. With
a = 0 every point is its own record, and the estimate is the path tracer's first-bounce
irradiance estimator (unbiased; tests/render/test_irradiance_cache.py).

Pixel values: the mean over the pixel's samples of direct light (``direct``'s estimate), plus
the mean over its first ``lookup_spp`` samples (per group) of albedo(x) / pi * E(x) at their
first hits x that are Lambertian (textured albedo included): each mean is unbiased for its part
of the pixel's box-filtered radiance, and the indirect part, smooth and interpolated, needs far
fewer samples than the direct part (lookups, not records, would dominate the time otherwise).
The query points of a group's cache are those looked-up samples' first hits.
Reaches effects direct, shadows, soft_shadows, interreflection; specular surfaces, caustics,
media and GGX materials are refused by :func:`render.integrators.choice.choose_integrator`
(one line naming the effect); without 'interreflection' among the effects there is nothing to
cache and the render is ``direct``'s. ``auto`` never picks it (it is biased).

Groups: like sppm, a render's samples are split into :data:`GROUPS` independent groups, each
with its own cache built from its own samples' first hits; the film holds one image per group,
so the variance image is that of the mean across groups (the noise; not the interpolation bias
all groups share). Random numbers: records are keyed by (seed, group, record index, ray).

For the bias study: :func:`cached_irradiance` (irradiance at given points and normals, total,
through the same cache) and :func:`cache_records` (the cache itself, with its stats).
"""
from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from ..accel import offset_eps
from ..camera import Camera
from ..film import Film, RenderResult, whole_groups
from ..sampling import _GOLDEN, _M2, _mix64, orthonormal_frame
from ..scene import Scene
from .path import _trace, kernel_scene_of, path_config, pinhole_of
from .path_kernels import F_AFTER_DIFF, F_DELTA, LAMBERT, sample_camera_rays
from .prepared import PreparedScene, prepare
from .settings import RenderSettings, check_heuristic
from .wavefront import continue_paths, new_state

__all__ = ["Options", "render_result", "render_cache", "GROUPS", "ROUNDS", "NEIGHBOURS", "IrradianceCache",
           "cache_records", "cached_irradiance", "ward_weight", "ward_error"]

#: independent groups a render's samples are split into (fewer when spp < GROUPS), each with its own cache
GROUPS = 4
#: placement rounds before every point still unserved becomes a record of its own
ROUNDS = 6
#: records considered per query point (its nearest): the interpolation's and the coverage test's set
NEIGHBOURS = 8
_RECORD_BATCH = 1 << 17  # record rays per wavefront batch
_LOOKUP_BATCH = 1 << 17  # query points per k-nearest lookup (bounds the (N, NEIGHBOURS) arrays)
_EPS_FLOOR = 1e-9  # smallest error estimate: a point on a record gets a large, finite weight


@dataclass(frozen=True)
class Options:
    """Options of ``irradiance_cache`` (roulette, rr_depth, heuristic: RenderSettings fields of
    the same names; the others are not on the CLI and keep their defaults there)."""

    #: Ward's error bound a: record i serves x when 1 / w_i(x) <= a (0: every point its own record)
    error_bound: float = 0.3
    #: cosine-weighted hemisphere rays per record, each continued by path's kernels
    record_rays: int = 256
    #: smallest record spacing R_i as a fraction of the scene's extent (Radiance's -ar)
    min_spacing: float = 0.005
    #: largest record spacing R_i as a fraction of the scene's extent
    max_spacing: float = 0.15
    #: camera samples per pixel (of each group) that look the cache up; all samples add direct light
    lookup_spp: int = 4
    #: records hold total irradiance (True) or indirect only, direct light per pixel sample (False)
    cache_direct: bool = False
    #: Russian roulette on the record rays' paths when leaving vertices of index >= rr_depth
    roulette: bool = True
    #: first vertex index (0: the record's point) whose outgoing path roulette may end
    rr_depth: int = 3
    #: MIS weights on the record rays' paths: "power" or "balance" (Veach and Guibas)
    heuristic: str = "power"

    def __post_init__(self):
        check_heuristic(self.heuristic)
        if not (math.isfinite(self.error_bound) and self.error_bound >= 0):
            raise ValueError(f"irradiance_cache: error_bound must be finite and >= 0, got {self.error_bound}")
        if self.record_rays < 1:
            raise ValueError(f"irradiance_cache: record_rays must be >= 1, got {self.record_rays}")
        if not 0 < self.min_spacing <= self.max_spacing:
            raise ValueError("irradiance_cache: need 0 < min_spacing <= max_spacing, got "
                             f"{self.min_spacing}, {self.max_spacing}")
        if self.lookup_spp < 1:
            raise ValueError(f"irradiance_cache: lookup_spp must be >= 1, got {self.lookup_spp}")
        if self.rr_depth < 0:
            raise ValueError(f"irradiance_cache: rr_depth must be >= 0, got {self.rr_depth}")


def ward_error(x: np.ndarray, n: np.ndarray, xi: np.ndarray, ni: np.ndarray, Ri: np.ndarray) -> np.ndarray:
    """Ward's error estimate 1 / w_i(x) = |x - x_i| / R_i + sqrt(1 - n . n_i), broadcast over
    leading axes: x, n, xi, ni (..., 3) float64 (unit normals), Ri (...) > 0. Returns (...)."""
    d = np.sqrt(np.sum((x - xi) ** 2, axis=-1))
    c = np.clip(np.sum(n * ni, axis=-1), -1.0, 1.0)
    return d / Ri + np.sqrt(1.0 - c)


def ward_weight(x: np.ndarray, n: np.ndarray, xi: np.ndarray, ni: np.ndarray, Ri: np.ndarray) -> np.ndarray:
    """Ward's interpolation weight w_i(x) = 1 / (|x - x_i| / R_i + sqrt(1 - n . n_i)) (shapes as
    :func:`ward_error`), finite: the error is floored at 1e-9 (a point on a record)."""
    return 1.0 / np.maximum(ward_error(x, n, xi, ni, Ri), _EPS_FLOOR)


@dataclass
class IrradianceCache:
    """The records of one cache. position, normal: (M, 3) float64 (unit normals); irradiance:
    (M, 3) float64 W/m^2 per channel (indirect only unless ``total``); spacing: (M,) R_i in scene
    units; stats: records, record_rays (traced hemisphere rays), rays (every ray traced),
    rounds, create_s (time tracing records), lookup_s (time finding and weighting records)."""

    position: np.ndarray
    normal: np.ndarray
    irradiance: np.ndarray
    spacing: np.ndarray
    error_bound: float
    total: bool
    stats: dict = field(default_factory=dict)
    _tree: cKDTree | None = None

    def tree(self) -> cKDTree:
        if self._tree is None or self._tree.n != len(self.position):
            self._tree = cKDTree(self.position)
        return self._tree

    def lookup(self, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated irradiance at points (N, 3) with unit normals (N, 3): ((N, 3) float64,
        (N,) bool served). Unserved points (no valid record among their NEIGHBOURS nearest) get 0."""
        t0 = time.perf_counter()
        n = len(points)
        out = np.zeros((n, 3))
        served = np.zeros(n, bool)
        if len(self.position) and n:
            tree = self.tree()
            k = min(NEIGHBOURS, len(self.position))
            reach = self.error_bound * float(self.spacing.max()) * (1 + 1e-9) + 1e-12 * float(np.abs(self.position).max())
            for s in range(0, n, _LOOKUP_BATCH):
                p, nr = points[s:s + _LOOKUP_BATCH], normals[s:s + _LOOKUP_BATCH]
                # a record serves within a R_i of itself at most: search no farther (absent: index M)
                _, idx = tree.query(p, k=k, distance_upper_bound=reach)
                _interpolate(p, nr, np.ascontiguousarray(idx.reshape(len(p), k), dtype=np.int64), self.position,
                             self.normal, self.irradiance, self.spacing, float(self.error_bound),
                             out[s:s + len(p)], served[s:s + len(p)])
        self.stats["lookup_s"] = self.stats.get("lookup_s", 0.0) + time.perf_counter() - t0
        return out, served


@njit(cache=True, nogil=True)
def _interpolate(points, normals, idx, pos, nrm, E, R, a, out, served):
    """Ward's interpolation over each point's candidate records (compiled: one pass, no (N, k, 3)
    temporaries). points, normals (N, 3); idx (N, k) int64 candidates; pos, nrm, E (M, 3), R (M,)
    the records; a the error bound. Writes out (N, 3) (0 where unserved) and served (N,) bool.
    A record serves x when ward_error <= a, n . n_i > 0 (no reuse across a normal flip) and
    (x - x_i) . (n + n_i) / 2 >= -0.01 R_i (Ward's test: x_i not in front of x)."""
    for i in range(len(points)):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        ws, e0, e1, e2 = 0.0, 0.0, 0.0, 0.0
        for j in range(idx.shape[1]):
            r = idx[i, j]
            if r >= len(pos):  # fewer than k records within reach
                break
            dx, dy, dz = px - pos[r, 0], py - pos[r, 1], pz - pos[r, 2]
            c = nx * nrm[r, 0] + ny * nrm[r, 1] + nz * nrm[r, 2]
            if not c > 0.0:
                continue
            if 0.5 * (dx * (nx + nrm[r, 0]) + dy * (ny + nrm[r, 1]) + dz * (nz + nrm[r, 2])) < -0.01 * R[r]:
                continue
            err = math.sqrt(dx * dx + dy * dy + dz * dz) / R[r] + math.sqrt(max(0.0, 1.0 - min(c, 1.0)))
            if not err <= a:
                continue
            w = 1.0 / max(err, _EPS_FLOOR)
            ws += w
            e0 += w * E[r, 0]
            e1 += w * E[r, 1]
            e2 += w * E[r, 2]
        if ws > 0.0:
            out[i, 0], out[i, 1], out[i, 2] = e0 / ws, e1 / ws, e2 / ws
            served[i] = True
        else:
            out[i, 0] = out[i, 1] = out[i, 2] = 0.0
            served[i] = False


def _record_keys(seed: int, stream: int, first: int, count: int, rays: int) -> np.ndarray:
    """(count * rays,) uint64 RNG keys of the hemisphere rays of records first .. first + count
    of stream ``stream`` (a group): hashes of (seed, stream, record, ray), render.sampling's mix."""
    s = _mix64(np.array([np.uint64(seed & 0xFFFFFFFFFFFFFFFF)], np.uint64) + _GOLDEN)[0]
    s = _mix64(s ^ (np.array([stream], np.uint64) * _M2 + _GOLDEN))[0]  # arrays: uint64 wraps silently
    rec = _mix64((np.arange(first, first + count, dtype=np.uint64) * _GOLDEN) ^ s)
    ray = np.arange(rays, dtype=np.uint64) * _M2 + _GOLDEN
    return _mix64(rec[:, None] ^ ray[None, :]).ravel()


def _uniform01(keys: np.ndarray, dim: int) -> np.ndarray:
    """render.sampling.uniform: (N,) float64 in [0, 1) of dimension ``dim`` of each key."""
    x = _mix64(keys + np.array([dim + 1], np.uint64) * _GOLDEN)
    return (x >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def _trace_records(ps: PreparedScene, cfg, points: np.ndarray, normals: np.ndarray, rays: int, keys: np.ndarray,
                   total: bool) -> tuple[np.ndarray, np.ndarray, int]:
    """Hemisphere rays of M records: points, normals (M, 3) float64, ``rays`` each with RNG keys
    (M * rays,). Returns (sum over rays of the incident radiance (M, 3), sum over rays of 1 / hit
    distance (M,) (0 for escaping rays), rays traced). Directions are cosine-weighted about the
    normal, stratified in u = cos^2 theta ((k + xi) / rays, dims 0, 1 of each key, which the
    kernels' depth >= 1 never read); each is continued by shade_bounce from depth 1."""
    m = len(points)
    ks = kernel_scene_of(ps)
    n = m * rays
    strata = np.tile(np.arange(rays, dtype=np.float64), m)
    u0 = (strata + _uniform01(keys, 0)) / rays
    phi = 2.0 * np.pi * _uniform01(keys, 1)
    r = np.sqrt(u0)
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u0))], axis=1)
    nrm = np.repeat(normals, rays, axis=0)
    s, t = orthonormal_frame(nrm)
    d = local[:, :1] * s + local[:, 1:2] * t + local[:, 2:3] * nrm
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p = np.repeat(points, rays, axis=0)
    o = p + offset_eps(p, ps.geom.extent)[:, None] * nrm
    cur = new_state(n)
    cur[0][:] = np.arange(n)
    cur[1][:] = keys
    cur[2][:] = 1.0
    cur[3][:] = local[:, 2] / np.pi  # the cosine density (read only by MIS on emission, pruned or delta below)
    # total: the first hit's emission and the background count in full (as after a delta
    # vertex); indirect only: F_AFTER_DIFF with F_DELTA is the kernels' pruned caustic path,
    # which adds neither emission nor background at that hit and continues as a diffuse path
    cur[4][:] = F_DELTA if total else (F_DELTA | F_AFTER_DIFF)
    cur[5][:] = o
    cur[6][:] = d
    hits = ps.accel.intersect_fast(cur[5], cur[6])
    prim, tfar = hits[0], hits[1]
    hit = prim >= 0  # Embree leaves tfar and u, v of a miss undefined: read them on hits only
    inv_t = np.zeros(n)
    inv_t[hit] = 1.0 / np.maximum(tfar[hit].astype(np.float64), 1e-30)
    L = np.zeros((n, 3))
    nrays = n + continue_paths(ps.accel, ks, cfg, cur, hits, 1, L)
    return L.reshape(m, rays, 3).sum(axis=1), inv_t.reshape(m, rays).sum(axis=1), nrays


def _make_records(ps: PreparedScene, cfg, points: np.ndarray, normals: np.ndarray, options: Options, seed: int,
                  stream: int, first: int, threads: int) -> tuple[np.ndarray, np.ndarray, int]:
    """New records at points / normals (M, 3): ((M, 3) irradiance, (M,) clamped spacing R_i,
    rays traced), batches of whole records over ``threads`` threads (the same sums whatever
    the threads: each record's rays stay in one batch)."""
    m, k = len(points), options.record_rays
    per = max(1, _RECORD_BATCH // k)
    chunks = [(c, min(c + per, m)) for c in range(0, m, per)]

    def work(ch):
        a, b = ch
        keys = _record_keys(seed, stream, first + a, b - a, k)
        return _trace_records(ps, cfg, points[a:b], normals[a:b], k, keys, options.cache_direct)

    pool = ThreadPoolExecutor(threads) if threads > 1 and len(chunks) > 1 else None
    try:
        results = list(pool.map(work, chunks) if pool is not None else map(work, chunks))
    finally:
        if pool is not None:
            pool.shutdown()
    if not results:
        return np.zeros((0, 3)), np.zeros(0), 0
    L = np.concatenate([r[0] for r in results])
    inv = np.concatenate([r[1] for r in results])
    extent = ps.geom.extent
    # harmonic mean distance K / sum(1 / t); escaping rays see infinitely far (1 / t = 0)
    R = np.where(inv > 0, k / np.maximum(inv, 1e-300), np.inf)
    R = np.clip(R, options.min_spacing * extent, options.max_spacing * extent)
    return np.pi * L / k, R, int(sum(r[2] for r in results))


def _direction_class(normals: np.ndarray) -> np.ndarray:
    """(N,) int64 in 0..5: the dominant axis of each normal and its sign (cells never mix walls)."""
    ax = np.argmax(np.abs(normals), axis=1)
    return 2 * ax + (normals[np.arange(len(normals)), ax] < 0)


def build_cache(ps: PreparedScene, points: np.ndarray, normals: np.ndarray, options: Options, max_depth: int,
                seed: int, stream: int = 0, threads: int = 2) -> IrradianceCache:
    """The cache serving every query point: points, normals (N, 3) float64 (unit normals on the
    side the irradiance is wanted). Rounds of wavefront placement (module docstring); records
    keyed by (seed, stream, record index). Every point is served when this returns."""
    t_all = time.perf_counter()
    # record rays are keyed by hashes of (seed, stream, record, ray): the independent sampler
    cfg = path_config(ps, max_depth, "mis", options.heuristic, options.roulette, options.rr_depth, False, False,
                      "independent")
    a = float(options.error_bound)
    cache = IrradianceCache(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), a,
                            options.cache_direct, {"records": 0, "record_rays": 0, "rays": 0, "rounds": 0,
                                                   "create_s": 0.0, "lookup_s": 0.0})
    n = len(points)
    if n == 0:
        return cache
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, int(stream), 7])
    unserved = np.arange(n)
    spacing = 0.5 * options.max_spacing * ps.geom.extent  # the first round's guess of R
    for rnd in range(ROUNDS + 1):
        if len(unserved) == 0:
            break
        if a == 0.0 or rnd == ROUNDS:
            chosen = unserved
        else:
            cell = max(a * spacing / 2.0 ** rnd, 1e-12 * ps.geom.extent)
            pts = points[unserved]
            ijk = np.floor(pts / cell).astype(np.int64).astype(np.uint64)
            # one 64-bit key per (cell, direction class): a hash (a rare collision merges two
            # cells for one round; the next round places what that left unserved)
            keys = _mix64(_mix64(_mix64(ijk[:, 0] + _GOLDEN) ^ ijk[:, 1]) ^ ijk[:, 2])
            keys = (keys & ~np.uint64(7)) | _direction_class(normals[unserved]).astype(np.uint64)
            order = rng.permutation(len(unserved))
            _, first = np.unique(keys[order], return_index=True)
            chosen = unserved[np.sort(order[first])]
        t0 = time.perf_counter()
        E, R, nr = _make_records(ps, cfg, points[chosen], normals[chosen], options, seed, stream,
                                 len(cache.position), threads)
        cache.stats["create_s"] += time.perf_counter() - t0
        cache.stats["rays"] += nr
        cache.stats["record_rays"] += len(chosen) * options.record_rays
        cache.position = np.concatenate([cache.position, points[chosen]])
        cache.normal = np.concatenate([cache.normal, normals[chosen]])
        cache.irradiance = np.concatenate([cache.irradiance, E])
        cache.spacing = np.concatenate([cache.spacing, R])
        cache.stats["rounds"] = rnd + 1
        spacing = float(np.median(cache.spacing))
        if a == 0.0:
            break
        _, served = cache.lookup(points[unserved], normals[unserved])
        unserved = unserved[~served]
    cache.stats["records"] = len(cache.position)
    cache.stats["build_s"] = time.perf_counter() - t_all
    return cache


def _check_points(points, normals) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise ValueError(f"irradiance_cache: points and normals must both be (N, 3), got {p.shape}, {n.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
        raise ValueError("irradiance_cache: points and normals must be finite")
    length = np.linalg.norm(n, axis=1)
    if np.any(length < 1e-12):
        raise ValueError("irradiance_cache: normals must be non-zero")
    return p, n / length[:, None]


def cache_records(scene: Scene, points: np.ndarray, normals: np.ndarray, error_bound: float, record_rays: int,
                  seed: int, max_depth: int = 8, prepared: PreparedScene | None = None) -> IrradianceCache:
    """The cache :func:`cached_irradiance` builds for these points: records placed among the
    points (N, 3) float64 with normals (N, 3) float64 (normalised here; the hemisphere on the
    normal's side) as the integrator places them among its first hits, each holding *total*
    irradiance (direct included: its hemisphere rays see emitters and the background).
    ``.stats``: records, record_rays, rays, rounds, create_s, lookup_s, build_s."""
    p, n = _check_points(points, normals)
    ps = prepared if prepared is not None else prepare(scene)
    options = Options(error_bound=float(error_bound), record_rays=int(record_rays), cache_direct=True)
    return build_cache(ps, p, n, options, int(max_depth), int(seed))


def cached_irradiance(scene: Scene, points: np.ndarray, normals: np.ndarray, error_bound: float, record_rays: int,
                      seed: int, max_depth: int = 8, prepared: PreparedScene | None = None,
                      stats: dict | None = None) -> np.ndarray:
    """Irradiance (W/m^2 per linear RGB channel) at points (N, 3) float64 on the side of normals
    (N, 3) float64, by Ward's cache with error bound ``error_bound`` and ``record_rays``
    cosine-weighted rays per record (:func:`cache_records`): total irradiance (direct light
    included, through the records). error_bound 0: every point its own record, the unbiased
    path-traced estimate. Returns (N, 3) float64; ``stats`` (a dict) receives the cache's stats."""
    p, n = _check_points(points, normals)
    cache = cache_records(scene, p, n, error_bound, record_rays, seed, max_depth, prepared)
    E, served = cache.lookup(p, n)
    assert served.all()  # build_cache serves every point it was given
    if stats is not None:
        stats.update(cache.stats)
    return E


# ------------------------------------------------------------------ the integrator
def _first_hits(ps: PreparedScene, cam: Camera, seed: int, sample0: int, start: int, stop: int, sampler: int):
    """The camera samples of flat indices [start, stop) as ``path`` generates them with
    ``sampler`` (a PathConfig.sampler code; same keys, same rays): (pixel (N,) int64, global
    triangle (N,) int64 (-1 on a miss), hit points (N, 3), geometric normals turned toward the
    camera (N, 3), barycentrics u, v (N,) float64)."""
    k = cam.intrinsics
    n = stop - start
    npix = k.width * k.height
    keys, pix = np.empty(n, np.uint64), np.empty(n, np.int64)
    o32, d32, jit = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 2))
    seed_mix = _mix64(np.array([np.uint64(seed & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    pinhole = not k.has_distortion
    sample_camera_rays(start, stop, npix, k.width, sample0, seed_mix, pinhole_of(cam), pinhole, keys, pix, o32, d32,
                       jit, sampler)
    if not pinhole:
        o, d = cam.pixel_rays(jit)
        o32[:], d32[:] = o, d
    prim, _, hu, hv = ps.accel.intersect_fast(o32, d32)
    hit = prim >= 0
    tri = np.where(hit, ps.accel.ids[np.maximum(prim, 0)], 0)
    u = np.where(hit, hu, np.float32(0)).astype(np.float64)  # Embree leaves a miss's u, v undefined
    v = np.where(hit, hv, np.float32(0)).astype(np.float64)
    p, ng = ps.geom.point_normal(tri, u, v)
    facing = np.sum(ng * d32.astype(np.float64), axis=1) > 0
    ng = np.where(facing[:, None], -ng, ng)
    return pix, np.where(hit, tri, -1), p, ng, u, v


def render_cache(scene: Scene, camera: Camera, settings: RenderSettings, options: Options,
                 sample_range: tuple[int, int], effects: frozenset, prepared: PreparedScene,
                 progress=None, groups: int = GROUPS) -> RenderResult:
    """The integrator with any :class:`Options` (what the caching study calls; render_result is
    the registry's door with RenderSettings' options). Groups of samples as the module says
    (``groups``: how many; 1 builds one cache from all samples, as Ward's, at the price of a
    zero variance image: the caching study's timed runs); stats: time_s, paths, rays, groups, records, record_rays, create_s (tracing records),
    lookup_s (placing and interpolating), direct_s (direct light per sample)."""
    a, b = sample_range
    group_list = whole_groups((a, b), settings.spp, groups, "irradiance_cache")
    t_start = time.perf_counter()
    ps = prepared
    k = camera.intrinsics
    npix = k.width * k.height
    film = Film(k.width, k.height)
    interreflection = "interreflection" in effects
    # direct light per sample (direct's kernels), or with cache_direct only what the camera sees.
    # Independent samples when there are several groups: Sobol points of consecutive indices are
    # stratified together, so contiguous groups of them would not be independent and the variance
    # across groups would overstate the noise (measured: 3x on the Cornell box); one group (the
    # caching study's timed runs, no variance image) takes path's default, Sobol
    sampler = "sobol" if len(group_list) == 1 and groups == 1 else "independent"
    direct_cfg = path_config(ps, 0 if options.cache_direct and interreflection else settings.max_depth,
                             "mis", options.heuristic, False, 0, True, False, sampler)
    query_emitters = ps.emit_accel is not None
    stats = {"time_s": 0.0, "paths": 0, "rays": 0, "groups": 0, "records": 0, "record_rays": 0,
             "create_s": 0.0, "lookup_s": 0.0, "direct_s": 0.0}
    kernel_scene_of(ps)
    lambert = ps.mats.kind == LAMBERT
    for g0, g1 in group_list:
        total = npix * (g1 - g0)
        t0 = time.perf_counter()
        L = np.zeros((total, 3))
        pix_all = np.empty(total, np.int64)
        chunks = [(c, min(c + settings.batch_paths, total)) for c in range(0, total, settings.batch_paths)]

        def direct_work(ch):
            return _trace(ps, camera, direct_cfg, settings.seed, query_emitters, ch[0], ch[1], g0)

        pool = ThreadPoolExecutor(settings.threads) if settings.threads > 1 and len(chunks) > 1 else None
        try:
            for ch, (pix, Ld, nr) in zip(chunks, pool.map(direct_work, chunks) if pool else map(direct_work, chunks)):
                L[ch[0]:ch[1]] = Ld
                pix_all[ch[0]:ch[1]] = pix
                stats["rays"] += nr
        finally:
            if pool is not None:
                pool.shutdown()
        stats["direct_s"] += time.perf_counter() - t0
        # the group's image: mean over its samples of direct light, plus the cached indirect term
        # averaged over the first ``lookups`` samples of each pixel (each mean unbiased for its part)
        image = np.zeros((npix, 3))
        for c in range(3):
            image[:, c] = np.bincount(pix_all, weights=L[:, c], minlength=npix) / (g1 - g0)
        lookups = min(options.lookup_spp, g1 - g0)
        if interreflection:
            nl = npix * lookups
            pix, tri, p, ng, u, v = _first_hits(ps, camera, settings.seed, g0, 0, nl, direct_cfg.sampler)
            stats["rays"] += nl
            obj = np.where(tri >= 0, ps.geom.obj[np.maximum(tri, 0)], 0)
            diffuse = (tri >= 0) & lambert[obj] if len(lambert) else np.zeros(nl, bool)
            if diffuse.any():
                sel = np.flatnonzero(diffuse)
                cache = build_cache(ps, p[sel], ng[sel], options, settings.max_depth, settings.seed,
                                    stream=g0, threads=settings.threads)
                E, _ = cache.lookup(p[sel], ng[sel])
                tri_s, u_s, v_s = tri[sel], u[sel], v[sel]
                albedo = ps.mats.diffuse_albedo(obj[sel], lambda m: ps.geom.texcoords(tri_s[m], u_s[m], v_s[m]))
                indirect = albedo / np.pi * E
                for c in range(3):
                    image[:, c] += np.bincount(pix[sel], weights=indirect[:, c], minlength=npix) / lookups
                for key in ("records", "record_rays", "create_s", "lookup_s"):
                    stats[key] += cache.stats[key]
                stats["rays"] += cache.stats["rays"]
        # one film sample per group (groups are independent)
        film.add_moments(image, image * image, np.ones(npix, np.int64))
        stats["paths"] += total
        stats["groups"] += 1
        if progress is not None:
            progress((g1 - a) * npix, (b - a) * npix)
    stats["time_s"] = time.perf_counter() - t_start
    return RenderResult.from_film(film, (a, b), "irradiance_cache", stats)


def render_result(scene: Scene, camera: Camera, settings: RenderSettings, options: Options,
                  sample_range: tuple[int, int], effects: frozenset, prepared: PreparedScene,
                  progress=None) -> RenderResult:
    """Render samples [a, b) = ``sample_range`` (whole groups: :func:`render.film.whole_groups`,
    ValueError naming the integrator otherwise, which also refuses refine()) with Ward's cache
    (the registry's interface). progress: optional ``progress(done_paths, total_paths)`` per group."""
    return render_cache(scene, camera, settings, options, sample_range, effects, prepared, progress)
