"""The wavefront bounce loop for paths that start at a known hit, inside the scene.

`path` starts its paths at the camera (render.integrators.path._trace). Two estimators start
theirs at a surface point instead and then continue them exactly as `path` does: the
irradiance cache's hemisphere rays (render.integrators.irradiance_cache) and the illuminance
sensors' paths (render.sensors). Both call :func:`continue_paths`, so the loop (one Embree query
for the live paths, one compiled shading pass, one occlusion query for the shadow rays, per
depth) is written once.
"""
from __future__ import annotations

import numpy as np

from ..accel import Accel
from .path import _last_ray_buffers, _queue_buffers, _state_buffers
from .path_kernels import KernelScene, PathConfig, add_unoccluded, shade_bounce

__all__ = ["new_state", "continue_paths"]


def new_state(n: int) -> tuple:
    """A wavefront state for n paths: (slot (n,) int64, RNG key (n,) uint64, throughput (n, 3)
    float64, pdf (n,) float64, flags (n,) uint8, ray origin (n, 3) float32, ray direction (n, 3)
    float32), uninitialised: the caller fills it."""
    return _state_buffers(n)


def continue_paths(accel: Accel, ks: KernelScene, cfg: PathConfig, state: tuple, first_hits: tuple,
                   first_depth: int, L: np.ndarray) -> int:
    """Continue n paths from their first hits to ``cfg.max_depth``, adding radiance into L.

    state: a filled :func:`new_state` of n paths (slot i adds into L[i]); its origins and
    directions are the rays that produced ``first_hits``. first_hits: (prim (n,) int32, tfar,
    u, v (n,) float32) of those rays, as Embree returns them (or made up by the caller, e.g. the
    sensors' own primitives). first_depth: the depth of those hits (the kernels' roulette and
    MIS read it). L: (n, 3) float64, accumulated in place. ``cfg.direct`` must be off (no last
    BSDF rays here). Returns the rays traced after the first hits (the caller counts those).
    """
    if cfg.direct:
        raise ValueError("continue_paths: `direct`'s last-bounce rays are not handled here")
    n = len(state[0])
    cur, nxt = state, _state_buffers(n)
    queue, last = _queue_buffers(n), _last_ray_buffers(0)
    prim, tfar, hu, hv = first_hits
    rays, live = 0, n
    for depth in range(first_depth, cfg.max_depth + 1):
        if live == 0:
            break
        idx, keys, beta, pdf, flags, o32, d32 = (a[:live] for a in cur)
        if depth > first_depth:
            prim, tfar, hu, hv = accel.intersect_fast(o32, d32)
            rays += live
        live_next, nq, _ = shade_bounce(ks, cfg, depth, prim, tfar, hu, hv, idx, keys, beta, d32, pdf, flags, L,
                                        *nxt, *queue, *last)
        if nq:
            occluded = accel.occluded_fast(queue[0][:nq], queue[1][:nq], queue[2][:nq])
            rays += nq
            add_unoccluded(L, queue[3], queue[4], occluded)
        cur, nxt, live = nxt, cur, live_next
    return rays
