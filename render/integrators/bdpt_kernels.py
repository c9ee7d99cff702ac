"""Compiled (numba) wavefront kernels of ``bdpt``: subpath starts, one extension step per vertex,
the MIS prefix sums, and every (s, t) join with its shadow ray.

:mod:`render.integrators.bdpt` drives them: camera and light subpaths are extended one vertex
at a time for the whole batch (one Embree query through :meth:`render.accel.Accel.intersect_fast`,
then :func:`extend` over the hits), :func:`prefix_sums` fills pbrt's MISWeight prefix data, and
:func:`connect` evaluates every strategy of every camera sample (s = 0 straight into the pass
images, the others as a shadow-ray queue that :meth:`render.accel.Accel.occluded_fast` and
:func:`render.integrators.path_kernels.add_unoccluded` resolve). The estimator, random
dimensions and conventions are those of the numpy implementation in :mod:`render.integrators.bdpt`
(``render_bdpt_numpy``), which stays the tested reference; read its module docstring for the
math. Only the loops moved: one scalar loop per camera sample instead of array operations per
(s, t) family.

Layout: a batch of N camera samples holds its subpaths sample-major: ``V`` (N, nv, N_FIELDS)
float64 vertex fields (the ``_P`` .. ``_SUM`` column offsets below: point, geometric normal,
BSDF frame normal, unit wo, throughput, albedo, pdfFwd, pdfRev, conversion factor, MIS cond and
prefix sum), ``Fl`` (N, nv) uint8 flags (alive, delta, the two caustics-pruning flags) and ``Iv``
(N, nv, 2) int64 (object, global triangle). Walk state per live ray: ``st`` (M, N_STATE)
float64 (direction, throughput, direction density, the previous vertex's density mode, roulette
reference, the previous vertex's point and normal: carried, since reading them back from V
missed the cache, 0.9-0.97x bdpt's time) with ``idx`` (M,) the sample it extends and float32 rays
(M, 3) for Embree. Every kernel releases the GIL and visits samples in index order, so the
bytes do not depend on threads.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import embree_direct as _edirect
from .path_kernels import (_GOLDEN, _M2, _albedo, _cos_sin_2pi, _facing_normal, _frame, _fresnel_dielectric, _hit_point,
                           _mix64, _pick, _sample_area, _sample_delta)
from .path_kernels import _offset as _eps
from .path_kernels import _uniform as _u

__all__ = ["BdptConfig", "N_FIELDS", "N_STATE", "start_camera", "start_light", "extend", "prefix_sums", "connect",
           "queue_bound", "trace_batch", "add_pass_moments"]

LAMBERT, MIRROR, DIELECTRIC = 0, 1, 2  # render.bsdf kinds
POINT, SPOT, DIRECTIONAL = 0, 1, 2  # render.lights kinds
AREA = 3
SURF, POINTLIKE, INFINITE = 0, 1, 2  # how a density leaving a vertex converts to an area density

# vertex fields of V
_P, _NG, _NF, _WO, _BETA, _ALB = 0, 3, 6, 9, 12, 15
_FWD, _REV, _CONV, _COND, _SUM = 18, 19, 20, 21, 22
N_FIELDS = 23
# flags of Fl
F_ALIVE, F_DELTA, F_HAS, F_CAUS = np.uint8(1), np.uint8(2), np.uint8(4), np.uint8(8)
# walk state columns of st
_D, _B, _PDF, _MODE, _REF, _PP, _PN = 0, 3, 6, 7, 8, 9, 12
N_STATE = 15

#: random dimensions (render.integrators.bdpt): eye jitter (0, 1), then per vertex i >= 1 from
#: 2 + 8 (i - 1) lobe, direction (2), roulette, light pick, light point (2); light: pick, point
#: (2), direction (2), side, then per vertex from 6 + 4 (i - 1): lobe, direction (2), roulette
_EYE_DIM0, _EYE_STEP, _LIGHT_DIM0, _LIGHT_STEP = 2, 8, 6, 4
_LIGHT_STREAM = np.uint64(1 << 40)
_CLAMP = 1e150
_BIG = 1e300
_INV_PI = 1.0 / math.pi
_TMAX_CAP = 3e38

_JIT = dict(cache=True, nogil=True, error_model="numpy")


class BdptConfig(NamedTuple):
    """What the kernels read of the render's settings, scene and camera (built by
    :func:`render.integrators.bdpt._kernel_config`)."""

    max_depth: int  #: maximum scattering events of a full path
    nv_e: int  #: eye subpath vertices (max_depth + 2, the pinhole included)
    nv_l: int  #: light subpath vertices (max_depth + 1)
    roulette: bool  #: Russian roulette on subpath extension
    rr_depth: int  #: first vertex index whose extension roulette may end
    caustics: bool  #: keep caustic paths (False: pruned as the numpy version does)
    hexp: float  #: MIS exponent: 2.0 power heuristic, 1.0 balance
    weighted: bool  #: MIS-weight the strategies (False: the ``strategies`` diagnostic, unweighted)
    use: np.ndarray  #: (nv_l + 1, nv_e + 1) bool: strategy (s, t) evaluated
    has_bg: bool  #: escaping eye rays gather a non-black background
    radius: float  #: the scene's bounding radius (directional lights' emission disk)
    centre: np.ndarray  #: (3,) the scene's bounding centre
    width: int  #: image width (pixels)
    height: int  #: image height
    area: float  #: the image's area on the plane z = 1 (W H / (fx fy))


# ------------------------------------------------------------------ small helpers
@njit(inline="always", **_JIT)
def _key(seed_mix, pixel, sample):
    """render.sampling.path_keys for one (pixel, sample)."""
    k = _mix64(np.uint64(pixel) * _GOLDEN ^ seed_mix)
    return _mix64(k ^ (np.uint64(sample) * _M2 + _GOLDEN))


@njit(inline="always", **_JIT)
def _spawn(px, py, pz, nx, ny, nz, wx, wy, wz, extent):
    """render.accel.spawn_origin for one point: p offset along +-n to the side w leaves on."""
    e = _eps(px, py, pz, extent)
    side = e if wx * nx + wy * ny + wz * nz >= 0.0 else -e
    return px + side * nx, py + side * ny, pz + side * nz


@njit(inline="always", **_JIT)
def _ratio(num, den, hexp):
    """(remap0(num) / remap0(den))^hexp clamped to [1e-150, 1e150] before the power."""
    r = (num if num != 0.0 else 1.0) / (den if den != 0.0 else 1.0)
    r = min(max(r, 1.0 / _CLAMP), _CLAMP)
    return r * r if hexp == 2.0 else r ** hexp


@njit(inline="always", **_JIT)
def _side_sum(V, Fl, k, n, r1, r2):
    """Sum of relative densities^hexp of the strategies moving the join into a subpath whose
    last joined vertex is n - 1, n >= 3 (render.integrators.bdpt._eye_sum / _light_sum): r1, r2
    the join's ratios at vertices n - 1 and n - 2."""
    inner = V[k, n - 2, _COND] + V[k, n - 3, _SUM]
    nd = 0.0 if (Fl[k, n - 2] & F_DELTA) != 0 else 1.0
    return min(r1 * (nd + min(r2 * inner, _BIG)), _BIG)


@njit(inline="always", **_JIT)
def _eye_sum(V, Fl, k, t, r1, r2):
    """render.integrators.bdpt._eye_sum for one sample: the pinhole (t = 2's z_0) is no join."""
    if t <= 1:
        return 0.0
    if t == 2:
        return r1
    return _side_sum(V, Fl, k, t, r1, r2)


@njit(inline="always", **_JIT)
def _light_sum(V, Fl, k, s, r1, r2, cond0):
    """render.integrators.bdpt._light_sum for one sample (cond0: s = 1's light not delta)."""
    if s == 0:
        return 0.0
    if s == 1:
        return r1 * cond0
    if s == 2:  # inner = cond[0] (no S[-1])
        nd = 0.0 if (Fl[k, 0] & F_DELTA) != 0 else 1.0
        return min(r1 * (nd + min(r2 * V[k, 0, _COND], _BIG)), _BIG)
    return _side_sum(V, Fl, k, s, r1, r2)


@njit(inline="always", **_JIT)
def _lambert(V, k, i, wx, wy, wz):
    """Lambertian BSDF at vertex (k, i) towards w: (f / albedo scale (1/pi or 0), cos of w on the
    frame normal, pdf of sampling w given wo, pdf of sampling wo given w) (render.bsdf's
    lambert_eval / lambert_pdf; only the frame normal's components matter)."""
    nx, ny, nz = V[k, i, _NF], V[k, i, _NF + 1], V[k, i, _NF + 2]
    co = V[k, i, _WO] * nx + V[k, i, _WO + 1] * ny + V[k, i, _WO + 2] * nz
    ci = wx * nx + wy * ny + wz * nz
    f = _INV_PI if (co > 0.0 and ci > 0.0) else 0.0
    pdf_f = max(ci, 0.0) * _INV_PI if co > 0.0 else 0.0
    pdf_r = max(co, 0.0) * _INV_PI if ci > 0.0 else 0.0
    return f, ci, pdf_f, pdf_r


@njit(inline="always", **_JIT)
def _queue(q_o32, q_d32, q_t32, q_idx, q_val, nq, ox, oy, oz, dx, dy, dz, tmax, slot, c0, c1, c2):
    q_o32[nq, 0], q_o32[nq, 1], q_o32[nq, 2] = ox, oy, oz
    q_d32[nq, 0], q_d32[nq, 1], q_d32[nq, 2] = dx, dy, dz
    q_t32[nq] = min(tmax, _TMAX_CAP)
    q_idx[nq] = slot
    q_val[nq, 0], q_val[nq, 1], q_val[nq, 2] = c0, c1, c2
    return nq + 1


@njit(inline="always", **_JIT)
def _queue_segment(q_o32, q_d32, q_t32, q_idx, q_val, nq, ax, ay, az, anx, any_, anz, bx, by, bz, bnx, bny, bnz,
                   b_on_surface, extent, slot, c0, c1, c2):
    """render.integrators.bdpt._segment: a shadow ray between surface point a (normal an) and b
    (normal bn, or a point off any surface), both ends offset towards each other."""
    wx, wy, wz = bx - ax, by - ay, bz - az
    nrm = max(math.sqrt(wx * wx + wy * wy + wz * wz), 1e-300)
    wx, wy, wz = wx / nrm, wy / nrm, wz / nrm
    ox, oy, oz = _spawn(ax, ay, az, anx, any_, anz, wx, wy, wz, extent)
    if b_on_surface:
        bx, by, bz = _spawn(bx, by, bz, bnx, bny, bnz, -wx, -wy, -wz, extent)
    vx, vy, vz = bx - ox, by - oy, bz - oz
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    dd = max(dist, 1e-300)
    return _queue(q_o32, q_d32, q_t32, q_idx, q_val, nq, ox, oy, oz, vx / dd, vy / dd, vz / dd,
                  dist * (1.0 - 1e-6), slot, c0, c1, c2)


def queue_bound(max_depth: int) -> int:
    """Most shadow rays one camera sample queues: s = 1 and t = 1 (max_depth each) and the
    inner joins ((max_depth + 1)^2 bounds them)."""
    return (max_depth + 2) ** 2


# ------------------------------------------------------------------ subpath starts
@njit(**_JIT)
def start_camera(cfg, cam, seed_mix, sample0, pix0, npc, keys_e, keys_l, tgt, V, Fl, idx, st, o32, d32):
    """Camera samples 0 .. N - 1 of a batch (sample k: pass sample0 + k // npc, pixel pix0 +
    k % npc): hash keys of the eye and light subpaths (render.sampling.path_keys; light pixels
    offset by 2^40), image slot tgt (pass_local H W + pixel), eye vertex 0 (the pinhole) and the
    jittered camera rays as the walk's first state (cam: a path_kernels.PinholeCamera)."""
    rot, org = cam.rotation, cam.origin
    npix = cfg.width * cfg.height
    for k in range(len(keys_e)):
        pl = k // npc
        pixel = pix0 + k % npc
        s = sample0 + pl
        ke = _key(seed_mix, pixel, s)
        keys_e[k] = ke
        keys_l[k] = _key(seed_mix, np.uint64(pixel) + _LIGHT_STREAM, s)
        tgt[k] = pl * npix + pixel
        x = (pixel % cfg.width + _u(ke, 0) - cam.cx) / cam.fx
        y = (pixel // cfg.width + _u(ke, 1) - cam.cy) / cam.fy
        nrm = math.sqrt(x * x + y * y + 1.0)
        x, y, z = x / nrm, y / nrm, 1.0 / nrm
        cos0 = 0.0
        for c in range(3):
            dc = rot[c, 0] * x + rot[c, 1] * y + rot[c, 2] * z
            st[k, _D + c] = dc
            st[k, _B + c] = 1.0
            V[k, 0, _P + c] = org[c]
            d32[k, c] = dc
            o32[k, c] = org[c]
            cos0 += dc * rot[c, 2]
        V[k, 0, _FWD] = 1.0
        V[k, 0, _REV] = 0.0
        Fl[k, 0] = F_ALIVE
        st[k, _PDF] = 1.0 / (cfg.area * cos0 * cos0 * cos0)
        st[k, _MODE] = POINTLIKE
        st[k, _REF] = 1.0
        for c in range(3):
            st[k, _PP + c] = org[c]
            st[k, _PN + c] = 0.0
        idx[k] = k


@njit(**_JIT)
def start_light(ks, cfg, keys_l, V, Fl, lkind, idx, st, o32, d32):
    """Light vertex 0 of every sample (render.lights.sample_emission from dimensions 0 .. 5 of
    its light key) and the first rays of those that carry flux (the walk's state, compacted in
    order). lkind (N,) int64: AREA or the delta light's kind. Returns the number of live rays."""
    cdf, pmf, area, tri = ks.cdf, ks.pmf, ks.area, ks.tri
    extent, n_area = ks.scal[0], np.int64(ks.scal[2])
    if not cdf[len(cdf) - 1] > 0.0:
        return 0
    R = cfg.radius
    m = 0
    for k in range(len(keys_l)):
        key = keys_l[k]
        u0, u1, u2, u3, u4, u5 = _u(key, 0), _u(key, 1), _u(key, 2), _u(key, 3), _u(key, 4), _u(key, 5)
        ent = _pick(cdf, u0)
        pm = pmf[ent]
        nx = ny = nz = 0.0
        if ent < n_area:
            su = math.sqrt(u1)
            b1, b2 = 1.0 - su, u2 * su
            px = area[ent, 0] + b1 * area[ent, 3] + b2 * area[ent, 6]
            py = area[ent, 1] + b1 * area[ent, 4] + b2 * area[ent, 7]
            pz = area[ent, 2] + b1 * area[ent, 5] + b2 * area[ent, 8]
            nx, ny, nz = area[ent, 9], area[ent, 10], area[ent, 11]
            two = area[ent, 16] > 0.0
            if two and u5 < 0.5:
                nx, ny, nz = -nx, -ny, -nz
            (sx, sy, sz), (tx, ty, tz) = _frame(nx, ny, nz)
            r = math.sqrt(u3)
            c_, s_ = _cos_sin_2pi(u4)
            lx, ly, lz = r * c_, r * s_, math.sqrt(max(0.0, 1.0 - u3))
            dx = lx * sx + ly * tx + lz * nx
            dy = lx * sy + ly * ty + lz * ny
            dz = lx * sz + ly * tz + lz * nz
            cx_ = area[ent, 4] * area[ent, 8] - area[ent, 5] * area[ent, 7]
            cy_ = area[ent, 5] * area[ent, 6] - area[ent, 3] * area[ent, 8]
            cz_ = area[ent, 3] * area[ent, 7] - area[ent, 4] * area[ent, 6]
            tri_area = 0.5 * math.sqrt(cx_ * cx_ + cy_ * cy_ + cz_ * cz_)
            scale = math.pi * tri_area * (2.0 if two else 1.0) / max(pm, 1e-300)
            f0, f1, f2 = area[ent, 13] * scale, area[ent, 14] * scale, area[ent, 15] * scale
            ox, oy, oz = _spawn(px, py, pz, nx, ny, nz, dx, dy, dz, extent)
            pdf_pos = 1.0 / max(tri_area, 1e-300)
            pdf_dir = lz * _INV_PI * (0.5 if two else 1.0)
            kind = AREA
            mode = SURF
            fwd = pm * pdf_pos
        else:
            li = ent - n_area
            kind = ks.d_kind[li]
            pmc = max(pm, 1e-300)
            I0, I1, I2 = ks.d_I[li, 0], ks.d_I[li, 1], ks.d_I[li, 2]
            ax, ay, az = ks.d_dir[li, 0], ks.d_dir[li, 1], ks.d_dir[li, 2]
            pdf_pos = 1.0
            mode = POINTLIKE
            if kind == POINT:
                px, py, pz = ks.d_pos[li, 0], ks.d_pos[li, 1], ks.d_pos[li, 2]
                z = 1.0 - 2.0 * u3
                r = math.sqrt(max(0.0, 1.0 - z * z))
                c_, s_ = _cos_sin_2pi(u4)
                dx, dy, dz = r * c_, r * s_, z
                s = 4.0 * math.pi / pmc
                f0, f1, f2 = I0 * s, I1 * s, I2 * s
                pdf_dir = 0.25 * _INV_PI
            elif kind == SPOT:
                px, py, pz = ks.d_pos[li, 0], ks.d_pos[li, 1], ks.d_pos[li, 2]
                ci, co = ks.d_cos[li, 0], ks.d_cos[li, 1]
                cz = 1.0 - u3 * (1.0 - co)
                sz_ = math.sqrt(max(0.0, 1.0 - cz * cz))
                c_, s_ = _cos_sin_2pi(u4)
                (sx, sy, sz), (tx, ty, tz) = _frame(ax, ay, az)
                lx, ly = sz_ * c_, sz_ * s_
                dx = lx * sx + ly * tx + cz * ax
                dy = lx * sy + ly * ty + cz * ay
                dz = lx * sz + ly * tz + cz * az
                x = min(max((cz - co) / max(ci - co, 1e-9), 0.0), 1.0)
                s = x * x * (3.0 - 2.0 * x) * 2.0 * math.pi * (1.0 - co) / pmc
                f0, f1, f2 = I0 * s, I1 * s, I2 * s
                pdf_dir = 1.0 / (2.0 * math.pi * max(1.0 - co, 1e-300))
            else:  # directional: a disk of the scene's bounding radius, upstream of the scene
                (sx, sy, sz), (tx, ty, tz) = _frame(ax, ay, az)
                r = R * math.sqrt(u1)
                c_, s_ = _cos_sin_2pi(u2)
                rc, rs = r * c_, r * s_
                px = (cfg.centre[0] - 2.0 * R * ax) + rc * sx + rs * tx
                py = (cfg.centre[1] - 2.0 * R * ay) + rc * sy + rs * ty
                pz = (cfg.centre[2] - 2.0 * R * az) + rc * sz + rs * tz
                dx, dy, dz = ax, ay, az
                s = math.pi * R * R / pmc
                f0, f1, f2 = I0 * s, I1 * s, I2 * s
                pdf_pos = 1.0 / (math.pi * R * R)
                pdf_dir = pdf_pos  # the walk's first density: per unit area perpendicular to d
                mode = INFINITE
            ox, oy, oz = px, py, pz
            fwd = 0.0 if kind == DIRECTIONAL else pm * pdf_pos
        lkind[k] = kind
        V[k, 0, _P], V[k, 0, _P + 1], V[k, 0, _P + 2] = px, py, pz
        V[k, 0, _NG], V[k, 0, _NG + 1], V[k, 0, _NG + 2] = nx, ny, nz
        V[k, 0, _FWD] = fwd
        V[k, 0, _REV] = 0.0
        flux_max = max(max(f0, f1), f2)
        if not flux_max > 0.0:
            continue
        Fl[k, 0] = F_ALIVE
        idx[m] = k
        st[m, _D], st[m, _D + 1], st[m, _D + 2] = dx, dy, dz
        st[m, _B], st[m, _B + 1], st[m, _B + 2] = f0, f1, f2
        st[m, _PDF] = pdf_dir
        st[m, _MODE] = mode
        st[m, _REF] = flux_max
        st[m, _PP], st[m, _PP + 1], st[m, _PP + 2] = px, py, pz
        st[m, _PN], st[m, _PN + 1], st[m, _PN + 2] = nx, ny, nz
        o32[m, 0], o32[m, 1], o32[m, 2] = ox, oy, oz
        d32[m, 0], d32[m, 1], d32[m, 2] = dx, dy, dz
        m += 1
    return m


# ------------------------------------------------------------------ one vertex more
@njit(**_JIT)
def extend(ks, cfg, i, light, prim, hu, hv, m, idx, st, keys, V, Fl, Iv, img, tgt,
           n_idx, n_st, n_o32, n_d32):
    """Store vertex i of the m live subpaths from their rays' first hits (prim, hu, hv from
    Embree) and sample the ray leaving it (render.integrators.bdpt._walk, one step).

    light: light subpaths (importance: no (eta_i / eta_t)^2 through glass) or eye subpaths.
    Escaping eye rays add throughput x background to img[tgt[k]] (strategy (0, i + 1), the only
    one that reaches the background). Survivors' next state goes to n_* compacted in order.
    Returns their number."""
    ids, tri_obj, tris, kinds, albedo, iors = ks.ids, ks.tri_obj, ks.tri, ks.kind, ks.albedo, ks.ior
    tex, uv, tex_data, bg = ks.tex, ks.uv, ks.tex_data, ks.bg
    extent = ks.scal[0]
    floor2 = (1e-9 * extent) ** 2
    nv = cfg.nv_l if light else cfg.nv_e
    last = i == nv - 1
    base = (_LIGHT_DIM0 + _LIGHT_STEP * (i - 1)) if light else (_EYE_DIM0 + _EYE_STEP * (i - 1))
    bg_on = (not light) and cfg.has_bg and cfg.use[0, i + 1]
    roulette = cfg.roulette and i - 1 >= cfg.rr_depth
    nn = 0
    for r in range(m):
        k = idx[r]
        dx, dy, dz = st[r, _D], st[r, _D + 1], st[r, _D + 2]
        b0, b1, b2 = st[r, _B], st[r, _B + 1], st[r, _B + 2]
        if prim[r] < 0:
            if bg_on and (cfg.caustics or (Fl[k, i - 1] & F_CAUS) == 0):
                g = tgt[k]
                img[g, 0] += b0 * bg[0]
                img[g, 1] += b1 * bg[1]
                img[g, 2] += b2 * bg[2]
            continue
        t = ids[prim[r]]
        obj = tri_obj[t]
        kind = kinds[obj]
        u, v = np.float64(hu[r]), np.float64(hv[r])
        px, py, pz = _hit_point(tris, t, u, v)
        ngx, ngy, ngz = tris[t, 9], tris[t, 10], tris[t, 11]
        wx, wy, wz = px - st[r, _PP], py - st[r, _PP + 1], pz - st[r, _PP + 2]
        d2 = max(wx * wx + wy * wy + wz * wz, floor2)
        dng = dx * ngx + dy * ngy + dz * ngz
        cos_in = abs(dng)
        pdf = st[r, _PDF]
        mode = st[r, _MODE]
        if mode == INFINITE:
            fwd = pdf * cos_in
            conv = 1.0
        else:
            fwd = pdf * cos_in / d2
            if mode == SURF:
                conv = abs(st[r, _PN] * dx + st[r, _PN + 1] * dy + st[r, _PN + 2] * dz) / d2
            else:
                conv = 1.0 / d2
        nx, ny, nz = _facing_normal(ngx, ngy, ngz, -dng, kind)
        lamb = kind == LAMBERT
        delta = kind == MIRROR or kind == DIELECTRIC
        if lamb and tex[obj, 1] != 0:
            a0, a1, a2 = _albedo(albedo, tex, uv, tex_data, obj, t, u, v)
        else:
            a0, a1, a2 = albedo[obj, 0], albedo[obj, 1], albedo[obj, 2]
        f0 = Fl[k, i - 1]
        has0, caus0 = (f0 & F_HAS) != 0, (f0 & F_CAUS) != 0
        if light:  # read from the light: a specular vertex, then a diffuse one
            has, caus = has0 or delta, caus0 or (has0 and lamb)
        else:  # read from the eye: a diffuse vertex, then a specular one
            has, caus = has0 or lamb, caus0 or (has0 and delta)
        fl = F_ALIVE
        if delta:
            fl |= F_DELTA
        if has:
            fl |= F_HAS
        if caus:
            fl |= F_CAUS
        Fl[k, i] = fl
        V[k, i, _P], V[k, i, _P + 1], V[k, i, _P + 2] = px, py, pz
        V[k, i, _NG], V[k, i, _NG + 1], V[k, i, _NG + 2] = ngx, ngy, ngz
        V[k, i, _NF], V[k, i, _NF + 1], V[k, i, _NF + 2] = nx, ny, nz
        V[k, i, _WO], V[k, i, _WO + 1], V[k, i, _WO + 2] = -dx, -dy, -dz
        V[k, i, _BETA], V[k, i, _BETA + 1], V[k, i, _BETA + 2] = b0, b1, b2
        V[k, i, _ALB], V[k, i, _ALB + 1], V[k, i, _ALB + 2] = a0, a1, a2
        V[k, i, _FWD] = fwd
        V[k, i, _REV] = 0.0  # until the next vertex is sampled from this one
        V[k, i, _CONV] = conv
        Iv[k, i, 0] = obj
        Iv[k, i, 1] = t
        if last or not (lamb or delta) or (caus and not cfg.caustics):
            continue
        key = keys[k]
        (sx, sy, sz), (tx, ty, tz) = _frame(nx, ny, nz)
        wox = -(dx * sx + dy * sy + dz * sz)
        woy = -(dx * tx + dy * ty + dz * tz)
        woz = -(dx * nx + dy * ny + dz * nz)
        spdf = 1.0
        if lamb:
            u1, u2 = _u(key, base + 1), _u(key, base + 2)
            rr = math.sqrt(u1)
            c_, s_ = _cos_sin_2pi(u2)
            lx, ly, lz = rr * c_, rr * s_, math.sqrt(max(0.0, 1.0 - u1))
            spdf = max(lz, 0.0) * _INV_PI
            valid = woz > 0.0 and spdf > 0.0
            w0, w1, w2 = a0, a1, a2
        elif kind == MIRROR:
            lx, ly, lz = -wox, -woy, woz
            valid = woz != 0.0
            w0, w1, w2 = a0, a1, a2
        else:  # smooth dielectric (render.bsdf.dielectric_sample)
            ior = iors[obj]
            F, eta = _fresnel_dielectric(woz, ior)
            if _u(key, base) < F:
                lx, ly, lz = -wox, -woy, woz
                spdf = F
                sc = 1.0
            else:
                c = abs(woz)
                cos_t = math.sqrt(max(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
                lx, ly, lz = -wox / eta, -woy / eta, -cos_t if woz >= 0.0 else cos_t
                spdf = 1.0 - F
                sc = 1.0 / (eta * eta)
            valid = woz != 0.0 and spdf > 0.0
            if light:  # importance transport: no radiance scaling through glass
                sc = 1.0
            w0 = w1 = w2 = sc
        if delta:
            rev_solid = 0.0
        else:  # lambert_pdf(wi, wo): density of sampling wo given wi
            rev_solid = max(woz, 0.0) * _INV_PI if lz > 0.0 else 0.0
        V[k, i - 1, _REV] = rev_solid * conv
        if not valid:
            continue
        c0, c1, c2 = b0 * w0, b1 * w1, b2 * w2
        mx = max(max(c0, c1), c2)
        if not mx > 0.0:
            continue
        if roulette:
            q = min(1.0, mx / st[r, _REF])
            if not _u(key, base + 3) < q:
                continue
            c0, c1, c2 = c0 / q, c1 / q, c2 / q
        ox_ = lx * sx + ly * tx + lz * nx
        oy_ = lx * sy + ly * ty + lz * ny
        oz_ = lx * sz + ly * tz + lz * nz
        n_idx[nn] = k
        n_st[nn, _D], n_st[nn, _D + 1], n_st[nn, _D + 2] = ox_, oy_, oz_
        n_st[nn, _B], n_st[nn, _B + 1], n_st[nn, _B + 2] = c0, c1, c2
        n_st[nn, _PDF] = 0.0 if delta else spdf
        n_st[nn, _MODE] = SURF
        n_st[nn, _REF] = st[r, _REF]
        n_st[nn, _PP], n_st[nn, _PP + 1], n_st[nn, _PP + 2] = px, py, pz
        n_st[nn, _PN], n_st[nn, _PN + 1], n_st[nn, _PN + 2] = ngx, ngy, ngz
        sxo, syo, szo = _spawn(px, py, pz, ngx, ngy, ngz, ox_, oy_, oz_, extent)
        n_o32[nn, 0], n_o32[nn, 1], n_o32[nn, 2] = sxo, syo, szo
        n_d32[nn, 0], n_d32[nn, 1], n_d32[nn, 2] = ox_, oy_, oz_
        nn += 1
    return nn


# ------------------------------------------------------------------ MIS prefix sums
@njit(**_JIT)
def prefix_sums(V, Fl, hexp, light, lkind):
    """pbrt's MISWeight prefix data per subpath (render.integrators.bdpt._prefix): cond[m] = 1
    when neither vertex m nor m - 1 is delta (a light subpath's vertex 0: its light is not a
    delta light, from lkind); S[m] = sum_{i <= m} cond[i] prod_{i <= j <= m} r_j^hexp with
    r_j = pdfRev / pdfFwd (remapped, clamped), over the alive vertices."""
    N, nv = Fl.shape
    for k in range(N):
        if (Fl[k, 0] & F_ALIVE) == 0:
            continue
        if light:
            c0 = 1.0 if lkind[k] == AREA else 0.0
            V[k, 0, _COND] = c0
            V[k, 0, _SUM] = _ratio(V[k, 0, _REV], V[k, 0, _FWD], hexp) * c0
        else:
            V[k, 0, _COND] = 0.0
            V[k, 0, _SUM] = 0.0
        for j in range(1, nv):
            if (Fl[k, j] & F_ALIVE) == 0:
                break
            cond = 1.0 if ((Fl[k, j] | Fl[k, j - 1]) & F_DELTA) == 0 else 0.0
            V[k, j, _COND] = cond
            V[k, j, _SUM] = min(_ratio(V[k, j, _REV], V[k, j, _FWD], hexp) * (cond + V[k, j - 1, _SUM]), _BIG)


# ------------------------------------------------------------------ every (s, t) join
@njit(**_JIT)
def connect(ks, cfg, cam, k0, npc, keys_e, tgt, E, EF, EI, L, LF, LI, lkind, img,
            q_o32, q_d32, q_t32, q_idx, q_val):
    """Join the subpaths of camera samples k0, k0 + 1, ..: s = 0 (eye vertices on emitters)
    added to img[tgt[k]]; s = 1 (next-event estimation from a fresh light sample, dimensions 4 ..
    6 of the eye vertex's block), t = 1 (light tracing: the light vertex projected onto the
    pinhole's image, slot pass_local H W + pixel) and s, t >= 2 queued as shadow rays with their
    MIS-weighted unoccluded contributions (render.integrators.bdpt's _connect_* functions, the
    same weights). Stops before a sample whose joins might overflow the queue.
    Returns (next sample to join, queued shadow rays)."""
    tri_obj, kinds, emits, two_sided, Le = ks.tri_obj, ks.kind, ks.emits, ks.two_sided, ks.Le
    tri_pdf_area, cdf, pmf, area = ks.tri_pdf_area, ks.cdf, ks.pmf, ks.area
    d_kind, d_pos, d_dir, d_I, d_cos = ks.d_kind, ks.d_pos, ks.d_dir, ks.d_I, ks.d_cos
    extent, floor, n_area = ks.scal[0], ks.scal[1], np.int64(ks.scal[2])
    hexp, weighted, use = cfg.hexp, cfg.weighted, cfg.use
    has_lights = cdf[len(cdf) - 1] > 0.0
    W, H = cfg.width, cfg.height
    npix = W * H
    rot, org = cam.rotation, cam.origin
    floor2 = (1e-9 * extent) ** 2
    cap = len(q_idx)
    need = queue_bound_jit(cfg.max_depth)
    nq = 0
    N = len(keys_e)
    k = k0
    while k < N:
        if nq + need > cap:
            return k, nq
        slot_eye = tgt[k]
        # ---- s = 0: eye vertices on emitters (escapes were added by the walk)
        for t in range(2, cfg.nv_e + 1):
            i = t - 1
            fl = EF[k, i]
            if (fl & F_ALIVE) == 0:
                break
            if not use[0, t]:
                continue
            obj = EI[k, i, 0]
            if not emits[obj] or (not cfg.caustics and (EF[k, i - 1] & F_CAUS) != 0):
                continue
            cos_e = (E[k, i, _WO] * E[k, i, _NG] + E[k, i, _WO + 1] * E[k, i, _NG + 1]
                     + E[k, i, _WO + 2] * E[k, i, _NG + 2])
            two = two_sided[obj]
            if not (two or cos_e > 0.0):
                continue
            w = 1.0
            if weighted and t > 2:
                pt_rev = tri_pdf_area[EI[k, i, 1]]
                ptm_rev = abs(cos_e) * _INV_PI * (0.5 if two else 1.0) * E[k, i, _CONV]
                w = 1.0 / (1.0 + _eye_sum(E, EF, k, t, _ratio(pt_rev, E[k, i, _FWD], hexp),
                                          _ratio(ptm_rev, E[k, i - 1, _FWD], hexp)))
            for c in range(3):
                img[slot_eye, c] += E[k, i, _BETA + c] * Le[obj, c] * w
        # ---- s = 1: next-event estimation at z_{t-1}
        if has_lights:
            key = keys_e[k]
            for t in range(2, cfg.max_depth + 2):
                i = t - 1
                fl = EF[k, i]
                if (fl & F_ALIVE) == 0:
                    break
                if not use[1, t] or kinds[EI[k, i, 0]] != LAMBERT or (not cfg.caustics and (fl & F_CAUS) != 0):
                    continue
                base = _EYE_DIM0 + _EYE_STEP * (i - 1) + 4
                u0, u1, u2 = _u(key, base), _u(key, base + 1), _u(key, base + 2)
                px, py, pz = E[k, i, _P], E[k, i, _P + 1], E[k, i, _P + 2]
                ent = _pick(cdf, u0)
                is_area = ent < n_area
                if is_area:
                    ok, wx, wy, wz, dist, L0, L1, L2, lpdf = _sample_area(area, ent, floor, px, py, pz, u1, u2)
                else:
                    ok, wx, wy, wz, dist, L0, L1, L2 = _sample_delta(d_kind, d_pos, d_dir, d_I, d_cos, ent - n_area,
                                                                     floor, px, py, pz)
                    lpdf = pmf[ent]
                if not ok:
                    continue
                f, cos_p, pdf_l, pdf_r = _lambert(E, k, i, wx, wy, wz)
                if not (cos_p > 0.0 and lpdf > 0.0 and math.isfinite(lpdf)):
                    continue
                s_ = f * cos_p / lpdf
                C0 = E[k, i, _BETA] * E[k, i, _ALB] * L0 * s_
                C1 = E[k, i, _BETA + 1] * E[k, i, _ALB + 1] * L1 * s_
                C2 = E[k, i, _BETA + 2] * E[k, i, _ALB + 2] * L2 * s_
                finite_c = math.isfinite(C0) and math.isfinite(C1) and math.isfinite(C2)
                if not finite_c or not max(max(C0, C1), C2) > 0.0:
                    continue
                finite = math.isfinite(dist)
                dist_f = dist if finite else 1.0
                d2 = dist_f * dist_f
                lnx = lny = lnz = 0.0
                if is_area:
                    lnx, lny, lnz = area[ent, 9], area[ent, 10], area[ent, 11]
                if weighted:
                    if is_area:
                        cos_l = abs(wx * lnx + wy * lny + wz * lnz)
                        fwd_q = area[ent, 12]
                        pdir = cos_l * _INV_PI * (0.5 if area[ent, 16] > 0.0 else 1.0)
                        conv_q = cos_l / d2
                    else:
                        li = ent - n_area
                        lk = d_kind[li]
                        fwd_q = 0.0 if lk == DIRECTIONAL else pmf[ent]
                        conv_q = 1.0 / d2 if finite else 1.0
                        if lk == POINT:
                            pdir = 0.25 * _INV_PI
                        elif lk == SPOT:
                            co = d_cos[li, 1]
                            inside = -(wx * d_dir[li, 0] + wy * d_dir[li, 1] + wz * d_dir[li, 2]) >= co
                            pdir = (1.0 if inside else 0.0) / (2.0 * math.pi * max(1.0 - co, 1e-300))
                        else:
                            pdir = 1.0 / (math.pi * cfg.radius * cfg.radius)
                    pt_rev = pdir * cos_p * (1.0 / d2 if finite else 1.0)
                    r1 = _ratio(pt_rev, E[k, i, _FWD], hexp)
                    r2 = _ratio(pdf_r * E[k, i, _CONV], E[k, i - 1, _FWD], hexp)
                    light_side = _ratio(pdf_l * conv_q, fwd_q, hexp) * (1.0 if is_area else 0.0)  # s = 0 counts
                    tot = _eye_sum(E, EF, k, t, r1, r2) + light_side
                    w = 1.0 / (1.0 + tot)
                    C0, C1, C2 = C0 * w, C1 * w, C2 * w
                ngx, ngy, ngz = E[k, i, _NG], E[k, i, _NG + 1], E[k, i, _NG + 2]
                ox, oy, oz = _spawn(px, py, pz, ngx, ngy, ngz, wx, wy, wz, extent)
                tx_, ty_, tz_ = px + wx * dist_f, py + wy * dist_f, pz + wz * dist_f
                if is_area:
                    tx_, ty_, tz_ = _spawn(tx_, ty_, tz_, lnx, lny, lnz, -wx, -wy, -wz, extent)
                vx, vy, vz = tx_ - ox, ty_ - oy, tz_ - oz
                dd = math.sqrt(vx * vx + vy * vy + vz * vz)
                if finite:
                    inv = 1.0 / max(dd, 1e-300)
                    nq = _queue(q_o32, q_d32, q_t32, q_idx, q_val, nq, ox, oy, oz, vx * inv, vy * inv, vz * inv,
                                dd * (1.0 - 1e-6), slot_eye, C0, C1, C2)
                else:
                    nq = _queue(q_o32, q_d32, q_t32, q_idx, q_val, nq, ox, oy, oz, wx, wy, wz, _TMAX_CAP,
                                slot_eye, C0, C1, C2)
        # ---- t = 1: light tracing, splatted where y_{s-1} projects
        pass_off = (k // npc) * npix
        for s in range(2, cfg.nv_l + 1):
            j = s - 1
            fl = LF[k, j]
            if (fl & F_ALIVE) == 0:
                break
            if not use[s, 1] or kinds[LI[k, j, 0]] != LAMBERT or (not cfg.caustics and (fl & F_CAUS) != 0):
                continue
            qx, qy, qz = L[k, j, _P], L[k, j, _P + 1], L[k, j, _P + 2]
            rx, ry, rz = qx - org[0], qy - org[1], qz - org[2]
            xc = rot[0, 0] * rx + rot[1, 0] * ry + rot[2, 0] * rz
            yc = rot[0, 1] * rx + rot[1, 1] * ry + rot[2, 1] * rz
            zc = rot[0, 2] * rx + rot[1, 2] * ry + rot[2, 2] * rz
            if not zc > 0.0:
                continue
            ux = cam.fx * (xc / zc) + cam.cx
            uy = cam.fy * (yc / zc) + cam.cy
            if not (ux >= 0.0 and ux < W and uy >= 0.0 and uy < H):
                continue
            wx, wy, wz = org[0] - qx, org[1] - qy, org[2] - qz
            d2 = wx * wx + wy * wy + wz * wz
            dist = math.sqrt(d2)
            wx, wy, wz = wx / dist, wy / dist, wz / dist
            f, cos_q, pdf_l, pdf_r = _lambert(L, k, j, wx, wy, wz)
            cos_cam = zc / dist
            pdf_cam = 1.0 / (cfg.area * cos_cam * cos_cam * cos_cam)
            s_ = f * max(cos_q, 0.0) * (pdf_cam / cos_cam) * cos_cam / d2
            C0 = L[k, j, _BETA] * L[k, j, _ALB] * s_
            C1 = L[k, j, _BETA + 1] * L[k, j, _ALB + 1] * s_
            C2 = L[k, j, _BETA + 2] * L[k, j, _ALB + 2] * s_
            if not (cos_q > 0.0 and max(max(C0, C1), C2) > 0.0):
                continue
            if weighted:
                r1 = _ratio(pdf_cam * cos_q / d2, L[k, j, _FWD], hexp)
                r2 = _ratio(pdf_r * L[k, j, _CONV], L[k, j - 1, _FWD], hexp)
                w = 1.0 / (1.0 + _light_sum(L, LF, k, s, r1, r2, 0.0))
                C0, C1, C2 = C0 * w, C1 * w, C2 * w
            pxl = min(np.int64(math.floor(ux)), W - 1)
            pyl = min(np.int64(math.floor(uy)), H - 1)
            nq = _queue_segment(q_o32, q_d32, q_t32, q_idx, q_val, nq, qx, qy, qz, L[k, j, _NG], L[k, j, _NG + 1],
                                L[k, j, _NG + 2], org[0], org[1], org[2], 0.0, 0.0, 0.0, False, extent,
                                pass_off + pyl * W + pxl, C0, C1, C2)
        # ---- s, t >= 2: y_{s-1} and z_{t-1} joined by a shadow ray
        for t in range(2, cfg.nv_e + 1):
            i = t - 1
            fe = EF[k, i]
            if (fe & F_ALIVE) == 0:
                break
            if kinds[EI[k, i, 0]] != LAMBERT:
                continue
            for s in range(2, cfg.nv_l + 1):
                if s + t - 2 > cfg.max_depth:
                    break
                j = s - 1
                fq = LF[k, j]
                if (fq & F_ALIVE) == 0:
                    break
                if not use[s, t] or kinds[LI[k, j, 0]] != LAMBERT:
                    continue
                if not cfg.caustics and ((fe & F_CAUS) != 0 or (fq & F_CAUS) != 0
                                         or ((fe & F_HAS) != 0 and (fq & F_HAS) != 0)):
                    continue
                qx, qy, qz = L[k, j, _P], L[k, j, _P + 1], L[k, j, _P + 2]
                px, py, pz = E[k, i, _P], E[k, i, _P + 1], E[k, i, _P + 2]
                wx, wy, wz = px - qx, py - qy, pz - qz
                d2 = max(wx * wx + wy * wy + wz * wz, floor2)
                dn = math.sqrt(d2)
                wx, wy, wz = wx / dn, wy / dn, wz / dn
                fq_, cos_q, pq_f, pq_r = _lambert(L, k, j, wx, wy, wz)
                fp_, cos_p, pp_f, pp_r = _lambert(E, k, i, -wx, -wy, -wz)
                if not (cos_q > 0.0 and cos_p > 0.0):
                    continue
                g = fq_ * fp_ * cos_q * cos_p / d2
                C0 = L[k, j, _BETA] * L[k, j, _ALB] * E[k, i, _ALB] * E[k, i, _BETA] * g
                C1 = L[k, j, _BETA + 1] * L[k, j, _ALB + 1] * E[k, i, _ALB + 1] * E[k, i, _BETA + 1] * g
                C2 = L[k, j, _BETA + 2] * L[k, j, _ALB + 2] * E[k, i, _ALB + 2] * E[k, i, _BETA + 2] * g
                if not max(max(C0, C1), C2) > 0.0:
                    continue
                if weighted:
                    r1e = _ratio(pq_f * cos_p / d2, E[k, i, _FWD], hexp)
                    r2e = _ratio(pp_r * E[k, i, _CONV], E[k, i - 1, _FWD], hexp)
                    r1l = _ratio(pp_f * cos_q / d2, L[k, j, _FWD], hexp)
                    r2l = _ratio(pq_r * L[k, j, _CONV], L[k, j - 1, _FWD], hexp)
                    w = 1.0 / (1.0 + _eye_sum(E, EF, k, t, r1e, r2e) + _light_sum(L, LF, k, s, r1l, r2l, 0.0))
                    C0, C1, C2 = C0 * w, C1 * w, C2 * w
                nq = _queue_segment(q_o32, q_d32, q_t32, q_idx, q_val, nq, qx, qy, qz, L[k, j, _NG], L[k, j, _NG + 1],
                                    L[k, j, _NG + 2], px, py, pz, E[k, i, _NG], E[k, i, _NG + 1], E[k, i, _NG + 2],
                                    True, extent, slot_eye, C0, C1, C2)
        k += 1
    return k, nq


@njit(inline="always", **_JIT)
def queue_bound_jit(max_depth):
    """:func:`queue_bound` inside compiled code."""
    return (max_depth + 2) * (max_depth + 2)


# ------------------------------------------------------------------ a whole batch in one call
if _edirect.AVAILABLE:
    _intersect_many, _occluded_many = _edirect.intersect_many, _edirect.occluded_many

    @njit(**_JIT)
    def _walk_direct(ks, cfg, handle, light, m, keys, V, Fl, Iv, img, tgt, cur, nxt, hit):
        """Extend m subpaths whose first rays are in ``cur`` vertex by vertex, Embree called from
        here (render.embree_direct): what the Python driver does with Accel.intersect_fast."""
        prim, tfar, hu, hv = hit
        rays = 0
        for i in range(1, cfg.nv_l if light else cfg.nv_e):
            if m == 0:
                break
            _intersect_many(handle, cur[2][:m], cur[3][:m], prim[:m], tfar[:m], hu[:m], hv[:m])
            rays += m
            m = extend(ks, cfg, i, light, prim, hu, hv, m, cur[0], cur[1], keys, V, Fl, Iv, img, tgt,
                       nxt[0], nxt[1], nxt[2], nxt[3])
            cur, nxt = nxt, cur
        return rays

    @njit(**_JIT)
    def trace_batch(ks, cfg, cam, handle, seed_mix, sample0, pix0, npc, keys_e, keys_l, tgt, lkind,
                    E, EF, EI, L, LF, LI, cur, nxt, hit, queue, occ, img):
        """One batch of camera samples in a single compiled call (N = len(keys_e), sample k:
        pass sample0 + k // npc, pixel pix0 + k % npc): both subpaths, the MIS prefix sums,
        every join and its shadow ray, unoccluded contributions added to img (n_pass H W, 3).
        handle: the batch's render.embree_direct.DirectScene handle. cur, nxt: walk buffers
        (idx, st, o32, d32); hit: (prim, tfar, u, v) Embree outputs; queue: the shadow-ray queue
        (o32, d32, t32, slot, value); occ: (cap,) int32. Returns the rays traced."""
        N = len(keys_e)
        start_camera(cfg, cam, seed_mix, sample0, pix0, npc, keys_e, keys_l, tgt, E, EF,
                     cur[0], cur[1], cur[2], cur[3])
        rays = _walk_direct(ks, cfg, handle, False, N, keys_e, E, EF, EI, img, tgt, cur, nxt, hit)
        m = start_light(ks, cfg, keys_l, L, LF, lkind, cur[0], cur[1], cur[2], cur[3])
        rays += _walk_direct(ks, cfg, handle, True, m, keys_l, L, LF, LI, img, tgt, cur, nxt, hit)
        prefix_sums(E, EF, cfg.hexp, False, lkind)
        prefix_sums(L, LF, cfg.hexp, True, lkind)
        q_o32, q_d32, q_t32, q_idx, q_val = queue
        k = 0
        while k < N:
            k, nq = connect(ks, cfg, cam, k, npc, keys_e, tgt, E, EF, EI, L, LF, LI, lkind, img,
                            q_o32, q_d32, q_t32, q_idx, q_val)
            if nq > 0:
                _occluded_many(handle, q_o32[:nq], q_d32[:nq], q_t32[:nq], occ[:nq])
                rays += nq
                for r in range(nq):
                    if occ[r] == -1:
                        s = q_idx[r]
                        img[s, 0] += q_val[r, 0]
                        img[s, 1] += q_val[r, 1]
                        img[s, 2] += q_val[r, 2]
        return rays
else:  # pragma: no cover - the Python driver calls Embree through embreex
    trace_batch = None


@njit(**_JIT)
def add_pass_moments(img, npix, s1, s2, n):
    """Add whole pass images img (P npix, 3) to a film's moments s1, s2 (npix, 3) and counts n
    (npix,): per pixel the sum over the passes and of their squares, in numpy's order (the passes
    summed in turn, then added), so the bytes of render.film.Film.add_moments(x.sum(0), (x * x).sum(0))
    without its temporaries. Returns False, adding nothing, if any value is non-finite."""
    m = img.shape[0]
    for i in range(m):
        if not (math.isfinite(img[i, 0]) and math.isfinite(img[i, 1]) and math.isfinite(img[i, 2])):
            return False
    passes = m // npix
    for p in range(npix):
        for c in range(3):
            a = img[p, c]
            b = a * a
            for q in range(1, passes):
                v = img[q * npix + p, c]
                a += v
                b += v * v
            s1[p, c] += a
            s2[p, c] += b
        n[p] += passes
    return True
