"""The fast NeRF's held-out ray marching (density pass) as one compiled loop per ray.

:meth:`recon.nerf.models.FastNeRF.render_inference` marched every alive ray in torch segments:
each step of each ray cost a dozen tensor operations and an advanced-indexing gather, ~0.4-0.6 ms
a ray on the default scene (a 1280x960 view in 8-11 minutes). This module walks each ray in
registers instead: the same samples (t0 + (k + 1/2) step from the box entry), the occupancy grid
with empty-space jumps (a cell at Chebyshev distance D >= 2 from the nearest occupied cell lets
the ray pass (D - 1) cells: every cell passed is empty), the density by trilinear interpolation
of the dense feature grid (what ``grid_sample(align_corners=True, padding_mode="zeros")`` does)
and softplus, front-to-back compositing with early termination at ``stop_t``. It returns each
ray's opacity and sum of w t, and the (t, w) of the samples whose weight exceeds ``min_weight``:
torch evaluates their colour in one batch (appearance grids and MLP; not worth compiling).

Compiled with ``nogil``: :func:`march` splits the rays over threads, so both cores work.
Conventions: rays (R, 3) float32 origins and unit directions in world units; the unit box maps
``lo`` -> -1 and ``hi`` -> +1; the dense grid is indexed [z, y, x] (grid_sample's (D, H, W)).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

__all__ = ["march"]

_JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)


@njit(inline="always", **_JIT)
def _trilinear(grid, ux, uy, uz):
    """grid_sample(align_corners=True, zeros padding) of a (Z, Y, X) grid at unit coordinates."""
    nz, ny, nx = grid.shape
    fx = (ux + 1.0) * 0.5 * (nx - 1)
    fy = (uy + 1.0) * 0.5 * (ny - 1)
    fz = (uz + 1.0) * 0.5 * (nz - 1)
    x0, y0, z0 = math.floor(fx), math.floor(fy), math.floor(fz)
    ax, ay, az = fx - x0, fy - y0, fz - z0
    x0, y0, z0 = int(x0), int(y0), int(z0)
    acc = 0.0
    for dz in range(2):
        z = z0 + dz
        if z < 0 or z >= nz:
            continue
        wz = az if dz else 1.0 - az
        for dy in range(2):
            y = y0 + dy
            if y < 0 or y >= ny:
                continue
            wy = ay if dy else 1.0 - ay
            for dx in range(2):
                x = x0 + dx
                if x < 0 or x >= nx:
                    continue
                wx = ax if dx else 1.0 - ax
                acc += wz * wy * wx * grid[z, y, x]
    return acc


@njit(**_JIT)
def _march_range(lo_r, hi_r, o, d, t0, s1, k_first, step, box_lo, box_hi, occupancy, skip, cell_steps,
                 grid, shift, scale, stop_t, min_weight, colour_weight, capacity, opacity, wsum_t, count, sample_t, sample_w, evals):
    g = occupancy.shape[0]
    for r in range(lo_r, hi_r):
        k = k_first[r]
        trans = 1.0
        op = 0.0
        wt = 0.0
        n = 0
        n_eval = 0
        ox, oy, oz = o[r, 0], o[r, 1], o[r, 2]
        dx, dy, dz = d[r, 0], d[r, 1], d[r, 2]
        while True:
            t = t0[r] + (k + 0.5) * step
            if t >= s1[r]:
                break
            ux = (ox + t * dx - box_lo[0]) / (box_hi[0] - box_lo[0]) * 2.0 - 1.0
            uy = (oy + t * dy - box_lo[1]) / (box_hi[1] - box_lo[1]) * 2.0 - 1.0
            uz = (oz + t * dz - box_lo[2]) / (box_hi[2] - box_lo[2]) * 2.0 - 1.0
            ix = min(max(int((ux + 1.0) * 0.5 * g), 0), g - 1)
            iy = min(max(int((uy + 1.0) * 0.5 * g), 0), g - 1)
            iz = min(max(int((uz + 1.0) * 0.5 * g), 0), g - 1)
            if not occupancy[ix, iy, iz]:
                jump = int(math.floor((skip[ix, iy, iz] - 1) * cell_steps))
                k += jump if jump > 0 else 1
                continue
            n_eval += 1
            feat = _trilinear(grid, ux, uy, uz) + shift
            sigma = (feat if feat > 20.0 else math.log1p(math.exp(feat))) * scale   # torch's softplus
            tau = min(max(sigma * step, 0.0), 1.0e3)
            w = trans * -math.expm1(-tau)
            op += w
            wt += w * t
            if w > min_weight:
                if n < capacity:
                    sample_t[r, n] = t
                    sample_w[r, n] = w
                n += 1
            trans *= math.exp(-tau)
            if trans < stop_t:
                break
            k += 1
        opacity[r] = op
        wsum_t[r] = wt
        if n <= capacity and n > 0:
            # keep the samples above colour_weight and the heaviest; spread the weight of the others
            # over the kept ones in proportion (the colour of a surface varies little across it)
            heaviest = 0.0
            listed = 0.0
            for j in range(n):
                listed += sample_w[r, j]
                heaviest = max(heaviest, sample_w[r, j])
            kept = 0
            kept_w = 0.0
            for j in range(n):
                if sample_w[r, j] > colour_weight or sample_w[r, j] == heaviest:
                    sample_t[r, kept] = sample_t[r, j]
                    sample_w[r, kept] = sample_w[r, j]
                    kept_w += sample_w[r, j]
                    kept += 1
            for j in range(kept):
                sample_w[r, j] *= listed / kept_w
            n = kept
        count[r] = n
        evals[r] = n_eval


def march(o: np.ndarray, d: np.ndarray, t0: np.ndarray, s1: np.ndarray, k_first: np.ndarray, step: float,
          box_lo: np.ndarray, box_hi: np.ndarray, occupancy: np.ndarray, skip: np.ndarray, cell_steps: float,
          grid: np.ndarray, shift: float, scale: float, stop_t: float, min_weight: float,
          colour_weight: float | None = None, threads: int = 2, capacity: int = 32):
    """March R rays (module docstring). o, d: (R, 3) float32; t0: (R,) box entry; s1: (R,) end of
    the occupied box; k_first: (R,) int64 first step index; occupancy: (g, g, g) bool indexed
    [x, y, z]; skip: (g, g, g) int64 distances (:meth:`FastNeRF.skip_distance`); cell_steps: an
    occupancy cell's smallest side in steps; grid: (Z, Y, X) float32 density features; sigma =
    softplus(feature + shift) * scale per world unit. Samples of weight above ``min_weight`` are
    listed; of those, the ones above ``colour_weight`` and each ray's heaviest are kept, their
    weights scaled so that they sum to the listed ones' (``colour_weight`` None: min_weight, all kept).
    Returns (opacity (R,), sum of w t (R,), count (R,) int64 kept samples, t (R, C), w (R, C),
    evals (R,) int64 density lookups) with C >= every count: rays
    that overflow ``capacity`` are marched again with room for all of theirs."""
    R = o.shape[0]
    args = (np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32),
            np.ascontiguousarray(t0, np.float32), np.ascontiguousarray(s1, np.float32),
            np.ascontiguousarray(k_first, np.int64), float(step), np.asarray(box_lo, np.float64),
            np.asarray(box_hi, np.float64), np.ascontiguousarray(occupancy, np.bool_),
            np.ascontiguousarray(skip, np.int64), float(cell_steps), np.ascontiguousarray(grid, np.float32),
            float(shift), float(scale), float(stop_t), float(min_weight),
            float(min_weight if colour_weight is None else max(colour_weight, min_weight)))
    while True:
        opacity = np.zeros(R, np.float64)
        wsum_t = np.zeros(R, np.float64)
        count = np.zeros(R, np.int64)
        sample_t = np.zeros((R, capacity), np.float32)
        sample_w = np.zeros((R, capacity), np.float32)
        evals = np.zeros(R, np.int64)
        out = (capacity, opacity, wsum_t, count, sample_t, sample_w, evals)
        n_chunks = max(1, min(threads * 4, R // 256 + 1))
        bounds = np.linspace(0, R, n_chunks + 1).astype(np.int64)
        if threads > 1 and n_chunks > 1:
            with ThreadPoolExecutor(threads) as pool:
                list(pool.map(lambda i: _march_range(bounds[i], bounds[i + 1], *args, *out), range(n_chunks)))
        else:
            _march_range(0, R, *args, *out)
        most = int(count.max()) if R else 0
        if most <= capacity:
            return opacity, wsum_t, count, sample_t, sample_w, evals
        capacity = most  # rare: a ray with that many visible samples; march again with room for all
