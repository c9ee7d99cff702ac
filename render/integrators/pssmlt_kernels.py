"""Compiled kernels of ``pssmlt``'s Metropolis chains (render.integrators.pssmlt), a wavefront over
chains: each call advances every active chain of a batch of independent groups by one step.

A step of chain c reads D + 2 random numbers, dimensions ``step (D + 2) + j`` of the chain's
counter-based hash key (render.sampling.uniform, splitmix64): j = 0 decides a large step
(u < p_large), j = 1 .. D are the proposal's coordinates (a large step takes them as they are; a
small step moves coordinate i of the state X by +-SMALL_STEPS[floor(2 L u) mod L] (L levels), the
sign + where u >= 1/2, wrapped into [0, 1)), j = D + 1 decides acceptance (u < a).
So a chain is a pure function of (key, start state), whatever other chains share the wavefront:
render.integrators.pssmlt._run_group_numpy is the same chain in numpy, value for value.

Shapes: X, Y (C, D) float64 primary samples; pix (C,) int64 row-major pixel; f (C, 3) float64
contribution; I (C,) float64 luminance importance; keys (C,) uint64; group (C,) int64 index of a
chain's group in the batch (0 .. G - 1); image (G, npix, 3) float64 each group's splat sums.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .path_kernels import _uniform
from .path_types import F_DELTA
from .volpath_kernels import trace_surfaces

__all__ = ["S1", "S2", "SMALL_STEPS", "SMALL_STEP_LEVELS", "LUM_R", "LUM_G", "LUM_B", "IMPORTANCE_EDGES", "propose",
           "uniform_rows", "accept_and_splat", "splat_uniform", "sanitize_rows", "pinhole_rays", "run_chains"]

_JIT = dict(cache=True, nogil=True, error_model="numpy")

#: Kelemen's small-step range: offsets between S1 and S2, exponentially distributed
S1, S2 = 1.0 / 1024.0, 1.0 / 64.0
#: Kelemen's offsets S2 exp(-ln(S2 / S1) xi), xi uniform, quantized to this many log-spaced
#: magnitudes (adjacent ones 0.07% apart), the midpoints of equal xi bins: a table lookup instead
#: of an exp per coordinate (the exp was 2/3 of a step's proposal time); the sign stays a fair coin,
#: so the proposal stays symmetric
SMALL_STEP_LEVELS = 4096
SMALL_STEPS = S2 * np.exp(-math.log(S2 / S1) * (np.arange(SMALL_STEP_LEVELS) + 0.5) / SMALL_STEP_LEVELS)
_LEVELS2 = 2.0 * SMALL_STEP_LEVELS  # u in [0, 1/2) and [1/2, 1) each spans the levels once
#: Rec. 709 luminance weights (render.integrators.pssmlt.LUMINANCE), summed in this order
LUM_R, LUM_G, LUM_B = 0.2126, 0.7152, 0.0722
#: I / b bin edges of the acceptance statistics (render.integrators.pssmlt._IMPORTANCE_BINS)
IMPORTANCE_EDGES = np.array([0.1, 1.0, 10.0, 100.0])


@njit(**_JIT)
def propose(X, active, keys, step, large_step, Y, large):
    """Proposals of step ``step`` for the chains ``active`` (M,) int64 (rows of X (C, D)): row m
    of Y (>= M, D) is chain active[m]'s proposal and large[m] (bool) whether it is a large step."""
    D = X.shape[1]
    base = step * (D + 2)
    for m in range(active.shape[0]):
        c = active[m]
        key = keys[c]
        is_large = _uniform(key, base) < large_step
        large[m] = is_large
        x, y = X[c], Y[m]
        if is_large:
            for j in range(D):
                y[j] = _uniform(key, base + 1 + j)
        else:
            for j in range(D):  # branch-free (selects): a coin flip per coordinate defeats prediction
                u = _uniform(key, base + 1 + j)
                s = SMALL_STEPS[np.int64(u * _LEVELS2) & (SMALL_STEP_LEVELS - 1)]
                v = x[j] + (s if u >= 0.5 else -s)
                # v - floor(v) for v in (-1, 2), the same bits; 0.77x a small step's time
                v = v + 1.0 if v < 0.0 else (v - 1.0 if v >= 1.0 else v)
                y[j] = v if v < 1.0 else 0.0  # a tiny negative number wraps to 1.0 in rounding


@njit(**_JIT)
def uniform_rows(keys, dim0, count):
    """(N, count) float64: dimensions dim0 .. dim0 + count - 1 of each key (N,) uint64, the values
    of render.sampling.uniform_block."""
    out = np.empty((keys.shape[0], count))
    for i in range(keys.shape[0]):
        for j in range(count):
            out[i, j] = _uniform(keys[i], dim0 + j)
    return out


@njit(**_JIT)
def accept_and_splat(active, keys, step, uniform_share, group, b, X, pix_x, f_x, I_x, Y, large, pix_y, f_y,
                     image, rejections, moved, g_proposed, g_accepted, g_large, g_accepted_large, g_longest,
                     g_bins_proposed, g_bins_accepted, g_nonfinite):
    """Finish step ``step`` of the chains ``active`` (M,): their proposals Y (M, D), pix_y (M,),
    f_y (M, 3) (from the path sampler; non-finite or negative contributions are zeroed here and
    counted in g_nonfinite). Splats Kelemen's expected-value contributions (balance heuristic with
    the uniform samples: uniform_share (G,) is each group's uniform samples per step, p_large +
    n_bootstrap / mutations, the c of :func:`splat_uniform`) of the proposal and the current state
    into image[group] (b (G,): each group's bootstrap normalisation), draws acceptance, moves
    accepted chains to their proposal, and
    counts per group: proposals, acceptances, large steps (and their acceptances), proposals and
    acceptances by the current state's I / b bin (G, 5), the longest rejection run.
    rejections (C,) int64 and moved (C,) bool are the chains' running counters."""
    D = X.shape[1]
    u_accept = step * (D + 2) + D + 1
    nb = IMPORTANCE_EDGES.shape[0]
    for m in range(active.shape[0]):
        c = active[m]
        g = group[c]
        bg = b[g]
        cg = uniform_share[g]
        y0, y1, y2 = f_y[m, 0], f_y[m, 1], f_y[m, 2]
        if not (math.isfinite(y0) and math.isfinite(y1) and math.isfinite(y2)) or min(y0, y1, y2) < 0.0:
            y0 = y1 = y2 = 0.0
            g_nonfinite[g] += 1
        iy = LUM_R * y0 + LUM_G * y1 + LUM_B * y2
        ix = I_x[c]
        a = iy / ix  # ix > 0 always: a zero-importance proposal is never accepted
        if a > 1.0:
            a = 1.0
        lg = 1.0 if large[m] else 0.0
        den_y = iy / bg + cg
        w_y = (a + lg) / den_y if den_y > 0.0 else 0.0
        w_x = (1.0 - a) / (ix / bg + cg)
        py = pix_y[m]
        px = pix_x[c]
        image[g, py, 0] += y0 * w_y
        image[g, py, 1] += y1 * w_y
        image[g, py, 2] += y2 * w_y
        image[g, px, 0] += f_x[c, 0] * w_x
        image[g, px, 1] += f_x[c, 1] * w_x
        image[g, px, 2] += f_x[c, 2] * w_x
        accept = _uniform(keys[c], u_accept) < a
        rel = ix / bg
        bi = 0
        while bi < nb and IMPORTANCE_EDGES[bi] <= rel:
            bi += 1
        g_bins_proposed[g, bi] += 1.0
        g_proposed[g] += 1
        if large[m]:
            g_large[g] += 1
        if accept:
            g_bins_accepted[g, bi] += 1.0
            g_accepted[g] += 1
            if large[m]:
                g_accepted_large[g] += 1
            rejections[c] = 0
            moved[c] = True
            for j in range(D):
                X[c, j] = Y[m, j]
            pix_x[c] = py
            f_x[c, 0], f_x[c, 1], f_x[c, 2] = y0, y1, y2
            I_x[c] = iy
        else:
            rejections[c] += 1
            if rejections[c] > g_longest[g]:
                g_longest[g] = rejections[c]


@njit(**_JIT)
def sanitize_rows(f, bad):
    """Zero the rows of f (N, 3) float64 with a non-finite or negative entry, in place, and mark
    them in bad (N,) bool (render.integrators.pssmlt._sanitize in one pass)."""
    for i in range(f.shape[0]):
        a, b, c = f[i, 0], f[i, 1], f[i, 2]
        if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c)) or min(a, b, c) < 0.0:
            f[i, 0] = f[i, 1] = f[i, 2] = 0.0
            bad[i] = True
        else:
            bad[i] = False


@njit(**_JIT)
def splat_uniform(image, pix, f, I, b, c):
    """Splat uniform (independent) path samples into one group's image (npix, 3): pix (N,) int64,
    f (N, 3) float64 contributions, I (N,) their luminance, each weighted 1 / (I / b + c) (the
    balance heuristic of the bootstrap's samples against the chains, b the group's normalisation
    and c its uniform samples per step: render.integrators.pssmlt's estimator)."""
    for i in range(pix.shape[0]):
        if I[i] > 0.0:
            w = 1.0 / (I[i] / b + c)
            p = pix[i]
            image[p, 0] += f[i, 0] * w
            image[p, 1] += f[i, 1] * w
            image[p, 2] += f[i, 2] * w


@njit(inline="always", **_JIT)
def _pinhole_ray(u0, u1, width, height, fx, fy, cx, cy, R):
    """One primary sample's row-major pixel and unit ray direction (3 floats, world axes)."""
    x = u0 * width
    y = u1 * height
    pix = min(np.int64(y), height - 1) * width + min(np.int64(x), width - 1)
    a = (x - cx) / fx
    b = (y - cy) / fy
    inv = 1.0 / math.sqrt(a * a + b * b + 1.0)
    a, b, c = a * inv, b * inv, inv
    return (pix, a * R[0, 0] + b * R[0, 1] + c * R[0, 2], a * R[1, 0] + b * R[1, 1] + c * R[1, 2],
            a * R[2, 0] + b * R[2, 1] + c * R[2, 2])


@njit(**_JIT)
def pinhole_rays(U, width, height, fx, fy, cx, cy, R, t):
    """The camera rays of primary samples U (N, >= 2) through an undistorted pinhole camera
    (intrinsics fx, fy, cx, cy; camera-to-world rotation R (3, 3) and centre t (3,)): the
    image-plane point (x, y) = (width u0, height u1), its row-major pixel (N,) int64 and the
    ray's origin and unit direction (N, 3) float64 (render.camera.Camera.pixel_rays' arithmetic,
    in one pass instead of its numpy temporaries)."""
    n = U.shape[0]
    pix = np.empty(n, np.int64)
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    for i in range(n):
        pix[i], d[i, 0], d[i, 1], d[i, 2] = _pinhole_ray(U[i, 0], U[i, 1], width, height, fx, fy, cx, cy, R)
        o[i, 0], o[i, 1], o[i, 2] = t[0], t[1], t[2]
    return pix, o, d


if trace_surfaces is not None:
    @njit(**_JIT)
    def run_chains(tracer, cam, large_step, X, active, owner, steps_of, keys, Y, large, pix_y, bufs, L, err,
                   uniform_share, b, pix_x, f_x, I_x, image, rejections, moved, g_proposed, g_accepted, g_large,
                   g_accepted_large, g_longest, g_bins_proposed, g_bins_accepted, g_nonfinite):
        """Every step of the chains ``active`` in one compiled call: per step, the chains whose
        group has run steps_of[group] steps leave ``active`` (compacted in place, in order),
        :func:`propose`, the proposals' pinhole rays, the path sampler
        (render.integrators.volpath_kernels.trace_surfaces, Embree called from compiled code) and
        :func:`accept_and_splat`: render.integrators.pssmlt._run_groups' Python loop, the same
        operations in the same order. tracer: render.integrators.volpath.surface_tracer's tuple;
        cam: (width, height, fx, fy, cx, cy, R (3, 3) camera-to-world rotation, centre (3,));
        bufs: render.integrators.volpath.vol_buffers of at least len(active) rows; pix_y (C,)
        int64 and L (C, 3) float64 scratch. Returns the rays traced."""
        ks, m_alpha, m_eta, m_k, md, cfg, handle, rounds = tracer
        width, height, fx, fy, cx, cy, R, t = cam
        cur, nxt, q, hit, occ = bufs
        ints, keys0, flt, flags, last_p, o32, d32 = cur
        m = active.shape[0]
        n_steps = 0
        for g in range(steps_of.shape[0]):
            n_steps = max(n_steps, steps_of[g])
        rays = 0
        for step in range(n_steps if m > 0 else 0):
            live = 0
            for i in range(m):
                c = active[i]
                if steps_of[owner[c]] > step:
                    active[live] = c
                    live += 1
            m = live
            act = active[:m]
            propose(X, act, keys, step, large_step, Y, large)
            for i in range(m):
                pix_y[i], dx, dy, dz = _pinhole_ray(Y[i, 0], Y[i, 1], width, height, fx, fy, cx, cy, R)
                ints[i, 0], ints[i, 1], ints[i, 2], ints[i, 3] = i, 2, 0, -1
                keys0[i] = 0
                flt[i, 0], flt[i, 1], flt[i, 2], flt[i, 3] = 1.0, 1.0, 1.0, 0.0
                flags[i] = F_DELTA  # the camera ray counts as specular: emission seen directly has weight 1
                o32[i, 0], o32[i, 1], o32[i, 2] = t[0], t[1], t[2]
                d32[i, 0], d32[i, 1], d32[i, 2] = dx, dy, dz
                last_p[i, 0], last_p[i, 1], last_p[i, 2] = o32[i, 0], o32[i, 1], o32[i, 2]
                L[i, 0] = L[i, 1] = L[i, 2] = 0.0
            rays += trace_surfaces(ks, m_alpha, m_eta, m_k, md, cfg, Y[:m], handle, rounds, m, cur, nxt, q, hit, occ,
                                   L, err)
            accept_and_splat(act, keys, step, uniform_share, owner, b, X, pix_x, f_x, I_x, Y, large, pix_y[:m], L[:m],
                             image, rejections, moved, g_proposed, g_accepted, g_large, g_accepted_large, g_longest,
                             g_bins_proposed, g_bins_accepted, g_nonfinite)
        return rays
else:  # pragma: no cover - the Python loop of render.integrators.pssmlt runs the steps
    run_chains = None
