"""Reference Monte Carlo path tracer: wavefront, unbiased, with NEE, MIS and Russian roulette.

Every model in lumigraph is judged against this renderer. It estimates the measurement

    I_pixel = 1/|pixel| \\int_pixel L(x_cam, w(x)) dx            (box filter)

with L expanded recursively by the rendering equation. Paths are traced *wavefront*: an array
of live paths, each bounce one Embree call for all of them, shading vectorized over the hits,
finished paths compacted away. There is no Python loop per ray or per pixel.

Integrators (Heckbert's notation; see render.effects):

* ``direct``: L D E and L D S* E / L S* E: camera rays follow mirror and glass, and at the
  first diffuse vertex light is gathered by next-event estimation and / or one BSDF sample
  (combined by MIS); that last BSDF ray is traced against an emitter-only BVH plus one
  occlusion query. Reaches effects direct, shadows, soft_shadows, specular.
* ``path``: L (S|D)* E with NEE + MIS at every diffuse vertex and Russian roulette: adds
  interreflection and caustics from area sources (found by BSDF sampling). Caustics from
  point, spot and directional lights are unreachable (a delta light through a delta BSDF):
  asking for them is an error, never a silent omission; so is ``media``.

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
sample ranges merge exactly (:func:`render.film.merge_results`) and :func:`refine` adds samples.

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

from .accel import Accel, Geometry, offset_eps, spawn_origin
from .bsdf import DIELECTRIC, EMISSIVE, LAMBERT, MIRROR, MaterialTable, bsdf_sample
from .camera import Camera
from .effects import scene_effects
from .film import Film, RenderResult, merge_results
from .lights import LightSet
from .sampling import (INV_PI, cosine_hemisphere, mis_weight, orthonormal_frame, path_keys, to_local, to_world,
                       uniform_block, dot3, max3)
from .scene import DirectionalLight, PointLight, Scene, SpotLight

__all__ = [
    "RenderSettings", "PreparedScene", "prepare", "choose_integrator", "render", "refine",
    "INTEGRATOR_EFFECTS",
]

#: light-transport effects each integrator reaches (sensor effects are applied downstream)
INTEGRATOR_EFFECTS = {
    "direct": frozenset({"direct", "shadows", "soft_shadows", "specular"}),
    "path": frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics"}),
}
_TRANSPORT = frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics", "media"})
_DIMS_PER_BOUNCE = 8  # random dimensions per bounce: light pick, light uv (2), lobe, bsdf uv (2), roulette, spare


@dataclass(frozen=True)
class RenderSettings:
    """How to render.

    integrator: "auto" (chosen from the scene's effects), "direct" or "path".
    spp: samples per pixel when no sample range is given. max_depth: maximum bounces.
    roulette / rr_depth: Russian roulette when leaving vertices of index >= rr_depth.
    seed: the render's seed. strategy: "mis" (light + BSDF sampling, MIS-weighted), "light"
    (next-event estimation only) or "bsdf" (BSDF sampling only for area sources; delta lights
    are always sampled). heuristic: "power" or "balance" (Veach and Guibas).
    threads: worker threads. batch_paths: camera samples per wavefront batch.
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
    batch_paths: int = 1 << 14

    def __post_init__(self):
        if self.integrator not in ("auto", "direct", "path"):
            raise ValueError(f"integrator must be auto, direct or path, got {self.integrator!r}")
        if self.strategy not in ("mis", "light", "bsdf"):
            raise ValueError(f"strategy must be mis, light or bsdf, got {self.strategy!r}")
        if self.heuristic not in ("power", "balance"):
            raise ValueError(f"heuristic must be power or balance, got {self.heuristic!r}")
        if self.spp < 1 or self.max_depth < 0 or self.rr_depth < 0 or self.threads < 1 or self.batch_paths < 1:
            raise ValueError("spp, threads and batch_paths must be >= 1; max_depth, rr_depth >= 0")


def choose_integrator(effects, requested: str = "auto", has_delta_lights: bool = False) -> str:
    """The integrator covering ``effects`` (a set of effect names) and nothing more.

    ``auto``: "direct" unless interreflection or caustics are needed, then "path". A requested
    integrator that cannot reach an effect raises ValueError naming the effect, as do ``media``
    and caustics with point/spot/directional lights (unreachable by any integrator here).
    """
    eff = frozenset(effects) & _TRANSPORT
    if "media" in eff:
        raise ValueError("effect 'media' is not reachable by the path tracer yet (no participating media)")
    if "caustics" in eff and has_delta_lights:
        raise ValueError("effect 'caustics' with point/spot/directional lights is unreachable by a path "
                         "tracer (a delta light seen through a delta BSDF); use area lights or drop "
                         "'caustics' from the scene's effects")
    if requested == "auto":
        return "path" if eff & {"interreflection", "caustics"} else "direct"
    if requested not in INTEGRATOR_EFFECTS:
        raise ValueError(f"unknown integrator {requested!r}; known: auto, {', '.join(INTEGRATOR_EFFECTS)}")
    missing = sorted(eff - INTEGRATOR_EFFECTS[requested])
    if missing:
        raise ValueError(f"integrator '{requested}' cannot reach effect '{missing[0]}' "
                         f"(needed: {sorted(eff)}); use 'path' or 'auto'")
    return requested


@dataclass
class PreparedScene:
    """A scene's BVH, triangle arrays, material table and light distribution (reusable).

    emit_accel: a BVH over the emissive triangles alone: `direct` finds what its last BSDF ray
    could hit there first, and asks the full BVH only an occlusion query up to that emitter.
    """

    geom: Geometry
    accel: Accel
    mats: MaterialTable
    lights: LightSet
    background: np.ndarray
    has_delta_lights: bool
    emit_accel: Accel | None = None


def prepare(scene: Scene, threads: int = 2) -> PreparedScene:
    """Build everything a render of ``scene`` needs once (reuse it across views and refinements)."""
    geom = Geometry.from_scene(scene)
    accel = Accel(scene, threads=threads, geometry=geom)
    mats = MaterialTable.from_scene(scene)
    lights = LightSet(scene, geom, mats)
    delta = any(isinstance(l, (PointLight, SpotLight, DirectionalLight)) for l in scene.lights)
    emitters = mats.emits[geom.obj] if len(geom.obj) else np.zeros(0, bool)
    emit_accel = Accel(scene, threads=1, geometry=geom, subset=emitters) if emitters.any() else None
    return PreparedScene(geom, accel, mats, lights, np.asarray(scene.background, np.float64), delta, emit_accel)


def _last_bounce(ps: PreparedScene, st: RenderSettings, heur, o: np.ndarray, d: np.ndarray,
                 beta: np.ndarray, pdf: np.ndarray) -> tuple[np.ndarray, int]:
    """Radiance a `direct` path's final BSDF ray brings back, without a full intersection.

    o, d: (K, 3) ray origins and directions leaving the diffuse vertex; beta: (K, 3) throughput
    including the BSDF weight; pdf: (K,) the BSDF sample's density. An emitter hit found in the
    emitter-only BVH counts (MIS-weighted against NEE) unless the full BVH has an occluder
    before it; an escaping ray brings the background. Returns ((K, 3) radiance, ray queries).
    """
    k = len(o)
    out = np.zeros((k, 3))
    g, mats, lights = ps.geom, ps.mats, ps.lights
    nrays = 0
    hit_tri = np.full(k, -1, np.int64)
    t_hit = np.full(k, np.inf)
    if ps.emit_accel is not None and st.strategy != "light":
        h = ps.emit_accel.intersect(o, d, threads=1)
        nrays += k
        hit_tri, t_hit = h.tri, h.t
        e = np.nonzero(hit_tri >= 0)[0]
        if len(e):
            occ = ps.accel.occluded(o[e], d[e], t_hit[e] * (1.0 - 1e-6), threads=1)
            nrays += len(e)
            e = e[~occ]
            tri = hit_tri[e]
            obj = g.obj[tri]
            cos_hit = -dot3(d[e], g.normal[tri])
            front = mats.two_sided[obj] | (cos_hit > 0)
            e, tri, obj, cos_hit = e[front], tri[front], obj[front], cos_hit[front]
            w = np.ones(len(e))
            if st.strategy == "mis" and lights.has_area:
                w = heur(pdf[e], lights.pdf_hit(tri, t_hit[e], cos_hit))
            out[e] = beta[e] * mats.Le[obj] * w[:, None]
    if ps.background.max() > 0:
        m = np.nonzero(hit_tri < 0)[0]
        if len(m):
            occ = ps.accel.occluded(o[m], d[m], np.inf, threads=1)
            nrays += len(m)
            m = m[~occ]
            out[m] += beta[m] * ps.background
    return out, nrays


def _heuristic(settings: RenderSettings):
    beta = 2.0 if settings.heuristic == "power" else 1.0
    return lambda pf, pg: mis_weight(pf, pg, beta)


def _trace(ps: PreparedScene, cam: Camera, st: RenderSettings, integ: str, caustics: bool,
           pix: np.ndarray, sidx: np.ndarray) -> tuple[np.ndarray, int]:
    """Trace one camera sample per (pixel, sample index) pair. Returns ((N, 3) radiance, rays).

    Wavefront state per live path: idx (into the output), beta (throughput), keys (RNG), the
    ray d, prev_pdf / prev_delta (how the ray was sampled, for MIS), after_diff (a diffuse
    vertex lies behind: the path can no longer be a camera-side specular chain).
    """
    g, mats, lights, accel = ps.geom, ps.mats, ps.lights, ps.accel
    heur = _heuristic(st)
    n = len(pix)
    width = cam.intrinsics.width
    keys = path_keys(st.seed, pix, sidx)
    jit = uniform_block(keys, 0, 2)
    jit[:, 0] += pix % width
    jit[:, 1] += pix // width
    o, d = cam.pixel_rays(jit)
    L = np.zeros((n, 3))
    idx = np.arange(n)
    beta = np.ones((n, 3))
    prev_pdf = np.zeros(n)
    prev_delta = np.ones(n, bool)  # the camera ray counts as specular: emission seen directly has weight 1
    after_diff = np.zeros(n, bool)
    bg = ps.background
    has_bg = bool(bg.max() > 0)
    direct = integ == "direct"
    nee_area = st.strategy != "bsdf" and lights.has_area
    nee_any = nee_area or lights.has_delta
    mis_on_hits = lights.has_area and st.strategy != "bsdf"
    continue_diffuse = not (direct and st.strategy == "light" and not has_bg)
    has_specular = bool(np.any((mats.kind == MIRROR) | (mats.kind == DIELECTRIC)))
    extent = g.extent
    nrays = 0
    for depth in range(st.max_depth + 1):
        if len(idx) == 0:
            break
        h = accel.intersect(o, d, threads=1)
        nrays += len(idx)
        tri = h.tri
        hit = tri >= 0
        all_hit = bool(hit.all())
        if not all_hit and has_bg:
            m = np.nonzero(~hit)[0]
            w = np.ones(len(m))
            if not caustics:
                w[prev_delta[m] & after_diff[m]] = 0.0
            L[idx[m]] += beta[m] * bg * w[:, None]
        obj = g.obj[tri]  # tri = -1 on misses gives a valid, masked-out index
        kind = mats.kind[obj]
        # ---- emission found by the ray (camera, specular chain, or BSDF sample)
        em = mats.emits[obj] & hit
        if em.any():
            e = np.nonzero(em)[0]
            cos_hit = -np.einsum("ij,ij->i", d[e], g.normal[tri[e]])
            front = mats.two_sided[obj[e]] | (cos_hit > 0)
            e, cos_hit = e[front], cos_hit[front]
            if len(e):
                w = np.ones(len(e))
                nd = np.nonzero(~prev_delta[e])[0]
                if len(nd) and st.strategy == "light" and lights.has_area:
                    w[nd] = 0.0
                elif len(nd) and mis_on_hits:
                    en = e[nd]
                    w[nd] = heur(prev_pdf[en], lights.pdf_hit(tri[en], h.t[en], cos_hit[nd]))
                if not caustics:
                    w[prev_delta[e] & after_diff[e]] = 0.0
                L[idx[e]] += beta[e] * mats.Le[obj[e]] * w[:, None]
        if depth == st.max_depth:
            break
        alive = hit & (kind != EMISSIVE)
        if direct:
            alive &= ~after_diff
        if not alive.all():
            s = np.nonzero(alive)[0]
            idx, beta, after_diff, keys, d, tri, obj, kind = (
                a[s] for a in (idx, beta, after_diff, keys, d, tri, obj, kind))
            hu, hv = h.u[s], h.v[s]
        else:
            hu, hv = h.u, h.v
        m_live = len(idx)
        if m_live == 0:
            break
        p, ng = g.point_normal(tri, hu, hv)
        cos_o = -dot3(d, ng)
        # shading normal: facing wo for two-sided materials, outward for dielectrics
        flip = cos_o < 0
        if has_specular:
            flip &= kind != DIELECTRIC
        nrm = np.where(flip[:, None], -ng, ng)
        rnd = uniform_block(keys, 2 + _DIMS_PER_BOUNCE * depth, 7)
        diff = np.nonzero(kind == LAMBERT)[0]
        all_diff = len(diff) == m_live
        wi = np.zeros((m_live, 3))
        weight = np.zeros((m_live, 3))
        pdf = np.zeros(m_live)
        delta = np.zeros(m_live, bool)
        valid = np.zeros(m_live, bool)
        if len(diff):
            sub = slice(None) if all_diff else diff
            td, ud, vd = tri[sub], hu[sub], hv[sub]
            alb = mats.diffuse_albedo(obj[sub], lambda m: g.texcoords(td[m], ud[m], vd[m]))
            n_d = nrm[sub]
            beta_d = beta[sub]
            # ---- next-event estimation at diffuse vertices
            if nee_any:
                ls = lights.sample(p[sub], rnd[sub, 0], rnd[sub, 1:3])
                cos_i = dot3(ls.wi, n_d)
                ok = ls.valid & (cos_i > 0)
                if not nee_area:
                    ok &= ls.delta
                k = np.nonzero(ok)[0]
                if len(k):
                    w = np.ones(len(k))
                    if st.strategy == "mis":
                        area = ~ls.delta[k]
                        w[area] = heur(ls.pdf[k][area], cos_i[k][area] * INV_PI)
                    pk = p[diff[k]]
                    wk = ls.wi[k]
                    origin = spawn_origin(pk, ng[diff[k]], wk, extent)
                    tmax = np.maximum(ls.dist[k] * (1.0 - 1e-4) - 2.0 * offset_eps(pk, extent), 0.0)
                    occ = accel.occluded(origin, wk, tmax, threads=1)
                    nrays += len(k)
                    vis = np.nonzero(~occ)[0]
                    kv = k[vis]
                    scale = INV_PI * cos_i[kv] * w[vis] / ls.pdf[kv]
                    L[idx[diff[kv]]] += beta_d[kv] * alb[kv] * ls.Li[kv] * scale[:, None]
            # ---- cosine-weighted BSDF sample, built in world space
            if continue_diffuse:
                loc = cosine_hemisphere(rnd[sub, 4:6])
                s_ax, t_ax = orthonormal_frame(n_d)
                wi[sub] = to_world(loc, s_ax, t_ax, n_d)
                weight[sub] = alb
                pdf[sub] = loc[:, 2] * INV_PI
                valid[sub] = (loc[:, 2] > 0) & (cos_o[sub] != 0)
                if direct:  # the path ends here: gather what the last BSDF ray brings back
                    ok = np.nonzero(valid[sub] & (max3(alb) > 0))[0]
                    dk = diff[ok]
                    wk = wi[dk]
                    Lk, nr = _last_bounce(ps, st, heur, spawn_origin(p[dk], ng[dk], wk, extent), wk,
                                          beta[dk] * alb[ok], pdf[dk])
                    L[idx[dk]] += Lk
                    nrays += nr
                    valid[sub] = False
        if has_specular and not all_diff:
            spec = np.nonzero(kind != LAMBERT)[0]
            n_s = nrm[spec]
            s_ax, t_ax = orthonormal_frame(n_s)
            wo_l = to_local(-d[spec], s_ax, t_ax, n_s)
            os_ = obj[spec]
            bs = bsdf_sample(kind[spec], mats.albedo[os_], mats.ior[os_], wo_l, rnd[spec, 3], rnd[spec, 4:6])
            weight[spec], pdf[spec], delta[spec], valid[spec] = bs.weight, bs.pdf, bs.delta, bs.valid
            bs_wi = bs.wi
            wi[spec] = to_world(bs_wi, s_ax, t_ax, n_s)
        beta = beta * weight
        if integ == "path" and st.roulette and depth >= st.rr_depth:
            survive = np.minimum(1.0, max3(beta))
            live = rnd[:, 6] < survive
            beta[live] /= survive[live][:, None]
            valid &= live
        valid &= max3(beta) > 0
        if not valid.all():
            s = np.nonzero(valid)[0]
            idx, beta, keys, kind, after_diff = idx[s], beta[s], keys[s], kind[s], after_diff[s]
            prev_pdf, prev_delta, d, p, ng = pdf[s], delta[s], wi[s], p[s], ng[s]
        else:
            prev_pdf, prev_delta, d = pdf, delta, wi
        after_diff = after_diff | (kind == LAMBERT)
        o = spawn_origin(p, ng, d, extent)
    return L, nrays


def _moments(pix: np.ndarray, values: np.ndarray, npix: int):
    s1 = np.stack([np.bincount(pix, weights=values[:, c], minlength=npix) for c in range(3)], axis=1)
    s2 = np.stack([np.bincount(pix, weights=values[:, c] * values[:, c], minlength=npix) for c in range(3)], axis=1)
    return s1, s2, np.bincount(pix, minlength=npix)


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
    integ = choose_integrator(eff, settings.integrator, ps.has_delta_lights)
    caustics = "caustics" in eff
    a, b = (0, settings.spp) if sample_range is None else (int(sample_range[0]), int(sample_range[1]))
    if not 0 <= a < b:
        raise ValueError(f"sample_range must satisfy 0 <= start < stop, got {(a, b)}")
    k = camera.intrinsics
    npix = k.width * k.height
    total = npix * (b - a)
    chunks = [(c, min(c + settings.batch_paths, total)) for c in range(0, total, settings.batch_paths)]

    def work(chunk):
        flat = np.arange(chunk[0], chunk[1], dtype=np.int64)
        pix = flat % npix
        sidx = a + flat // npix
        L, nr = _trace(ps, camera, settings, integ, caustics, pix, sidx)
        return (*_moments(pix, L, npix), nr)

    film = Film(k.width, k.height)
    rays = 0
    if settings.threads > 1 and len(chunks) > 1:
        with ThreadPoolExecutor(settings.threads) as ex:
            results = ex.map(work, chunks)
            for ch, (s1, s2, cnt, nr) in zip(chunks, results):
                film.add_moments(s1, s2, cnt)
                rays += nr
                if progress is not None:
                    progress(ch[1], total)
    else:
        for ch in chunks:
            s1, s2, cnt, nr = work(ch)
            film.add_moments(s1, s2, cnt)
            rays += nr
            if progress is not None:
                progress(ch[1], total)
    stats = {"time_s": time.perf_counter() - t0, "paths": int(total), "rays": int(rays)}
    return RenderResult.from_film(film, (a, b), integ, stats)


def refine(result: RenderResult, scene: Scene, camera: Camera, settings: RenderSettings,
           extra_spp: int, effects=None, prepared: PreparedScene | None = None, progress=None) -> RenderResult:
    """Progressive rendering: add ``extra_spp`` samples after ``result``'s range and merge."""
    a = result.sample_range[1]
    more = render(scene, camera, replace(settings, integrator=result.integrator), (a, a + int(extra_spp)),
                  effects, prepared, progress)
    return merge_results(result, more)
