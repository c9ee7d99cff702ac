"""Compiled (numba) slab rendering of a pinhole camera: one pass over the pixels per slab.

:func:`render.lightfield.rendering.render_pinhole` hands each band of image rows to two kernels: :func:`select_band`
intersects every pixel-centre ray with every slab and keeps the slab it crosses most steeply
(the largest cosine with the slab's ``forward``; -1 where no slab is crossed), then
:func:`interpolate_band`, once per slab, re-intersects that slab's pixels and interpolates its
samples (plain float32 arrays, or vector-quantized tiles through the codebook). Nothing is
stored per ray between the two, and the kernels release the GIL, so two bands render on two
cores at once.

The math is that of the numpy reference in :mod:`render.lightfield` (:func:`render.lightfield.geometry.slab_coordinates`
and the interpolation of :func:`render.lightfield.rendering.lookup`), which stays the public path for arbitrary
rays; ``tests/render/test_slab.py`` checks the two against each other. Precision: float64
throughout (the numpy path's float64 answers are matched to rounding).

Per-slab parameters, one float64 row (:data:`N_PARAMS`), built by ``render.lightfield.rendering._kernel_params``:
``A`` (9, row-major 3x3 = R_slab R_cam K^-1: pixel (x, y, 1) -> ray direction in the slab frame
(e_s, e_t, forward)), the eye in that frame relative to uv corner 0 (3), the uv -> st distance D,
the uv size (2), the st size (2), the st offset (2) and the depth mode's default focal distance.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import overload

from .._kernel_cache import skip_numba_blas_probe

# numba freezes these as constants
from .geometry import DEPTH_SEARCH_STEPS, EMPTY_DEPTH, FAR_DEPTH, MIN_COS, VISIBILITY_TOL

skip_numba_blas_probe()  # before the first kernel loads (see render._kernel_cache)

__all__ = ["N_PARAMS", "MODE_IDS", "HALF_TO_FLOAT", "select_band", "interpolate_band"]

#: (65536,) float32 value of every float16 bit pattern: numba has no float16 on the CPU, so half
#: precision samples reach the kernels as uint16 and are decoded by one lookup (256 KiB, cached)
HALF_TO_FLOAT = np.arange(2**16, dtype=np.uint32).astype(np.uint16).view(np.float16).astype(np.float32)

N_PARAMS = 20
MODE_IDS = {"nearest": 0, "uv": 1, "st": 2, "quadrilinear": 3, "depth": 4}

_JIT = dict(cache=True, nogil=True, error_model="numpy")


@njit(inline="always", **_JIT)
def _crossing(p, k, x, y):
    """(ok, cos, u, v, s, t) of the ray through image point (x, y) for slab ``k`` of the
    parameter rows ``p`` (S, N_PARAMS) (indexed in place: no row views in the pixel loops)."""
    dx = p[k, 0] * x + p[k, 1] * y + p[k, 2]
    dy = p[k, 3] * x + p[k, 4] * y + p[k, 5]
    dz = p[k, 6] * x + p[k, 7] * y + p[k, 8]
    norm = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not norm > 0.0:
        return False, 0.0, 0.5, 0.5, 0.5, 0.5
    cos = dz / norm
    if not (cos > MIN_COS and p[k, 11] < p[k, 12]):  # parallel or backwards, or the eye beyond st
        return False, 0.0, 0.5, 0.5, 0.5, 0.5
    f_uv = -p[k, 11] / dz
    f_st = (p[k, 12] - p[k, 11]) / dz
    u = (p[k, 9] + f_uv * dx) / p[k, 13]
    v = (p[k, 10] + f_uv * dy) / p[k, 14]
    s = (p[k, 9] - p[k, 17] + f_st * dx) / p[k, 15]
    t = (p[k, 10] - p[k, 18] + f_st * dy) / p[k, 16]
    ok = 0.0 <= u <= 1.0 and 0.0 <= v <= 1.0 and 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0
    return ok, cos, u, v, s, t


@njit(**_JIT)
def select_band(params, row0, row1, width, best):
    """For pixel rows [row0, row1) of a ``width``-wide image, the index of the slab each pixel's
    ray crosses most steeply into ``best`` ((row1 - row0) * width,) int64, -1 for none.
    params: (S, N_PARAMS) float64."""
    n_slabs = params.shape[0]
    for i in range(row0, row1):
        y = i + 0.5
        for j in range(width):
            x = j + 0.5
            k_best = -1
            c_best = 0.0
            for k in range(n_slabs):
                ok, cos, u, v, s, t = _crossing(params, k, x, y)
                if ok and cos > c_best:
                    k_best = k
                    c_best = cos
            best[(i - row0) * width + j] = k_best


@njit(inline="always", **_JIT)
def _taps(c, n, linear):
    """(i0, w0, i1, w1, count) along one axis of n samples at sample coordinate c, edge-clamped."""
    if c < 0.0:
        c = 0.0
    if c > n - 1.0:
        c = n - 1.0
    if not linear or n == 1:
        return int(math.floor(c + 0.5)), 1.0, 0, 0.0, 1
    f0 = min(math.floor(c), n - 2.0)
    i0 = int(f0)
    f = c - f0
    return i0, 1.0 - f, i0 + 1, f, 2


def _sample(x, lut):
    """A stored sample as a float: uint16 (float16 bits) through ``lut``, floats as they are."""


@overload(_sample, inline="always")
def _sample_impl(x, lut):
    if isinstance(x, types.Integer):
        return lambda x, lut: lut[x]
    return lambda x, lut: x


@njit(inline="always", **_JIT)
def _row(codes, vq, dims, tdims, iv, iu, it, is_):
    """Row of the (M, 3) sample table holding ray (iv, iu, it, is_): of the radiance array, or
    of the codebook through the ray's tile's codeword (vector-quantized slabs)."""
    if not vq:
        return ((iv * dims[0] + iu) * dims[3] + it) * dims[2] + is_
    tile = (((iv >> 1) * tdims[1] + (iu >> 1)) * tdims[2] + (it >> 1)) * tdims[3] + (is_ >> 1)
    return np.int64(codes[tile]) * 16 + (iv & 1) * 8 + (iu & 1) * 4 + (it & 1) * 2 + (is_ & 1)


@njit(inline="always", **_JIT)
def _seen_depth(depth, lut, nu, ns, nt, jv, ju, cu, cv, cs, ct, ks, kt, D, z):
    """Depth seen by uv sample (jv, ju) at depth ``z`` of the eye ray (sample coordinates cu, cv,
    cs, ct): its nearest st sample's depth on its ray through the eye ray's point at z; empty
    samples read FAR_DEPTH x D (the numpy reference: ``rendering._depth_search``)."""
    shift = D / z - 1.0
    js, _, _, _, _ = _taps(cs + shift * ks * (cu - ju), ns, False)
    jt, _, _, _, _ = _taps(ct + shift * kt * (cv - jv), nt, False)
    d = _sample(depth[((jv * nu + ju) * nt + jt) * ns + js], lut)
    return d if d > EMPTY_DEPTH * D else FAR_DEPTH * D


@njit(**_JIT)
def interpolate_band(params, dims, rad, depth, codes, codebook, tdims, lut, mode, best, k, row0, row1, width, out):
    """Radiance of the pixels of rows [row0, row1) whose ``best`` slab is ``k`` into ``out``
    ((row1 - row0) * width, 3) float32, interpolated in ``mode`` (:data:`MODE_IDS`).

    params: (S, N_PARAMS) float64 (row k is this slab's); dims: (4,) int64 (Nu, Nv, Ns, Nt). Samples: ``rad``
    (Nv Nu Nt Ns, 3) float32, or uint16 float16 bit patterns decoded through ``lut``
    (:data:`HALF_TO_FLOAT`), when ``codes`` is empty, else vector-quantized: ``codes``
    (Tv Tu Tt Ts,) codewords, ``codebook`` (K 16, 3) float32 with tile dims ``tdims`` (4,) int64
    (Tv, Tu, Tt, Ts). depth: (Nv Nu Nt Ns,) float32 or uint16 (float16 bits), or empty (no depth)."""
    nu, nv, ns, nt = dims[0], dims[1], dims[2], dims[3]
    vq = codes.shape[0] > 0
    has_depth = depth.shape[0] > 0
    D = params[k, 12]
    ks = params[k, 13] * ns / (params[k, 15] * nu)
    kt = params[k, 14] * nt / (params[k, 16] * nv)
    lin_uv = mode == 1 or mode >= 3
    lin_st = mode >= 2
    for i in range(row0, row1):
        y = i + 0.5
        for j in range(width):
            q = (i - row0) * width + j
            if best[q] != k:
                continue
            ok, cos, u, v, s, t = _crossing(params, k, j + 0.5, y)
            cu, cv, cs, ct = u * nu - 0.5, v * nv - 0.5, s * ns - 0.5, t * nt - 0.5
            v0, wv0, v1, wv1, nvt = _taps(cv, nv, lin_uv)
            u0, wu0, u1, wu1, nut = _taps(cu, nu, lin_uv)
            shift = 0.0
            search = mode == 4 and has_depth
            visible_total = 0.0
            zeta = params[k, 19]
            if search:  # the focal depth and the visible uv taps (rendering._depth_search)
                jv, _, _, _, _ = _taps(cv, nv, False)
                ju, _, _, _, _ = _taps(cu, nu, False)
                z0 = _seen_depth(depth, lut, nu, ns, nt, jv, ju, cu, cv, cs, ct, ks, kt, D, D)
                best_z = np.inf
                for a in range(nvt):
                    iv = v0 if a == 0 else v1
                    for bb in range(nut):
                        iu = u0 if bb == 0 else u1
                        z = z0
                        for _ in range(DEPTH_SEARCH_STEPS):
                            z = _seen_depth(depth, lut, nu, ns, nt, iv, iu, cu, cv, cs, ct, ks, kt, D, z)
                        zc = _seen_depth(depth, lut, nu, ns, nt, iv, iu, cu, cv, cs, ct, ks, kt, D, z)
                        if abs(D / zc - D / z) <= VISIBILITY_TOL and z < best_z:
                            best_z = z
                zeta = best_z if best_z < np.inf else z0
                for a in range(nvt):
                    iv = v0 if a == 0 else v1
                    wv = wv0 if a == 0 else wv1
                    for bb in range(nut):
                        iu = u0 if bb == 0 else u1
                        zc = _seen_depth(depth, lut, nu, ns, nt, iv, iu, cu, cv, cs, ct, ks, kt, D, zeta)
                        if abs(D / zc - D / zeta) <= VISIBILITY_TOL:
                            visible_total += wv * (wu0 if bb == 0 else wu1)
            if mode == 4:
                shift = D / zeta - 1.0
            r = 0.0
            g = 0.0
            b = 0.0
            for a in range(nvt):
                iv = v0 if a == 0 else v1
                wv = wv0 if a == 0 else wv1
                t0, wt0, t1, wt1, ntt = _taps(ct + shift * kt * (cv - iv), nt, lin_st)
                for bb in range(nut):
                    iu = u0 if bb == 0 else u1
                    wu = wu0 if bb == 0 else wu1
                    if visible_total > 0.0:  # only the taps that see the surface, renormalized
                        zc = _seen_depth(depth, lut, nu, ns, nt, iv, iu, cu, cv, cs, ct, ks, kt, D, zeta)
                        wu = wu / visible_total if abs(D / zc - D / zeta) <= VISIBILITY_TOL else 0.0
                    s0, ws0, s1, ws1, nst = _taps(cs + shift * ks * (cu - iu), ns, lin_st)
                    for c_ in range(ntt):
                        it = t0 if c_ == 0 else t1
                        wt = wt0 if c_ == 0 else wt1
                        for d_ in range(nst):
                            is_ = s0 if d_ == 0 else s1
                            w = wv * wu * wt * (ws0 if d_ == 0 else ws1)
                            m = _row(codes, vq, dims, tdims, iv, iu, it, is_)
                            if vq:
                                r += w * codebook[m, 0]
                                g += w * codebook[m, 1]
                                b += w * codebook[m, 2]
                            else:
                                r += w * _sample(rad[m, 0], lut)
                                g += w * _sample(rad[m, 1], lut)
                                b += w * _sample(rad[m, 2], lut)
            out[q, 0] = r
            out[q, 1] = g
            out[q, 2] = b
