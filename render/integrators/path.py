"""``path``: the reference path tracer: wavefront, unbiased, with NEE, MIS and Russian roulette.

Every model in lumigraph is judged against this renderer. It estimates the measurement

    I_pixel = 1/|pixel| \\int_pixel L(x_cam, w(x)) dx            (box filter)

with L expanded recursively by the rendering equation: L (S|D)* E with next-event estimation
and MIS at every diffuse vertex and Russian roulette. Caustics from area sources are found by
BSDF sampling; caustics from point, spot and directional lights are unreachable (a delta light
through a delta BSDF): asking for them is an error (render.integrators.choice), never a silent
omission. :mod:`render.integrators.direct` runs the same driver and kernels, its paths ending
at the first diffuse vertex.

Paths are traced *wavefront*: an array of live paths, each bounce one Embree query for all of
them, one compiled shading pass over the hits (:mod:`render.integrators.path_kernels`, numba;
compiled ahead of time into an extension when `make setup` built one, :mod:`render.path_aot`;
it writes the next rays and the shadow rays as the float32 arrays Embree reads and compacts
finished paths away), one occlusion query for all shadow rays. Embree is called from compiled
code through the library embreex ships (:mod:`render.embree_direct`), or through embreex's
batch API when that library is not found. There is no Python loop per ray or per pixel; the
kernels release the GIL, so the ``threads`` render threads (one batch of ``batch_paths`` camera
samples each) trace and shade in parallel. The numpy BSDFs (:mod:`render.bsdf`), light sampling
(:mod:`render.lights`) and warps (:mod:`render.sampling`) remain the reference interfaces for
the other integrators; the kernels implement the same formulas and tests compare them.

Conventions: radiometry and light units of :mod:`render.scene`; pixel centres at +0.5 and
OpenCV camera axes of :mod:`render.camera`; scene.background is the radiance of every escaping
ray (a uniform environment, sampled by BSDF sampling only); surfaces are shaded with their
geometric normal (flat shading). Lambertian and mirror surfaces are two-sided; emitters and
dielectrics are not. Max depth counts scattering events: max_depth = N keeps paths of up to N
bounces (0: emitters seen directly only). Russian roulette (pbrt-v4) applies when leaving a
vertex of index >= rr_depth (0 = the first hit): survive with probability min(1, max(beta)),
survivors divided by it.

With 'caustics' not among the effects, light that reaches a diffuse vertex through one or more
specular vertices (from an emitter or the background) is dropped: the pruned render simulates
the listed effects and nothing more.

Random numbers are a pure function of (seed, pixel, sample index, dimension), so renders of
disjoint sample ranges merge exactly (:func:`render.film.merge_results`): Owen-scrambled Sobol
points from one sequence per pixel (``sampler="sobol-blocks"``, the default, :mod:`render.sobol`:
sample s is point s, so a render is one net; the variance image comes from R =
render.sobol.replicates_for(spp) (4, 8 or 16) consecutive blocks under a fitted power law of the
net size, :func:`render.film.blocks_variance`), the same points split into R interleaved
independent replicates (``sampler="sobol"``: sample s of a pixel is point s div R of its
replicate s mod R; R nets of n / R points, noisier, but the variance image from the R replicate
means is unbiased without a model, :meth:`render.film.Film.variance`: R - 1 degrees of freedom
per pixel, so per-pixel tests against it use Student-t thresholds), or an independent hash per dimension (``sampler="independent"``, :mod:`render.sampling`; the variance image is the
sample variance over n).
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..film import Film, RenderResult
from ..path_aot import for_scene
from ..sampling import _GOLDEN, _mix64
from ..scene import Scene
from ..sobol import REPLICATES, SAMPLERS, block_size, key_replicates, replicate_of, replicates_for, shuffle_bits
from .path_types import (F_DELTA, SAMPLER_SOBOL, STRAT_BSDF, STRAT_LIGHT, STRAT_MIS, KernelScene, PathConfig,
                         PinholeCamera, kernel_scene)
from .prepared import PreparedScene
from .settings import RenderSettings, check_heuristic, check_sampler, check_strategy, heuristic_exponent

__all__ = ["Options", "render_result", "kernel_scene_of", "path_config", "pinhole_of"]

_STRATEGY_CODES = {"mis": STRAT_MIS, "light": STRAT_LIGHT, "bsdf": STRAT_BSDF}


@dataclass(frozen=True)
class Options:
    """Options of ``path`` (RenderSettings fields of the same names)."""

    #: Russian roulette when leaving vertices of index >= rr_depth
    roulette: bool = True
    #: first vertex index (0: the first hit) whose outgoing path roulette may end: 5, Mitsuba 3's
    #: policy (issue 16: Cornell 128x128, four seeds, 4 rounds, against 3: variance 0.77x a sample,
    #: 1.06-1.17x the efficiency at max_depth 64, 1.01-1.12x at 8; docs/architecture.md)
    rr_depth: int = 5
    #: "mis" (light + BSDF sampling, MIS-weighted), "light" (next-event estimation alone) or
    #: "bsdf" (BSDF sampling alone for area sources; delta lights are always sampled)
    strategy: str = "mis"
    #: MIS weights: "power" or "balance" (Veach and Guibas)
    heuristic: str = "power"
    #: random numbers: "sobol-blocks" (one Owen-scrambled Sobol sequence per pixel, model
    #: variance: render.film.blocks_variance; the default), "sobol" (R interleaved replicates,
    #: model-free variance) or "independent" (hash)
    sampler: str = "sobol-blocks"

    def __post_init__(self):
        check_strategy(self.strategy)
        check_heuristic(self.heuristic)
        check_sampler(self.sampler)
        if self.rr_depth < 0:
            raise ValueError(f"path: rr_depth must be >= 0, got {self.rr_depth}")


def kernel_scene_of(ps: PreparedScene) -> KernelScene:
    """``ps`` packed for the compiled kernels (built once, kept in ``ps.kernel``)."""
    if ps.kernel is None:
        emit_ids = ps.emit_accel.ids if ps.emit_accel is not None else np.zeros(0, np.int64)
        ps.kernel = kernel_scene(ps.geom, ps.mats, ps.lights, ps.accel.ids, emit_ids, ps.background)
    return ps.kernel


def path_config(ps: PreparedScene, max_depth: int, strategy: str, heuristic: str, roulette: bool, rr_depth: int,
                direct: bool, caustics: bool, sampler: str = "independent") -> PathConfig:
    """The kernels' :class:`render.integrators.path_kernels.PathConfig` for ``ps`` (roulette is
    ignored when ``direct``: its paths end at the first diffuse vertex; sampler: a name of
    render.sobol.SAMPLERS)."""
    lights = ps.lights
    has_bg = bool(ps.background.max() > 0)
    nee_area = strategy != "bsdf" and lights.has_area
    return PathConfig(
        max_depth=int(max_depth), direct=bool(direct), caustics=bool(caustics), strategy=_STRATEGY_CODES[strategy],
        mis_exponent=heuristic_exponent(heuristic), roulette=bool(roulette and not direct), rr_depth=int(rr_depth),
        has_bg=has_bg, nee_area=bool(nee_area), nee_any=bool(nee_area or lights.has_delta),
        mis_on_hits=bool(lights.has_area and strategy != "bsdf"),
        continue_diffuse=not (direct and strategy == "light" and not has_bg), has_area=bool(lights.has_area),
        sampler=SAMPLERS[sampler])


def pinhole_of(cam: Camera) -> PinholeCamera:
    """The kernels' :class:`render.integrators.path_kernels.PinholeCamera` of ``cam``."""
    k = cam.intrinsics
    c2w = np.asarray(cam.cam_to_world, dtype=np.float64)
    return PinholeCamera(float(k.fx), float(k.fy), float(k.cx), float(k.cy),
                         np.ascontiguousarray(c2w[:3, :3]), np.ascontiguousarray(c2w[:3, 3]))


def _state_buffers(n: int) -> tuple:
    """A wavefront state: [slot, RNG key, throughput (3), pdf, flags, ray origin (3) f32, ray direction (3) f32]."""
    return (np.empty(n, np.int64), np.empty(n, np.uint64), np.empty((n, 3)), np.empty(n), np.empty(n, np.uint8),
            np.empty((n, 3), np.float32), np.empty((n, 3), np.float32))


def _queue_buffers(n: int) -> tuple:
    """A shadow-ray queue: origin, direction, tmax (float32, as Embree reads them), path slot, contribution."""
    return (np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32),
            np.empty(n, np.int64), np.empty((n, 3)))


def _last_ray_buffers(n: int) -> tuple:
    """`direct`'s last BSDF rays: origin, direction (float32), throughput, pdf, path slot."""
    return (np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 3)), np.empty(n),
            np.empty(n, np.int64))


def _trace(ps: PreparedScene, cam: Camera, cfg: PathConfig, seed: int, query_emitters: bool,
           start: int, stop: int, sample0: int, replicates: int = REPLICATES,
           kern=None, shuffle: int = 0) -> tuple[np.ndarray, np.ndarray, int]:
    """Trace the camera samples of flat indices [start, stop) (flat = (sample - sample0) * H * W
    + pixel); replicates: the Sobol sampler's R (render.sobol.replicates_for), shuffle its
    render.sobol.shuffle_bits. Returns ((N,) int64 pixels, (N, 3) float64 radiance, rays traced).

    Wavefront: each bounce is one Embree call for all live paths, one compiled shading pass
    (:func:`render.integrators.path_kernels.shade_bounce`) that also writes the next rays and
    the shadow rays, then one occlusion call for every shadow ray of the bounce (next-event
    estimation and, for `direct`, the last BSDF rays, first traced against the emitter-only BVH
    when ``query_emitters``).
    kern: the kernels (:func:`render.path_aot.for_scene`; default: those for ``ps``).
    """
    ks = kernel_scene_of(ps)
    kern = kern or for_scene(ks)
    accel = ps.accel
    k = cam.intrinsics
    n = stop - start
    npix = k.width * k.height
    # double-buffered (current, next) and reused across bounces
    cur, nxt = _state_buffers(n), _state_buffers(n)
    q = _queue_buffers(2 * n if cfg.direct else n)
    last = _last_ray_buffers(n if cfg.direct else 0)
    pix = np.empty(n, np.int64)
    jit = np.empty((n, 2))
    seed_mix = _mix64(np.array([np.uint64(seed & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    pinhole = not k.has_distortion
    kern.sample_camera_rays(start, stop, npix, k.width, sample0, seed_mix, pinhole_of(cam), pinhole, cur[1], pix,
                            cur[5], cur[6], jit, cfg.sampler, replicates, shuffle)
    if not pinhole:
        o, d = cam.pixel_rays(jit)
        cur[5][:], cur[6][:] = o, d
    cur[0][:] = np.arange(n)
    cur[2][:] = 1.0
    cur[3][:] = 0.0
    cur[4][:] = F_DELTA  # the camera ray counts as specular: emission seen directly has weight 1
    L = np.zeros((n, 3))
    no_hits = (np.zeros(0, np.int32), np.zeros(0, np.float32))
    nrays = 0
    m = n
    for depth in range(cfg.max_depth + 1):
        if m == 0:
            break
        idx, keys, beta, pdf, flags, o32, d32 = (a[:m] for a in cur)
        prim, tfar, hu, hv = accel.intersect_fast(o32, d32)
        nrays += m
        nn, nq, nl = kern.shade_bounce(ks, cfg, depth, prim, tfar, hu, hv, idx, keys, beta, d32, pdf, flags, L,
                                       *nxt, *q, *last)
        if nl:
            l_o32, l_d32 = last[0][:nl], last[1][:nl]
            ehits = no_hits
            if query_emitters:
                ehits = ps.emit_accel.intersect_fast(l_o32, l_d32)[:2]
                nrays += nl
            nq = kern.last_bounce_queue(ks, cfg, nl, ehits[0], ehits[1], last[2], last[3], last[4],
                                        l_o32, l_d32, nq, *q)
        if nq:
            occ = accel.occluded_fast(q[0][:nq], q[1][:nq], q[2][:nq])
            nrays += nq
            kern.add_unoccluded(L, q[3], q[4], occ)
        cur, nxt, m = nxt, cur, nn
    return pix, L, nrays


def trace_view(scene: Scene, camera: Camera, settings: RenderSettings, options, sample_range: tuple[int, int],
               effects: frozenset, ps: PreparedScene, progress, direct: bool) -> RenderResult:
    """The wavefront driver of ``path`` and ``direct``: batches of ``settings.batch_paths`` camera
    samples over ``settings.threads`` threads, accumulated in batch order (the same sums
    whatever the threads). options: a path or direct ``Options`` (an options type without
    ``sampler`` gets the independent sampler). The Sobol samplers' film also keeps per-replicate
    (or per-block, "sobol-blocks") sums (:class:`render.film.Film`), so its variance image is the
    replicates'."""
    t0 = time.perf_counter()
    a, b = sample_range
    roulette, rr_depth = (False, 0) if direct else (options.roulette, options.rr_depth)
    sampler = getattr(options, "sampler", "independent")
    cfg = path_config(ps, settings.max_depth, options.strategy, options.heuristic, roulette, rr_depth, direct,
                      "caustics" in effects, sampler)
    query_emitters = direct and ps.emit_accel is not None and options.strategy != "light"
    k = camera.intrinsics
    total = k.width * k.height * (b - a)
    chunks = [(c, min(c + settings.batch_paths, total)) for c in range(0, total, settings.batch_paths)]
    kern = for_scene(kernel_scene_of(ps))  # the AOT extension's kernels, or numba's
    replicates = replicates_for(settings.spp)  # of the variance estimate
    block = block_size(sampler, settings.spp)  # 0: interleaved replicates, else consecutive blocks
    keys_r = key_replicates(sampler, settings.spp)  # 1 under "sobol-blocks": one sequence per pixel
    shuffle = shuffle_bits(sampler, settings.spp)

    def work(chunk):
        return _trace(ps, camera, cfg, settings.seed, query_emitters, chunk[0], chunk[1], a, keys_r, kern, shuffle)

    film = Film(k.width, k.height)
    npix = k.width * k.height
    if cfg.sampler == SAMPLER_SOBOL:
        film.r1 = np.zeros((replicates, npix, 3))
        film.rn = np.bincount(replicate_of(np.arange(a, b), replicates, block), minlength=replicates).astype(np.int64)
        film.blocks = block > 0  # blocks of one sequence: the model variance (render.film.blocks_variance)
    rays = 0
    pool = ThreadPoolExecutor(settings.threads) if settings.threads > 1 and len(chunks) > 1 else None
    try:
        results = pool.map(work, chunks) if pool is not None else map(work, chunks)
        for ch, (pix, L, nr) in zip(chunks, results):  # in chunk order: the same sums whatever the threads
            kern.accumulate(film.s1, film.s2, film.n, pix, L)
            if film.r1 is not None:
                kern.accumulate_replicates(film.r1, ch[0], npix, a, L, block)
            rays += nr
            if progress is not None:
                progress(ch[1], total)
    finally:
        if pool is not None:
            pool.shutdown()
    stats = {"time_s": time.perf_counter() - t0, "paths": int(total), "rays": int(rays)}
    return RenderResult.from_film(film, (a, b), "direct" if direct else "path", stats)


def render_result(scene: Scene, camera: Camera, settings: RenderSettings, options: Options,
                  sample_range: tuple[int, int], effects: frozenset, prepared: PreparedScene,
                  progress=None) -> RenderResult:
    """Render samples [a, b) = ``sample_range`` of ``camera``'s view by path tracing (the
    registry's interface: :func:`render.integrators.render` calls it). progress: optional
    ``progress(done_paths, total_paths)`` after each batch."""
    return trace_view(scene, camera, settings, options, sample_range, effects, prepared, progress, direct=False)
