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
        n = 0            # kept samples: weight above colour_weight (stored while n < capacity)
        listed = 0.0     # sum of the listed weights (above min_weight), as float32 values
        kept_w = 0.0     # sum of the kept ones
        heavy_w = 0.0    # the heaviest listed sample
        heavy_t = 0.0
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
                w32 = np.float32(w)
                listed += w32
                if w32 > heavy_w:
                    heavy_w = w32
                    heavy_t = t
                if w32 > colour_weight:
                    if n < capacity:
                        sample_t[r, n] = t
                        sample_w[r, n] = w32
                    n += 1
                    kept_w += w32
            trans *= math.exp(-tau)
            if trans < stop_t:
                break
            k += 1
        opacity[r] = op
        wsum_t[r] = wt
        if n == 0 and heavy_w > 0.0:
            # no sample above colour_weight: the heaviest listed one alone (every kept sample would
            # outweigh it, so it is kept exactly when none is)
            sample_t[r, 0] = heavy_t
            sample_w[r, 0] = heavy_w
            kept_w = heavy_w
            n = 1
        if 0 < n <= capacity:
            # the weight of the listed samples passed over, spread over the kept ones in proportion
            # (the colour of a surface varies little across it)
            for j in range(n):
                sample_w[r, j] *= listed / kept_w
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
    evals (R,) int64 density lookups) with C >= every count. The kept samples are chosen as the ray
    is marched (only those above ``colour_weight`` are stored, the heaviest held aside), so ``capacity``
    bounds the kept samples, not the listed ones; the rays with more are marched again, alone, with
    room for all of theirs. (Storing every listed sample overflowed 32 on most rays through the
    default scene's subject and marched whole chunks twice: 1.8x the time of a 1280x960 view.)"""
    R = o.shape[0]
    args = (np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32),
            np.ascontiguousarray(t0, np.float32), np.ascontiguousarray(s1, np.float32),
            np.ascontiguousarray(k_first, np.int64), float(step), np.asarray(box_lo, np.float64),
            np.asarray(box_hi, np.float64), np.ascontiguousarray(occupancy, np.bool_),
            np.ascontiguousarray(skip, np.int64), float(cell_steps), np.ascontiguousarray(grid, np.float32),
            float(shift), float(scale), float(stop_t), float(min_weight),
            float(min_weight if colour_weight is None else max(colour_weight, min_weight)))
    out = _alloc(R, capacity)
    n_chunks = max(1, min(threads * 4, R // 256 + 1))
    bounds = np.linspace(0, R, n_chunks + 1).astype(np.int64)
    if threads > 1 and n_chunks > 1:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda i: _march_range(bounds[i], bounds[i + 1], *args, *out), range(n_chunks)))
    else:
        _march_range(0, R, *args, *out)
    _, opacity, wsum_t, count, sample_t, sample_w, evals = out
    over = np.nonzero(count > capacity)[0]
    if over.size:
        # rare: rays with more kept samples than room; only they are marched again, with room for all
        sub = march(o[over], d[over], t0[over], s1[over], k_first[over], step, box_lo, box_hi, occupancy, skip,
                    cell_steps, grid, shift, scale, stop_t, min_weight, colour_weight, threads, int(count[over].max()))
        width = sub[3].shape[1]
        sample_t = np.concatenate([sample_t, np.zeros((R, width - capacity), np.float32)], axis=1)
        sample_w = np.concatenate([sample_w, np.zeros((R, width - capacity), np.float32)], axis=1)
        for full, part in zip((opacity, wsum_t, count, sample_t, sample_w, evals), sub):
            full[over] = part
    return opacity, wsum_t, count, sample_t, sample_w, evals


def _alloc(R: int, capacity: int) -> tuple:
    return (capacity, np.zeros(R, np.float64), np.zeros(R, np.float64), np.zeros(R, np.int64),
            np.zeros((R, capacity), np.float32), np.zeros((R, capacity), np.float32), np.zeros(R, np.int64))
