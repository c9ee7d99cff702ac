"""The rebinning's per-ray blend (:func:`recon.slab.rebin._blend_rays_numpy`) as one compiled loop.

The numpy version materializes (rays, views, 3) arrays per uv sample: at the capture's pixel
footprint (a quarter-billion slab rays on the default scene) it ran for more than half an hour.
This module does the same work per ray in registers: the direction cosine to every view, the
``candidates`` best kept by insertion, the visibility test against each candidate's depth map,
the unstructured lumigraph's weights and the bilinear samples. It is compiled with ``nogil``, so
:func:`blend_rays` splits the rays over threads and both cores work.

Same conventions as the numpy version: views' world-to-camera (M, 3, 4) OpenCV matrices,
pixel centres at +0.5, one shared pinhole (fx, fy, cx, cy).
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

__all__ = ["blend_rays", "splat_depth_images"]

_JIT = dict(cache=True, nogil=True, error_model="numpy")


@njit(inline="always", **_JIT)
def _project(w2c, view, px, py, pz, fx, fy, cx, cy):
    """Pixel (x, y) and camera z of world point (px, py, pz) in ``view`` (ideal pinhole)."""
    M = w2c[view]
    x = M[0, 0] * px + M[0, 1] * py + M[0, 2] * pz + M[0, 3]
    y = M[1, 0] * px + M[1, 1] * py + M[1, 2] * pz + M[1, 3]
    z = M[2, 0] * px + M[2, 1] * py + M[2, 2] * pz + M[2, 3]
    zs = z if z > 1e-9 else 1.0
    return fx * x / zs + cx, fy * y / zs + cy, z


@njit(**_JIT)
def _blend_range(lo, hi, P, r, rgb, depth, centres, w2c, fx, fy, cx, cy, m, k, tol_rel, tol_abs, out, filled):
    """Fill out[lo:hi] (float32 radiance) and filled[lo:hi] (bool) for rays of unit direction
    r reaching surface points P ((N, 3) float64 each)."""
    n_views, H, W = depth.shape[0], depth.shape[1], depth.shape[2]
    best_cos = np.empty(m)
    best_view = np.empty(m, np.int64)
    vis = np.empty(m, np.bool_)
    order = np.empty(m, np.int64)
    w = np.empty(k)
    for n in range(lo, hi):
        px, py, pz = P[n, 0], P[n, 1], P[n, 2]
        rx, ry, rz = r[n, 0], r[n, 1], r[n, 2]
        # the m views whose direction to P is closest to the ray's, best first
        count = 0
        for v in range(n_views):
            dx, dy, dz = px - centres[v, 0], py - centres[v, 1], pz - centres[v, 2]
            c = (dx * rx + dy * ry + dz * rz) / max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
            if count == m and c <= best_cos[m - 1]:
                continue
            slot = count if count < m else m - 1
            while slot > 0 and best_cos[slot - 1] < c:
                if slot < m:
                    best_cos[slot] = best_cos[slot - 1]
                    best_view[slot] = best_view[slot - 1]
                slot -= 1
            best_cos[slot] = c
            best_view[slot] = v
            if count < m:
                count += 1
        # which candidates see P (their depth map agrees with P's depth)
        for c in range(m):
            x, y, z = _project(w2c, best_view[c], px, py, pz, fx, fy, cx, cy)
            ok = z > 0 and x >= 0 and x < W and y >= 0 and y < H
            if ok:
                dm = depth[best_view[c], min(max(int(y), 0), H - 1), min(max(int(x), 0), W - 1)]
                ok = dm > 0 and abs(dm - z) <= tol_rel * z + tol_abs
            vis[c] = ok
        # visible candidates first, each group by angle (the numpy version's stable sort)
        j = 0
        for c in range(m):
            if vis[c]:
                order[j] = c
                j += 1
        n_visible = j
        for c in range(m):
            if not vis[c]:
                order[j] = c
                j += 1
        out[n, 0] = out[n, 1] = out[n, 2] = 0.0
        filled[n] = n_visible > 0
        if n_visible == 0:
            continue
        thresh = math.pi
        if m > k and k < n_visible:
            thresh = math.acos(min(max(best_cos[order[k]], -1.0), 1.0))
        total = 0.0
        for c in range(k):
            if c < n_visible:
                a = math.acos(min(max(best_cos[order[c]], -1.0), 1.0))
                w[c] = max(1.0 - a / thresh, 0.0) / max(a, 1e-4)
            else:
                w[c] = 0.0
            total += w[c]
        if total <= 0.0:        # all at the threshold angle: take the best view
            w[0], total = 1.0, 1.0
        for c in range(k):
            if w[c] <= 0.0:
                continue
            view = best_view[order[c]]
            x, y, _ = _project(w2c, view, px, py, pz, fx, fy, cx, cy)
            sx, sy = min(max(x - 0.5, 0.0), W - 1.0), min(max(y - 0.5, 0.0), H - 1.0)
            x0, y0 = min(int(math.floor(sx)), W - 2), min(int(math.floor(sy)), H - 2)
            ax, ay = sx - x0, sy - y0
            wc = w[c] / total
            for ch in range(3):
                top = (1.0 - ax) * rgb[view, y0, x0, ch] + ax * rgb[view, y0, x0 + 1, ch]
                bottom = (1.0 - ax) * rgb[view, y0 + 1, x0, ch] + ax * rgb[view, y0 + 1, x0 + 1, ch]
                out[n, ch] += np.float32(wc * ((1.0 - ay) * top + ay * bottom))


@njit(**_JIT)
def _splat_range(lo, hi, q, nu, nv, uv_w, uv_h, D, sx0, sy0, ws, ht, out, scratch):
    """Proxy depth images out[j, i] (nt, ns) float32 of the uv samples lo..hi-1 (row-major over
    (nv, nu)): points ``q`` (P, 3) in the slab frame, nearest first, splatted through each uv
    sample onto the st plane (the first point per st sample wins); then single holes closed."""
    nt, ns = out.shape[2], out.shape[3]
    for flat in range(lo, hi):
        j, i = flat // nu, flat % nu
        ux, uy = (i + 0.5) / nu * uv_w, (j + 0.5) / nv * uv_h
        scratch[:] = 0.0
        for p in range(q.shape[0]):
            mag = D / q[p, 2]
            col = math.floor(((ux + mag * (q[p, 0] - ux)) - sx0) / ws * ns)
            row = math.floor(((uy + mag * (q[p, 1] - uy)) - sy0) / ht * nt)
            if col >= 0 and col < ns and row >= 0 and row < nt:
                r, c = int(row), int(col)
                if scratch[r, c] == 0.0:
                    scratch[r, c] = q[p, 2]
        # an empty sample with at least 6 of 8 non-empty neighbours takes the nearest of them
        for r in range(nt):
            for c in range(ns):
                z = scratch[r, c]
                if z == 0.0:
                    count, nearest = 0, np.inf
                    for dr in range(-1, 2):
                        for dc in range(-1, 2):
                            rr, cc = r + dr, c + dc
                            if (dr != 0 or dc != 0) and 0 <= rr < nt and 0 <= cc < ns and scratch[rr, cc] > 0:
                                count += 1
                                nearest = min(nearest, scratch[rr, cc])
                    if count >= 6:
                        z = nearest
                out[j, i, r, c] = z


def splat_depth_images(q: np.ndarray, shape: tuple[int, int, int, int], uv_size, distance: float, st_offset, st_size,
                       threads: int | None = None) -> np.ndarray:
    """(Nv, Nu, Nt, Ns) float32 proxy depth for a slab of ``shape`` (Nu, Nv, Ns, Nt): ``q`` (P, 3)
    float64 surface points in the slab's frame (uv corner at the origin, z towards the st plane at
    ``distance``), sorted nearest first, with z > 0. uv samples are split over ``threads``."""
    nu, nv, ns, nt = shape
    out = np.zeros((nv, nu, nt, ns), np.float32)
    q = np.ascontiguousarray(q, np.float64)
    threads = max(1, min(int(threads or os.cpu_count() or 1), nu * nv))
    bounds = np.linspace(0, nu * nv, threads + 1).astype(np.int64)

    def run(lo: int, hi: int) -> None:
        _splat_range(lo, hi, q, nu, nv, float(uv_size[0]), float(uv_size[1]), float(distance),
                     float(st_offset[0]), float(st_offset[1]), float(st_size[0]), float(st_size[1]),
                     out, np.zeros((nt, ns), np.float32))
    if threads == 1:
        run(0, nu * nv)
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda b: run(*b), zip(bounds[:-1], bounds[1:])))
    return out


def blend_rays(P: np.ndarray, r: np.ndarray, rgb: np.ndarray, depth: np.ndarray, centres: np.ndarray,
               w2c: np.ndarray, intrinsics: tuple[float, float, float, float], candidates: int,
               cameras_per_ray: int, depth_tolerance: float, tol_abs: float, threads: int | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Radiance (N, 3) float32 and filled (N,) bool for rays of unit direction ``r`` (N, 3)
    reaching surface points ``P`` (N, 3) (world, float64), blended from views ``rgb``
    (M, H, W, 3) float32 linear, ``depth`` (M, H, W) float32 z-depth, ``centres`` (M, 3),
    ``w2c`` (M, 3, 4) world-to-camera OpenCV; ``intrinsics`` (fx, fy, cx, cy) in pixels.
    ``threads`` (default: all cores) split the rays; the result does not depend on it."""
    P = np.ascontiguousarray(P, np.float64)
    r = np.ascontiguousarray(r, np.float64)
    n, n_views = len(P), len(centres)
    m = min(int(candidates), n_views)
    k = min(int(cameras_per_ray), m)
    out = np.zeros((n, 3), np.float32)
    filled = np.zeros(n, bool)
    if n == 0:
        return out, filled
    fx, fy, cx, cy = (float(x) for x in intrinsics)
    args = (P, r, np.ascontiguousarray(rgb, np.float32), np.ascontiguousarray(depth, np.float32),
            np.ascontiguousarray(centres, np.float64), np.ascontiguousarray(w2c, np.float64),
            fx, fy, cx, cy, m, k, float(depth_tolerance), float(tol_abs), out, filled)
    threads = max(1, int(threads or os.cpu_count() or 1))
    bounds = np.linspace(0, n, min(threads * 4, max(1, n // 4096)) + 1).astype(np.int64)
    chunks = list(zip(bounds[:-1], bounds[1:]))
    if threads == 1 or len(chunks) == 1:
        for lo, hi in chunks:
            _blend_range(lo, hi, *args)
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda c: _blend_range(c[0], c[1], *args), chunks))
    return out, filled
