"""Rendering from light slabs: ray lookup and interpolation (Levoy and Hanrahan 1996, Fig. 13).

Interpolation modes: ``nearest``; ``uv`` (bilinear in u, v, nearest in s, t); ``st`` (nearest in
u, v, bilinear in s, t); ``quadrilinear``; and ``depth``, the depth-corrected variant of the
Lumigraph (Gortler et al. 1996) and of dynamically reparameterized light fields (Isaksen et al.
2000): the eye ray is intersected with a focal surface (the slab's depth where it has one, else
the focal plane ``focal_depth``), and each of the four nearest uv samples is looked up
bilinearly where *its* ray through that focal point crosses st. Coordinates outside a quad mean
the ray misses the slab; inside, interpolation clamps to the edge samples. With depth samples
the focal depth is searched per eye ray and occluded taps are dropped (:func:`_depth_search`:
the nearest sample's depth alone belongs to another surface wherever the nearest uv sample sees
past a silhouette, which ghosted the box over the board and the background at uv 8); empty
samples are background at FAR_DEPTH x D. Slab geometry and conventions:
:mod:`render.lightfield.geometry`.

Two implementations of the same math: :func:`render_rays` / :func:`lookup` for arbitrary rays
(numpy, float64 coordinates, all taps of a ray gathered at once), and :func:`render_pinhole` for
pinhole cameras (the compiled kernels of :mod:`render.lightfield.kernels`, one pass per pixel,
bands of rows on several threads); tests check one against the other. Both look a
:class:`~render.lightfield.geometry.VQRadiance` up through its codebook.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..camera import Camera
from .geometry import (DEPTH_SEARCH_STEPS, EMPTY_DEPTH, FAR_DEPTH, VISIBILITY_TOL, LightSlab, SlabHits, VQRadiance,
                       check_rays, slab_coordinates)

__all__ = ["MODES", "lookup", "select_slabs", "render_rays", "render_pinhole"]

MODES = ("nearest", "uv", "st", "quadrilinear", "depth")


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
    return np.asarray(radiance).reshape(-1, 3).take(idx, axis=0).astype(np.float32, copy=False)


def _depth_search(depth: np.ndarray, shape, D: float, ks: float, kt: float, cu, cv, cs, ct, iu, iv
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The depth mode's focal depth per eye ray and which uv taps see it.

    depth: the slab's (Nv Nu Nt Ns,) depth samples (float32 or float16); shape (Nu, Nv, Ns, Nt);
    cu, cv, cs, ct (N,) the eye rays' sample coordinates; iu (N, C), iv (N, A) their uv taps.
    Returns ``(zeta (N,) float64 distance from the uv plane, visible (N, A, C) bool)``.

    The depth "seen by uv sample U at depth z" is U's nearest st sample's depth on U's ray through
    the eye ray's point at z (empty samples read as FAR_DEPTH x D). Start: z0, the nearest uv
    sample's depth at the eye ray's st point (the former focal surface). Each uv tap then follows
    z <- its depth at z for DEPTH_SEARCH_STEPS steps, and its z is a candidate when the tap's
    depth there agrees with it (|D / z' - D / z| <= VISIBILITY_TOL): the tap sees a surface on
    the eye ray. The eye sees the nearest candidate (z0 when there is none). A tap is visible
    when its depth at that zeta agrees with zeta; the others look at an occluder or past the
    silhouette and get no weight (the caller renormalizes the visible taps' uv weights)."""
    nu, nv, ns, nt = shape
    cu, cv, cs, ct = (np.asarray(c, np.float64) for c in (cu, cv, cs, ct))

    def nearest(c, m):
        return np.floor(np.clip(c, 0.0, m - 1.0) + 0.5).astype(np.intp)

    def seen(jv, ju, z):
        shift = D / z - 1.0
        js, jt = nearest(cs + shift * ks * (cu - ju), ns), nearest(ct + shift * kt * (cv - jv), nt)
        d = depth.take(((jv * nu + ju) * nt + jt) * ns + js).astype(np.float64)
        return np.where(d > EMPTY_DEPTH * D, d, FAR_DEPTH * D)

    z0 = seen(nearest(cv, nv), nearest(cu, nu), np.full(len(cu), D))
    best = np.full(len(cu), np.inf)
    for a in range(iv.shape[1]):
        for c in range(iu.shape[1]):
            z = z0
            for _ in range(DEPTH_SEARCH_STEPS):
                z = seen(iv[:, a], iu[:, c], z)
            ok = np.abs(D / seen(iv[:, a], iu[:, c], z) - D / z) <= VISIBILITY_TOL
            best = np.where(ok & (z < best), z, best)
    zeta = np.where(np.isfinite(best), best, z0)
    visible = np.stack([np.stack([np.abs(D / seen(iv[:, a], iu[:, c], zeta) - D / zeta) <= VISIBILITY_TOL
                                  for c in range(iu.shape[1])], -1) for a in range(iv.shape[1])], 1)
    return zeta, visible


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
    visible = None
    if mode == "depth":
        D = g.distance
        ks = g.uv_size[0] * ns / (g.st_size[0] * nu)
        kt = g.uv_size[1] * nt / (g.st_size[1] * nv)
        if slab.depth is None:
            zeta = np.full(n, D if slab.focal_depth is None else slab.focal_depth, np.float64)
        else:
            zeta, visible = _depth_search(np.asarray(slab.depth).reshape(-1), g.shape, D, ks, kt, cu, cv, cs, ct,
                                          iu, iv)
        shift = D / zeta - 1.0
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
    if visible is not None:  # keep the uv taps that see the surface, their uv weights renormalized
        A, B, C, E = iv.shape[1], it.shape[-1], iu.shape[1], is_.shape[-1]
        w_uv = (np.ones((n, A, 1)) if wv is None else wv[:, :, None]) * (np.ones((n, 1, C)) if wu is None else wu[:, None, :])
        total = (w_uv * visible).sum(axis=(1, 2))
        some = total > 0  # else no tap sees it: every tap with its uv weight, as without depth
        keep = np.where(some[:, None, None], visible / np.where(some, total, 1.0)[:, None, None], 1.0)
        w = (w.reshape(n, A, B, C, E) * keep[:, :, None, :, None]).reshape(n, -1)
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
    o, d = check_rays(origins, dirs)
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
    o, d = check_rays(origins, dirs)
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
    """(N_PARAMS,) float64 parameters of :mod:`render.lightfield.kernels` for a slab seen by a pinhole
    camera with pixel (x, y, 1) -> world direction map ``pix_to_world`` = R_cam K^-1 (3, 3) and
    centre ``eye`` (3,): the slab-frame direction map A = R_slab R_cam K^-1, the eye in the slab
    frame, the slab's sizes and its default focal distance."""
    g = slab.geometry
    A = g.rotation @ pix_to_world
    eye = g.rotation @ (eye - g.uv_corners[0])
    focal = g.distance if slab.focal_depth is None else float(slab.focal_depth)
    return np.concatenate([A.reshape(-1), eye, [g.distance], g.uv_size, g.st_size, g.st_offset, [focal]])


def _as_kernel_samples(a: np.ndarray) -> np.ndarray:
    """A float32 array as is, a float16 one as its uint16 bit patterns (numba has no float16 on
    the CPU; the kernels decode them through :data:`render.lightfield.kernels.HALF_TO_FLOAT`). Views, no copies."""
    a = np.asarray(a)
    return a.view(np.uint16) if a.dtype == np.float16 else a


def _kernel_arrays(slab: LightSlab) -> tuple:
    """(dims, rad, depth, codes, codebook, tdims) of a slab as the kernels take them (views, no copies)."""
    nu, nv, ns, nt = slab.geometry.shape
    dims = np.array([nu, nv, ns, nt], np.int64)
    depth = np.zeros(0, np.float32) if slab.depth is None else _as_kernel_samples(slab.depth).reshape(-1)
    r = slab.radiance
    if isinstance(r, VQRadiance):
        return (dims, np.zeros((0, 3), np.float32), depth, r.codes.reshape(-1), r.codebook.reshape(-1, 3),
                np.array(r.codes.shape, np.int64))
    return (dims, _as_kernel_samples(r).reshape(-1, 3), depth, np.zeros(0, np.uint16), np.zeros((0, 3), np.float32),
            np.zeros(4, np.int64))


def render_pinhole(slabs: Sequence[LightSlab], camera: Camera, mode: str = "quadrilinear",
                background=(0.0, 0.0, 0.0), threads: int = 2) -> np.ndarray:
    """(H, W, 3) float32 linear image of ``camera`` rendered from a slab set (every pixel centre);
    each pixel's ray is looked up in the slab it crosses most steeply, else gets ``background``.

    Pinhole cameras render through the compiled kernels of :mod:`render.lightfield.kernels` in
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
    from . import kernels as sk

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
            sk.interpolate_band(params, *arr[:6], sk.HALF_TO_FLOAT, mode_id, best, i, r0, r1, k.width, part)

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
