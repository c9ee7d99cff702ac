"""Compiled (numba) kernels of ``sppm``: the eye pass, photon emission and bounces, and a hash-grid gather.

:mod:`render.integrators.sppm` drives them wavefront-style, as :mod:`render.integrators.path`
drives its kernels: Embree (:meth:`render.accel.Accel.intersect_fast` / ``occluded_fast``) finds
the hits of a whole batch of rays, then one kernel here processes every hit in one loop and
writes the next rays (float32, what Embree reads), compacted in index order. The estimator is
the numpy reference's (:func:`render.integrators.sppm.render_sppm_numpy`), term by term:

* :func:`eye_bounce`: camera paths through mirror and glass (radiance transport: the glass
  weight carries 1 / eta^2) to their first Lambertian hit, the pixel's visible point (position,
  geometric normal, normal facing the viewer, weight beta x albedo / pi, depth, footprint);
  emission seen directly or through the specular chain goes to the pixel's direct term, and
  one next-event sample at the visible point is queued as a shadow ray.
* :func:`emit_photons`: render.lights.sample_emission for one photon per index (light by the
  power pmf; area: uniform point, cosine direction on the emitting side, a random side if
  two-sided; point: uniform sphere; spot: uniform outer cone times the falloff; directional: a
  disk of the scene's bounding radius 2 R upstream).
* :func:`photon_bounce`: photons stored at every Lambertian hit but the first; scattering off
  Lambertian, mirror and glass (importance transport: the glass weight is 1), Russian roulette
  with survival min(1, max(weight)).
* :func:`build_grid` / :func:`gather`: a spatial hash over the stored photons (cell side = the
  largest gather radius, so a query sphere overlaps at most 2 x 2 x 2 cells), a stable counting
  sort by bucket; each visible point sums the flux x weight of the photons within its radius,
  arriving on its front side, whose whole path respects max_depth.

Random numbers: the hash of :mod:`render.sampling` (render.integrators.path_kernels' ``_uniform``)
keyed per (seed, pass, pixel) for eye paths (the keys of ``path``'s sample ``pass``) and per
(seed, pass, photon index) for photons. Dimensions of an eye path: 0, 1 pixel jitter, then per
bounce from 2 + 8 depth: light pick, light point (2), Fresnel lobe. Of a photon: 0 light pick,
1, 2 position, 3, 4 direction, 5 side; per bounce from 8 + 8 depth: Fresnel lobe (+3),
direction (+4, +5), roulette (+6). Every kernel is a pure function of its inputs and writes its
outputs in index order: a render does not depend on threads or batch boundaries.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .path_kernels import (_GOLDEN, _INV_PI, _JIT, _cos_sin_2pi, _M2, _TMAX_CAP, DIELECTRIC, DIRECTIONAL, LAMBERT,
                           MIRROR, POINT, SAMPLER_INDEPENDENT, SPOT, _facing_normal, _frame, _hit_point,
                           _lambert_albedo, _mix64, _offset, _pick,
                           _queue_ray, _sample_area, _sample_delta, _sample_specular, _uniform)

__all__ = ["eye_bounce", "add_unoccluded_direct", "photon_keys", "emit_photons", "photon_bounce", "build_grid",
           "gather", "gather_update", "PHOTON_STREAM"]

#: xor-ed into the seed's mix so photon keys never coincide with camera-path keys
PHOTON_STREAM = np.uint64(0x243F6A8885A308D3)
_EMIT_DIMS = 8  # photon dimensions used by emission (0 .. 5, two spare)


# ------------------------------------------------------------------ eye pass
@njit(**_JIT)
def eye_bounce(ks, depth, max_depth, inv_fx, prim, tfar, hu, hv, pix, keys, beta, plen, d32, direct,
               vp_ok, vp_depth, vp_p, vp_ng, vp_n, vp_w, vp_fp,
               n_pix, n_keys, n_beta, n_plen, n_o32, n_d32,
               q_o32, q_d32, q_t32, q_idx, q_val):
    """Process the first hits (prim, tfar, hu, hv from Embree) of the live eye paths at ``depth``.

    State of live path i: pix (its pixel), keys (RNG key), beta (3) specular throughput, plen
    path length so far, d32 (its float32 direction). direct (npix, 3): emission seen (and the
    background), added in place. A Lambertian hit with a non-zero weight becomes the pixel's
    visible point (vp_* rows of the pixel: ok flag, depth, p, geometric normal ng, normal n
    facing the viewer, weight w = beta albedo / pi, footprint plen / fx) and queues one
    next-event shadow ray (q_*: origin, direction, tmax, pixel, unoccluded contribution
    w Li cos / pdf). Mirror and glass hits continue (n_*: survivors compacted in order).
    Returns (survivors, shadow rays).
    """
    extent, floor, n_area = ks.scal[0], ks.scal[1], np.int64(ks.scal[2])
    base = 2 + 8 * depth
    bg = ks.bg
    has_bg = bg[0] > 0.0 or bg[1] > 0.0 or bg[2] > 0.0
    ids, tri_obj, tris, kinds, albedo, iors, Le = ks.ids, ks.tri_obj, ks.tri, ks.kind, ks.albedo, ks.ior, ks.Le
    emits, two_sided, tex, uv, tex_data = ks.emits, ks.two_sided, ks.tex, ks.uv, ks.tex_data
    cdf, pmf, area, d_kind, d_pos, d_dir, d_I, d_cos = ks.cdf, ks.pmf, ks.area, ks.d_kind, ks.d_pos, ks.d_dir, ks.d_I, ks.d_cos
    has_lights = cdf[len(cdf) - 1] > 0.0
    nn = 0
    nq = 0
    for i in range(len(prim)):
        px_ = pix[i]
        dx, dy, dz = np.float64(d32[i, 0]), np.float64(d32[i, 1]), np.float64(d32[i, 2])
        b0, b1, b2 = beta[i, 0], beta[i, 1], beta[i, 2]
        if prim[i] < 0:
            if has_bg:
                direct[px_, 0] += b0 * bg[0]
                direct[px_, 1] += b1 * bg[1]
                direct[px_, 2] += b2 * bg[2]
            continue
        t = ids[prim[i]]
        obj = tri_obj[t]
        kind = kinds[obj]
        ngx, ngy, ngz = tris[t, 9], tris[t, 10], tris[t, 11]
        cos_o = -(dx * ngx + dy * ngy + dz * ngz)
        length = plen[i] + np.float64(tfar[i])
        if emits[obj] and (two_sided[obj] or cos_o > 0.0):
            direct[px_, 0] += b0 * Le[obj, 0]
            direct[px_, 1] += b1 * Le[obj, 1]
            direct[px_, 2] += b2 * Le[obj, 2]
        if depth == max_depth:
            continue
        if kind != LAMBERT and kind != MIRROR and kind != DIELECTRIC:
            continue
        u, v = np.float64(hu[i]), np.float64(hv[i])
        px, py, pz = _hit_point(tris, t, u, v)
        nx, ny, nz = _facing_normal(ngx, ngy, ngz, cos_o, kind)
        key = keys[i]
        eps = _offset(px, py, pz, extent)
        if kind == LAMBERT:
            a0, a1, a2 = _lambert_albedo(albedo, tex, uv, tex_data, obj, t, u, v)
            w0, w1, w2 = b0 * a0 * _INV_PI, b1 * a1 * _INV_PI, b2 * a2 * _INV_PI
            if not max(max(w0, w1), w2) > 0.0:
                continue
            vp_ok[px_] = True
            vp_depth[px_] = depth
            vp_p[px_, 0], vp_p[px_, 1], vp_p[px_, 2] = px, py, pz
            vp_ng[px_, 0], vp_ng[px_, 1], vp_ng[px_, 2] = ngx, ngy, ngz
            vp_n[px_, 0], vp_n[px_, 1], vp_n[px_, 2] = nx, ny, nz
            vp_w[px_, 0], vp_w[px_, 1], vp_w[px_, 2] = w0, w1, w2
            vp_fp[px_] = length * inv_fx
            if not has_lights:
                continue
            k = _pick(cdf, _uniform(key, base))
            u1, u2 = _uniform(key, base + 1), _uniform(key, base + 2)
            if k < n_area:
                ok, lx, ly, lz, ldist, L0, L1, L2, lpdf = _sample_area(area, k, floor, px, py, pz, u1, u2)
            else:
                ok, lx, ly, lz, ldist, L0, L1, L2 = _sample_delta(d_kind, d_pos, d_dir, d_I, d_cos, k - n_area,
                                                                  floor, px, py, pz)
                lpdf = pmf[k]
            cos_i = lx * nx + ly * ny + lz * nz
            if not (ok and cos_i > 0.0 and lpdf > 0.0 and lpdf < np.inf and max(max(L0, L1), L2) > 0.0):
                continue
            _queue_ray(q_o32, q_d32, nq, px, py, pz, ngx, ngy, ngz, eps, lx, ly, lz)
            q_t32[nq] = min(max(ldist * (1.0 - 1e-5) - 2.0 * eps, 0.0), _TMAX_CAP)
            s = cos_i / lpdf
            q_val[nq, 0], q_val[nq, 1], q_val[nq, 2] = w0 * L0 * s, w1 * L1 * s, w2 * L2 * s
            q_idx[nq] = px_
            nq += 1
            continue
        valid, wx, wy, wz, f0, f1, f2, spdf = _sample_specular(kind, albedo[obj, 0], albedo[obj, 1], albedo[obj, 2],
                                                               iors[obj], SAMPLER_INDEPENDENT, key, base,
                                                               dx, dy, dz, nx, ny, nz)
        b0, b1, b2 = b0 * f0, b1 * f1, b2 * f2
        if not (valid and max(max(b0, b1), b2) > 0.0):
            continue
        n_pix[nn] = px_
        n_keys[nn] = key
        n_beta[nn, 0], n_beta[nn, 1], n_beta[nn, 2] = b0, b1, b2
        n_plen[nn] = length
        _queue_ray(n_o32, n_d32, nn, px, py, pz, ngx, ngy, ngz, eps, wx, wy, wz)
        nn += 1
    return nn, nq


@njit(**_JIT)
def add_unoccluded_direct(direct, q_idx, q_val, occ):
    """direct[q_idx[k]] += q_val[k] for the shadow rays Embree found unoccluded (occ[k] == -1)."""
    for k in range(len(occ)):
        if occ[k] == -1:
            s = q_idx[k]
            direct[s, 0] += q_val[k, 0]
            direct[s, 1] += q_val[k, 1]
            direct[s, 2] += q_val[k, 2]


# ------------------------------------------------------------------ photons
@njit(**_JIT)
def photon_keys(seed_mix, pass0, per_pass, start, stop):
    """(stop - start,) uint64 RNG keys of the photons of flat indices [start, stop), flat = (pass
    - pass0) per_pass + index: mix64(mix64(seed_mix ^ PHOTON_STREAM ^ pass M2) ^ index golden)."""
    out = np.empty(stop - start, np.uint64)
    for i in range(stop - start):
        flat = start + i
        pk = _mix64(seed_mix ^ PHOTON_STREAM ^ (np.uint64(pass0 + flat // per_pass) * _M2 + _GOLDEN))
        out[i] = _mix64(pk ^ (np.uint64(flat % per_pass) * _GOLDEN))
    return out


@njit(inline="always", **_JIT)
def _to_world(lx, ly, lz, nx, ny, nz):
    (sx, sy, sz), (tx, ty, tz) = _frame(nx, ny, nz)
    return (lx * sx + ly * tx + lz * nx, lx * sy + ly * ty + lz * ny, lx * sz + ly * tz + lz * nz)


@njit(**_JIT)
def emit_photons(ks, centre, radius, keys, idx, o32, d32, beta):
    """One photon per key leaving the lights (render.lights.sample_emission): writes the
    survivors (non-zero flux), compacted in order, as float32 rays o32, d32 (N, 3) (area
    sources: offset off the triangle on the emitting side), flux beta (N, 3) and their keys
    and tags (idx (N,) int64, e.g. flat photon indices) in place of ``keys`` and ``idx``. centre (3,), radius: the disk of directional lights
    (render.lights.scene_bounds). Returns the number of photons written."""
    extent, n_area = ks.scal[0], np.int64(ks.scal[2])
    cdf, pmf, area, d_kind, d_pos, d_dir, d_I, d_cos = ks.cdf, ks.pmf, ks.area, ks.d_kind, ks.d_pos, ks.d_dir, ks.d_I, ks.d_cos
    if not cdf[len(cdf) - 1] > 0.0:
        return 0
    n = 0
    for i in range(len(keys)):
        key = keys[i]
        k = _pick(cdf, _uniform(key, 0))
        up0, up1 = _uniform(key, 1), _uniform(key, 2)
        ud0, ud1 = _uniform(key, 3), _uniform(key, 4)
        if k < n_area:
            su = math.sqrt(up0)
            c1, c2 = 1.0 - su, up1 * su
            px = area[k, 0] + c1 * area[k, 3] + c2 * area[k, 6]
            py = area[k, 1] + c1 * area[k, 4] + c2 * area[k, 7]
            pz = area[k, 2] + c1 * area[k, 5] + c2 * area[k, 8]
            nx, ny, nz = area[k, 9], area[k, 10], area[k, 11]
            two = area[k, 16] > 0.0
            if two and _uniform(key, 5) < 0.5:
                nx, ny, nz = -nx, -ny, -nz
            r = math.sqrt(ud0)
            c_, s_ = _cos_sin_2pi(ud1)
            wx, wy, wz = _to_world(r * c_, r * s_, math.sqrt(max(0.0, 1.0 - ud0)), nx, ny, nz)
            s = math.pi * (2.0 if two else 1.0) / max(area[k, 12], 1e-300)  # pi A [x 2] / pmf
            f0, f1, f2 = area[k, 13] * s, area[k, 14] * s, area[k, 15] * s
            eps = _offset(px, py, pz, extent)
            side = eps if wx * nx + wy * ny + wz * nz >= 0.0 else -eps
            ox, oy, oz = px + side * nx, py + side * ny, pz + side * nz
        else:
            li = k - n_area
            lk = d_kind[li]
            pm = max(pmf[k], 1e-300)
            if lk == POINT:
                z = 1.0 - 2.0 * ud0
                r = math.sqrt(max(0.0, 1.0 - z * z))
                c_, s_ = _cos_sin_2pi(ud1)
                wx, wy, wz = r * c_, r * s_, z
                ox, oy, oz = d_pos[li, 0], d_pos[li, 1], d_pos[li, 2]
                s = 4.0 * math.pi / pm
            elif lk == SPOT:
                ci, co = d_cos[li, 0], d_cos[li, 1]
                cz = 1.0 - ud0 * (1.0 - co)
                sz = math.sqrt(max(0.0, 1.0 - cz * cz))
                c_, s_ = _cos_sin_2pi(ud1)
                wx, wy, wz = _to_world(sz * c_, sz * s_, cz, d_dir[li, 0], d_dir[li, 1], d_dir[li, 2])
                ox, oy, oz = d_pos[li, 0], d_pos[li, 1], d_pos[li, 2]
                x = min(max((cz - co) / max(ci - co, 1e-9), 0.0), 1.0)  # render.scene.spot_falloff
                s = x * x * (3.0 - 2.0 * x) * 2.0 * math.pi * (1.0 - co) / pm
            elif lk == DIRECTIONAL:
                ax, ay, az = d_dir[li, 0], d_dir[li, 1], d_dir[li, 2]
                (sx, sy, sz_), (tx, ty, tz) = _frame(ax, ay, az)
                r = radius * math.sqrt(up0)
                c_, s_ = _cos_sin_2pi(up1)
                rc, rs = r * c_, r * s_
                ox = centre[0] - 2.0 * radius * ax + rc * sx + rs * tx
                oy = centre[1] - 2.0 * radius * ay + rc * sy + rs * ty
                oz = centre[2] - 2.0 * radius * az + rc * sz_ + rs * tz
                wx, wy, wz = ax, ay, az
                s = math.pi * radius * radius / pm
            else:
                continue
            f0, f1, f2 = d_I[li, 0] * s, d_I[li, 1] * s, d_I[li, 2] * s
        if not max(max(f0, f1), f2) > 0.0:
            continue
        o32[n, 0], o32[n, 1], o32[n, 2] = ox, oy, oz
        d32[n, 0], d32[n, 1], d32[n, 2] = wx, wy, wz
        beta[n, 0], beta[n, 1], beta[n, 2] = f0, f1, f2
        keys[n] = key
        idx[n] = idx[i]
        n += 1
    return n


@njit(**_JIT)
def photon_bounce(ks, depth, max_depth, caustics, prim, hu, hv, keys, idx, beta, d32,
                  n_keys, n_idx, n_beta, n_o32, n_d32, s_p, s_wi, s_flux, s_depth, s_idx, ns):
    """Process the hits of the live photons at ``depth`` (scattering events so far).

    A Lambertian hit stores the photon when depth >= 1 (the first hit is direct light, counted
    by next-event estimation): s_p position, s_wi (towards where it came from), s_flux, s_depth,
    s_idx (the photon's tag idx), appended from row ns. Unless depth + 1 >= max_depth (no later hit could be counted), it
    scatters off Lambertian (cosine lobe about the normal facing it, weight = albedo), mirror
    and glass (render.bsdf's delta lobes; glass weight 1: importance transport) surfaces — off
    Lambertian ones alone when not ``caustics`` — and survives roulette with probability
    min(1, max(weight)), divided by it. Survivors go to n_* compacted in order.
    Returns (survivors, new stored count).
    """
    extent = ks.scal[0]
    base = _EMIT_DIMS + 8 * depth
    ids, tri_obj, tris, kinds, albedo, iors = ks.ids, ks.tri_obj, ks.tri, ks.kind, ks.albedo, ks.ior
    tex, uv, tex_data = ks.tex, ks.uv, ks.tex_data
    nn = 0
    for i in range(len(prim)):
        if prim[i] < 0:
            continue
        t = ids[prim[i]]
        obj = tri_obj[t]
        kind = kinds[obj]
        if kind != LAMBERT and not (caustics and (kind == MIRROR or kind == DIELECTRIC)):
            continue  # absorbed (emitters), or a specular bounce pruned with caustics
        dx, dy, dz = np.float64(d32[i, 0]), np.float64(d32[i, 1]), np.float64(d32[i, 2])
        ngx, ngy, ngz = tris[t, 9], tris[t, 10], tris[t, 11]
        u, v = np.float64(hu[i]), np.float64(hv[i])
        px, py, pz = _hit_point(tris, t, u, v)
        b0, b1, b2 = beta[i, 0], beta[i, 1], beta[i, 2]
        if kind == LAMBERT and depth >= 1:
            s_p[ns, 0], s_p[ns, 1], s_p[ns, 2] = px, py, pz
            s_wi[ns, 0], s_wi[ns, 1], s_wi[ns, 2] = -dx, -dy, -dz
            s_flux[ns, 0], s_flux[ns, 1], s_flux[ns, 2] = b0, b1, b2
            s_depth[ns] = depth
            s_idx[ns] = idx[i]
            ns += 1
        if depth + 1 >= max_depth:
            continue
        cos_o = -(dx * ngx + dy * ngy + dz * ngz)
        nx, ny, nz = _facing_normal(ngx, ngy, ngz, cos_o, kind)
        key = keys[i]
        if kind == LAMBERT:
            f0, f1, f2 = _lambert_albedo(albedo, tex, uv, tex_data, obj, t, u, v)
            u4, u5 = _uniform(key, base + 4), _uniform(key, base + 5)
            r = math.sqrt(u4)
            c_, s_ = _cos_sin_2pi(u5)
            lz = math.sqrt(max(0.0, 1.0 - u4))
            wx, wy, wz = _to_world(r * c_, r * s_, lz, nx, ny, nz)
            valid = cos_o != 0.0 and lz > 0.0
        else:
            valid, wx, wy, wz, f0, f1, f2, spdf = _sample_specular(kind, albedo[obj, 0], albedo[obj, 1],
                                                                   albedo[obj, 2], iors[obj], SAMPLER_INDEPENDENT,
                                                                   key, base, dx, dy, dz, nx, ny, nz)
            if kind == DIELECTRIC:  # importance transport: no (eta_i / eta_t)^2 radiance scaling
                f0 = f1 = f2 = 1.0
        q = min(1.0, max(max(f0, f1), f2))
        if not (valid and q > 0.0 and _uniform(key, base + 6) < q):
            continue
        b0, b1, b2 = b0 * (f0 / q), b1 * (f1 / q), b2 * (f2 / q)
        n_keys[nn] = key
        n_idx[nn] = idx[i]
        n_beta[nn, 0], n_beta[nn, 1], n_beta[nn, 2] = b0, b1, b2
        _queue_ray(n_o32, n_d32, nn, px, py, pz, ngx, ngy, ngz, _offset(px, py, pz, extent), wx, wy, wz)
        nn += 1
    return nn, ns


# ------------------------------------------------------------------ gather
@njit(inline="always", **_JIT)
def _bucket(ix, iy, iz, mask):
    h = (np.uint64(ix) * np.uint64(73856093)) ^ (np.uint64(iy) * np.uint64(19349663)) ^ (np.uint64(iz) * np.uint64(83492791))
    return np.int64(_mix64(h) & mask)


@njit(**_JIT)
def build_grid(pos, cell):
    """A spatial hash of points pos (P, 3) float64 on cubic cells of side ``cell``.

    Returns (cells (P, 3) int64 each point's cell, start (B + 1,) int64 bucket offsets, order
    (P,) int64 point indices sorted by bucket, stably: within a bucket in index order), with B
    a power of two >= 2 P. Distinct cells may share a bucket: queries compare cells."""
    n = len(pos)
    nb = 2
    while nb < 2 * n:
        nb *= 2
    mask = np.uint64(nb - 1)
    cells = np.empty((n, 3), np.int64)
    bucket = np.empty(n, np.int64)
    start = np.zeros(nb + 1, np.int64)
    inv = 1.0 / cell
    for i in range(n):
        for c in range(3):
            cells[i, c] = np.int64(math.floor(pos[i, c] * inv))
        b = _bucket(cells[i, 0], cells[i, 1], cells[i, 2], mask)
        bucket[i] = b
        start[b + 1] += 1
    for b in range(nb):
        start[b + 1] += start[b]
    fill = start[:nb].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        b = bucket[i]
        order[fill[b]] = i
        fill[b] += 1
    return cells, start, order


@njit(**_JIT)
def gather(rows, vp_p, vp_n, vp_w, vp_depth, radius, cell, cells, start, order, ph_p, ph_wi, ph_flux, ph_depth,
           max_depth, phi, count):
    """For visible points ``rows`` (indices into the vp_* arrays: p (V, 3), n (V, 3) gather side,
    w (V, 3) weight, depth (V,); radius (V,) <= cell): phi[row] = sum of flux x w and count[row]
    = number of the photons (ph_*: p, wi, flux (P, 3), depth (P,)) within the radius, arriving on
    the front side (wi . n > 0), with depth + 1 + photon depth <= max_depth. cell, cells,
    start, order: :func:`build_grid` of ph_p. Sums run over cells in (x, y, z) order and photons
    in index order within a cell (deterministic)."""
    nb = len(start) - 1
    mask = np.uint64(nb - 1)
    inv = 1.0 / cell
    for k in range(len(rows)):
        v = rows[k]
        r = radius[v]
        r2 = r * r
        x, y, z = vp_p[v, 0], vp_p[v, 1], vp_p[v, 2]
        nx, ny, nz = vp_n[v, 0], vp_n[v, 1], vp_n[v, 2]
        budget = max_depth - 1 - vp_depth[v]
        s0 = s1 = s2 = 0.0
        m = 0
        x0, x1 = np.int64(math.floor((x - r) * inv)), np.int64(math.floor((x + r) * inv))
        y0, y1 = np.int64(math.floor((y - r) * inv)), np.int64(math.floor((y + r) * inv))
        z0, z1 = np.int64(math.floor((z - r) * inv)), np.int64(math.floor((z + r) * inv))
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                for iz in range(z0, z1 + 1):
                    b = _bucket(ix, iy, iz, mask)
                    for a in range(start[b], start[b + 1]):
                        j = order[a]
                        if cells[j, 0] != ix or cells[j, 1] != iy or cells[j, 2] != iz:
                            continue
                        ex, ey, ez = ph_p[j, 0] - x, ph_p[j, 1] - y, ph_p[j, 2] - z
                        if ex * ex + ey * ey + ez * ez > r2:
                            continue
                        if not (ph_wi[j, 0] * nx + ph_wi[j, 1] * ny + ph_wi[j, 2] * nz > 0.0):
                            continue
                        if ph_depth[j] > budget:
                            continue
                        s0 += ph_flux[j, 0]
                        s1 += ph_flux[j, 1]
                        s2 += ph_flux[j, 2]
                        m += 1
        phi[v, 0] = s0 * vp_w[v, 0]
        phi[v, 1] = s1 * vp_w[v, 1]
        phi[v, 2] = s2 * vp_w[v, 2]
        count[v] = m


@njit(**_JIT)
def gather_update(vp_ok, vp_p, vp_n, vp_w, vp_depth, ph_p, ph_wi, ph_flux, ph_depth, max_depth, alpha, r_floor,
                  R, N, tau):
    """One pass's gather and progressive update (render.integrators.sppm._Progressive.add_photons).

    vp_*: the pass's visible points per pixel (ok (npix,) bool, p, n, w (npix, 3), depth
    (npix,)); ph_*: its stored photons. R, N (npix,), tau (npix, 3): radii, photon counts and
    rescaled flux, updated in place where M > 0 photons are found: N' = N + alpha M,
    R' = max(R sqrt(N' / (N + M)), r_floor), tau' = (tau + Phi) (R' / R)^2.
    Returns the number of photons gathered."""
    rows = np.nonzero(vp_ok)[0]
    if len(rows) == 0 or len(ph_p) == 0:
        return 0
    cell = 0.0
    for v in rows:
        cell = max(cell, R[v])
    cells, start, order = build_grid(ph_p, cell)
    npix = len(R)
    phi = np.zeros((npix, 3))
    count = np.zeros(npix, np.int64)
    gather(rows, vp_p, vp_n, vp_w, vp_depth, R, cell, cells, start, order, ph_p, ph_wi, ph_flux, ph_depth, max_depth,
           phi, count)
    total = 0
    for v in rows:
        m = count[v]
        if m == 0:
            continue
        total += m
        n_new = N[v] + alpha * m
        r_new = max(R[v] * math.sqrt(n_new / (N[v] + m)), r_floor)
        ratio = r_new / R[v]
        scale = ratio * ratio
        for c in range(3):
            tau[v, c] = (tau[v, c] + phi[v, c]) * scale
        N[v] = n_new
        R[v] = r_new
    return total
