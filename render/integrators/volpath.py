"""``volpath``: a wavefront volumetric path tracer with glossy surfaces and media (compiled; numpy reference).

It estimates the same measurement as :mod:`render.integrators.path` (box-filtered pixel radiance,
the same camera, light and radiometric conventions) and adds what path's kernels lack:

* GGX microfacet surfaces (:mod:`render.microfacet`: rough conductors and rough dielectrics),
  with next-event estimation and BSDF sampling combined by MIS (power heuristic);
* participating media (:mod:`render.media`): free flights by delta tracking with a majorant,
  emission collected at every tentative collision, real scattering with the Henyey-Greenstein
  phase function, next-event estimation from medium vertices (phase sampling and light
  sampling, MIS), shadow rays attenuated by ratio tracking (exp(-sigma_t d) exactly in
  homogeneous media) across every medium they cross.

What the integrator name runs (:func:`render_result`) is compiled: numba kernels in
:mod:`render.integrators.volpath_kernels` shade, track and sample every live path in one pass
per round (Embree queries for surfaces, media boundaries and shadow rays in between, media
queries only when the scene has media), over ``threads`` render threads. Its random numbers are
a pure function of (seed, pixel, sample, dimension), so its bytes do not depend on threads or
batches and disjoint sample ranges merge exactly (:func:`render.film.merge_results`).

Samplers (``Options.sampler``), as render.integrators.path has them: "sobol-blocks" (the
default: one Owen-scrambled Sobol sequence per pixel, :mod:`render.sobol`; the variance image
from R = render.sobol.replicates_for(spp) consecutive blocks under a fitted power law,
:func:`render.film.blocks_variance`), "sobol" (R interleaved independent replicates; variance
from the replicate means, model-free, R - 1 degrees of freedom per pixel) or "independent" (the
hash; variance the sample variance over n). Under both Sobol samplers every vertex draws its
light point, lobe, direction and roulette from fixed dimensions of its bounce, and the first
tentative collision of each flight its distance and event; delta tracking's further collisions
and the shadow rays' ratio tracking, whose counts vary, draw from the hash
(render.integrators.volpath_kernels, "Random numbers").

Measured (bench/results/sampler_volpath.json, 64 x 64, max_depth 8): "sobol-blocks" RMSE /
"independent" RMSE at equal spp 0.59-0.69 on cornell_fog (16-256 spp) and 0.90-0.95 on
glowing_smoke (its light is emission at delta tracking's many null collisions, only the first
of each flight stratified); 1.06x the cost per spp; at equal time 0.70 and 0.93. Variance image
against the spread of the mean over 8 seeds (one-off, 64 x 64, 64 and 256 spp), empirical /
estimated: "sobol-blocks" 1.11-1.13 (cornell_fog), 1.03-1.12 (glowing_smoke), i.e. about 10%
low; "sobol" 0.88-1.02.

The numpy version (:func:`trace`, :func:`render_result_numpy`; ``render_volpath(...,
numpy_reference=True)``) is the same estimator, vectorized in numpy, kept as the tested
reference (tests/render/test_volpath_compiled.py compares the two per pixel). Each of its rounds
is one Embree query for the surfaces, one for the media boundaries, vectorized tracking and
shading, one occlusion query for the shadow rays. Vertex bookkeeping (throughput,
previous-vertex density and delta flag for MIS, the medium a ray travels in) lives in the arrays
of :func:`trace`. Its random numbers come from a numpy Generator seeded by (seed, sample range,
batch): deterministic for a given (seed, sample range, batch_paths).

Max depth counts scattering events (surface or medium), as in render.integrators.path; Russian
roulette from vertex rr_depth. Without 'caustics' among the effects, paths are cut when they
leave a non-delta vertex along a delta (specular) sample (what render.integrators.path drops).
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..accel import spawn_origin
from ..bsdf import CONDUCTOR, DIELECTRIC, EMISSIVE, LAMBERT, ROUGH_DIELECTRIC, bsdf_sample, lambert_eval, lambert_pdf
from ..camera import Camera
from ..effects import scene_effects
from ..film import Film, RenderResult
from ..media import EV_ABSORB, EV_SCATTER, MajorantError, MediumSet, hg_pdf, hg_sample
from ..microfacet import (conductor_eval, conductor_pdf, conductor_sample, rough_dielectric_eval,
                          rough_dielectric_pdf, rough_dielectric_sample)
from ..sampling import _GOLDEN, _mix64, mis_weight, orthonormal_frame, to_local, to_world
from ..sobol import SAMPLERS, block_size, key_replicates, replicate_of, replicates_for, shuffle_bits
from .path import _STRATEGY_CODES, kernel_scene_of, pinhole_of
from .path_kernels import F_DELTA, SAMPLER_SOBOL, accumulate, accumulate_replicates, add_unoccluded, sample_camera_rays
from .prepared import PreparedScene, prepare
from .volpath_kernels import (MediaKernel, VolConfig, media_kernel, shadow_flush, shadow_media_step, shadow_start,
                              trace_surfaces, vol_bounce)
from .settings import RenderSettings, check_heuristic, check_sampler, check_strategy, heuristic_exponent, parse_sample_range

__all__ = ["Options", "VolContext", "volpath_context", "trace", "render_volpath", "render_result", "render_result_numpy",
           "trace_primary", "primary_config", "surface_tracer", "vol_buffers", "surface_eval",
           "surface_sample", "shadow_transmittance"]

_MAX_CROSSINGS = 16


@dataclass(frozen=True)
class Options:
    """Options of ``volpath`` (RenderSettings fields of the same names)."""

    #: Russian roulette when leaving vertices of index >= rr_depth
    roulette: bool = True
    #: first vertex index (0: the first hit) whose outgoing path roulette may end
    rr_depth: int = 3
    #: "mis" (light + BSDF / phase sampling, MIS-weighted), "light" (next-event estimation
    #: alone) or "bsdf" (BSDF / phase sampling alone for area sources)
    strategy: str = "mis"
    #: MIS weights: "power" or "balance" (Veach and Guibas)
    heuristic: str = "power"
    #: random numbers of the compiled kernels: "sobol-blocks" (one Owen-scrambled Sobol sequence
    #: per pixel, model variance: render.film.blocks_variance; the default), "sobol" (R
    #: interleaved replicates, model-free variance) or "independent" (hash). The numpy
    #: reference (render_result_numpy) keeps its own Generator whatever this says.
    sampler: str = "sobol-blocks"

    def __post_init__(self):
        check_strategy(self.strategy)
        check_heuristic(self.heuristic)
        check_sampler(self.sampler)
        if self.rr_depth < 0:
            raise ValueError(f"volpath: rr_depth must be >= 0, got {self.rr_depth}")


@dataclass
class VolContext:
    """What volpath needs beyond a :class:`render.integrators.prepared.PreparedScene`: the media (or None)."""

    ps: PreparedScene
    media: MediumSet | None
    #: the compiled kernels' packed view (built on first use by :func:`_compiled_of`)
    compiled: object | None = None


def volpath_context(scene, ps, majorants: dict | None = None) -> VolContext:
    """Context for ``scene`` with its prepared scene ``ps``; media built only if present."""
    return VolContext(ps, MediumSet(scene.media, majorants) if scene.media else None)


# ---------------------------------------------------------------- surfaces
def surface_eval(mats, obj: np.ndarray, albedo: np.ndarray, wo: np.ndarray, wi: np.ndarray):
    """(f (N, 3), pdf (N,)) of the objects' BSDFs for local wo, wi (N, 3) (frames: two-sided
    materials face wo, dielectrics outward). Delta lobes give 0."""
    kind = mats.kind[obj]
    n = len(obj)
    f = np.zeros((n, 3))
    pdf = np.zeros(n)
    s = np.nonzero(kind == LAMBERT)[0]
    if len(s):
        f[s], pdf[s] = lambert_eval(albedo[s], wo[s], wi[s]), lambert_pdf(wo[s], wi[s])
    s = np.nonzero(kind == CONDUCTOR)[0]
    if len(s):
        o = obj[s]
        a, e, k = mats.alpha[o], mats.eta[o], mats.k[o]
        f[s] = conductor_eval(a, e, k, wo[s], wi[s])
        pdf[s] = conductor_pdf(a, wo[s], wi[s])
    s = np.nonzero(kind == ROUGH_DIELECTRIC)[0]
    if len(s):
        o = obj[s]
        f[s] = rough_dielectric_eval(mats.alpha[o], mats.ior[o], wo[s], wi[s])
        pdf[s] = rough_dielectric_pdf(mats.alpha[o], mats.ior[o], wo[s], wi[s])
    return f, pdf


def surface_sample(mats, obj: np.ndarray, albedo: np.ndarray, wo: np.ndarray, u1: np.ndarray, u2: np.ndarray):
    """Sample every vertex's BSDF (local frames as :func:`surface_eval`): a
    :class:`render.bsdf.BSDFSample`."""
    kind = mats.kind[obj]
    out = bsdf_sample(np.where((kind == CONDUCTOR) | (kind == ROUGH_DIELECTRIC), EMISSIVE, kind), albedo,
                      mats.ior[obj], wo, u1, u2)
    for kk, fn in ((CONDUCTOR, lambda s, o: conductor_sample(mats.alpha[o], mats.eta[o], mats.k[o], wo[s], u2[s])),
                   (ROUGH_DIELECTRIC, lambda s, o: rough_dielectric_sample(mats.alpha[o], mats.ior[o], wo[s],
                                                                           u1[s], u2[s]))):
        s = np.nonzero(kind == kk)[0]
        if len(s):
            bs = fn(s, obj[s])
            out.wi[s], out.weight[s], out.pdf[s], out.delta[s], out.valid[s] = bs.wi, bs.weight, bs.pdf, bs.delta, bs.valid
    return out


def _frames(mats, obj, ng, d):
    """Shading normals (N, 3): geometric normal, flipped to face -d unless the material is a
    (smooth or rough) dielectric, whose frame is the outward normal."""
    kind = mats.kind[obj]
    diel = (kind == DIELECTRIC) | (kind == ROUGH_DIELECTRIC)
    flip = (np.einsum("ij,ij->i", ng, d) > 0) & ~diel
    return np.where(flip[:, None], -ng, ng)


# ---------------------------------------------------------------- shadow rays
def shadow_transmittance(ctx: VolContext, p: np.ndarray, ng: np.ndarray | None, wi: np.ndarray,
                         dist: np.ndarray, mid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) visibility x transmittance of segments from p (N, 3) along wi (N, 3) over dist (N,)
    (inf: to a directional light) starting in media mid (N,): 0 if a surface blocks the segment,
    else the product of each crossed medium's transmittance. ng: (N, 3) geometric normals to
    offset surface points along (None for medium points)."""
    ps = ctx.ps
    extent = ps.geom.extent
    o = p if ng is None else spawn_origin(p, ng, wi, extent)
    tmax = np.where(np.isfinite(dist), dist * (1.0 - 1e-5) - 1e-6 * extent, 3e38)
    vis = ~ps.accel.occluded(o, wi, np.maximum(tmax, 0.0))
    T = np.repeat(vis.astype(np.float64)[:, None], 3, axis=1)
    ms = ctx.media
    if ms is None:
        return T
    live = np.nonzero(vis)[0]
    rem = tmax.copy()
    o = o.copy()
    m = mid.copy()
    for _ in range(_MAX_CROSSINGS):
        if len(live) == 0:
            break
        tb, bm, entering, btri = ms.boundary(o[live], wi[live])
        seg = np.minimum(tb, rem[live])
        inm = m[live] >= 0
        if np.any(inm):
            s = live[inm]
            T[s] *= ms.transmittance(m[s], o[s], wi[s], seg[inm], rng)
        cross = tb < rem[live]
        if not np.any(cross):
            break
        c = live[cross]
        x = o[c] + tb[cross, None] * wi[c]
        o[c] = spawn_origin(x, ms.geom.normal[btri[cross]], wi[c], ms.geom.extent)
        rem[c] -= tb[cross]
        m[c] = np.where(entering[cross], bm[cross], -1)
        live = c[T[c].max(axis=1) > 0]
    return T


# ---------------------------------------------------------------- the integrator
class _Paths:
    """The live paths of :func:`trace`, one row each: idx (their slot in the radiance array),
    beta (N, 3) throughput, pdf_prev (density of the ray being traced, solid angle), delta_prev
    (it left a delta vertex), after_diffuse (a non-delta vertex lies behind), bounces
    (scattering events so far), last_p (N, 3) the last scattering vertex (for the light density
    of an emitter hit by sampling), o, d (N, 3) the ray, mid (N,) the medium it travels in (-1:
    vacuum)."""

    _FIELDS = ("idx", "beta", "pdf_prev", "delta_prev", "after_diffuse", "bounces", "last_p", "o", "d", "mid")

    def __init__(self, o: np.ndarray, d: np.ndarray, mid: np.ndarray):
        n = len(o)
        self.idx = np.arange(n)
        self.beta = np.ones((n, 3))
        self.pdf_prev = np.zeros(n)
        self.delta_prev = np.ones(n, bool)  # camera rays: emission seen directly has weight 1
        self.after_diffuse = np.zeros(n, bool)
        self.bounces = np.zeros(n, np.int64)
        self.last_p = o.copy()
        self.o, self.d, self.mid = o.copy(), d.copy(), mid.copy()

    def __len__(self) -> int:
        return len(self.idx)

    def keep(self, sel: np.ndarray) -> None:
        for name in self._FIELDS:
            setattr(self, name, getattr(self, name)[sel])


def _track_media(ms: MediumSet, st: _Paths, h, L: np.ndarray, rng: np.random.Generator):
    """Free flights of the paths inside media up to their surface hits ``h`` (delta tracking:
    emission collected, absorbed paths dropped) and boundary crossings (same direction, new
    medium, not a bounce). Returns (h, cross, scat, t_scat) for the surviving paths: the hits,
    (N,) bool crossing a boundary, (N,) bool scattering in a medium at distance t_scat."""
    n = len(st)
    scat = np.zeros(n, bool)
    t_scat = np.zeros(n)
    tb, bm, entering, btri = ms.boundary(st.o, st.d)
    cross = tb < h.t
    t_end = np.minimum(h.t, tb)
    inm = np.nonzero(st.mid >= 0)[0]
    if len(inm):
        ev, ts, w, em = ms.delta_track(st.mid[inm], st.o[inm], st.d[inm], t_end[inm], rng)
        np.add.at(L, st.idx[inm], st.beta[inm] * em)
        st.beta[inm] *= w
        gone = np.zeros(n, bool)
        gone[inm[ev == EV_ABSORB]] = True
        s = inm[ev == EV_SCATTER]
        scat[s] = True
        t_scat[s] = ts[ev == EV_SCATTER]
        cross &= ~scat
        st.keep(~gone)
        h.t, h.tri, h.u, h.v = h.t[~gone], h.tri[~gone], h.u[~gone], h.v[~gone]
        tb, bm, entering, btri = tb[~gone], bm[~gone], entering[~gone], btri[~gone]
        cross, scat, t_scat = cross[~gone], scat[~gone], t_scat[~gone]
    c = np.nonzero(cross)[0]
    if len(c):
        x = st.o[c] + tb[c, None] * st.d[c]
        st.o[c] = spawn_origin(x, ms.geom.normal[btri[c]], st.d[c], ms.geom.extent)
        st.mid[c] = np.where(entering[c], bm[c], -1)
    return h, cross, scat, t_scat


def _add_emission(ps: PreparedScene, st: _Paths, si, tri, p, ng, obj, L, strategy: str, hexp: float) -> None:
    """Emission found at surface vertices si (triangles tri, points p, normals ng, objects obj),
    MIS-weighted against light sampling unless the previous vertex was delta."""
    mats, lights = ps.mats, ps.lights
    em = mats.emits[obj]
    if not np.any(em):
        return
    e = np.nonzero(em)[0]
    cos_l = -np.einsum("ij,ij->i", st.d[si][e], ng[e])
    front = mats.two_sided[obj[e]] | (cos_l > 0)
    dist = np.linalg.norm(p[e] - st.last_p[si[e]], axis=1)
    w = np.ones(len(e))
    nd = ~st.delta_prev[si[e]]
    if np.any(nd) and not lights.empty and strategy != "bsdf":
        if strategy == "light":
            w[nd] = 0.0
        else:
            pl = lights.pdf_hit(tri[e[nd]], dist[nd], cos_l[nd])
            w[nd] = mis_weight(st.pdf_prev[si[e[nd]]], pl, hexp)
    np.add.at(L, st.idx[si[e]], st.beta[si[e]] * mats.Le[obj[e]] * (w * front)[:, None])


def _surface_frames(ps: PreparedScene, st: _Paths, sa, tri, hu, hv, ng):
    """BSDF frames and local wo at live surface vertices sa: (objects, normal, t1, t2, wo_l, albedo)."""
    mats, geom = ps.mats, ps.geom
    objs = geom.obj[tri]
    nrm = _frames(mats, objs, ng, st.d[sa])
    t1, t2 = orthonormal_frame(nrm)
    wo_l = to_local(-st.d[sa], t1, t2, nrm)
    alb = mats.diffuse_albedo(objs, lambda m: geom.texcoords(tri[m], hu[m], hv[m]))
    return objs, nrm, t1, t2, wo_l, alb


def _next_event(ctx: VolContext, st: _Paths, sa, ma, p_s, ng_s, frames, pm, L, rng, strategy: str,
                hexp: float) -> None:
    """Next-event estimation at surface vertices sa (points p_s, normals ng_s, BSDF ``frames``)
    and medium vertices ma (points pm): one light sample each, its shadow ray attenuated by the
    media it crosses, MIS-weighted against BSDF / phase sampling."""
    ps, ms = ctx.ps, ctx.media
    nsv = len(sa)
    pts = np.concatenate([p_s, pm])
    lsmp = ps.lights.sample(pts, rng.random(len(pts)), rng.random((len(pts), 2)))
    f = np.zeros((len(pts), 3))
    pb = np.zeros(len(pts))
    if nsv:
        objs, nrm, t1, t2, wo_l, alb = frames
        wi_l = to_local(lsmp.wi[:nsv], t1, t2, nrm)
        fs, pbs = surface_eval(ps.mats, objs, alb, wo_l, wi_l)
        f[:nsv] = fs * np.abs(wi_l[:, 2:3])
        pb[:nsv] = pbs
    if len(ma):
        ph = hg_pdf(ms.g[st.mid[ma]], st.d[ma], lsmp.wi[nsv:])
        f[nsv:] = ph[:, None]
        pb[nsv:] = ph
    ok = lsmp.valid & (f.max(axis=1) > 0)
    if strategy == "bsdf":
        ok &= lsmp.delta
    if not np.any(ok):
        return
    k = np.nonzero(ok)[0]
    surf_k = k < nsv
    start_mid = np.concatenate([st.mid[sa], st.mid[ma]])[k]
    # medium points: no offset (the sample lies inside the medium)
    o_sh = pts[k].copy()
    if np.any(surf_k):
        o_sh[surf_k] = spawn_origin(pts[k[surf_k]], ng_s[k[surf_k]], lsmp.wi[k[surf_k]], ps.geom.extent)
    T = shadow_transmittance(ctx, o_sh, None, lsmp.wi[k], lsmp.dist[k], start_mid, rng)
    w = (np.ones(len(k)) if strategy == "light"
         else np.where(lsmp.delta[k], 1.0, mis_weight(lsmp.pdf[k], pb[k], hexp)))
    contrib = f[k] * lsmp.Li[k] * T * (w / lsmp.pdf[k])[:, None]
    owner = np.concatenate([sa, ma])[k]
    np.add.at(L, st.idx[owner], st.beta[owner] * contrib)


def _scatter(ctx: VolContext, st: _Paths, sa, ma, p_s, ng_s, frames, pm, rng, caustics: bool) -> np.ndarray:
    """The next ray of every live vertex: a BSDF sample at surface vertices sa, a phase sample
    at medium vertices ma (the state's o, d and MIS bookkeeping updated). Returns (N,) bool:
    the path continues (without 'caustics', not along a delta sample after a diffuse vertex)."""
    ps, ms = ctx.ps, ctx.media
    nxt = np.zeros(len(st), bool)
    new_d = st.d.copy()
    new_o = st.o.copy()
    if len(sa):
        objs, nrm, t1, t2, wo_l, alb = frames
        bs = surface_sample(ps.mats, objs, alb, wo_l, rng.random(len(sa)), rng.random((len(sa), 2)))
        wi = to_world(bs.wi, t1, t2, nrm)
        ok = bs.valid
        if not caustics:
            ok &= ~(bs.delta & st.after_diffuse[sa])
        st.beta[sa] *= bs.weight
        st.pdf_prev[sa] = bs.pdf
        st.delta_prev[sa] = bs.delta
        st.after_diffuse[sa] |= ~bs.delta
        new_d[sa] = wi
        new_o[sa] = spawn_origin(p_s, ng_s, wi, ps.geom.extent)
        st.last_p[sa] = p_s
        nxt[sa[ok]] = True
    if len(ma):
        wi = hg_sample(ms.g[st.mid[ma]], st.d[ma], rng.random((len(ma), 2)))
        st.pdf_prev[ma] = hg_pdf(ms.g[st.mid[ma]], st.d[ma], wi)
        st.delta_prev[ma] = False
        st.after_diffuse[ma] = True
        new_d[ma] = wi
        new_o[ma] = pm
        st.last_p[ma] = pm
        nxt[ma] = True
    bounced = np.zeros(len(st), bool)
    bounced[sa] = True
    bounced[ma] = True
    st.bounces[bounced] += 1
    st.o, st.d = new_o, new_d
    return nxt


def _roulette(st: _Paths, nxt: np.ndarray, rr_depth: int, rng: np.random.Generator) -> None:
    """Russian roulette on continuing paths whose last vertex had index >= rr_depth: survive
    with min(1, max(beta)), survivors divided by it (nxt updated in place)."""
    rr = np.nonzero(nxt & (st.bounces > rr_depth))[0]
    if len(rr):
        q = np.minimum(1.0, st.beta[rr].max(axis=1))
        live = rng.random(len(rr)) < q
        st.beta[rr[live]] /= q[live, None]
        nxt[rr[~live]] = False


def trace(ctx: VolContext, o: np.ndarray, d: np.ndarray, mid: np.ndarray, rng: np.random.Generator,
          max_depth: int = 8, rr_depth: int = 3, roulette: bool = True, caustics: bool = True,
          heuristic: str = "power", strategy: str = "mis") -> np.ndarray:
    """Radiance (N, 3) arriving along camera rays (origins o, unit directions d (N, 3)) that
    start in media mid (N,) (-1: vacuum), by volumetric path tracing with NEE and MIS.
    strategy: "mis", or one technique alone for area sources (as the compiled path kernels):
    "light" (NEE only: emission reached by a BSDF or phase sample counts only after a delta
    vertex) or "bsdf" (no NEE towards area sources; delta lights keep NEE, nothing else finds
    them). All three are unbiased; Veach's MIS scene shows where each wins. heuristic: "power"
    or "balance" (MIS weights).

    Each round: surface hits for every live path, free flights through media
    (:func:`_track_media`), background for escaping rays, emission at surface hits
    (:func:`_add_emission`), next-event estimation (:func:`_next_event`), the next rays
    (:func:`_scatter`), Russian roulette (:func:`_roulette`)."""
    check_strategy(strategy)
    hexp = heuristic_exponent(heuristic)
    ps = ctx.ps
    geom = ps.geom
    ms = ctx.media
    L = np.zeros((len(o), 3))
    st = _Paths(o, d, mid)
    bg = ps.background
    has_bg = bool(bg.max() > 0)
    for _ in range(4 * (max_depth + 1) + _MAX_CROSSINGS):
        if len(st) == 0:
            break
        h = ps.accel.intersect(st.o, st.d)
        cross = np.zeros(len(st), bool)
        scat = np.zeros(len(st), bool)
        t_scat = np.zeros(len(st))
        if ms is not None:
            h, cross, scat, t_scat = _track_media(ms, st, h, L, rng)
        surf = ~cross & ~scat & (h.tri >= 0)
        esc = ~cross & ~scat & (h.tri < 0)
        if has_bg and np.any(esc):
            np.add.at(L, st.idx[esc], st.beta[esc] * bg)
        # surface vertices
        si = np.nonzero(surf)[0]
        tri = h.tri[si]
        p, ng = geom.point_normal(tri, h.u[si], h.v[si])
        obj = geom.obj[tri]
        _add_emission(ps, st, si, tri, p, ng, obj, L, strategy, hexp)
        alive_s = (ps.mats.kind[obj] != EMISSIVE) & (st.bounces[si] < max_depth)
        # medium vertices
        mi = np.nonzero(scat)[0]
        pm = st.o[mi] + t_scat[mi, None] * st.d[mi]
        alive_m = st.bounces[mi] < max_depth
        sa, ma = si[alive_s], mi[alive_m]
        p_s, ng_s, pm = p[alive_s], ng[alive_s], pm[alive_m]
        frames = _surface_frames(ps, st, sa, tri[alive_s], h.u[sa], h.v[sa], ng_s) if len(sa) else None
        if not ps.lights.empty and len(sa) + len(ma):
            _next_event(ctx, st, sa, ma, p_s, ng_s, frames, pm, L, rng, strategy, hexp)
        nxt = _scatter(ctx, st, sa, ma, p_s, ng_s, frames, pm, rng, caustics)
        if roulette:
            _roulette(st, nxt, rr_depth, rng)
        nxt |= cross
        nxt &= st.beta.max(axis=1) > 0
        st.keep(nxt)
    return L


def render_volpath(scene, camera: Camera, settings: RenderSettings, sample_range=None, effects=None,
                   prepared: PreparedScene | None = None, ctx: VolContext | None = None,
                   numpy_reference: bool = False) -> RenderResult:
    """Render ``camera``'s view with ``volpath`` (settings: a :class:`RenderSettings` whose
    integrator options volpath reads: :class:`Options`). sample_range: [a, b) (default (0,
    spp)). effects: default scene_effects(scene). prepared / ctx: to reuse. numpy_reference:
    run the numpy reference (:func:`render_result_numpy`) instead of the compiled kernels.

    Returns a :class:`render.film.RenderResult` (mean and variance (H, W, 3) float32).
    """
    eff = scene_effects(scene) if effects is None else frozenset(effects)
    ps = prepared if prepared is not None else prepare(scene, threads=settings.threads)
    run = render_result_numpy if numpy_reference else render_result
    return run(scene, camera, settings, settings.options("volpath", Options),
               parse_sample_range(settings.spp, sample_range, "volpath"), eff, ps, ctx=ctx)


# ---------------------------------------------------------------- the compiled integrator
@dataclass
class _Compiled:
    """What the compiled kernels read besides path_kernels.KernelScene: GGX parameters per object
    (alpha (M,), eta, k (M, 3)), the media packed (volpath_kernels.MediaKernel), the media BVH."""

    alpha: np.ndarray
    eta: np.ndarray
    k: np.ndarray
    media: MediaKernel
    media_accel: object


def _compiled_of(ctx: VolContext) -> _Compiled:
    """The kernels' view of ``ctx`` (built once, kept on the context)."""
    if ctx.compiled is None:
        mats = ctx.ps.mats
        m = len(mats.kind)
        alpha = np.zeros(m) if mats.alpha is None else np.ascontiguousarray(mats.alpha, dtype=np.float64)
        eta = np.ones((m, 3)) if mats.eta is None else np.ascontiguousarray(mats.eta, dtype=np.float64)
        kk = np.zeros((m, 3)) if mats.k is None else np.ascontiguousarray(mats.k, dtype=np.float64)
        if m == 0:
            alpha, eta, kk = np.zeros(1), np.ones((1, 3)), np.zeros((1, 3))
        ctx.compiled = _Compiled(alpha, eta, kk, media_kernel(ctx.media),
                                 ctx.media.accel if ctx.media is not None else None)
    return ctx.compiled


def _vol_state(n: int) -> tuple:
    """A wavefront state (volpath_kernels' layout): ints (N, 4) [slot, dimension, bounces, medium],
    keys, flt (N, 4) [throughput, pdf], flags, last_p (N, 3), o32, d32 (N, 3) float32."""
    return (np.empty((n, 4), np.int64), np.empty(n, np.uint64), np.empty((n, 4)), np.empty(n, np.uint8),
            np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty((n, 3), np.float32))


def _shadow_queue(n: int) -> tuple:
    """Shadow rays: origin, direction, tmax (float32, as Embree reads them), ints (N, 3), keys, contribution."""
    return (np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32),
            np.empty((n, 3), np.int64), np.empty(n, np.uint64), np.empty((n, 3)))


def _media_walk(n: int) -> tuple:
    """The media walk of shadow rays: o32, d32, rem, ints (N, 3) [slot, medium, dimension], keys, log T, contribution."""
    return (np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n), np.empty((n, 3), np.int64),
            np.empty(n, np.uint64), np.empty((n, 3)), np.empty((n, 3)))


def _raise_majorant(ctx: VolContext, err: np.ndarray) -> None:
    i = int(err[0]) - 1
    raise MajorantError(f"medium {i}: extinction above the majorant {ctx.media.mu[i]:g} during tracking "
                        "(the estimate would be biased)")


def _trace_compiled(ctx: VolContext, comp: _Compiled, cam: Camera, cfg: VolConfig, seed: int, mid0: int,
                    start: int, stop: int, sample0: int, replicates: int = 1,
                    shuffle: int = 0) -> tuple[np.ndarray, np.ndarray, int]:
    """Trace the camera samples of flat indices [start, stop) (flat = (sample - sample0) * H * W
    + pixel) with the compiled kernels; replicates: the R the Sobol keys are built with
    (render.sobol.key_replicates; unread by the independent sampler), shuffle their
    render.sobol.shuffle_bits. Returns ((N,) int64
    pixels, (N, 3) float64 radiance, rays traced: Embree queries for surfaces, media boundaries
    and shadows)."""
    k = cam.intrinsics
    n = stop - start
    npix = k.width * k.height
    cur = _vol_state(n)
    pix = np.empty(n, np.int64)
    jit = np.empty((n, 2))
    seed_mix = _mix64(np.array([np.uint64(seed & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    pinhole = not k.has_distortion
    sample_camera_rays(start, stop, npix, k.width, sample0, seed_mix, pinhole_of(cam), pinhole, cur[1], pix,
                       cur[5], cur[6], jit, cfg.sampler, replicates, shuffle)
    if not pinhole:
        o, d = cam.pixel_rays(jit)
        cur[5][:], cur[6][:] = o, d
    L, nrays = _wavefront(ctx, comp, cfg, cur, mid0, _NO_PRIMARY)
    return pix, L, nrays


_NO_PRIMARY = np.zeros((0, 0))


def _wavefront(ctx: VolContext, comp: _Compiled, cfg: VolConfig, cur: tuple, mid0, U: np.ndarray
               ) -> tuple[np.ndarray, int]:
    """Trace the rays of state ``cur`` (keys and rays o32, d32 filled; the rest set here) to the
    end. mid0: their medium (int or (N,)). U: primary samples (N, D) read instead of the hash,
    or (0, 0). Returns ((N, 3) radiance, rays traced).

    Each round: one Embree query for the surfaces, one for the media boundaries (with media),
    :func:`render.integrators.volpath_kernels.vol_bounce`, one occlusion query for the shadow
    rays, then (with media) their walk through the media boundaries, one Embree query per crossing.
    """
    ps = ctx.ps
    ks = kernel_scene_of(ps)
    accel, maccel = ps.accel, comp.media_accel
    n = len(cur[0])
    nxt = _vol_state(n)
    q = _shadow_queue(n)
    walk = _media_walk(n) if cfg.has_media else None
    cur[0][:, 0] = np.arange(n)
    cur[0][:, 1] = 2  # dimensions 0 and 1: the pixel jitter
    cur[0][:, 2] = 0
    cur[0][:, 3] = mid0
    cur[2][:, :3] = 1.0
    cur[2][:, 3] = 0.0
    cur[3][:] = F_DELTA  # the camera ray counts as specular: emission seen directly has weight 1
    cur[4][:] = cur[5]
    L = np.zeros((n, 3))
    err = np.zeros(1, np.int64)
    rounds = 4 * (cfg.max_depth + 1) + _MAX_CROSSINGS
    if not cfg.has_media and accel.direct is not None and trace_surfaces is not None:  # one compiled call
        hit = (np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32))
        nrays = trace_surfaces(ks, comp.alpha, comp.eta, comp.k, comp.media, cfg, U, accel.direct.handle, rounds,
                               n, cur, nxt, q, hit, np.empty(n, np.int32), L, err)
        return L, int(nrays)
    no_hits = (np.zeros(0, np.int32), np.zeros(0, np.float32))
    m = n
    nrays = 0
    for _ in range(rounds):
        if m == 0:
            break
        nrays += 2 * m if cfg.has_media else m
        st = tuple(a[:m] for a in cur)
        prim, tfar, hu, hv = accel.intersect_fast(st[5], st[6])
        bhits = maccel.intersect_fast(st[5], st[6])[:2] if cfg.has_media else no_hits
        m, nq = vol_bounce(ks, comp.alpha, comp.eta, comp.k, comp.media, cfg, U, prim, tfar, hu, hv, *bhits, *st, L,
                           *nxt, *q, err)
        if err[0]:
            _raise_majorant(ctx, err)
        if nq:
            occ = accel.occluded_fast(q[0][:nq], q[1][:nq], q[2][:nq])
            nrays += nq
            if not cfg.has_media:
                add_unoccluded(L, q[3][:, 0], q[5], occ)
            else:
                ns = shadow_start(occ, *q, *walk)
                for _c in range(_MAX_CROSSINGS):
                    if ns == 0:
                        break
                    bp, bt = maccel.intersect_fast(walk[0][:ns], walk[1][:ns])[:2]
                    nrays += ns
                    ns = shadow_media_step(comp.media, ns, bp, bt, *walk, L, err)
                    if err[0]:
                        _raise_majorant(ctx, err)
                if ns:
                    shadow_flush(ns, walk[3], walk[5], walk[6], L)
        cur, nxt = nxt, cur
    return L, nrays


def primary_config(ps: PreparedScene, max_depth: int, caustics: bool, heuristic: str,
                   rr_depth: int | None = None) -> VolConfig:
    """The kernels' :class:`VolConfig` of :func:`trace_primary` (no media; path's pruning and
    shadow-ray rules)."""
    return VolConfig(max_depth=int(max_depth), rr_depth=int(rr_depth or 0), roulette=rr_depth is not None,
                     caustics=bool(caustics),
                     strategy=_STRATEGY_CODES["mis"], mis_exponent=heuristic_exponent(heuristic),
                     has_bg=bool(ps.background.max() > 0), has_media=False, has_lights=not ps.lights.empty,
                     path_rules=True)


def surface_tracer(ctx: VolContext, cfg: VolConfig):
    """What :func:`render.integrators.volpath_kernels.trace_surfaces` reads besides the wavefront
    (kernel scene, GGX tables, media kernel, config, Embree scene handle, rounds), or None when
    Embree cannot be called from compiled code or the scene has media: then only
    :func:`trace_primary`'s Python driver applies."""
    accel = ctx.ps.accel
    if cfg.has_media or accel.direct is None or trace_surfaces is None:
        return None
    comp = _compiled_of(ctx)
    return (kernel_scene_of(ctx.ps), comp.alpha, comp.eta, comp.k, comp.media, cfg, accel.direct.handle,
            4 * (cfg.max_depth + 1) + _MAX_CROSSINGS)


def vol_buffers(n: int) -> tuple:
    """Two wavefront states, a shadow queue, Embree's hit outputs and occlusion flags for up to
    n paths (:func:`render.integrators.volpath_kernels.trace_surfaces`' buffers)."""
    hit = (np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32))
    return _vol_state(n), _vol_state(n), _shadow_queue(n), hit, np.empty(n, np.int32)


def trace_primary(ps: PreparedScene, o: np.ndarray, d: np.ndarray, U: np.ndarray, max_depth: int, caustics: bool,
                  heuristic: str, ctx: VolContext | None = None, rr_depth: int | None = None) -> np.ndarray:
    """Radiance (N, 3) along rays o, d (N, 3) of a scene without media, every random number read
    from the primary samples U (N, D) float64 in [0, 1) (D >= 2 + 7 max_depth; columns 0, 1 are
    the caller's, vertex k owns 2 + 7k .. 8 + 7k: light pick, light point (2), lobe, direction
    (2), roulette): the compiled kernels as render.integrators.pssmlt's path sampler (NEE + BSDF
    sampling MIS-weighted, path's pruning of caustics; path's roulette when leaving vertices of
    index >= rr_depth, none when rr_depth is None). ctx: a ``VolContext(ps, None)`` to reuse
    across calls (its packed materials are built once)."""
    ctx = ctx if ctx is not None else VolContext(ps, None)
    comp = _compiled_of(ctx)
    n = len(o)
    cfg = primary_config(ps, max_depth, caustics, heuristic, rr_depth)
    cur = _vol_state(n)
    cur[1][:] = 0
    cur[5][:], cur[6][:] = o, d
    L, _ = _wavefront(ctx, comp, cfg, cur, -1, np.ascontiguousarray(U, dtype=np.float64))
    return L


def render_result(scene, camera: Camera, settings: RenderSettings, options: Options, sample_range: tuple[int, int],
                  effects: frozenset, prepared: PreparedScene, progress=None,
                  ctx: VolContext | None = None) -> RenderResult:
    """Render samples [a, b) = ``sample_range`` with volpath's compiled kernels (the registry's
    interface). Batches of ``settings.batch_paths`` camera samples over ``settings.threads``
    threads, accumulated in batch order; every random number is a function of (seed, pixel,
    sample, dimension), so the bytes do not depend on threads or batch size. progress: optional
    ``progress(done_paths, total_paths)`` after each batch. The Sobol samplers' film also keeps
    per-replicate ("sobol") or per-block ("sobol-blocks") sums, as path's
    (render.integrators.path.trace_view), so its variance image is theirs."""
    t0 = time.perf_counter()
    ps = prepared
    ctx = ctx if ctx is not None else volpath_context(scene, ps)
    comp = _compiled_of(ctx)
    a, b = sample_range
    k = camera.intrinsics
    npix = k.width * k.height
    total = npix * (b - a)
    mid0 = -1
    if ctx.media is not None:
        mid0 = int(ctx.media.medium_at(camera.cam_to_world[:3, 3][None])[0])
    cfg = VolConfig(max_depth=int(settings.max_depth), rr_depth=int(options.rr_depth), roulette=bool(options.roulette),
                    caustics="caustics" in effects, strategy=_STRATEGY_CODES[options.strategy],
                    mis_exponent=heuristic_exponent(options.heuristic), has_bg=bool(ps.background.max() > 0),
                    has_media=ctx.media is not None, has_lights=not ps.lights.empty,
                    sampler=SAMPLERS[options.sampler])
    chunks = [(c, min(c + settings.batch_paths, total)) for c in range(0, total, settings.batch_paths)]
    kernel_scene_of(ps)
    replicates = replicates_for(settings.spp)  # of the variance estimate (the render's planned spp)
    block = block_size(options.sampler, settings.spp)  # 0: interleaved replicates, else consecutive blocks
    keys_r = key_replicates(options.sampler, settings.spp)  # 1 under "sobol-blocks": one sequence per pixel
    shuffle = shuffle_bits(options.sampler, settings.spp)

    def work(chunk):
        return _trace_compiled(ctx, comp, camera, cfg, settings.seed, mid0, chunk[0], chunk[1], a, keys_r, shuffle)

    film = Film(k.width, k.height)
    if cfg.sampler == SAMPLER_SOBOL:
        film.r1 = np.zeros((replicates, npix, 3))
        film.rn = np.bincount(replicate_of(np.arange(a, b), replicates, block), minlength=replicates).astype(np.int64)
        film.blocks = block > 0  # blocks of one sequence: the model variance (render.film.blocks_variance)
    rays = 0
    pool = ThreadPoolExecutor(settings.threads) if settings.threads > 1 and len(chunks) > 1 else None
    try:
        results = pool.map(work, chunks) if pool is not None else map(work, chunks)
        for ch, (pix, L, nr) in zip(chunks, results):  # in chunk order: the same sums whatever the threads
            rays += nr
            if not np.all(np.isfinite(L)):
                raise FloatingPointError("volpath produced a non-finite radiance (a bug: please report)")
            accumulate(film.s1, film.s2, film.n, pix, L)
            if film.r1 is not None:
                accumulate_replicates(film.r1, ch[0], npix, a, L, block)
            if progress is not None:
                progress(ch[1], total)
    finally:
        if pool is not None:
            pool.shutdown()
    stats = {"time_s": time.perf_counter() - t0, "paths": int(total), "rays": int(rays)}
    return RenderResult.from_film(film, (a, b), "volpath", stats)


def render_result_numpy(scene, camera: Camera, settings: RenderSettings, options: Options, sample_range: tuple[int, int],
                  effects: frozenset, prepared: PreparedScene, progress=None,
                  ctx: VolContext | None = None) -> RenderResult:
    """The numpy reference of :func:`render_result` (same estimator, its own random numbers):
    samples [a, b) = ``sample_range`` (progress unused). Batches of ``settings.batch_paths``
    camera samples, each with its own Generator seeded by (seed, a, b, batch start), so its
    bytes depend on the batch size; the compiled one's do not."""
    t0 = time.perf_counter()
    ps = prepared
    ctx = ctx if ctx is not None else volpath_context(scene, ps)
    a, b = sample_range
    k = camera.intrinsics
    npix = k.width * k.height
    total = npix * (b - a)
    mid0 = -1
    if ctx.media is not None:
        mid0 = int(ctx.media.medium_at(camera.cam_to_world[:3, 3][None])[0])
    film = Film(k.width, k.height)
    for c0 in range(0, total, settings.batch_paths):
        c1 = min(c0 + settings.batch_paths, total)
        rng = np.random.default_rng([settings.seed & 0xFFFFFFFF, a, b, c0])
        flat = np.arange(c0, c1)
        pix = flat % npix
        jit = np.stack([pix % k.width + rng.random(len(flat)), pix // k.width + rng.random(len(flat))], axis=1)
        o, d = camera.pixel_rays(jit)
        L = trace(ctx, o, d, np.full(len(o), mid0, np.int64), rng, settings.max_depth, options.rr_depth,
                  options.roulette, "caustics" in effects, options.heuristic, options.strategy)
        if not np.all(np.isfinite(L)):
            raise FloatingPointError("volpath produced a non-finite radiance (a bug: please report)")
        film.add(pix, L)
    stats = {"time_s": time.perf_counter() - t0, "paths": int(total)}
    return RenderResult.from_film(film, (a, b), "volpath", stats)
