"""Reference Monte Carlo path tracer: wavefront, unbiased, with NEE, MIS and Russian roulette.

Every model in lumigraph is judged against this renderer. It estimates the measurement

    I_pixel = 1/|pixel| \\int_pixel L(x_cam, w(x)) dx            (box filter)

with L expanded recursively by the rendering equation. Paths are traced *wavefront*: an array
of live paths, each bounce one Embree query for all of them, one compiled shading pass over the
hits (:mod:`render.pt_kernels`, numba; it writes the next rays and the shadow rays as the
float32 arrays Embree reads and compacts finished paths away), one occlusion query for all
shadow rays. Embree is called from compiled code through the library embreex ships
(:mod:`render.embree_direct`), or through embreex's batch API when that library is not found.
There is no Python loop per ray or per pixel; the kernels release the GIL, so the ``threads``
render threads (one batch of ``batch_paths`` camera samples each) trace and shade in parallel.
The numpy BSDFs (:mod:`render.bsdf`), light sampling (:mod:`render.lights`) and warps
(:mod:`render.sampling`) remain the reference interfaces for other integrators; the kernels
implement the same formulas and tests compare them.

Integrators (Heckbert's notation; see render.effects):

* ``direct``: L D E and L D S* E / L S* E: camera rays follow mirror and glass, and at the
  first diffuse vertex light is gathered by next-event estimation and / or one BSDF sample
  (combined by MIS); that last BSDF ray is traced against an emitter-only BVH plus one
  occlusion query. Reaches effects direct, shadows, soft_shadows, specular.
* ``path``: L (S|D)* E with NEE + MIS at every diffuse vertex and Russian roulette: adds
  interreflection and caustics from area sources (found by BSDF sampling). Caustics from
  point, spot and directional lights are unreachable (a delta light through a delta BSDF):
  asking for them is an error, never a silent omission.
* ``volpath`` (:mod:`render.volpath`, numpy): the path integrator plus participating media
  (delta tracking, NEE through media by ratio tracking) and GGX microfacet surfaces
  (:mod:`render.microfacet`), which the compiled kernels do not shade: ``auto`` picks it when
  the scene has media (effect ``media``) or glossy materials, and only then (it is slower).
* ``sppm`` (:mod:`render.sppm`, numpy): stochastic progressive photon mapping (Hachisuka and
  Jensen 2009) for caustics (L S+ D E) that path tracing finds only by chance: direct light by
  next-event estimation at each pixel's visible point, everything else from photons. Consistent,
  not unbiased: ``spp`` is the number of passes, ``photons_per_pass`` the photons per pass,
  split into independent groups of passes whose spread is the variance image (noise, not the
  blur bias they share); a sample range must hold whole groups (no refine). Reaches caustics
  from point, spot and directional lights too. Never chosen by ``auto``; no media, no GGX
  materials.
* ``bdpt`` (:mod:`render.bdpt`, numpy): bidirectional path tracing with every (s, t) strategy
  (light tracing to the camera included), power-heuristic MIS; ``auto`` picks it for caustics
  from point, spot and directional lights. No media, no GGX materials.
* ``pssmlt`` (:mod:`render.pssmlt`, numpy): Metropolis light transport in primary sample space
  over a path sampler; ``spp`` is mutations per pixel; its variance comes from independent
  groups of chains, and a sample range must hold whole groups (no refine). Never chosen by
  ``auto``; no media, no GGX materials.

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

A render is a pure function of (scene, camera, settings, sample range): random numbers are a
hash of (seed, pixel, sample index, dimension) (:mod:`render.sampling`), so renders of disjoint
sample ranges merge exactly (:func:`render.film.merge_results`) and :func:`refine` adds samples
(sppm and pssmlt: ranges of whole independent groups, :func:`work_units`).

Usage (what ``lumigraph reference`` calls)::

    ps = prepare(scene)                                   # BVHs, lights, materials: once per scene
    res = render(scene, camera, RenderSettings(integrator="auto", spp=256, seed=0), prepared=ps)
    res.mean, res.variance                                # (H, W, 3) float32 radiance, its variance
    res = refine(res, scene, camera, settings, 256, prepared=ps)   # 256 more samples
    part = render(scene, camera, settings, sample_range=(256, 512))  # a batch for another worker
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from .accel import Accel, Geometry
from .bsdf import MaterialTable
from .camera import Camera
from .effects import scene_effects
from .film import Film, RenderResult, merge_results
from .lights import LightSet
from .pt_kernels import (F_DELTA, STRAT_BSDF, STRAT_LIGHT, STRAT_MIS, KernelScene, accumulate, add_unoccluded,
                         camera_rays, kernel_scene, last_bounce_queue, shade_bounce)
from .sampling import _GOLDEN, _mix64
from .scene import DirectionalLight, PointLight, Scene, SpotLight

__all__ = [
    "RenderSettings", "PreparedScene", "prepare", "choose_integrator", "render", "refine", "work_units",
    "INTEGRATOR_EFFECTS",
]

#: light-transport effects each integrator reaches (sensor effects are applied downstream)
INTEGRATOR_EFFECTS = {
    "direct": frozenset({"direct", "shadows", "soft_shadows", "specular"}),
    "path": frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics"}),
    "volpath": frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics", "media"}),
    "sppm": frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics"}),
    "bdpt": frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics"}),
    "pssmlt": frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics"}),
}
#: integrators implemented in their own modules, each exposing render_result(scene, camera, settings,
#: sample_range, effects, prepared) -> RenderResult
_MODULE_INTEGRATORS = frozenset({"sppm", "bdpt", "pssmlt"})
#: integrators whose samples are not independent: a render splits into independent groups (each
#: module's GROUPS; render.film.group_ranges), and a unit of work is a run of whole groups
_GROUPED_INTEGRATORS = frozenset({"sppm", "pssmlt"})
#: integrators that trace light subpaths, and so reach caustics from point/spot/directional lights
_LIGHT_TRACING = frozenset({"sppm", "bdpt"})
_TRANSPORT = frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics", "media"})
#: random dimensions per bounce (render.pt_kernels.shade_bounce): light pick, light uv (2), lobe, bsdf uv (2),
#: roulette, spare; camera jitter takes dimensions 0 and 1
_DIMS_PER_BOUNCE = 8


@dataclass(frozen=True)
class RenderSettings:
    """How to render.

    integrator: "auto" (chosen from the scene's effects), "direct", "path", "volpath", "bdpt"
    (render.bdpt), "pssmlt" (render.pssmlt) or "sppm" (render.sppm). spp: samples per pixel when
    no sample range is given (sppm: passes; pssmlt: mutations per pixel on average).
    max_depth: maximum bounces. photons_per_pass: photons emitted per sppm pass (sppm only;
    None: the view's pixel count, pbrt-v3's default for its SPPM, so the photon work follows the
    image like the eye pass does).
    roulette / rr_depth: Russian roulette when leaving vertices of index >= rr_depth.
    seed: the render's seed. strategy: "mis" (light + BSDF sampling, MIS-weighted), "light"
    (next-event estimation only) or "bsdf" (BSDF sampling only for area sources; delta lights
    are always sampled). heuristic: "power" or "balance" (Veach and Guibas).
    threads: worker threads. batch_paths: camera samples per wavefront batch. Neither changes
    a render's bytes (samples are summed per pixel in sample order).
    """

    integrator: str = "auto"
    spp: int = 16
    max_depth: int = 8
    roulette: bool = True
    rr_depth: int = 3
    seed: int = 0
    strategy: str = "mis"
    heuristic: str = "power"
    threads: int = 2
    batch_paths: int = 1 << 16
    photons_per_pass: int | None = None

    def __post_init__(self):
        if self.integrator not in ("auto", *INTEGRATOR_EFFECTS):
            raise ValueError(f"integrator must be auto or one of {', '.join(INTEGRATOR_EFFECTS)}, "
                             f"got {self.integrator!r}")
        if self.strategy not in ("mis", "light", "bsdf"):
            raise ValueError(f"strategy must be mis, light or bsdf, got {self.strategy!r}")
        if self.heuristic not in ("power", "balance"):
            raise ValueError(f"heuristic must be power or balance, got {self.heuristic!r}")
        if self.spp < 1 or self.max_depth < 0 or self.rr_depth < 0 or self.threads < 1 or self.batch_paths < 1:
            raise ValueError("spp, threads and batch_paths must be >= 1; max_depth, rr_depth >= 0")
        if self.photons_per_pass is not None and self.photons_per_pass < 1:
            raise ValueError(f"photons_per_pass must be >= 1, got {self.photons_per_pass}")


#: emitters subtending less than this solid angle (sr) from the scene's centre make caustics hard
#: for path tracing. bench_hard_paths' source-size sweep (glass ball under a square source 2.35 m
#: from the scene's centre, same power) measured bdpt's equal-time image RMSE at 2.8x path's for
#: sources of 0.4 and 0.2 m (0.029, 0.0072 sr; in the caustic alone 0.63x, 0.27x) and 0.14x for
#: 0.1 m (0.0018 sr): the threshold sits between the last two, at their geometric mean
SMALL_SOURCE_SR = 0.0036


def choose_integrator(effects, requested: str = "auto", has_delta_lights: bool = False,
                      glossy: bool = False, small_sources: bool = False) -> str:
    """The cheapest integrator covering ``effects`` (a set of effect names) and nothing more.

    ``auto``: "volpath" when media are needed or the scene has GGX materials (``glossy``: the
    compiled kernels do not shade them), else "direct" unless interreflection or caustics are
    needed, then "path", or "bdpt" when the caustics come from point/spot/directional lights
    (a delta light seen through a delta BSDF: only light tracing reaches it, and bdpt is the
    unbiased integrator that does; sppm is consistent only and never chosen by auto) or from
    ``small_sources`` (every area emitter below SMALL_SOURCE_SR: path finds their caustics only
    when a BSDF sample happens to hit them, bdpt's light subpaths do not depend on size). A
    requested integrator that cannot reach an effect (or shade a glossy material) raises
    ValueError naming it, as do delta-light caustics asked of an eye-path-only integrator.
    """
    eff = frozenset(effects) & _TRANSPORT
    if (requested == "auto" and "caustics" in eff and (has_delta_lights or small_sources)
            and not (glossy or "media" in eff)):
        return "bdpt"
    if glossy and requested not in ("auto", "volpath"):
        raise ValueError(f"integrator '{requested}' cannot shade glossy (GGX) materials; use 'volpath' or 'auto'")
    if "caustics" in eff and has_delta_lights and requested not in _LIGHT_TRACING:
        raise ValueError("effect 'caustics' with point/spot/directional lights is unreachable by a path "
                         "tracer (a delta light seen through a delta BSDF); use area lights, integrator "
                         "'bdpt' or 'sppm', or drop 'caustics' from the scene's effects")
    if requested == "auto":
        if "media" in eff or glossy:
            return "volpath"
        return "path" if eff & {"interreflection", "caustics"} else "direct"
    if requested not in INTEGRATOR_EFFECTS:
        raise ValueError(f"unknown integrator {requested!r}; known: auto, {', '.join(INTEGRATOR_EFFECTS)}")
    missing = sorted(eff - INTEGRATOR_EFFECTS[requested])
    if missing:
        raise ValueError(f"integrator '{requested}' cannot reach effect '{missing[0]}' "
                         f"(needed: {sorted(eff)}); use 'auto'")
    return requested


@dataclass
class PreparedScene:
    """A scene's BVH, triangle arrays, material table and light distribution (reusable).

    emit_accel: a BVH over the emissive triangles alone: `direct` finds what its last BSDF ray
    could hit there first, and asks the full BVH only an occlusion query up to that emitter.
    kernel: the same scene packed as flat arrays for the compiled kernels (built on first use).
    """

    geom: Geometry
    accel: Accel
    mats: MaterialTable
    lights: LightSet
    background: np.ndarray
    has_delta_lights: bool
    emit_accel: Accel | None = None
    kernel: KernelScene | None = None
    #: largest solid angle (sr) an area emitter subtends from the scene's centre (0: none)
    emitter_solid_angle: float = 0.0

    @property
    def small_sources(self) -> bool:
        """Area emitters exist and each subtends less than SMALL_SOURCE_SR."""
        return 0.0 < self.emitter_solid_angle < SMALL_SOURCE_SR

    def choose(self, effects, requested: str = "auto") -> str:
        """:func:`choose_integrator` with this scene's lights and materials."""
        return choose_integrator(effects, requested, self.has_delta_lights, self.mats.has_glossy, self.small_sources)


def emitter_solid_angle(geom: Geometry, mats: MaterialTable) -> float:
    """Largest A / d^2 over emissive objects: A the object's area, d the distance from its
    area-weighted centre to the centre of the bounding box of everything that does not emit.
    A / d^2 bounds the solid angle of any shape's projection (a sphere's is a quarter of it)."""
    if len(geom.obj) == 0:
        return 0.0
    emit = mats.emits[geom.obj] & geom.valid
    if not emit.any() or emit.all():
        return 0.0
    rest = np.concatenate([geom.v0[~emit], (geom.v0 + geom.e1)[~emit], (geom.v0 + geom.e2)[~emit]])
    centre = 0.5 * (rest.min(axis=0) + rest.max(axis=0))
    best = 0.0
    for k in np.unique(geom.obj[emit]):
        t = emit & (geom.obj == k)
        a = geom.area[t]
        c = ((geom.v0[t] + (geom.e1[t] + geom.e2[t]) / 3.0) * a[:, None]).sum(axis=0) / max(a.sum(), 1e-300)
        d2 = float(np.sum((c - centre) ** 2))
        best = max(best, min(2.0 * np.pi, float(a.sum()) / max(d2, 1e-300)))
    return best


def prepare(scene: Scene, threads: int = 2) -> PreparedScene:
    """Build everything a render of ``scene`` needs once (reuse it across views and refinements)."""
    geom = Geometry.from_scene(scene)
    accel = Accel(scene, threads=threads, geometry=geom)
    mats = MaterialTable.from_scene(scene)
    lights = LightSet(scene, geom, mats)
    delta = any(isinstance(l, (PointLight, SpotLight, DirectionalLight)) for l in scene.lights)
    emitters = mats.emits[geom.obj] if len(geom.obj) else np.zeros(0, bool)
    emit_accel = Accel(scene, threads=1, geometry=geom, subset=emitters) if emitters.any() else None
    return PreparedScene(geom, accel, mats, lights, np.asarray(scene.background, np.float64), delta, emit_accel,
                         emitter_solid_angle=emitter_solid_angle(geom, mats))


def _kernel_scene(ps: PreparedScene) -> KernelScene:
    if ps.kernel is None:
        emit_ids = ps.emit_accel.ids if ps.emit_accel is not None else np.zeros(0, np.int64)
        ps.kernel = kernel_scene(ps.geom, ps.mats, ps.lights, ps.accel.ids, emit_ids, ps.background)
    return ps.kernel


def _config(ps: PreparedScene, st: RenderSettings, integ: str, caustics: bool) -> np.ndarray:
    """The (16,) float64 settings vector of :func:`render.pt_kernels.shade_bounce`."""
    lights = ps.lights
    has_bg = bool(ps.background.max() > 0)
    direct = integ == "direct"
    nee_area = st.strategy != "bsdf" and lights.has_area
    cfg = np.zeros(16)
    cfg[:13] = [st.max_depth, direct, caustics, {"mis": STRAT_MIS, "light": STRAT_LIGHT, "bsdf": STRAT_BSDF}[st.strategy],
                2.0 if st.heuristic == "power" else 1.0, integ == "path" and st.roulette, st.rr_depth, has_bg,
                nee_area, nee_area or lights.has_delta, lights.has_area and st.strategy != "bsdf",
                not (direct and st.strategy == "light" and not has_bg), lights.has_area]
    return cfg


def _camera_vector(cam: Camera) -> np.ndarray:
    """(16,) float64 [fx, fy, cx, cy, R row-major (9), t (3)] of a camera-to-world pinhole."""
    k = cam.intrinsics
    c2w = np.asarray(cam.cam_to_world, dtype=np.float64)
    return np.concatenate([[k.fx, k.fy, k.cx, k.cy], c2w[:3, :3].ravel(), c2w[:3, 3]])


def _state_buffers(n: int) -> tuple:
    return (np.empty(n, np.int64), np.empty(n, np.uint64), np.empty((n, 3)), np.empty(n), np.empty(n, np.uint8),
            np.empty((n, 3), np.float32), np.empty((n, 3), np.float32))


def _queue_buffers(n: int) -> tuple:
    return (np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32),
            np.empty(n, np.int64), np.empty((n, 3)))


def _trace(ps: PreparedScene, cam: Camera, st: RenderSettings, integ: str, cfg: np.ndarray,
           start: int, stop: int, sample0: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Trace the camera samples of flat indices [start, stop) (flat = (sample - sample0) * H * W
    + pixel). Returns ((N,) int64 pixels, (N, 3) float64 radiance, rays traced).

    Wavefront: each bounce is one Embree call for all live paths, one compiled shading pass
    (:func:`render.pt_kernels.shade_bounce`) that also writes the next rays and the shadow
    rays, then one occlusion call for every shadow ray of the bounce (next-event estimation
    and, for `direct`, the last BSDF rays).
    """
    ks = _kernel_scene(ps)
    accel = ps.accel
    k = cam.intrinsics
    n = stop - start
    npix = k.width * k.height
    direct = integ == "direct"
    # wavefront state, double-buffered (current, next) and reused across bounces:
    # [slot, RNG key, throughput (3), pdf, flags, ray origin (3) f32, ray direction (3) f32]
    cur, nxt = _state_buffers(n), _state_buffers(n)
    q = _queue_buffers(2 * n if direct else n)  # shadow rays: origin, dir, tmax, slot, contribution
    last = (np.empty((n if direct else 0, 3), np.float32), np.empty((n if direct else 0, 3), np.float32),
            np.empty((n if direct else 0, 3)), np.empty(n if direct else 0), np.empty(n if direct else 0, np.int64))
    pix = np.empty(n, np.int64)
    jit = np.empty((n, 2))
    seed_mix = _mix64(np.array([np.uint64(st.seed & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    pinhole = not k.has_distortion
    camera_rays(start, stop, npix, k.width, sample0, seed_mix, _camera_vector(cam), pinhole, cur[1], pix,
                cur[5], cur[6], jit)
    if not pinhole:
        o, d = cam.pixel_rays(jit)
        cur[5][:], cur[6][:] = o, d
    cur[0][:] = np.arange(n)
    cur[2][:] = 1.0
    cur[3][:] = 0.0
    cur[4][:] = F_DELTA  # the camera ray counts as specular: emission seen directly has weight 1
    L = np.zeros((n, 3))
    query_emitters = direct and ps.emit_accel is not None and st.strategy != "light"
    no_hits = (np.zeros(0, np.int32), np.zeros(0, np.float32))
    nrays = 0
    m = n
    for depth in range(st.max_depth + 1):
        if m == 0:
            break
        idx, keys, beta, pdf, flags, o32, d32 = (a[:m] for a in cur)
        prim, tfar, hu, hv = accel.intersect_fast(o32, d32)
        nrays += m
        nn, nq, nl = shade_bounce(ks, cfg, depth, prim, tfar, hu, hv, idx, keys, beta, d32, pdf, flags, L,
                                  *nxt, *q, *last)
        if nl:
            l_o32, l_d32 = last[0][:nl], last[1][:nl]
            ehits = no_hits
            if query_emitters:
                ehits = ps.emit_accel.intersect_fast(l_o32, l_d32)[:2]
                nrays += nl
            nq = last_bounce_queue(ks, cfg, nl, ehits[0], ehits[1], last[2], last[3], last[4], l_o32, l_d32, nq, *q)
        if nq:
            occ = accel.occluded_fast(q[0][:nq], q[1][:nq], q[2][:nq])
            nrays += nq
            add_unoccluded(L, q[3], q[4], occ)
        cur, nxt, m = nxt, cur, nn
    return pix, L, nrays


def render(scene: Scene, camera: Camera, settings: RenderSettings = RenderSettings(),
           sample_range: tuple[int, int] | None = None, effects=None,
           prepared: PreparedScene | None = None, progress=None) -> RenderResult:
    """Render ``camera``'s view of ``scene``: mean radiance and its per-pixel variance.

    sample_range: half-open range of sample indices [a, b) (default [0, settings.spp)); renders
    of disjoint ranges merge exactly. effects: the effects to simulate (default:
    :func:`render.effects.scene_effects`); the integrator is chosen from them when
    ``settings.integrator == "auto"``. Caustic paths are dropped when 'caustics' is not among
    them. prepared: a :class:`PreparedScene` from :func:`prepare` to reuse. progress: optional
    callable ``progress(done_paths, total_paths)`` called after each batch (e.g. a rich bar).
    Returns a :class:`render.film.RenderResult` (mean and variance (H, W, 3) float32).
    """
    t0 = time.perf_counter()
    eff = scene_effects(scene) if effects is None else frozenset(effects)
    ps = prepared if prepared is not None else prepare(scene, threads=settings.threads)
    integ = ps.choose(eff, settings.integrator)
    if integ == "volpath":
        from .volpath import render_volpath
        return render_volpath(scene, camera, settings, sample_range, eff, ps)
    if integ in _MODULE_INTEGRATORS:
        import importlib
        module = importlib.import_module(f".{integ}", __package__)
        return module.render_result(scene, camera, settings, sample_range, eff, ps)
    caustics = "caustics" in eff
    a, b = (0, settings.spp) if sample_range is None else (int(sample_range[0]), int(sample_range[1]))
    if not 0 <= a < b:
        raise ValueError(f"sample_range must satisfy 0 <= start < stop, got {(a, b)}")
    k = camera.intrinsics
    npix = k.width * k.height
    total = npix * (b - a)
    chunks = [(c, min(c + settings.batch_paths, total)) for c in range(0, total, settings.batch_paths)]
    cfg = _config(ps, settings, integ, caustics)
    _kernel_scene(ps)

    def work(chunk):
        return _trace(ps, camera, settings, integ, cfg, chunk[0], chunk[1], a)

    film = Film(k.width, k.height)
    rays = 0
    pool = ThreadPoolExecutor(settings.threads) if settings.threads > 1 and len(chunks) > 1 else None
    try:
        results = pool.map(work, chunks) if pool is not None else map(work, chunks)
        for ch, (pix, L, nr) in zip(chunks, results):  # in chunk order: the same sums whatever the threads
            accumulate(film.s1, film.s2, film.n, pix, L)
            rays += nr
            if progress is not None:
                progress(ch[1], total)
    finally:
        if pool is not None:
            pool.shutdown()
    stats = {"time_s": time.perf_counter() - t0, "paths": int(total), "rays": int(rays)}
    return RenderResult.from_film(film, (a, b), integ, stats)


def work_units(integrator: str, spp: int, batch: int) -> list[tuple[int, int]]:
    """The half-open sample ranges, in sample order, that a render of ``spp`` samples with
    ``integrator`` (a chosen one, not "auto") splits into as independent units of work: runs of
    ``batch`` samples, or for sppm and pssmlt their independent groups
    (:func:`render.film.group_ranges`). Renders of the units merge, in this order, to the same
    bytes wherever they ran (render.film.merge_results; the ``reference`` stage's fold)."""
    spp, batch = int(spp), int(batch)
    if spp < 1 or batch < 1:
        raise ValueError(f"spp and batch must be >= 1, got {spp}, {batch}")
    if integrator in _GROUPED_INTEGRATORS:
        import importlib
        from .film import group_ranges
        return group_ranges(spp, importlib.import_module(f".{integrator}", __package__).GROUPS)
    return [(a, min(a + batch, spp)) for a in range(0, spp, batch)]


def refine(result: RenderResult, scene: Scene, camera: Camera, settings: RenderSettings,
           extra_spp: int, effects=None, prepared: PreparedScene | None = None, progress=None) -> RenderResult:
    """Progressive rendering: add ``extra_spp`` samples after ``result``'s range and merge."""
    a = result.sample_range[1]
    more = render(scene, camera, replace(settings, integrator=result.integrator), (a, a + int(extra_spp)),
                  effects, prepared, progress)
    return merge_results(result, more)
