"""``sppm``: stochastic progressive photon mapping (Hachisuka and Jensen 2009), compiled wavefront.

Two implementations of one estimator: :func:`render_sppm` (what the integrator name runs) drives
the numba kernels of :mod:`render.integrators.sppm_kernels` over Embree hits and gathers on a
spatial hash grid; :func:`render_sppm_numpy` is the numpy version below (the steps' numpy
functions, cKDTree gather), kept as the tested reference (tests/render/test_sppm_compiled.py
compares them per pixel at equal photon counts). The steps, as the numpy version does them:

Caustics (L S+ D E paths) from small or delta sources are where the unidirectional path tracer
is weak: it must find the source by BSDF-sampling *through* the specular chain. SPPM traces
them from the light instead. Each pass (pbrt-v3's SPPMIntegrator, whose structure this follows):

1. **Eye pass.** One jittered camera ray per pixel follows mirror and glass (the numpy BSDFs of
   :mod:`render.bsdf`) up to the first diffuse (Lambertian) hit, the pixel's *visible point*:
   position, normal facing the viewer, weight = specular throughput x albedo / pi, depth.
   Emission seen directly or through the specular chain goes to the pixel's direct term, and so
   does next-event estimation (one light sample, one shadow ray) at the visible point: direct
   light never comes from photons.
2. **Photon pass.** ``photons_per_pass`` photons leave the lights
   (:func:`render.lights.sample_emission`: chosen by power as in :class:`render.lights.LightSet`;
   area sources: a uniform point, a cosine-weighted direction on the emitting side, flux
   Le pi A / p_select, twice that and a random side if two-sided; point, spot and directional
   lights: uniform sphere, uniform cone, a disk of the scene's bounding radius). They scatter
   off diffuse, mirror and glass surfaces with Russian roulette
   (survival = the BSDF's albedo, so flux stays constant on diffuse bounces) and are *stored at
   every diffuse hit but the first* (the first is direct light, counted by step 1).
   Photons carry importance, not radiance: refraction does not scale them by (eta_i/eta_t)^2
   (pbrt's TransportMode::Importance; Veach 1997, section 5.2), so the glass weight of
   :func:`render.bsdf.dielectric_sample` is replaced by 1.
3. **Gather.** (The compiled version: a hash grid over the photons, cells of the largest
   radius, each visible point scanning the <= 8 cells its sphere overlaps.) A ``scipy.spatial.cKDTree`` over the stored photons and one over the visible
   points (grouped into radius classes a factor sqrt(2) apart, so each query's search radius
   is at most sqrt(2) times the points' own) give all (visible point, photon) pairs closer
   than the point's radius in one ``sparse_distance_matrix`` call per class. A pair counts if
   the photon arrives on the visible point's front side and the full path respects max_depth;
   its contribution is photon flux x the point's weight (Lambert: albedo / pi).
4. **Progressive update** per pixel with M photons found (alpha = 2/3):
   N' = N + alpha M, R' = R sqrt(N' / (N + M)), tau' = (tau + Phi) (R' / R)^2.

After P passes of N_e photons: L = direct_sum / P + tau / (P N_e pi R^2). The estimate is
*consistent, not unbiased* (the density estimate blurs over the radius, which shrinks as
P^((alpha - 1) / 2) where photons land), and one progressive run has no per-pixel sample
variance (its passes are a chain, not a sum). :class:`SPPMResult` keeps the direct term's own
variance, the per-pixel radii and photon counts, and a per-pass history.

**Independent groups** (what :func:`render.integrators.render` and the ``reference`` stage run):
a render of ``spp`` passes is split into K = min(:data:`GROUPS`, spp) groups of consecutive
passes (:func:`render.film.group_ranges`), each an independent progressive run with its own
random streams (pass indices are global, so group g's passes draw what they would in any split)
and its own radius schedule starting from the initial radius. The image is the mean of the K
group images and its variance image the sample variance of the group images / K (K - 1 degrees
of freedom). That variance measures *noise only*: every group shares the same blur bias (that of
a spp / K pass run, larger than one run of spp passes would have), which no spread between
groups can show. A unit of work is a run of whole groups, so renders of whole groups merge and
batches and workers give the same bytes.

Max depth counts scattering events as in :mod:`render.integrators.path`: a path of k specular eye
bounces, the visible point and a photon that scattered d times before landing has k + 1 + d
bounces and is counted only if that is <= max_depth (NEE: k + 1, emission seen: k).

Shading uses geometric normals; Lambertian and mirror surfaces are two-sided, dielectrics and
emitters are not, as everywhere in :mod:`render`. GGX materials and participating media are
not supported (ValueError naming sppm). Random numbers: compiled, the hash of
:mod:`render.sampling` keyed by (seed, global pass index, pixel) for eye paths and (seed, pass,
photon) for photons; numpy, a Generator per pass seeded by (seed, global pass index, stream).
Either way a render is a pure function of (scene, camera, passes, photons, seed) and of its
group split (the compiled one's bytes depend on neither threads nor batch sizes), but the two
draw different numbers.
Secondary rays start at :func:`render.accel.spawn_origin` offsets (as volpath).
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..accel import spawn_origin
from ..bsdf import DIELECTRIC, LAMBERT, MIRROR, bsdf_sample
from ..camera import Camera
from ..film import Film, RenderResult, whole_groups
from ..lights import sample_emission, scene_bounds
from ..sampling import _GOLDEN, _mix64, INV_PI, dot3, max3, orthonormal_frame, to_local, to_world
from .path import kernel_scene_of, pinhole_of
from .path_kernels import sample_camera_rays
from .prepared import PreparedScene, prepare
from .settings import RenderSettings
from .sppm_kernels import (add_unoccluded_direct, emit_photons, eye_bounce, gather_update, photon_bounce,
                           photon_keys)

__all__ = ["Options", "SPPMResult", "render_sppm", "render_sppm_numpy", "render_result", "photon_pass_at", "direct_at", "ALPHA", "GROUPS"]

#: Hachisuka and Jensen's (and pbrt's) fraction of new photons kept per pass
ALPHA = 2.0 / 3.0
#: independent groups a render's passes are split into (fewer when spp < GROUPS): 8 gives the
#: variance image 7 degrees of freedom while each group keeps 1/8 of the passes to shrink its radii
GROUPS = 8
#: visible points per gather query (bounds the pair arrays' memory)
_GATHER_CHUNK = 2048
#: radius classes of the gather, a factor sqrt(2) apart
_RADIUS_CLASSES = 40


@dataclass(frozen=True)
class Options:
    """Options of ``sppm`` (RenderSettings fields of the same names; no roulette, strategy or
    heuristic: photon paths end at max_depth, direct light is next-event estimation alone)."""

    #: photons emitted per pass (None: the view's pixel count, pbrt-v3's default for its SPPM,
    #: so the photon work follows the image like the eye pass does)
    photons_per_pass: int | None = None

    def __post_init__(self):
        if self.photons_per_pass is not None and self.photons_per_pass < 1:
            raise ValueError(f"sppm: photons_per_pass must be >= 1, got {self.photons_per_pass}")


@dataclass
class SPPMResult:
    """An SPPM render.

    mean: (H, W, 3) float64 radiance estimate. radius: (H, W) float64 final gather radii (> 0).
    photons: (H, W) float64 accumulated photon count N. tau: (H, W, 3) float64 accumulated
    (radius-rescaled) flux. direct: (H, W, 3) float64 mean direct term (emission seen through
    specular chains + next-event estimation at the visible points) and direct_variance its
    variance of the mean (the photon term has none). passes, photons_per_pass: what was traced.
    history: one dict per pass (pass, mean_radius, visible_points, stored_photons, gathered,
    time_s). stats: time_s, paths (camera + photon paths), rays.
    """

    mean: np.ndarray
    radius: np.ndarray
    photons: np.ndarray
    tau: np.ndarray
    direct: np.ndarray
    direct_variance: np.ndarray
    passes: int
    photons_per_pass: int
    history: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)


def _check_supported(scene, mats) -> None:
    if mats.has_glossy:
        raise ValueError("integrator 'sppm' cannot shade glossy (GGX) materials; use 'volpath'")
    if getattr(scene, "media", None):
        raise ValueError("integrator 'sppm' cannot reach effect 'media' (participating media); use 'volpath'")


def _facing(ng: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Geometric normals (N, 3) flipped to face against the ray directions d (N, 3)."""
    return np.where((dot3(ng, d) > 0)[:, None], -ng, ng)


def _scatter_frames(kind: np.ndarray, ng: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Frame normals: dielectrics keep the outward normal, two-sided materials face -d."""
    return np.where((kind == DIELECTRIC)[:, None], ng, _facing(ng, d))


# ---------------------------------------------------------------- eye pass
def _eye_pass(ps, camera: Camera, rng: np.random.Generator, max_depth: int):
    """Trace one jittered camera ray per pixel to its visible point.

    Returns (direct (npix, 3) emission seen through specular chains, visible points dict with
    (V,) pix, depth, (V, 3) p, ng (geometric), n (facing the viewer), w (throughput x albedo / pi),
    (V,) footprint (path length / fx), rays traced).
    """
    geom, mats, accel = ps.geom, ps.mats, ps.accel
    k = camera.intrinsics
    npix = k.width * k.height
    pix = np.arange(npix)
    jit = np.stack([pix % k.width + rng.random(npix), pix // k.width + rng.random(npix)], axis=1)
    o, d = camera.pixel_rays(jit)
    beta = np.ones((npix, 3))
    plen = np.zeros(npix)
    direct = np.zeros((npix, 3))
    bg = ps.background
    has_bg = bool(bg.max() > 0)
    extent = geom.extent
    vps = []
    rays = 0
    for depth in range(max_depth + 1):
        if len(pix) == 0:
            break
        h = accel.intersect(o, d)
        rays += len(pix)
        hit = h.tri >= 0
        if has_bg and not hit.all():
            direct[pix[~hit]] += beta[~hit] * bg  # one path per pixel: indices are unique
        pix, o, d, beta, plen = pix[hit], o[hit], d[hit], beta[hit], plen[hit]
        tri, t = h.tri[hit], h.t[hit]
        p, ng = geom.point_normal(tri, h.u[hit], h.v[hit])
        obj = geom.obj[tri]
        kind = mats.kind[obj]
        plen = plen + t
        em = mats.emits[obj]
        if em.any():
            e = np.nonzero(em)[0]
            front = mats.two_sided[obj[e]] | (dot3(d[e], ng[e]) < 0)
            direct[pix[e]] += beta[e] * mats.Le[obj[e]] * front[:, None]
        if depth == max_depth:
            break
        diff = np.nonzero(kind == LAMBERT)[0]
        if len(diff):
            alb = mats.diffuse_albedo(obj[diff], lambda m: geom.texcoords(tri[diff][m], h.u[hit][diff][m],
                                                                          h.v[hit][diff][m]))
            w = beta[diff] * alb * INV_PI
            keep = max3(w) > 0
            s = diff[keep]
            vps.append((pix[s], np.full(len(s), depth), p[s], ng[s], _facing(ng[s], d[s]), w[keep],
                        plen[s] / max(k.fx, 1e-300)))
        spec = np.nonzero((kind == MIRROR) | (kind == DIELECTRIC))[0]
        if len(spec) == 0:
            pix = pix[:0]
            break
        kd, ngs, ds = kind[spec], ng[spec], d[spec]
        nrm = _scatter_frames(kd, ngs, ds)
        t1, t2 = orthonormal_frame(nrm)
        wo = to_local(-ds, t1, t2, nrm)
        bs = bsdf_sample(kd, mats.albedo[obj[spec]], mats.ior[obj[spec]], wo, rng.random(len(spec)),
                         rng.random((len(spec), 2)))
        wi = to_world(bs.wi, t1, t2, nrm)
        ok = bs.valid & (max3(bs.weight) > 0)
        s = spec[ok]
        pix, beta, plen = pix[s], beta[s] * bs.weight[ok], plen[s]
        d = wi[ok]
        o = spawn_origin(p[s], ng[s], d, extent)
    if vps:
        cols = [np.concatenate(c) for c in zip(*vps)]
    else:
        cols = [np.zeros(0, np.int64), np.zeros(0, np.int64)] + [np.zeros((0, 3))] * 4 + [np.zeros(0)]
    vp = dict(zip(("pix", "depth", "p", "ng", "n", "w", "footprint"), cols))
    return direct, vp, rays


def _direct_at_visible_points(ps, vp: dict, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """(V, 3) next-event estimate of direct light at the visible points (one light sample each)."""
    lights, accel = ps.lights, ps.accel
    nv = len(vp["pix"])
    out = np.zeros((nv, 3))
    if nv == 0 or lights.empty:
        return out, 0
    ls = lights.sample(vp["p"], rng.random(nv), rng.random((nv, 2)))
    cos = dot3(ls.wi, vp["n"])
    ok = ls.valid & (cos > 0) & (ls.pdf > 0) & np.isfinite(ls.pdf) & (max3(ls.Li) > 0)
    k = np.nonzero(ok)[0]
    if len(k) == 0:
        return out, 0
    extent = ps.geom.extent
    wi, dist = ls.wi[k], ls.dist[k]
    o = spawn_origin(vp["p"][k], vp["ng"][k], wi, extent)
    tmax = np.where(np.isfinite(dist), dist * (1.0 - 1e-5) - 1e-6 * extent, 3e38)
    vis = ~accel.occluded(o, wi, np.maximum(tmax, 0.0))
    # w = beta albedo / pi already holds the Lambert BSDF value
    out[k] = vp["w"][k] * ls.Li[k] * (vis * cos[k] / ls.pdf[k])[:, None]
    return out, len(k)


# ---------------------------------------------------------------- photon pass
def _emit_photons(ps, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n photons from the scene's lights: (origins (n, 3), unit directions (n, 3), flux (n, 3)),
    by :func:`render.lights.sample_emission` (light chosen by the LightSet's power pmf; flux =
    emitted power estimate / (pmf x pdfs)). Photons with zero flux (e.g. a spot's
    outside-the-cone direction) are dropped by the caller."""
    if ps.lights.empty or n == 0:
        o, d = np.zeros((n, 3)), np.zeros((n, 3))
        d[:, 2] = 1.0
        return o, d, np.zeros((n, 3))
    u_sel = rng.random(n)
    u_pos, u_dir, u_side = rng.random((n, 2)), rng.random((n, 2)), rng.random(n)
    es = sample_emission(ps.lights, ps.geom, u_sel, u_pos, u_dir, u_side)
    return es.o, es.d, es.flux


def _photon_pass(ps, n: int, rng: np.random.Generator, max_depth: int, caustics: bool):
    """Trace n photons; returns (stored photons dict: (P, 3) p, wi (towards where they came from),
    flux, (P,) depth (scattering events before the hit), rays traced)."""
    geom, mats, accel = ps.geom, ps.mats, ps.accel
    extent = geom.extent
    o, d, beta = _emit_photons(ps, n, rng)
    live = max3(beta) > 0
    o, d, beta = o[live], d[live], beta[live]
    stored = []
    rays = 0
    for depth in range(max_depth):  # a photon hit at depth >= max_depth can never be counted
        if len(o) == 0:
            break
        h = accel.intersect(o, d)
        rays += len(o)
        hit = h.tri >= 0
        o, d, beta = o[hit], d[hit], beta[hit]
        tri = h.tri[hit]
        p, ng = geom.point_normal(tri, h.u[hit], h.v[hit])
        obj = geom.obj[tri]
        kind = mats.kind[obj]
        diff = kind == LAMBERT
        if depth >= 1 and diff.any():
            stored.append((p[diff], -d[diff], beta[diff], np.full(int(diff.sum()), depth)))
        if depth + 1 >= max_depth:
            break
        # scatter: diffuse, mirror, glass (emitters and everything else absorb)
        sc = np.nonzero(diff | (kind == MIRROR) | (kind == DIELECTRIC))[0]
        if not caustics:  # drop light that would reach a diffuse vertex through a specular one
            sc = sc[kind[sc] == LAMBERT]
        if len(sc) == 0:
            break
        ks, ngs, ds, objs = kind[sc], ng[sc], d[sc], obj[sc]
        nrm = _scatter_frames(ks, ngs, ds)
        t1, t2 = orthonormal_frame(nrm)
        wo = to_local(-ds, t1, t2, nrm)
        u1, u2 = rng.random(len(sc)), rng.random((len(sc), 2))
        alb = mats.albedo[objs]
        dl = np.nonzero(ks == LAMBERT)[0]
        if len(dl) and mats.textures:
            alb[dl] = mats.diffuse_albedo(objs[dl], lambda m: geom.texcoords(tri[sc][dl][m], h.u[hit][sc][dl][m],
                                                                             h.v[hit][sc][dl][m]))
        bs = bsdf_sample(ks, alb, mats.ior[objs], wo, u1, u2)
        weight = bs.weight
        glass = ks == DIELECTRIC
        if glass.any():  # importance transport: no (eta_i / eta_t)^2 radiance scaling
            weight[glass] = bs.valid[glass, None].astype(np.float64)
        # Russian roulette with survival = the event's albedo (flux stays constant)
        q = np.minimum(1.0, max3(weight))
        ok = bs.valid & (q > 0) & (rng.random(len(sc)) < q)
        s = sc[ok]
        beta = beta[s] * (weight[ok] / q[ok, None])
        d = to_world(bs.wi[ok], t1[ok], t2[ok], nrm[ok])
        o = spawn_origin(p[s], ng[s], d, extent)
    if stored:
        cols = [np.concatenate(c) for c in zip(*stored)]
    else:
        cols = [np.zeros((0, 3))] * 3 + [np.zeros(0, np.int64)]
    return dict(zip(("p", "wi", "flux", "depth"), cols)), rays


# ---------------------------------------------------------------- gather
def _gather(vp: dict, radius: np.ndarray, ph: dict, max_depth: int) -> tuple[np.ndarray, np.ndarray]:
    """Photons within each visible point's radius: (Phi (V, 3) = sum flux x w, M (V,) count).

    radius: (V,) the points' current radii. Pairs from cKDTree.sparse_distance_matrix, one call
    per radius class and chunk of points (no loop over points or photons)."""
    nv = len(vp["pix"])
    phi = np.zeros((nv, 3))
    cnt = np.zeros(nv)
    if nv == 0 or len(ph["p"]) == 0:
        return phi, cnt
    tree_p = cKDTree(ph["p"])
    rmax = float(radius.max())
    cls = np.minimum(np.floor(2.0 * np.log2(rmax / radius)).astype(np.int64), _RADIUS_CLASSES - 1)
    order = np.argsort(cls, kind="stable")
    bounds = np.searchsorted(cls[order], np.arange(_RADIUS_CLASSES + 1))
    for c in range(_RADIUS_CLASSES):
        members = order[bounds[c]:bounds[c + 1]]
        for c0 in range(0, len(members), _GATHER_CHUNK):
            sel = members[c0:c0 + _GATHER_CHUNK]
            r_sel = radius[sel]
            tree_v = cKDTree(vp["p"][sel])
            pairs = tree_v.sparse_distance_matrix(tree_p, float(r_sel.max()), output_type="ndarray")
            if len(pairs) == 0:
                continue
            i, j, dist = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
            v = sel[i]
            ok = ((dist <= r_sel[i]) & (dot3(ph["wi"][j], vp["n"][v]) > 0)
                  & (vp["depth"][v] + 1 + ph["depth"][j] <= max_depth))
            v, j = v[ok], j[ok]
            if len(v) == 0:
                continue
            contrib = ph["flux"][j] * vp["w"][v]
            for ch in range(3):
                phi[:, ch] += np.bincount(v, weights=contrib[:, ch], minlength=nv)
            cnt += np.bincount(v, minlength=nv)
    return phi, cnt


# ---------------------------------------------------------------- passes at given points
def photon_pass_at(ps, points: dict, radius: np.ndarray, photons_per_pass: int, rng: np.random.Generator,
                   max_depth: int, caustics: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """One photon pass gathered at caller-given visible points (render.sensors' photon-mapped
    irradiance reuses this module's passes). points: dict of (V,) pix (0..V-1), depth, (V, 3) p,
    n (gather side), w (weight per photon flux; 1 gives irradiance). radius: (V,) gather radii.
    Returns (Phi (V, 3) weighted flux within the radii, M (V,) photon count, rays traced)."""
    photons, rays = _photon_pass(ps, int(photons_per_pass), rng, int(max_depth), caustics)
    phi, count = _gather(points, radius, photons, int(max_depth))
    return phi, count, rays


def direct_at(ps, points: dict, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """Next-event estimate (one light sample, one shadow ray) at caller-given points (keys of
    :func:`photon_pass_at` plus (V, 3) ng): (V, 3) w x Li cos / pdf, shadow rays traced."""
    return _direct_at_visible_points(ps, points, rng)


# ---------------------------------------------------------------- the progressive estimate
class _Progressive:
    """SPPM's per-pixel state over passes (both implementations): radii R, photon counts N,
    radius-rescaled flux tau, direct-term moments. npix pixels; r_floor: the smallest radius."""

    def __init__(self, npix: int, r_floor: float, alpha: float):
        self.R = np.zeros(npix)
        self.N = np.zeros(npix)
        self.tau = np.zeros((npix, 3))
        self.d_s1 = np.zeros((npix, 3))
        self.d_s2 = np.zeros((npix, 3))
        self.r_floor, self.alpha = r_floor, alpha

    def start(self, footprint: np.ndarray, initial_radius: float | None, extent: float) -> None:
        """Set every radius: ``initial_radius``, or the median of the first pass's visible points'
        footprints (V,) clamped to [1e-4, 0.05] x extent."""
        if initial_radius is None:
            fp = footprint[np.isfinite(footprint)]
            r0 = float(np.median(fp)) if len(fp) else 1e-2 * extent
            r0 = float(np.clip(r0, 1e-4 * extent, 5e-2 * extent))
        else:
            r0 = float(initial_radius)
        self.R[:] = max(r0, self.r_floor)

    def add_direct(self, direct: np.ndarray) -> None:
        """One pass's (npix, 3) direct term."""
        self.d_s1 += direct
        self.d_s2 += direct * direct

    def add_photons(self, vpix: np.ndarray, phi: np.ndarray, M: np.ndarray) -> None:
        """One pass's gather at the visible points of pixels vpix (V,): Phi (V, 3), M (V,)
        (alpha = fraction of new photons kept): N' = N + alpha M, R' = R sqrt(N' / (N + M)),
        tau' = (tau + Phi) (R' / R)^2."""
        g = M > 0
        if not g.any():
            return
        R, N, tau = self.R, self.N, self.tau
        px, m = vpix[g], M[g]
        n_new = N[px] + self.alpha * m
        r_new = np.maximum(R[px] * np.sqrt(n_new / (N[px] + m)), self.r_floor)
        scale = (r_new / R[px]) ** 2
        tau[px] = (tau[px] + phi[g]) * scale[:, None]
        N[px], R[px] = n_new, r_new

    def estimate(self, done: int, photons_per_pass: int) -> np.ndarray:
        """(npix, 3) L = direct_sum / P + tau / (P N_e pi R^2) after ``done`` passes."""
        area = np.pi * self.R * self.R
        ind = self.tau / (float(done) * photons_per_pass * np.maximum(area, 1e-300))[:, None]
        ind = np.where(self.N[:, None] > 0, ind, 0.0)
        return self.d_s1 / done + ind

    def result(self, passes: int, photons_per_pass: int, h: int, w: int, history: list, stats: dict) -> SPPMResult:
        mean = self.estimate(passes, photons_per_pass)
        if not np.all(np.isfinite(mean)):
            raise FloatingPointError("sppm produced a non-finite radiance (a bug: please report)")
        n = float(passes)
        d_s1, d_s2 = self.d_s1, self.d_s2
        dvar = np.zeros_like(d_s1) if passes < 2 else np.maximum(d_s2 - d_s1 * d_s1 / n, 0.0) / (n * (n - 1.0))
        return SPPMResult(mean.reshape(h, w, 3), self.R.reshape(h, w), self.N.reshape(h, w),
                          self.tau.reshape(h, w, 3), (d_s1 / n).reshape(h, w, 3), dvar.reshape(h, w, 3), passes,
                          photons_per_pass, history, stats)


def _check_arguments(passes, photons_per_pass, max_depth, first_pass, alpha, initial_radius) -> None:
    if passes < 1 or photons_per_pass < 1 or max_depth < 0 or first_pass < 0:
        raise ValueError("sppm: passes and photons_per_pass must be >= 1, max_depth and first_pass >= 0")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"sppm: alpha must lie in (0, 1), got {alpha}")
    if initial_radius is not None and not (np.isfinite(initial_radius) and initial_radius > 0):
        raise ValueError(f"sppm: initial_radius must be a positive finite number, got {initial_radius}")


# ---------------------------------------------------------------- the integrator: numpy reference
def render_sppm_numpy(scene, camera: Camera, passes: int, photons_per_pass: int, initial_radius: float | None = None,
                      max_depth: int = 8, seed: int = 0, *, prepared: PreparedScene | None = None,
                      alpha: float = ALPHA, caustics: bool = True, callback=None, first_pass: int = 0) -> SPPMResult:
    """:func:`render_sppm` in numpy (the tested reference of the compiled one; the same
    arguments, the same estimator; its random numbers: a numpy Generator per pass seeded by
    (seed, global pass index, stream), so its bytes differ from the compiled one's)."""
    t0 = time.perf_counter()
    passes, photons_per_pass, max_depth = int(passes), int(photons_per_pass), int(max_depth)
    first_pass = int(first_pass)
    _check_arguments(passes, photons_per_pass, max_depth, first_pass, alpha, initial_radius)
    ps = prepared if prepared is not None else prepare(scene)
    _check_supported(scene, ps.mats)
    k = camera.intrinsics
    h, w = k.height, k.width
    npix = h * w
    extent = ps.geom.extent
    state = _Progressive(npix, 1e-9 * extent, alpha)
    history = []
    rays = 0
    seed32 = int(seed) & 0xFFFFFFFF
    for it in range(passes):
        tp = time.perf_counter()
        rng_eye = np.random.default_rng([seed32, first_pass + it, 0])
        rng_ph = np.random.default_rng([seed32, first_pass + it, 1])
        direct, vp, nr = _eye_pass(ps, camera, rng_eye, max_depth)
        rays += nr
        nee, nsh = _direct_at_visible_points(ps, vp, rng_eye)
        rays += nsh
        if len(vp["pix"]):
            direct[vp["pix"]] += nee  # at most one visible point per pixel
        state.add_direct(direct)
        if it == 0:
            state.start(vp["footprint"], initial_radius, extent)
        ph, nr = _photon_pass(ps, photons_per_pass, rng_ph, max_depth, caustics)
        rays += nr
        vpix = vp["pix"]
        phi, M = _gather(vp, state.R[vpix], ph, max_depth)
        state.add_photons(vpix, phi, M)
        history.append({"pass": it + 1, "mean_radius": float(state.R.mean()), "min_radius": float(state.R.min()),
                        "visible_points": int(len(vpix)), "stored_photons": int(len(ph["p"])),
                        "gathered": int(M.sum()), "time_s": time.perf_counter() - tp})
        if callback is not None:
            callback(it + 1, state.estimate(it + 1, photons_per_pass).reshape(h, w, 3), state.R.reshape(h, w).copy())
    stats = {"time_s": time.perf_counter() - t0, "paths": int(passes * (npix + photons_per_pass)), "rays": int(rays)}
    return state.result(passes, photons_per_pass, h, w, history, stats)


# ---------------------------------------------------------------- the integrator: compiled
#: rays per wavefront batch of the compiled passes (fixed: batch boundaries never change the bytes)
_BATCH = 1 << 15
#: eye paths + photons traced together: consecutive passes are traced as one block (their rays do
#: not depend on each other's gathers) so small images do not pay the per-bounce overhead per pass
_BLOCK_RAYS = 4 * _BATCH


class _BlockBuffers:
    """A block's per-(pass, pixel) outputs, row = pass in block x npix + pixel: direct (rows, 3)
    and the visible points (ok (rows,) bool, depth (rows,) int64, p, ng, n, w (rows, 3),
    footprint (rows,)), filled by disjoint row ranges (threads never write the same row)."""

    def __init__(self, rows: int):
        self.direct = np.zeros((rows, 3))
        self.ok = np.zeros(rows, np.bool_)
        self.depth = np.zeros(rows, np.int64)
        self.p, self.ng, self.n, self.w = (np.zeros((rows, 3)) for _ in range(4))
        self.footprint = np.zeros(rows)


def _eye_batch(ps, ks, camera: Camera, pinhole, seed_mix, pass0: int, start: int, stop: int, max_depth: int,
               out: _BlockBuffers) -> int:
    """Eye paths of block rows [start, stop) (row = (pass - pass0) npix + pixel) into ``out``;
    returns rays traced."""
    accel = ps.accel
    k = camera.intrinsics
    npix = k.width * k.height
    n = stop - start
    cur = [np.empty(n, np.int64), np.empty(n, np.uint64), np.ones((n, 3)), np.zeros(n),
           np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)]
    nxt = [np.empty(n, np.int64), np.empty(n, np.uint64), np.empty((n, 3)), np.empty(n),
           np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)]
    q = (np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32), np.empty(n, np.int64),
         np.empty((n, 3)))
    jit = np.empty((n, 2))
    is_pinhole = not k.has_distortion
    sample_camera_rays(start, stop, npix, k.width, pass0, seed_mix, pinhole, is_pinhole, cur[1], cur[0],
                       cur[4], cur[5], jit)
    if not is_pinhole:
        o, d = camera.pixel_rays(jit)
        cur[4][:], cur[5][:] = o, d
    cur[0][:] = np.arange(start, stop)  # the paths' output rows
    inv_fx = 1.0 / max(k.fx, 1e-300)
    rays, m = 0, n
    for depth in range(max_depth + 1):
        if m == 0:
            break
        row, keys, beta, plen, o32, d32 = (a[:m] for a in cur)
        prim, tfar, hu, hv = accel.intersect_fast(o32, d32)
        rays += m
        m, nq = eye_bounce(ks, depth, max_depth, inv_fx, prim, tfar, hu, hv, row, keys, beta, plen, d32, out.direct,
                           out.ok, out.depth, out.p, out.ng, out.n, out.w, out.footprint, *nxt, *q)
        if nq:
            occ = accel.occluded_fast(q[0][:nq], q[1][:nq], q[2][:nq])
            rays += nq
            add_unoccluded_direct(out.direct, q[3][:nq], q[4][:nq], occ)
        cur, nxt = nxt, cur
    return rays


def _photon_batch(ps, ks, bounds, seed_mix, pass0: int, per_pass: int, start: int, stop: int, max_depth: int,
                  caustics: bool):
    """Photons of flat indices [start, stop) (flat = (pass - pass0) per_pass + index): (stored
    (p, wi, flux (P, 3), depth, flat index (P,)), rays traced)."""
    accel = ps.accel
    n = stop - start
    cur = [photon_keys(seed_mix, pass0, per_pass, start, stop), np.arange(start, stop, dtype=np.int64),
           np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)]
    nxt = [np.empty(n, np.uint64), np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3), np.float32),
           np.empty((n, 3), np.float32)]
    m = emit_photons(ks, bounds[0], bounds[1], cur[0], cur[1], cur[3], cur[4], cur[2])
    stored = []
    rays = 0
    for depth in range(max_depth):  # a photon hit at depth >= max_depth can never be counted
        if m == 0:
            break
        keys, idx, beta, o32, d32 = (a[:m] for a in cur)
        prim, _, hu, hv = accel.intersect_fast(o32, d32)
        rays += m
        s = (np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty(m, np.int64), np.empty(m, np.int64))
        m, ns = photon_bounce(ks, depth, max_depth, caustics, prim, hu, hv, keys, idx, beta, d32,
                              nxt[0], nxt[1], nxt[2], nxt[3], nxt[4], *s, 0)
        if ns:
            stored.append(tuple(a[:ns] for a in s))
        cur, nxt = nxt, cur
    return stored, rays


def render_sppm(scene, camera: Camera, passes: int, photons_per_pass: int, initial_radius: float | None = None,
                max_depth: int = 8, seed: int = 0, *, prepared: PreparedScene | None = None, alpha: float = ALPHA,
                caustics: bool = True, callback=None, first_pass: int = 0, threads: int | None = None) -> SPPMResult:
    """Render ``camera``'s view of ``scene`` by stochastic progressive photon mapping (compiled kernels).

    passes: eye + photon passes (the image converges as passes grow). photons_per_pass: photons
    emitted per pass. initial_radius: gather radius of every pixel at the start (scene units);
    None: the median pixel footprint (eye path length / fx) of the first pass's visible points,
    clamped to [1e-4, 0.05] x the scene extent (on the caustic bench scene twice that footprint
    doubled the image RMSE at 32 passes: blur bias dominates). max_depth: maximum scattering events of
    a full path. seed: the render's seed. prepared: a :class:`PreparedScene` of ``scene`` to
    reuse (default: :func:`prepare`). alpha: the fraction of
    new photons kept per pass (0 < alpha < 1). caustics: False drops photons that scattered off
    a specular surface (what the other integrators prune). callback: optional
    ``callback(pass_done, image (H, W, 3) float64, radius (H, W) float64)`` after every pass,
    with the estimate so far (for convergence studies). first_pass: global index of the first
    pass (its random streams are keyed by it): a group of passes [first_pass, first_pass +
    passes) draws the same numbers whatever else is rendered. threads: worker threads (None:
    the BVH's); the bytes do not depend on them.

    Passes are traced in blocks of about _BLOCK_RAYS eye paths + photons (one pass when the
    image alone is that large; one pass at a time when a callback is given), in batches of
    _BATCH rays run by the kernels of :mod:`render.integrators.sppm_kernels` over the threads;
    then pass by pass, in order, the stored photons (sorted by photon index and depth: an order
    no batching changes) are gathered on a hash grid and the radii updated. Random numbers: the
    hash keyed by (seed, pass, pixel) (eye paths: ``path``'s keys of sample ``pass``) and (seed,
    pass, photon). :func:`render_sppm_numpy` is the same estimator in numpy, its tested
    reference. A block's eye paths and photons are traced while the previous block's passes are
    gathered (they never read the radii; docs/architecture.md, session 41). history's time_s:
    the pass's share of its block's time, from the block's submission (so it overlaps the
    previous block's gathers).
    """
    t0 = time.perf_counter()
    passes, photons_per_pass, max_depth = int(passes), int(photons_per_pass), int(max_depth)
    first_pass = int(first_pass)
    _check_arguments(passes, photons_per_pass, max_depth, first_pass, alpha, initial_radius)
    ps = prepared if prepared is not None else prepare(scene)
    _check_supported(scene, ps.mats)
    (state, history), rays = _render_groups(ps, camera, [(first_pass, first_pass + passes)], photons_per_pass,
                                            initial_radius, max_depth, seed, alpha, caustics, callback, threads)[0]
    k = camera.intrinsics
    stats = {"time_s": time.perf_counter() - t0, "paths": int(passes * (k.width * k.height + photons_per_pass)),
             "rays": int(rays)}
    return state.result(passes, photons_per_pass, k.height, k.width, history, stats)


def _render_groups(ps, camera: Camera, groups: list, photons_per_pass: int, initial_radius, max_depth: int, seed: int,
                   alpha: float, caustics: bool, callback, threads) -> list:
    """Independent progressive runs over consecutive ranges of global passes ``groups`` [(a, b),
    ...] (b of one = a of the next), traced together: blocks of passes span group boundaries,
    each pass's gather updates its own group's state. Returns [((_Progressive, history), rays)
    per group], rays traced by its passes' blocks shared in proportion to its passes. Each
    group's result is that of render_sppm over its passes alone (the same bytes)."""
    ks = kernel_scene_of(ps)
    k = camera.intrinsics
    h, w = k.height, k.width
    npix = h * w
    extent = ps.geom.extent
    first, last = groups[0][0], groups[-1][1]
    starts = np.array([a for a, _ in groups])
    states = [_Progressive(npix, 1e-9 * extent, alpha) for _ in groups]
    histories = [[] for _ in groups]
    pinhole = pinhole_of(camera)
    bounds = scene_bounds(ps.geom)
    seed_mix = _mix64(np.array([np.uint64(int(seed) & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    nthreads = ps.accel.threads if threads is None else max(1, int(threads))
    pool = ThreadPoolExecutor(nthreads) if nthreads > 1 else None
    block = 1 if callback is not None else max(1, _BLOCK_RAYS // (npix + photons_per_pass))

    def launch(pass0):
        """Submit block pass0's eye paths and photons to the pool (traced at once without one):
        (pass0, passes, buffers, start time, results or futures)."""
        tb = time.perf_counter()
        nb = min(block, last - pass0)
        out = _BlockBuffers(nb * npix)
        n_eye, n_ph = nb * npix, nb * photons_per_pass
        jobs = ([("eye", a, min(a + _BATCH, n_eye)) for a in range(0, n_eye, _BATCH)]
                + [("photon", a, min(a + _BATCH, n_ph)) for a in range(0, n_ph, _BATCH)])

        def work(job):
            kind, a, b = job
            if kind == "eye":
                return [], _eye_batch(ps, ks, camera, pinhole, seed_mix, pass0, a, b, max_depth, out)
            return _photon_batch(ps, ks, bounds, seed_mix, pass0, photons_per_pass, a, b, max_depth, caustics)

        if pool is None:
            return pass0, nb, out, tb, [work(job) for job in jobs]
        return pass0, nb, out, tb, [pool.submit(work, job) for job in jobs]

    rays = 0
    try:
        # the next block is traced while this one's passes are gathered: eye paths and photons
        # never read the radii, so only the (serial, pass-ordered) gathers wait on each other
        block_starts = list(range(first, last, block))
        pending = launch(block_starts[0])
        for bi in range(len(block_starts)):
            pass0, nb, out, tb, parts_list = pending
            stored = []
            for part in parts_list:
                parts, nr = part.result() if pool is not None else part
                stored.extend(parts)
                rays += nr
            if bi + 1 < len(block_starts):
                pending = launch(block_starts[bi + 1])
            if stored:
                p, wi, flux, depth, idx = (np.concatenate(c) for c in zip(*stored))
            else:
                p, wi, flux = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
                depth, idx = np.zeros(0, np.int64), np.zeros(0, np.int64)
            order = np.argsort(idx * (max_depth + 1) + depth, kind="stable")  # canonical: batching never changes it
            p, wi, flux, depth, idx = p[order], wi[order], flux[order], depth[order], idx[order]
            cuts = np.searchsorted(idx, np.arange(nb + 1) * photons_per_pass)
            dt = (time.perf_counter() - tb) / nb
            for j in range(nb):
                tp = time.perf_counter()
                gp = pass0 + j
                g = int(np.searchsorted(starts, gp, side="right")) - 1
                state, done = states[g], gp - groups[g][0] + 1
                r0, r1 = j * npix, (j + 1) * npix
                c0, c1 = cuts[j], cuts[j + 1]
                state.add_direct(out.direct[r0:r1])
                ok = out.ok[r0:r1]
                if done == 1:
                    state.start(out.footprint[r0:r1][ok], initial_radius, extent)
                gathered = gather_update(ok, out.p[r0:r1], out.n[r0:r1], out.w[r0:r1], out.depth[r0:r1],
                                         p[c0:c1], wi[c0:c1], flux[c0:c1], depth[c0:c1], max_depth, alpha,
                                         state.r_floor, state.R, state.N, state.tau)
                histories[g].append({"pass": done, "mean_radius": float(state.R.mean()),
                                     "min_radius": float(state.R.min()), "visible_points": int(ok.sum()),
                                     "stored_photons": int(c1 - c0), "gathered": int(gathered),
                                     "time_s": dt + time.perf_counter() - tp})
                if callback is not None:
                    callback(done, state.estimate(done, photons_per_pass).reshape(h, w, 3), state.R.reshape(h, w).copy())
    finally:
        if pool is not None:
            pool.shutdown()
    total = last - first
    return [((st, hist), rays * (b - a) / total) for st, hist, (a, b) in zip(states, histories, groups)]


def render_result(scene, camera: Camera, settings: RenderSettings, options: Options, sample_range: tuple[int, int],
                  effects: frozenset, prepared: PreparedScene, progress=None) -> RenderResult:
    """SPPM as a :class:`render.film.RenderResult` (the registry's interface; progress unused):
    the independent groups of passes (module docstring) that ``sample_range`` covers, of a render
    of ``settings.spp`` passes; photons per pass ``options.photons_per_pass`` (None: the view's
    pixel count, as pbrt-v3's SPPM).

    sample_range must start and end on group boundaries (:func:`render.film.whole_groups`;
    ValueError naming sppm otherwise, which also refuses refine()). The film holds each group's
    image as one sample per pixel (n = groups), so its mean is the mean of the group images and
    its variance the variance of that mean across groups: noise, not the bias every group
    shares. stats: time_s, paths (camera + photon paths), rays, groups, photons (emitted), all
    additive."""
    a, b = sample_range
    groups = whole_groups((a, b), settings.spp, GROUPS, "sppm")
    k = camera.intrinsics
    film = Film(k.width, k.height)
    photons = int(options.photons_per_pass or k.width * k.height)
    stats = {"time_s": 0.0, "paths": 0, "rays": 0, "groups": 0, "photons": 0}
    t0 = time.perf_counter()
    if groups:
        ps = prepared if prepared is not None else prepare(scene)
        _check_supported(scene, ps.mats)
        runs = _render_groups(ps, camera, groups, photons, None, int(settings.max_depth), settings.seed, ALPHA,
                              "caustics" in effects, None, settings.threads)
        for (g0, g1), ((state, _), rays) in zip(groups, runs):
            image = state.estimate(g1 - g0, photons)
            if not np.all(np.isfinite(image)):
                raise FloatingPointError("sppm produced a non-finite radiance (a bug: please report)")
            film.add_moments(image, image * image, np.ones(k.width * k.height, np.int64))
            stats["rays"] += rays
            stats["groups"] += 1
            stats["photons"] += (g1 - g0) * photons
            stats["paths"] += (g1 - g0) * (k.width * k.height + photons)
        stats["rays"] = int(round(stats["rays"]))
    stats["time_s"] = time.perf_counter() - t0
    return RenderResult.from_film(film, (a, b), "sppm", stats)
