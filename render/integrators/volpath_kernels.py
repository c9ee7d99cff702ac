"""Compiled (numba) wavefront kernels of ``volpath``: delta tracking, ratio tracking, GGX surfaces.

:mod:`render.integrators.volpath` drives the wavefront: each round, Embree finds the surface hits
of every live path and (with media) the next medium-boundary crossing; one kernel here
(:func:`vol_bounce`) then runs, per path and in compiled code, the free flight through the
medium the ray travels in (delta tracking: emission collected at every tentative collision,
absorption, real scattering or a null collision), boundary crossings, background, emission at
surfaces (MIS-weighted), next-event estimation (the shadow ray queued with its unoccluded
contribution), the BSDF or Henyey-Greenstein phase sample and Russian roulette, and compacts the
survivors. Shadow rays are tested against the surfaces by one Embree occlusion query; with media,
:func:`shadow_media_step` then walks each unoccluded one through the media boundaries (one Embree
query per crossing for all of them), accumulating its transmittance in log space (exp(-sigma_t d)
exactly in homogeneous media, ratio tracking with roulette in grids), and adds
contribution x exp(log T) when it reaches its light.

It is the estimator of the numpy reference (:func:`render.integrators.volpath.trace`, kept and
tested): same events, probabilities, weights, MIS and roulette rules, and the same BSDFs as
:mod:`render.bsdf` and :mod:`render.microfacet` (ported here as scalar functions of local
z-up frames; tests/render/test_volpath_kernels.py checks them against the numpy ones).

Random numbers (:attr:`VolConfig.sampler`). Independent (``SAMPLER_INDEPENDENT``): the hash of
:mod:`render.sampling` (``path_kernels._uniform``) per (path key, dimension). A path's key is a
function of (seed, pixel, sample) (dimensions 0, 1: the pixel jitter); the path then draws
dimensions 2, 3, ... in the order its events need them (delta tracking consumes a variable
number): the running counter ``dim`` of the state. A shadow ray gets its own key, a hash of
(path key, dimension at queueing), and draws its ratio-tracking dimensions 0, 1, ... from it.

Sobol (``SAMPLER_SOBOL``: volpath's "sobol" and "sobol-blocks", whose keys are render.sobol's;
pbrt-v4's padded dimensions for a variable-length consumer). Every number a vertex needs comes
from a FIXED Sobol dimension of its bounce k (the scattering events before it), in path's
layout (:func:`render.sobol.dimension_group`, the same groups and scrambles as
``path_kernels._sobol``): dimensions 2 + 8 k + j, j = (1, 2) the light pick and point (one 2-D
group, the pick rescaled into the point as path does), 3 the BSDF lobe, (4, 5) the BSDF / phase
direction, 6 roulette, 7 the first collision (j = 0, path's pick, goes unused). Delta tracking
draws a variable number of collisions: the FIRST tentative collision of the segment that ends
at vertex k (the flight from vertex k - 1, or the camera, to whatever it meets, across boundary
crossings) takes its distance and event from the 2-D group at dimension 7 of bounce k
(components 0 and 1: ``_sobol2(key, 2 + 8 k + 7)``; path draws that group's component 0 only,
as its spare; flag ``F_FLIGHT`` set once they are drawn, cleared at the next vertex), so whether
a flight collides, where, and whether it scatters are stratified together; every later collision of the
segment takes them from the hash of (mix64(path key ^ salt), running counter ``dim``), and
shadow rays' ratio tracking from their own hashed keys as under the independent sampler. So the
dimensions with a fixed meaning are stratified (for single scattering in a homogeneous medium:
the flight, the light point, the phase direction), the rest are independent; each number
of one sample is still uniform and independent of the others (distinct groups, distinct
scrambles), so every estimator stays unbiased.

Either way every number is a pure function of (seed, pixel, sample, dimension): results do not
depend on threads, batches or the order of paths in the wavefront, and disjoint sample ranges
merge exactly.

pssmlt's path sampler runs the same kernels with every number read from a primary sample U
instead (``vol_bounce``'s U; seven dimensions per vertex, the last one roulette's, read only
when roulette applies; no media) and path's rules
(:attr:`VolConfig.path_rules`): render.integrators.volpath.trace_primary.

A majorant below the extinction found at a collision stops the path and records the medium in
``err`` (the driver raises :class:`render.media.MajorantError`): never a silently biased image.

State layouts (one row per live path), shared with the driver:
ints (N, 4) int64 [output slot, next dimension, bounces, medium (-1: vacuum)]; key (N,) uint64;
flt (N, 4) float64 [throughput (3), density of the ray's sampling (solid angle)]; flags (N,)
uint8 (path_kernels.F_DELTA, F_AFTER_DIFF, :data:`F_FLIGHT`); last_p (N, 3) float64 the last scattering vertex;
o32, d32 (N, 3) float32 the ray (what Embree reads).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import embree_direct as _edirect
from ..scene import ALPHA_SMOOTH
from .path_kernels import (DIELECTRIC, EMISSIVE, F_AFTER_DIFF, F_DELTA, LAMBERT, MIRROR, SAMPLER_INDEPENDENT,
                           SAMPLER_SOBOL, STRAT_BSDF, STRAT_LIGHT, _albedo, _frame, _hit_point, _mis, _mix64, _offset,
                           _pick, _sample_area, _sample_delta, _sobol, _sobol2, _uniform)

__all__ = ["VolConfig", "MediaKernel", "media_kernel", "vol_bounce", "trace_surfaces", "shadow_start", "shadow_media_step",
           "shadow_flush", "surface_eval_local", "surface_sample_local", "hg_pdf_k", "hg_sample_k",
           "F_FLIGHT", "SOBOL_BOUNCE_DIMS", "CONDUCTOR", "ROUGH_DIELECTRIC", "EV_PASS", "EV_SCATTER", "EV_ABSORB"]

CONDUCTOR, ROUGH_DIELECTRIC = 4, 5  # render.bsdf
EV_PASS, EV_SCATTER, EV_ABSORB = 0, 1, 2  # render.media
_JIT = dict(cache=True, nogil=True, error_model="numpy")
_EPS = 1e-12  # render.microfacet._EPS
_COS_FLOOR = 1e-12  # render.lights._COS_FLOOR
_LOG_RR_T = math.log(0.1)  # ratio tracking's roulette threshold (render.media._RR_T), in log space
_LOG2 = math.log(2.0)
_TMAX_CAP = 3e38
_SHADOW_SALT = np.uint64(0xD1B54A32D192ED03)
_TRACK_SALT = np.uint64(0x8CB92BA72F3D8DD7)  # the Sobol samplers' tracking hash key: mix64(path key ^ salt)
_ONE_MINUS = 1.0 - 2.0 ** -53  # the largest float64 below 1
#: per-path flag (beside path_kernels.F_DELTA, F_AFTER_DIFF): the Sobol samplers' first tentative
#: collision of the current segment has been drawn (its distance and event from the bounce's
#: Sobol dimensions; later collisions of the segment from the hash)
F_FLIGHT = np.uint8(4)
#: the Sobol layout of a bounce (render.sobol.dimension_group): dimensions 2 + 8 k + j, j = [unused
#: (path's light pick), light point (2), lobe, direction (2), roulette, first collision (2-D:
#: distance, event; its second component is the group's component 1, which path never draws)]
SOBOL_BOUNCE_DIMS = 8
_SD_LIGHT, _SD_LOBE, _SD_DIR, _SD_RR, _SD_FLIGHT = 1, 3, 4, 6, 7
_INV_4PI = 1.0 / (4.0 * math.pi)


class VolConfig(NamedTuple):
    """What :func:`vol_bounce` reads of the settings and the scene (render.integrators.volpath)."""

    max_depth: int  #: maximum scattering events (surface or medium)
    rr_depth: int  #: roulette on paths whose bounces exceed rr_depth
    roulette: bool  #: Russian roulette on
    caustics: bool  #: keep delta samples after a diffuse vertex (else the path is cut there)
    strategy: int  #: path_kernels.STRAT_MIS, STRAT_LIGHT or STRAT_BSDF
    mis_exponent: float  #: 2.0 power heuristic, 1.0 balance
    has_bg: bool  #: escaping rays gather a non-black background
    has_media: bool  #: the scene has media (boundary hits are passed)
    has_lights: bool  #: LightSet.empty is False: next-event estimation runs
    #: render.integrators.path's rules (pssmlt's sampler, scenes without media) instead of
    #: volpath's: without caustics, drop emission and background reached through a specular chain
    #: after a diffuse vertex and keep the path (volpath cuts the path at its first specular sample
    #: after a diffuse vertex); shadow rays end 1e-4 of their length and twice the offset short of
    #: the light (volpath: 1e-5 and 1e-6 extent); an emitter's distance for MIS is the hit distance
    path_rules: bool = False
    #: path_kernels.SAMPLER_INDEPENDENT (every number from the hash) or SAMPLER_SOBOL (the
    #: Owen-scrambled Sobol layout of the module docstring; "sobol" and "sobol-blocks" differ only
    #: in the keys); unread when primary samples U are given
    sampler: int = SAMPLER_INDEPENDENT


class MediaKernel(NamedTuple):
    """A :class:`render.media.MediumSet` as flat arrays (K media; K = 0 stored as one dummy row).

    sigma_a, sigma_s, Le (K, 3); g, mu (K,); homogeneous (K,) bool; lo, hi (K, 3) grid boxes;
    grid_shape (K, 3) int64, grid_off (K,) int64 into grid_data (flat float64, C order (X, Y, Z));
    b_normal (T, 3) boundary triangles' unit normals, b_obj (T,) their medium, b_ids (P,) Embree
    primID -> boundary triangle; extent: (1,) the boundaries' extent (ray offsets)."""

    sigma_a: np.ndarray
    sigma_s: np.ndarray
    Le: np.ndarray
    g: np.ndarray
    mu: np.ndarray
    homogeneous: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    grid_shape: np.ndarray
    grid_off: np.ndarray
    grid_data: np.ndarray
    b_normal: np.ndarray
    b_obj: np.ndarray
    b_ids: np.ndarray
    extent: np.ndarray


def media_kernel(ms) -> MediaKernel:
    """Pack a :class:`render.media.MediumSet` (or None: no media) for the kernels."""
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    if ms is None or len(ms) == 0:
        z3 = np.zeros((1, 3))
        return MediaKernel(z3, z3, z3, np.zeros(1), np.zeros(1), np.ones(1, np.bool_), z3, z3,
                           np.ones((1, 3), np.int64), np.zeros(1, np.int64), np.zeros(1), z3,
                           np.zeros(1, np.int64), np.zeros(1, np.int64), np.ones(1))
    k = len(ms)
    shape = np.ones((k, 3), np.int64)
    off = np.zeros(k, np.int64)
    chunks, o = [], 0
    for i in range(k):
        if i in ms.grids:
            gr = np.ascontiguousarray(ms.grids[i], dtype=np.float64)
            shape[i], off[i] = gr.shape, o
            chunks.append(gr.ravel())
            o += gr.size
    data = np.concatenate(chunks) if chunks else np.zeros(1)
    geom = ms.geom
    ids = ms.accel.ids if ms.accel is not None else np.zeros(1, np.int64)
    return MediaKernel(f64(ms.sigma_a), f64(ms.sigma_s), f64(ms.Le), f64(ms.g), f64(ms.mu),
                       np.ascontiguousarray(ms.homogeneous, dtype=np.bool_), f64(ms.lo), f64(ms.hi), shape, off,
                       f64(data), f64(geom.normal if len(geom.normal) else np.zeros((1, 3))),
                       np.ascontiguousarray(geom.obj if len(geom.obj) else np.zeros(1), dtype=np.int64),
                       np.ascontiguousarray(ids if len(ids) else np.zeros(1), dtype=np.int64),
                       np.array([geom.extent], np.float64))


# ------------------------------------------------------------------ GGX (render.microfacet, scalar)
@njit(inline="always", **_JIT)
def _clamp_alpha(a):
    return min(max(a, ALPHA_SMOOTH), 1.0)


@njit(inline="always", **_JIT)
def _tan2(x, y, z):
    c2 = z * z
    if not c2 > 0.0:
        return np.inf
    return max(0.0, x * x + y * y) / max(c2, _EPS * _EPS)


@njit(inline="always", **_JIT)
def _ggx_d(alpha, mx, my, mz):
    a2 = _clamp_alpha(alpha) ** 2
    t2 = _tan2(mx, my, mz)
    c2 = mz * mz
    if not (np.isfinite(t2) and c2 > 0.0):
        return 0.0
    e = 1.0 + t2 / a2
    return 1.0 / max(math.pi * a2 * c2 * c2 * e * e, 1e-300)


@njit(inline="always", **_JIT)
def _ggx_lambda(alpha, x, y, z):
    a2 = _clamp_alpha(alpha) ** 2
    t2 = _tan2(x, y, z)
    if not np.isfinite(t2):
        return np.inf
    return 0.5 * (math.sqrt(1.0 + a2 * t2) - 1.0)


@njit(inline="always", **_JIT)
def _ggx_g1(alpha, x, y, z):
    return 1.0 / (1.0 + _ggx_lambda(alpha, x, y, z))


@njit(inline="always", **_JIT)
def _ggx_g(alpha, ox, oy, oz, ix, iy, iz):
    return 1.0 / (1.0 + _ggx_lambda(alpha, ox, oy, oz) + _ggx_lambda(alpha, ix, iy, iz))


@njit(inline="always", **_JIT)
def _visible_pdf(alpha, wx, wy, wz, mx, my, mz):
    """render.microfacet.ggx_visible_pdf for one pair."""
    c = abs(wz)
    if not c > 0.0:
        return 0.0
    sgn = -1.0 if wz < 0.0 else 1.0
    dot = max(0.0, (wx * mx + wy * my + wz * mz) * sgn)
    return _ggx_g1(alpha, wx, wy, wz) / max(c, _EPS) * _ggx_d(alpha, mx, my, mz) * dot


@njit(inline="always", **_JIT)
def _sample_visible(alpha, wx, wy, wz, u0, u1):
    """render.microfacet.ggx_sample_visible for one direction: a unit normal, z > 0."""
    a = _clamp_alpha(alpha)
    hx, hy, hz = a * wx, a * wy, wz
    ln = max(math.sqrt(hx * hx + hy * hy + hz * hz), _EPS)
    hx, hy, hz = hx / ln, hy / ln, hz / ln
    if hz < 0.0:
        hx, hy, hz = -hx, -hy, -hz
    t1x, t1y = -hy, hx
    l1 = math.sqrt(t1x * t1x + t1y * t1y)
    if hz >= 0.99999 or l1 < 1e-9:
        t1x, t1y = 1.0, 0.0
    else:
        t1x, t1y = t1x / max(l1, _EPS), t1y / max(l1, _EPS)
    # t2 = cross(wh, t1) with t1 = (t1x, t1y, 0)
    t2x, t2y, t2z = -hz * t1y, hz * t1x, hx * t1y - hy * t1x
    r = math.sqrt(u0)
    phi = 2.0 * math.pi * u1
    px, py = r * math.cos(phi), r * math.sin(phi)
    h = math.sqrt(max(0.0, 1.0 - px * px))
    s = 0.5 * (1.0 + hz)
    py = (1.0 - s) * h + s * py
    pz = math.sqrt(max(0.0, 1.0 - px * px - py * py))
    nx = px * t1x + py * t2x + pz * hx
    ny = px * t1y + py * t2y + pz * hy
    nz = py * t2z + pz * hz
    mx, my, mz = a * nx, a * ny, max(1e-6, nz)
    lm = math.sqrt(mx * mx + my * my + mz * mz)
    return mx / lm, my / lm, mz / lm


@njit(inline="always", **_JIT)
def _fresnel_complex(cos_i, eta, k):
    """render.microfacet.fresnel_complex for one channel."""
    c = min(abs(cos_i), 1.0)
    e = complex(eta, k)
    s2 = 1.0 - c * c
    ct = np.sqrt(1.0 - s2 / (e * e))
    r_par = (e * c - ct) / (e * c + ct)
    r_perp = (c - e * ct) / (c + e * ct)
    f = 0.5 * (abs(r_par) ** 2 + abs(r_perp) ** 2)
    return min(max(f, 0.0), 1.0)


@njit(inline="always", **_JIT)
def _fresnel_dielectric(cos_i, ior):
    """render.bsdf.fresnel_dielectric for one cosine (outward normal; ior inside / outside)."""
    ci = min(max(cos_i, -1.0), 1.0)
    eta = 1.0 / ior if ci < 0.0 else ior
    ci = abs(ci)
    s2 = (1.0 - ci * ci) / (eta * eta)
    if s2 >= 1.0:
        return 1.0
    ct = math.sqrt(max(0.0, 1.0 - s2))
    rpa = (eta * ci - ct) / (eta * ci + ct)
    rpe = (ci - eta * ct) / (ci + eta * ct)
    return 0.5 * (rpa * rpa + rpe * rpe)


@njit(inline="always", **_JIT)
def _gen_half(ox, oy, oz, ix, iy, iz, ior):
    """render.microfacet._gen_half: (wm (3), eta', reflect, ok, wm . wi, wm . wo)."""
    reflect = oz * iz > 0.0
    etap = 1.0 if reflect else (ior if oz > 0.0 else 1.0 / ior)
    mx, my, mz = ix * etap + ox, iy * etap + oy, iz * etap + oz
    ln = math.sqrt(mx * mx + my * my + mz * mz)
    ok = oz != 0.0 and iz != 0.0 and ln > _EPS
    ln = max(ln, _EPS)
    mx, my, mz = mx / ln, my / ln, mz / ln
    if mz < 0.0:
        mx, my, mz = -mx, -my, -mz
    dwi = mx * ix + my * iy + mz * iz
    dwo = mx * ox + my * oy + mz * oz
    ok = ok and dwi * iz >= 0.0 and dwo * oz >= 0.0
    return mx, my, mz, etap, reflect, ok, dwi, dwo


# ------------------------------------------------------------------ surfaces in local frames
@njit(**_JIT)
def surface_eval_local(kind, a0, a1, a2, alpha, ior, e0, e1, e2, k0, k1, k2, ox, oy, oz, ix, iy, iz):
    """render.integrators.volpath.surface_eval for one vertex: (f (3), pdf) for local wo, wi.
    a: albedo (Lambert); alpha, ior, eta e, k: the GGX material. Delta lobes give 0."""
    if kind == LAMBERT:
        if oz > 0.0 and iz > 0.0:
            inv = 1.0 / math.pi
            return a0 * inv, a1 * inv, a2 * inv, iz * inv
        return 0.0, 0.0, 0.0, (max(iz, 0.0) / math.pi if oz > 0.0 else 0.0)
    if kind == CONDUCTOR:
        if not (oz > 0.0 and iz > 0.0 and alpha >= ALPHA_SMOOTH):
            return 0.0, 0.0, 0.0, 0.0
        mx, my, mz = ox + ix, oy + iy, oz + iz
        ln = math.sqrt(mx * mx + my * my + mz * mz)
        if not ln > _EPS:
            return 0.0, 0.0, 0.0, 0.0
        mx, my, mz = mx / ln, my / ln, mz / ln
        dot = ox * mx + oy * my + oz * mz
        val = _ggx_d(alpha, mx, my, mz) * _ggx_g(alpha, ox, oy, oz, ix, iy, iz) / max(4.0 * oz * iz, _EPS)
        pdf = _visible_pdf(alpha, ox, oy, oz, mx, my, mz) / max(4.0 * abs(dot), _EPS)
        return (_fresnel_complex(dot, e0, k0) * val, _fresnel_complex(dot, e1, k1) * val,
                _fresnel_complex(dot, e2, k2) * val, pdf)
    if kind == ROUGH_DIELECTRIC:
        mx, my, mz, etap, reflect, ok, dwi, dwo = _gen_half(ox, oy, oz, ix, iy, iz, ior)
        if not (ok and alpha >= ALPHA_SMOOTH):
            return 0.0, 0.0, 0.0, 0.0
        F = _fresnel_dielectric(dwo, ior)
        D = _ggx_d(alpha, mx, my, mz)
        G = _ggx_g(alpha, ox, oy, oz, ix, iy, iz)
        dvis = _visible_pdf(alpha, ox, oy, oz, mx, my, mz)
        cc = abs(iz * oz)
        if reflect:
            v = D * G * F / max(4.0 * cc, _EPS)
            return v, v, v, dvis / max(4.0 * abs(dwo), _EPS) * F
        dd = (dwi + dwo / etap) ** 2
        if not dd > 0.0:
            return 0.0, 0.0, 0.0, 0.0
        denom = dd * cc
        v = 0.0
        if denom > 0.0:
            v = D * (1.0 - F) * G * abs(dwi * dwo / denom) / (etap * etap)
        return v, v, v, dvis * abs(dwi) / dd * (1.0 - F)
    return 0.0, 0.0, 0.0, 0.0


@njit(**_JIT)
def surface_sample_local(kind, a0, a1, a2, alpha, ior, e0, e1, e2, k0, k1, k2, ox, oy, oz, u0, u1, u2):
    """render.integrators.volpath.surface_sample for one vertex (local frame; u0 the lobe choice,
    (u1, u2) the direction): (valid, wi (3), weight f |cos| / pdf (3), pdf, delta)."""
    if kind == LAMBERT:
        r = math.sqrt(u1)
        phi = 2.0 * math.pi * u2
        x, y, z = r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - u1))
        pdf = z / math.pi
        ok = oz > 0.0 and pdf > 0.0
        s = 1.0 if ok else 0.0
        return ok, x, y, z, a0 * s, a1 * s, a2 * s, pdf, False
    if kind == MIRROR:
        ok = oz != 0.0
        s = 1.0 if ok else 0.0
        return ok, -ox, -oy, oz, a0 * s, a1 * s, a2 * s, 1.0, True
    if kind == DIELECTRIC or (kind == ROUGH_DIELECTRIC and alpha < ALPHA_SMOOTH):
        F = _fresnel_dielectric(oz, ior)
        eta = ior if oz >= 0.0 else 1.0 / ior
        if u0 < F:
            ok = oz != 0.0 and F > 0.0
            s = 1.0 if ok else 0.0
            return ok, -ox, -oy, oz, s, s, s, F, True
        c = abs(oz)
        cos_t = math.sqrt(max(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
        sgn = 1.0 if oz >= 0.0 else -1.0
        ok = oz != 0.0 and 1.0 - F > 0.0
        s = 1.0 / (eta * eta) if ok else 0.0
        return ok, -ox / eta, -oy / eta, -sgn * cos_t, s, s, s, 1.0 - F, True
    if kind == CONDUCTOR:
        smooth = alpha < ALPHA_SMOOTH
        if smooth:
            mx, my, mz = 0.0, 0.0, 1.0
        else:
            mx, my, mz = _sample_visible(alpha, ox, oy, oz, u1, u2)
        dot = ox * mx + oy * my + oz * mz
        ix, iy, iz = -ox + 2.0 * dot * mx, -oy + 2.0 * dot * my, -oz + 2.0 * dot * mz
        ok = oz > 0.0 and iz > 0.0
        g_ratio = 1.0
        if ok and not smooth:
            g_ratio = _ggx_g(alpha, ox, oy, oz, ix, iy, iz) / max(_ggx_g1(alpha, ox, oy, oz), _EPS)
        pdf = 1.0 if smooth else _visible_pdf(alpha, ox, oy, oz, mx, my, mz) / max(4.0 * abs(dot), _EPS)
        ok = ok and pdf > 0.0
        s = g_ratio if ok else 0.0
        return (ok, ix, iy, iz, _fresnel_complex(dot, e0, k0) * s, _fresnel_complex(dot, e1, k1) * s,
                _fresnel_complex(dot, e2, k2) * s, pdf if ok else 0.0, smooth)
    if kind == ROUGH_DIELECTRIC:
        mx, my, mz = _sample_visible(alpha, ox, oy, oz, u1, u2)
        dwo = ox * mx + oy * my + oz * mz
        F = _fresnel_dielectric(dwo, ior)
        refl = u0 < F
        inside = dwo < 0.0
        eta = 1.0 / ior if inside else ior
        sg = -1.0 if inside else 1.0
        ci = abs(dwo)
        s2t = max(0.0, 1.0 - ci * ci) / (eta * eta)
        tir = s2t >= 1.0
        ct = math.sqrt(max(0.0, 1.0 - s2t))
        if refl:
            ix, iy, iz = -ox + 2.0 * dwo * mx, -oy + 2.0 * dwo * my, -oz + 2.0 * dwo * mz
        else:
            q = ci / eta - ct
            ix, iy, iz = -ox / eta + q * sg * mx, -oy / eta + q * sg * my, -oz / eta + q * sg * mz
        same = oz * iz > 0.0
        ok = (same if refl else (not same and not tir and iz != 0.0)) and oz != 0.0
        etap = 1.0 if refl else eta
        dwi = ix * mx + iy * my + iz * mz
        dvis = _visible_pdf(alpha, ox, oy, oz, mx, my, mz)
        denom = (dwi + dwo / etap) ** 2
        if refl:
            pdf = dvis / max(4.0 * ci, _EPS) * F
        else:
            pdf = dvis * abs(dwi) / (denom if denom > 0.0 else 1.0) * (1.0 - F)
        ok = ok and pdf > 0.0 and denom > 0.0
        w = 0.0
        if ok:
            w = _ggx_g(alpha, ox, oy, oz, ix, iy, iz) / max(_ggx_g1(alpha, ox, oy, oz), _EPS) / (etap * etap)
        return ok, ix, iy, iz, w, w, w, pdf if ok else 0.0, False
    return False, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False


# ------------------------------------------------------------------ Henyey-Greenstein (render.media)
@njit(inline="always", **_JIT)
def hg_pdf_k(g, dx, dy, dz, wx, wy, wz):
    """render.media.hg_pdf for one pair (d: travel direction)."""
    c = min(max(dx * wx + dy * wy + dz * wz, -1.0), 1.0)
    den = max(1.0 + g * g - 2.0 * g * c, 1e-12)
    return (1.0 - g * g) * _INV_4PI / (den * math.sqrt(den))


@njit(inline="always", **_JIT)
def hg_sample_k(g, dx, dy, dz, u0, u1):
    """render.media.hg_sample for one travel direction d: the scattered direction (3)."""
    if abs(g) < 1e-3:
        c = 1.0 - 2.0 * u0
    else:
        sq = (1.0 - g * g) / (1.0 - g + 2.0 * g * u0)
        c = (1.0 + g * g - sq * sq) / (2.0 * g)
    c = min(max(c, -1.0), 1.0)
    s = math.sqrt(max(0.0, 1.0 - c * c))
    phi = 2.0 * math.pi * u1
    sc, ss = s * math.cos(phi), s * math.sin(phi)
    (t1x, t1y, t1z), (t2x, t2y, t2z) = _frame(dx, dy, dz)
    return sc * t1x + ss * t2x + c * dx, sc * t1y + ss * t2y + c * dy, sc * t1z + ss * t2z + c * dz


# ------------------------------------------------------------------ media coefficients and tracking
@njit(inline="always", **_JIT)
def _density(homogeneous, lo, hi, gshape, goff, gdata, m, x, y, z):
    """render.media.MediumSet.density at one point of medium m (nearest voxel; 0 outside the box)."""
    if homogeneous[m]:
        return 1.0
    nx, ny, nz = gshape[m, 0], gshape[m, 1], gshape[m, 2]
    ux = (x - lo[m, 0]) / (hi[m, 0] - lo[m, 0]) * nx
    uy = (y - lo[m, 1]) / (hi[m, 1] - lo[m, 1]) * ny
    uz = (z - lo[m, 2]) / (hi[m, 2] - lo[m, 2]) * nz
    if not (ux >= 0.0 and ux < nx and uy >= 0.0 and uy < ny and uz >= 0.0 and uz < nz):
        return 0.0
    ix = min(np.int64(math.floor(ux)), nx - 1)
    iy = min(np.int64(math.floor(uy)), ny - 1)
    iz = min(np.int64(math.floor(uz)), nz - 1)
    return gdata[goff[m] + (ix * ny + iy) * nz + iz]


@njit(inline="always", **_JIT)
def _box_exit(lo, hi, m, ox, oy, oz, dx, dy, dz):
    """Distance along the ray to leave medium m's box (its bounds' axis-aligned box: outside it a
    medium is vacuum, so flights and transmittance stop there even if a boundary hit was lost)."""
    t = np.inf
    for c, o, d in ((0, ox, dx), (1, oy, dy), (2, oz, dz)):
        if d > 0.0:
            t = min(t, (hi[m, c] - o) / d)
        elif d < 0.0:
            t = min(t, (lo[m, c] - o) / d)
    return max(t, 0.0)


@njit(inline="always", **_JIT)
def _majorant_exceeded(s0, s1, s2, mu):
    return max(max(s0, s1), s2) > mu * (1.0 + 1e-9) + 1e-300


@njit(inline="always", **_JIT)
def _log_transmittance(md_sa, md_ss, homogeneous, lo, hi, gshape, goff, gdata, mus, m, ox, oy, oz, dx, dy, dz,
                       seg, key, dim, err):
    """log T (3) over [0, seg] of a ray in medium m: -sigma_t seg when homogeneous, else ratio
    tracking (render.media.MediumSet.transmittance) with roulette below T = 0.1 (on the segment's
    own T, as the numpy reference). Returns (lT (3), next dimension); -inf: the ray died."""
    if homogeneous[m]:
        return (-(md_sa[m, 0] + md_ss[m, 0]) * seg, -(md_sa[m, 1] + md_ss[m, 1]) * seg,
                -(md_sa[m, 2] + md_ss[m, 2]) * seg, dim)
    mu = mus[m]
    l0 = l1 = l2 = 0.0
    if not mu > 0.0:
        return l0, l1, l2, dim
    t = 0.0
    while True:
        t -= math.log1p(-_uniform(key, dim)) / mu
        dim += 1
        if not t < seg:
            return l0, l1, l2, dim
        dens = _density(homogeneous, lo, hi, gshape, goff, gdata, m, ox + t * dx, oy + t * dy, oz + t * dz)
        s0 = (md_sa[m, 0] + md_ss[m, 0]) * dens
        s1 = (md_sa[m, 1] + md_ss[m, 1]) * dens
        s2 = (md_sa[m, 2] + md_ss[m, 2]) * dens
        if _majorant_exceeded(s0, s1, s2, mu):
            err[0] = m + 1
            return -np.inf, -np.inf, -np.inf, dim
        f0, f1, f2 = 1.0 - s0 / mu, 1.0 - s1 / mu, 1.0 - s2 / mu
        l0 = l0 + math.log(f0) if f0 > 0.0 else -np.inf
        l1 = l1 + math.log(f1) if f1 > 0.0 else -np.inf
        l2 = l2 + math.log(f2) if f2 > 0.0 else -np.inf
        top = max(max(l0, l1), l2)
        if top == -np.inf:
            return l0, l1, l2, dim
        if top < _LOG_RR_T:
            u = _uniform(key, dim)
            dim += 1
            if u < 0.5:
                return -np.inf, -np.inf, -np.inf, dim
            l0, l1, l2 = l0 + _LOG2, l1 + _LOG2, l2 + _LOG2


# ------------------------------------------------------------------ light sampling (render.lights)
@njit(inline="always", **_JIT)
def _sample_light(cdf, pmf, area, d_kind, d_pos, d_dir, d_I, d_cos, n_area, floor, px, py, pz, u0, u1, u2):
    """LightSet.sample at one point: (valid, wi (3), dist, Li (3), pdf, delta)."""
    k = _pick(cdf, u0)
    if k < n_area:
        ok, lx, ly, lz, ldist, L0, L1, L2, lpdf = _sample_area(area, k, floor, px, py, pz, u1, u2)
        return ok, lx, ly, lz, ldist, L0, L1, L2, lpdf, False
    ok, lx, ly, lz, ldist, L0, L1, L2 = _sample_delta(d_kind, d_pos, d_dir, d_I, d_cos, k - n_area, floor, px, py, pz)
    return ok, lx, ly, lz, ldist, L0, L1, L2, pmf[k], True


# ------------------------------------------------------------------ one round of the wavefront
@njit(inline="always", **_JIT)
def _rand(key, dim, U, row):
    """Dimension ``dim`` of a path: the hash of (key, dim), or column dim of row ``row`` of the
    primary samples U when U has rows (pssmlt's sampler: render.integrators.pssmlt)."""
    if U.shape[0] > 0:
        return U[row, dim]
    return _uniform(key, dim)


@njit(inline="always", **_JIT)
def _light_uniforms(cdf, key, base):
    """The Sobol samplers' next-event numbers at a bounce of first dimension ``base``: (pick, u1,
    u2) for :func:`_sample_light`, pick and light point from the one 2-D group base + 1, base + 2:
    the pick's number, rescaled within the picked light's CDF interval, is uniform again and is
    the point's first coordinate (render.integrators.path_kernels._next_event's rule), so each
    light's points keep the pair's stratification."""
    ua, u2 = _sobol2(key, base + _SD_LIGHT)
    k = _pick(cdf, ua)
    lo = cdf[k - 1] if k > 0 else 0.0
    width = cdf[k] - lo
    u1 = min((ua * cdf[len(cdf) - 1] - lo) / width, _ONE_MINUS) if width > 0.0 else 0.5
    return ua, max(u1, 0.0), u2


@njit(**_JIT)
def vol_bounce(ks, m_alpha, m_eta, m_k, md, cfg, U, prim, tfar, hu, hv, bprim, btfar,
               ints, keys, flt, flags, last_p, o32, d32, L,
               n_ints, n_keys, n_flt, n_flags, n_last_p, n_o32, n_d32,
               q_o32, q_d32, q_t32, q_ints, q_keys, q_val, err):
    """One round of every live path (state layouts: the module docstring): free flight, crossing,
    escape, or a surface / medium vertex with emission, NEE and the next ray.

    ks: path_kernels.KernelScene; m_alpha (M,), m_eta, m_k (M, 3): GGX parameters; md:
    :class:`MediaKernel`; cfg: :class:`VolConfig`. U: (N0, D) primary samples read instead of
    the hash (row = the path's slot; shape (0, 0): the hash), without media: each vertex owns 7
    dimensions, light pick, light point (2), lobe, direction (2), roulette (read when cfg.roulette
    and the vertex's index >= cfg.rr_depth), as render.integrators.pssmlt's layout. prim, tfar, hu, hv: Embree surface hits;
    bprim, btfar: media-boundary hits (unread without media). L (paths, 3) accumulates in place.
    Survivors go compacted, in order, to n_*; shadow rays to q_* (origin, direction, tmax as
    Embree reads them; q_ints (N, 3) [slot, medium, 0]; q_keys their own RNG keys; q_val the
    unoccluded contribution). err (1,) int64: set to medium + 1 when a majorant is exceeded.
    Returns (survivors, shadow rays).
    """
    extent, floor, n_area = ks.scal[0], ks.scal[1], np.int64(ks.scal[2])
    bg = ks.bg
    ids, tri_obj, tris, kinds, albedo, iors, Le = ks.ids, ks.tri_obj, ks.tri, ks.kind, ks.albedo, ks.ior, ks.Le
    emits, two_sided, tex, uv, tex_data, tri_pdf_area = ks.emits, ks.two_sided, ks.tex, ks.uv, ks.tex_data, ks.tri_pdf_area
    cdf, pmf, area, d_kind, d_pos, d_dir, d_I, d_cos = ks.cdf, ks.pmf, ks.area, ks.d_kind, ks.d_pos, ks.d_dir, ks.d_I, ks.d_cos
    md_sa, md_ss, md_Le, md_g, mus, homog = md.sigma_a, md.sigma_s, md.Le, md.g, md.mu, md.homogeneous
    lo, hi, gshape, goff, gdata = md.lo, md.hi, md.grid_shape, md.grid_off, md.grid_data
    b_normal, b_obj, b_ids, m_extent = md.b_normal, md.b_obj, md.b_ids, md.extent[0]
    sob = cfg.sampler == SAMPLER_SOBOL and U.shape[0] == 0
    nn = 0
    nq = 0
    for i in range(len(prim)):
        slot, dim, bounces, mid = ints[i, 0], ints[i, 1], ints[i, 2], ints[i, 3]
        key = keys[i]
        base = 2 + SOBOL_BOUNCE_DIMS * bounces  # this bounce's Sobol dimensions (sob)
        tkey = _mix64(key ^ _TRACK_SALT) if sob else key  # the tracking hash's key
        b0, b1, b2, pdf_prev = flt[i, 0], flt[i, 1], flt[i, 2], flt[i, 3]
        fl = flags[i]
        delta_prev = (fl & F_DELTA) != 0
        after_diff = (fl & F_AFTER_DIFF) != 0
        pruned = cfg.path_rules and not cfg.caustics and delta_prev and after_diff
        ox, oy, oz = np.float64(o32[i, 0]), np.float64(o32[i, 1]), np.float64(o32[i, 2])
        dx, dy, dz = np.float64(d32[i, 0]), np.float64(d32[i, 1]), np.float64(d32[i, 2])
        lpx, lpy, lpz = last_p[i, 0], last_p[i, 1], last_p[i, 2]
        t_s = np.float64(tfar[i]) if prim[i] >= 0 else np.inf
        cross = False
        scat = False
        t_b = np.inf
        t_sc = 0.0
        if cfg.has_media:
            if bprim[i] >= 0:
                t_b = np.float64(btfar[i])
            cross = t_b < t_s
            if mid >= 0:
                # the medium lies inside its box: a flight never needs to go past the box's exit
                t_end = min(min(t_s, t_b), _box_exit(lo, hi, mid, ox, oy, oz, dx, dy, dz))
                mu = mus[mid]
                if mu > 0.0:  # delta tracking (render.media.MediumSet.delta_track)
                    t = 0.0
                    absorbed = False
                    while True:
                        first = sob and (fl & F_FLIGHT) == 0  # the segment's first collision: Sobol
                        if first:
                            fl = np.uint8(fl | F_FLIGHT)
                            u_fl, u_ev = _sobol2(key, base + _SD_FLIGHT)  # distance and event: one 2-D group
                            t -= math.log1p(-u_fl) / mu
                        else:
                            t -= math.log1p(-_uniform(tkey, dim)) / mu
                        dim += 1
                        if not t < t_end:
                            break
                        dens = _density(homog, lo, hi, gshape, goff, gdata, mid, ox + t * dx, oy + t * dy, oz + t * dz)
                        sa0, sa1, sa2 = md_sa[mid, 0] * dens, md_sa[mid, 1] * dens, md_sa[mid, 2] * dens
                        ss0, ss1, ss2 = md_ss[mid, 0] * dens, md_ss[mid, 1] * dens, md_ss[mid, 2] * dens
                        st0, st1, st2 = sa0 + ss0, sa1 + ss1, sa2 + ss2
                        if _majorant_exceeded(st0, st1, st2, mu):
                            err[0] = mid + 1
                            absorbed = True
                            break
                        # emission at every tentative collision: beta sigma_a Le / mu
                        L[slot, 0] += b0 * sa0 * md_Le[mid, 0] / mu
                        L[slot, 1] += b1 * sa1 * md_Le[mid, 1] / mu
                        L[slot, 2] += b2 * sa2 * md_Le[mid, 2] / mu
                        sn0, sn1, sn2 = max(mu - st0, 0.0), max(mu - st1, 0.0), max(mu - st2, 0.0)
                        pa = (sa0 + sa1 + sa2) / (3.0 * mu)
                        pss = (ss0 + ss1 + ss2) / (3.0 * mu)
                        pn = (sn0 + sn1 + sn2) / (3.0 * mu)
                        tot = pa + pss + pn
                        u = (u_ev if first else _uniform(tkey, dim)) * tot
                        dim += 1
                        if u < pa:
                            absorbed = True
                            break
                        if u < pa + pss:
                            c = 1.0 / (mu * (pss / tot))
                            b0, b1, b2 = b0 * ss0 * c, b1 * ss1 * c, b2 * ss2 * c
                            scat = True
                            t_sc = t
                            break
                        c = 1.0 / (mu * (pn / tot))
                        b0, b1, b2 = b0 * sn0 * c, b1 * sn1 * c, b2 * sn2 * c
                    if absorbed:
                        continue
                    if scat:
                        cross = False
        if cross:  # a medium boundary: same direction, new medium, not a bounce
            bt = b_ids[bprim[i]]
            bnx, bny, bnz = b_normal[bt, 0], b_normal[bt, 1], b_normal[bt, 2]
            x, y, z = ox + t_b * dx, oy + t_b * dy, oz + t_b * dz
            eps = _offset(x, y, z, m_extent)
            side = eps if dx * bnx + dy * bny + dz * bnz >= 0.0 else -eps
            entering = dx * bnx + dy * bny + dz * bnz < 0.0
            n_ints[nn, 0], n_ints[nn, 1], n_ints[nn, 2] = slot, dim, bounces
            n_ints[nn, 3] = b_obj[bt] if entering else -1
            n_keys[nn] = key
            n_flt[nn, 0], n_flt[nn, 1], n_flt[nn, 2], n_flt[nn, 3] = b0, b1, b2, pdf_prev
            n_flags[nn] = fl
            n_last_p[nn, 0], n_last_p[nn, 1], n_last_p[nn, 2] = lpx, lpy, lpz
            n_o32[nn, 0], n_o32[nn, 1], n_o32[nn, 2] = x + side * bnx, y + side * bny, z + side * bnz
            n_d32[nn, 0], n_d32[nn, 1], n_d32[nn, 2] = d32[i, 0], d32[i, 1], d32[i, 2]
            nn += 1
            continue
        if not scat and prim[i] < 0:
            if cfg.has_bg and not pruned:
                L[slot, 0] += b0 * bg[0]
                L[slot, 1] += b1 * bg[1]
                L[slot, 2] += b2 * bg[2]
            continue
        # ---------------------------------------------------------- a vertex: surface or medium
        if scat:
            px, py, pz = ox + t_sc * dx, oy + t_sc * dy, oz + t_sc * dz
            if bounces >= cfg.max_depth:
                continue
            g = md_g[mid]
            kind = -1
            obj = 0
            ngx = ngy = ngz = 0.0
            nx = ny = nz = 0.0
            s1x = s1y = s1z = s2x = s2y = s2z = 0.0
            wox = woy = woz = 0.0
            a0 = a1 = a2 = 0.0
            eps = 0.0
        else:
            tri = ids[prim[i]]
            obj = tri_obj[tri]
            kind = kinds[obj]
            g = 0.0
            ngx, ngy, ngz = tris[tri, 9], tris[tri, 10], tris[tri, 11]
            u, v = np.float64(hu[i]), np.float64(hv[i])
            px, py, pz = _hit_point(tris, tri, u, v)
            cos_l = -(dx * ngx + dy * ngy + dz * ngz)
            if emits[obj] and (two_sided[obj] or cos_l > 0.0) and not pruned:
                w = 1.0
                if not delta_prev and cfg.has_lights and cfg.strategy != STRAT_BSDF:
                    if cfg.strategy == STRAT_LIGHT:
                        w = 0.0
                    else:
                        ex, ey, ez = px - lpx, py - lpy, pz - lpz
                        d2 = t_s * t_s if cfg.path_rules else ex * ex + ey * ey + ez * ez
                        pl = tri_pdf_area[tri] * d2 / max(abs(cos_l), _COS_FLOOR)
                        w = _mis(pdf_prev, pl, cfg.mis_exponent)
                L[slot, 0] += b0 * Le[obj, 0] * w
                L[slot, 1] += b1 * Le[obj, 1] * w
                L[slot, 2] += b2 * Le[obj, 2] * w
            if kind == EMISSIVE or bounces >= cfg.max_depth:
                continue
            # shading frame: facing wo unless a (smooth or rough) dielectric (outward normal)
            if cos_l < 0.0 and kind != DIELECTRIC and kind != ROUGH_DIELECTRIC:
                nx, ny, nz = -ngx, -ngy, -ngz
            else:
                nx, ny, nz = ngx, ngy, ngz
            (s1x, s1y, s1z), (s2x, s2y, s2z) = _frame(nx, ny, nz)
            wox = -(dx * s1x + dy * s1y + dz * s1z)
            woy = -(dx * s2x + dy * s2y + dz * s2z)
            woz = -(dx * nx + dy * ny + dz * nz)
            if tex[obj, 1] == 0 or kind != LAMBERT:
                a0, a1, a2 = albedo[obj, 0], albedo[obj, 1], albedo[obj, 2]
            else:
                a0, a1, a2 = _albedo(albedo, tex, uv, tex_data, obj, tri, u, v)
            eps = _offset(px, py, pz, extent)
        # next-event estimation
        if cfg.has_lights:
            if sob:
                lu0, lu1, lu2 = _light_uniforms(cdf, key, base)
            else:
                lu0, lu1, lu2 = _rand(key, dim, U, slot), _rand(key, dim + 1, U, slot), _rand(key, dim + 2, U, slot)
            ok, lx, ly, lz, ldist, L0, L1, L2, lpdf, ldelta = _sample_light(
                cdf, pmf, area, d_kind, d_pos, d_dir, d_I, d_cos, n_area, floor, px, py, pz, lu0, lu1, lu2)
            skey = _mix64(key ^ (np.uint64(dim) * _SHADOW_SALT))
            if ok:
                if scat:
                    ph = hg_pdf_k(g, dx, dy, dz, lx, ly, lz)
                    f0 = f1 = f2 = ph
                    pb = ph
                else:
                    wix = lx * s1x + ly * s1y + lz * s1z
                    wiy = lx * s2x + ly * s2y + lz * s2z
                    wiz = lx * nx + ly * ny + lz * nz
                    f0, f1, f2, pb = surface_eval_local(kind, a0, a1, a2, m_alpha[obj], iors[obj], m_eta[obj, 0],
                                                        m_eta[obj, 1], m_eta[obj, 2], m_k[obj, 0], m_k[obj, 1],
                                                        m_k[obj, 2], wox, woy, woz, wix, wiy, wiz)
                    ac = abs(wiz)
                    f0, f1, f2 = f0 * ac, f1 * ac, f2 * ac
                ok = max(max(f0, f1), f2) > 0.0
                if cfg.strategy == STRAT_BSDF:
                    ok = ok and ldelta
            if ok:
                w = 1.0
                if cfg.strategy != STRAT_LIGHT and not ldelta:
                    w = _mis(lpdf, pb, cfg.mis_exponent)
                if scat:
                    sx, sy, sz = px, py, pz
                else:
                    side = eps if lx * ngx + ly * ngy + lz * ngz >= 0.0 else -eps
                    sx, sy, sz = px + side * ngx, py + side * ngy, pz + side * ngz
                q_o32[nq, 0], q_o32[nq, 1], q_o32[nq, 2] = sx, sy, sz
                q_d32[nq, 0], q_d32[nq, 1], q_d32[nq, 2] = lx, ly, lz
                if ldist < np.inf and cfg.path_rules:
                    q_t32[nq] = min(max(ldist * (1.0 - 1e-4) - 2.0 * eps, 0.0), _TMAX_CAP)
                elif ldist < np.inf:
                    q_t32[nq] = min(max(ldist * (1.0 - 1e-5) - 1e-6 * extent, 0.0), _TMAX_CAP)
                else:
                    q_t32[nq] = _TMAX_CAP
                q_ints[nq, 0], q_ints[nq, 1], q_ints[nq, 2] = slot, mid, 0
                q_keys[nq] = skey
                s = w / lpdf
                q_val[nq, 0] = b0 * f0 * L0 * s
                q_val[nq, 1] = b1 * f1 * L1 * s
                q_val[nq, 2] = b2 * f2 * L2 * s
                nq += 1
        dim += 3  # NEE's dimensions, used or not (a fixed layout per vertex)
        # the next ray
        if sob:
            u0 = _sobol(key, base + _SD_LOBE)
            u1, u2 = _sobol2(key, base + _SD_DIR)
        else:
            u0, u1, u2 = _rand(key, dim, U, slot), _rand(key, dim + 1, U, slot), _rand(key, dim + 2, U, slot)
        dim += 3
        if scat:
            wx, wy, wz = hg_sample_k(g, dx, dy, dz, u1, u2)
            pdf_new = hg_pdf_k(g, dx, dy, dz, wx, wy, wz)
            nfl = F_AFTER_DIFF
            qx, qy, qz = px, py, pz
        else:
            ok, lwx, lwy, lwz, w0, w1, w2, pdf_new, delta = surface_sample_local(
                kind, a0, a1, a2, m_alpha[obj], iors[obj], m_eta[obj, 0], m_eta[obj, 1], m_eta[obj, 2],
                m_k[obj, 0], m_k[obj, 1], m_k[obj, 2], wox, woy, woz, u0, u1, u2)
            if not ok or (not cfg.caustics and not cfg.path_rules and delta and after_diff):
                continue
            wx = lwx * s1x + lwy * s2x + lwz * nx
            wy = lwx * s1y + lwy * s2y + lwz * ny
            wz = lwx * s1z + lwy * s2z + lwz * nz
            b0, b1, b2 = b0 * w0, b1 * w1, b2 * w2
            nfl = F_DELTA if delta else np.uint8(0)
            if after_diff or not delta:
                nfl |= F_AFTER_DIFF
            side = eps if wx * ngx + wy * ngy + wz * ngz >= 0.0 else -eps
            qx, qy, qz = px + side * ngx, py + side * ngy, pz + side * ngz
        bounces += 1
        if cfg.roulette and bounces > cfg.rr_depth:
            q = min(1.0, max(max(b0, b1), b2))
            u = _sobol(key, base + _SD_RR) if sob else _rand(key, dim, U, slot)
            dim += 1
            if not u < q:
                continue
            b0, b1, b2 = b0 / q, b1 / q, b2 / q
        elif U.shape[0] > 0:
            dim += 1  # pssmlt's fixed layout: every vertex owns its roulette column, read or not
        if not max(max(b0, b1), b2) > 0.0:
            continue
        n_ints[nn, 0], n_ints[nn, 1], n_ints[nn, 2], n_ints[nn, 3] = slot, dim, bounces, mid
        n_keys[nn] = key
        n_flt[nn, 0], n_flt[nn, 1], n_flt[nn, 2], n_flt[nn, 3] = b0, b1, b2, pdf_new
        n_flags[nn] = nfl
        n_last_p[nn, 0], n_last_p[nn, 1], n_last_p[nn, 2] = px, py, pz
        n_o32[nn, 0], n_o32[nn, 1], n_o32[nn, 2] = qx, qy, qz
        n_d32[nn, 0], n_d32[nn, 1], n_d32[nn, 2] = wx, wy, wz
        nn += 1
    return nn, nq


# ------------------------------------------------------------------ shadow rays through media
@njit(**_JIT)
def shadow_start(occ, q_o32, q_d32, q_t32, q_ints, q_keys, q_val, s_o32, s_d32, s_rem, s_ints, s_keys, s_lt, s_val):
    """Compact the shadow rays Embree found unoccluded (occ == -1) into the media walk's state:
    s_o32, s_d32 (N, 3) float32; s_rem (N,) distance left to the light; s_ints (N, 3) [slot,
    medium, next dimension]; s_keys; s_lt (N, 3) log transmittance so far (0); s_val (N, 3) the
    unoccluded contribution. Returns the count."""
    n = 0
    for k in range(len(occ)):
        if occ[k] != -1:
            continue
        for c in range(3):
            s_o32[n, c] = q_o32[k, c]
            s_d32[n, c] = q_d32[k, c]
            s_lt[n, c] = 0.0
            s_val[n, c] = q_val[k, c]
        s_rem[n] = np.float64(q_t32[k])
        s_ints[n, 0], s_ints[n, 1], s_ints[n, 2] = q_ints[k, 0], q_ints[k, 1], 0
        s_keys[n] = q_keys[k]
        n += 1
    return n


@njit(**_JIT)
def shadow_media_step(md, n, bprim, btfar, s_o32, s_d32, s_rem, s_ints, s_keys, s_lt, s_val, L, err):
    """One boundary-to-boundary segment of n shadow rays (bprim, btfar: their next boundary hits):
    log transmittance of the medium they travel in over min(boundary, rem); rays reaching their
    light add s_val exp(log T) to L; rays crossing a boundary move past it (new medium, rem
    reduced) and stay, compacted in place, if not yet black. Returns the survivors' count."""
    md_sa, md_ss, mus, homog = md.sigma_a, md.sigma_s, md.mu, md.homogeneous
    lo, hi, gshape, goff, gdata = md.lo, md.hi, md.grid_shape, md.grid_off, md.grid_data
    b_normal, b_obj, b_ids, m_extent = md.b_normal, md.b_obj, md.b_ids, md.extent[0]
    live = 0
    for i in range(n):
        ox, oy, oz = np.float64(s_o32[i, 0]), np.float64(s_o32[i, 1]), np.float64(s_o32[i, 2])
        dx, dy, dz = np.float64(s_d32[i, 0]), np.float64(s_d32[i, 1]), np.float64(s_d32[i, 2])
        slot, mid, dim = s_ints[i, 0], s_ints[i, 1], s_ints[i, 2]
        key = s_keys[i]
        rem = s_rem[i]
        tb = np.float64(btfar[i]) if bprim[i] >= 0 else np.inf
        seg = min(tb, rem)
        l0, l1, l2 = s_lt[i, 0], s_lt[i, 1], s_lt[i, 2]
        if mid >= 0:
            seg = min(seg, _box_exit(lo, hi, mid, ox, oy, oz, dx, dy, dz))
            a0, a1, a2, dim = _log_transmittance(md_sa, md_ss, homog, lo, hi, gshape, goff, gdata, mus, mid,
                                                 ox, oy, oz, dx, dy, dz, seg, key, dim, err)
            l0, l1, l2 = l0 + a0, l1 + a1, l2 + a2
        if max(max(l0, l1), l2) == -np.inf:
            continue
        if not tb < rem:  # reached the light
            L[slot, 0] += s_val[i, 0] * math.exp(l0)
            L[slot, 1] += s_val[i, 1] * math.exp(l1)
            L[slot, 2] += s_val[i, 2] * math.exp(l2)
            continue
        bt = b_ids[bprim[i]]
        bnx, bny, bnz = b_normal[bt, 0], b_normal[bt, 1], b_normal[bt, 2]
        x, y, z = ox + tb * dx, oy + tb * dy, oz + tb * dz
        cosd = dx * bnx + dy * bny + dz * bnz
        eps = _offset(x, y, z, m_extent)
        side = eps if cosd >= 0.0 else -eps
        s_o32[live, 0], s_o32[live, 1], s_o32[live, 2] = x + side * bnx, y + side * bny, z + side * bnz
        for c in range(3):
            s_d32[live, c] = s_d32[i, c]
            s_val[live, c] = s_val[i, c]
        s_lt[live, 0], s_lt[live, 1], s_lt[live, 2] = l0, l1, l2
        s_rem[live] = rem - tb
        s_ints[live, 0], s_ints[live, 1], s_ints[live, 2] = slot, b_obj[bt] if cosd < 0.0 else -1, dim
        s_keys[live] = key
        live += 1
    return live


@njit(**_JIT)
def shadow_flush(n, s_ints, s_lt, s_val, L):
    """Shadow rays still crossing boundaries after the last allowed crossing: their transmittance
    so far counts (as the numpy reference's cap)."""
    for i in range(n):
        slot = s_ints[i, 0]
        for c in range(3):
            L[slot, c] += s_val[i, c] * math.exp(s_lt[i, c])


# ------------------------------------------------------------------ a whole wavefront in one call
if _edirect.AVAILABLE:
    _intersect_many, _occluded_many = _edirect.intersect_many, _edirect.occluded_many

    @njit(**_JIT)
    def trace_surfaces(ks, m_alpha, m_eta, m_k, md, cfg, U, handle, rounds, m, cur, nxt, q, hit, occ, L, err):
        """render.integrators.volpath._wavefront without media in a single compiled call, Embree
        queried from here (render.embree_direct): up to ``rounds`` rounds of one surface query,
        :func:`vol_bounce` and one occlusion query for its shadow rays, the same operations in
        the same order, so the same bytes. cur, nxt: wavefront states (cur's first m rows live);
        q: the shadow queue; hit: (prim, tfar, u, v) Embree outputs and occ (N,) int32, one row
        per path. Returns the rays traced. The per-round Python calls this replaces cost about
        as much as a 2048-path round of the pssmlt chains' sampler (render.integrators.pssmlt)."""
        prim, tfar, hu, hv = hit
        no_prim, no_t = prim[:0], tfar[:0]
        rays = 0
        for _ in range(rounds):
            if m == 0:
                break
            _intersect_many(handle, cur[5][:m], cur[6][:m], prim[:m], tfar[:m], hu[:m], hv[:m])
            rays += m
            m, nq = vol_bounce(ks, m_alpha, m_eta, m_k, md, cfg, U, prim[:m], tfar[:m], hu[:m], hv[:m], no_prim, no_t,
                               cur[0][:m], cur[1][:m], cur[2][:m], cur[3][:m], cur[4][:m], cur[5][:m], cur[6][:m], L,
                               nxt[0], nxt[1], nxt[2], nxt[3], nxt[4], nxt[5], nxt[6],
                               q[0], q[1], q[2], q[3], q[4], q[5], err)
            if nq:
                _occluded_many(handle, q[0][:nq], q[1][:nq], q[2][:nq], occ[:nq])
                rays += nq
                for r in range(nq):
                    if occ[r] == -1:
                        s = q[3][r, 0]
                        L[s, 0] += q[5][r, 0]
                        L[s, 1] += q[5][r, 1]
                        L[s, 2] += q[5][r, 2]
            cur, nxt = nxt, cur
        return rays
else:  # pragma: no cover - the Python driver calls Embree through embreex
    trace_surfaces = None
