"""``bdpt``: bidirectional path tracing (Veach 1997, ch. 10; pbrt-v3's BDPTIntegrator), compiled wavefront.

Two implementations of one estimator: :func:`render_bdpt` (what the integrator name runs) drives
the numba kernels of :mod:`render.integrators.bdpt_kernels`, a batch of camera samples per call
with Embree queried from compiled code; :func:`render_bdpt_numpy` is the numpy wavefront it was
ported from, kept as the tested reference (same random dimensions for the same purposes, so at
the same seed the two agree to float rounding: tests/render/test_bdpt_compiled.py). The
description below holds for both; the numpy functions in this module are its readable form.

For every camera sample one *eye subpath* z_0 (the pinhole) z_1 .. z_{t-1} and one *light
subpath* y_0 (a point on a light) y_1 .. y_{s-1} are traced, then every pair of prefixes is
joined, each join (s, t) being one sampling strategy for paths of s + t vertices:

* s = 0: the eye subpath hits an emitter (or escapes to the background, see below);
* s = 1: next-event estimation: a fresh light sample (:meth:`render.lights.LightSet.sample`)
  is connected to z_{t-1} with a shadow ray;
* t = 1: light tracing: y_{s-1} is connected to the pinhole and *splatted* to the pixel it
  projects to, with the pinhole's importance We = 1 / (A cos^4 theta) (pbrt's
  PerspectiveCamera; A = W H / (fx fy) is the image's area on the plane z = 1; each pass
  traces one light subpath per pixel, so a splat's expected sum over a pass is the pixel
  measurement with importance 1 / (A_pixel cos^4));
* s, t >= 2: y_{s-1} and z_{t-1} are joined by a shadow ray (f G f).

(s, t) = (1, 1) is skipped, as in pbrt: a light seen directly comes from s = 0 alone.
Every contribution is weighted by multiple importance sampling over all strategies of its path
length, power heuristic (Veach and Guibas 1995; ``heuristic="balance"`` gives pbrt's balance
weights), with pbrt-v3's MISWeight bookkeeping: each vertex stores the area densities
``pdfFwd`` (how its own subpath generated it) and ``pdfRev`` (how the other direction would
have), delta (specular) densities are stored as 0 and remapped to 1, a strategy whose join
touches a delta vertex (or a delta light's s = 0) is excluded from the sum, and the four
densities a join changes (the pdfRev of z_{t-1}, z_{t-2}, y_{s-1}, y_{s-2}) are recomputed for
it. The sums of ratio products over the unchanged vertices are prefix sums per subpath, so a
strategy's weight costs O(1) array operations.

Scope: Lambertian (RGB or texture; also :class:`render.bsdf.DiffuseEmitter`), mirror and
dielectric (Fresnel, refraction, total internal reflection) surfaces; one- and two-sided area
emitters and point, spot and directional lights (their emission sampled by
:func:`render.lights.sample_emission`; a directional light is an infinite, delta-direction
source as in pbrt: its light subpaths start on a disk of the scene's bounding radius).
``scene.background`` (uniform radiance at infinity) is reached by escaping eye rays only
(strategy s = 0, weight 1: no other strategy samples it). GGX materials, participating media
and distorted cameras raise ValueError naming bdpt.

Transport modes: eye subpaths carry radiance, so refraction scales their throughput by
(eta_i / eta_t)^2 (:func:`render.bsdf.dielectric_sample`); light subpaths carry importance and
are not scaled (pbrt's TransportMode::Importance; Veach 1997, section 5.2). Shading uses
geometric normals, so no shading-normal correction applies. Only Lambertian vertices are joined
(the delta BSDFs' f is zero for every given direction).

Path length: max_depth counts scattering events as in :mod:`render.integrators.path`: a full path
of s + t vertices has s + t - 2 bounces and is kept iff that is <= max_depth (eye subpaths have
up to max_depth + 2 vertices with the pinhole, light subpaths max_depth + 1). Russian roulette
on subpath extension, when leaving a surface vertex of index >= rr_depth (0 = the first hit):
survive with min(1, max(beta) / max(beta_1)) (beta_1 = 1 for eye subpaths, the emitted flux for
light subpaths), survivors divided by it. The MIS weights ignore roulette (they still sum to one
over the strategies, so the estimate stays unbiased).

Caustics pruning: without 'caustics' among the effects, a path is dropped when, read from the
light, a specular vertex precedes a diffuse one (light that reaches a diffuse vertex through a
specular one, L..S..D..E, what volpath and sppm prune): per subpath vertex two flags (a diffuse /
specular vertex seen so far, such an ordered pair seen so far) decide it for every join, and
subpaths stop extending once the pair is seen.

Film and variance: one *pass* = one eye and one light subpath per pixel; its image (eye
contributions plus all splats of its light subpaths) is an unbiased estimate of every pixel, and
passes are independent, so the film holds per-pixel moments of pass images (n = passes):
``RenderResult.variance`` is the honest variance of the mean even though splats land in other
pixels (0 below two passes). Random numbers are the counter-based hash of
:mod:`render.sampling` keyed by (seed, pixel, pass) (light subpaths on a separate key stream),
so a pass's image does not depend on how passes are batched: renders of disjoint sample
(= pass) ranges merge exactly (:func:`render.film.merge_results`) and are deterministic.
Batches are traced by ``threads`` threads (the kernels release the GIL) and summed in batch
order, so the bytes do not depend on the thread count.
Secondary and shadow rays start at :func:`render.accel.spawn_origin` offsets.
"""
from __future__ import annotations

import queue
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..accel import spawn_origin
from ..bsdf import DIELECTRIC, LAMBERT, MIRROR, bsdf_eval, bsdf_pdf, bsdf_sample
from ..camera import Camera
from ..film import Film, RenderResult
from ..lights import AREA, DIRECTIONAL, POINT, SPOT, sample_emission, scene_bounds
from ..sampling import (_GOLDEN, _mix64, INV_PI, dot3, max3, orthonormal_frame, path_keys, to_local, to_world,
                        uniform_block)
from .bdpt_kernels import (N_FIELDS, N_STATE, BdptConfig, add_pass_moments, connect, extend, prefix_sums, queue_bound,
                           start_camera, start_light, trace_batch)
from .path import kernel_scene_of, pinhole_of
from .path_kernels import add_unoccluded
from .prepared import PreparedScene, prepare
from .settings import RenderSettings, check_heuristic, heuristic_exponent, parse_sample_range

__all__ = ["Options", "render_bdpt", "render_bdpt_numpy", "render_result"]

# how a density leaving a vertex converts to an area density at the previous one
_SURF, _POINTLIKE, _INFINITE = 0, 1, 2
#: light subpath j's hash key is that of "pixel" j + _LIGHT_STREAM (eye subpaths use pixel j)
_LIGHT_STREAM = 1 << 40
#: random dimensions: eye: jitter (0, 1), then per vertex i >= 1 from 2 + 8 (i - 1): lobe,
#: direction (2), roulette, light pick, light point (2), spare. Light: pick, point (2),
#: direction (2), side, then per vertex from 6 + 4 (i - 1): lobe, direction (2), roulette.
_EYE_DIM0, _EYE_STEP, _LIGHT_DIM0, _LIGHT_STEP = 2, 8, 6, 4
_CLAMP = 1e150  # density ratios are clamped to [1 / _CLAMP, _CLAMP] before the heuristic's power
_BIG = 1e300
_DEFAULT_BATCH = 1 << 14
#: camera samples per batch of the compiled kernels: a batch's subpaths (about 3.5 kB a sample
#: at max depth 8) then stay within the caches; 4096 ran 1.4x faster than 16384 (bench_hard_paths' scene)
_COMPILED_BATCH = 1 << 12


@dataclass(frozen=True)
class Options:
    """Options of ``bdpt`` (RenderSettings fields of the same names; no ``strategy``: every (s, t)
    strategy is always MIS-weighted)."""

    #: Russian roulette on subpath extension, when leaving vertices of index >= rr_depth
    roulette: bool = True
    #: first vertex index (0: the first hit) whose extension roulette may end
    rr_depth: int = 3
    #: MIS weights over the (s, t) strategies: "power" or "balance" (pbrt's BDPT weights)
    heuristic: str = "power"

    def __post_init__(self):
        check_heuristic(self.heuristic)
        if self.rr_depth < 0:
            raise ValueError(f"bdpt: rr_depth must be >= 0, got {self.rr_depth}")


def _check_supported(scene, mats, camera: Camera) -> None:
    if mats.has_glossy:
        raise ValueError("integrator 'bdpt' cannot shade glossy (GGX) materials; use 'volpath'")
    if getattr(scene, "media", None):
        raise ValueError("integrator 'bdpt' cannot reach effect 'media' (participating media); use 'volpath'")
    if camera.intrinsics.has_distortion:
        raise ValueError("integrator 'bdpt' needs a pinhole camera without distortion (light tracing projects "
                         "onto the ideal image); render the pinhole image and distort it afterwards")


class _Subpaths:
    """N subpaths of up to nv vertices, vertex-major arrays (nv, N, ...).

    alive: the vertex exists. p, ng (geometric normal), nf (BSDF frame normal: facing wo for
    two-sided materials, outward for dielectrics), wo (unit, towards the previous vertex),
    beta (throughput arriving at the vertex), alb (diffuse albedo or mirror reflectance).
    fwd / rev: area densities of the vertex from its own subpath / from the other direction
    (0 = delta). conv: factor turning a solid-angle density leaving vertex i towards i - 1
    into an area density at i - 1. delta: specular vertex. kind, obj, tri: material kind,
    object, triangle. has / caus: caustics-pruning flags (see the module docstring).
    cond, S: MIS prefix data (:func:`_prefix`).
    """

    def __init__(self, nv: int, n: int):
        self.nv = nv
        self.alive = np.zeros((nv, n), bool)
        self.p, self.ng, self.nf, self.wo, self.beta, self.alb = (np.zeros((nv, n, 3)) for _ in range(6))
        self.fwd, self.rev, self.conv = np.zeros((nv, n)), np.zeros((nv, n)), np.zeros((nv, n))
        self.delta = np.zeros((nv, n), bool)
        self.kind = np.full((nv, n), -1, np.int64)
        self.obj = np.zeros((nv, n), np.int64)
        self.tri = np.zeros((nv, n), np.int64)
        self.has = np.zeros((nv, n), bool)
        self.caus = np.zeros((nv, n), bool)
        self.cond = np.zeros((nv, n))
        self.S = np.zeros((nv, n))


@dataclass
class _Ctx:
    ps: PreparedScene
    camera: Camera
    max_depth: int
    roulette: bool
    rr_depth: int
    caustics: bool
    hexp: float
    only: frozenset | None
    radius: float
    rays: int = 0

    def use(self, s: int, t: int) -> bool:
        return self.only is None or (s, t) in self.only


def _ratio(num: np.ndarray, den: np.ndarray, hexp: float) -> np.ndarray:
    """(remap0(num) / remap0(den))^hexp, clamped (pbrt's remap0: a zero (delta) density counts as 1)."""
    r = np.where(num != 0, num, 1.0) / np.where(den != 0, den, 1.0)
    return np.clip(r, 1.0 / _CLAMP, _CLAMP) ** hexp


def _prefix(sub: _Subpaths, hexp: float, cond0: np.ndarray | None) -> None:
    """MIS prefix sums of a subpath's stored densities (pbrt's MISWeight loops, unrolled).

    cond[i] = 1 if moving the join to vertex i is a valid strategy (neither vertex i nor i - 1
    is delta; for a light subpath's vertex 0: the light is not a delta light, ``cond0``).
    S[m] = sum_{i <= m} cond[i] prod_{i <= j <= m} r_j^hexp, r_j = rev_j / fwd_j, over vertices
    1..m of an eye subpath (the pinhole is never a join) or 0..m of a light subpath.
    """
    r = _ratio(sub.rev, sub.fwd, hexp)
    sub.cond[1:] = ~sub.delta[1:] & ~sub.delta[:-1]
    if cond0 is not None:
        sub.cond[0] = cond0
        sub.S[0] = r[0] * sub.cond[0]
    else:
        sub.S[0] = 0.0
    with np.errstate(over="ignore"):
        for m in range(1, sub.nv):
            sub.S[m] = np.minimum(r[m] * (sub.cond[m] + sub.S[m - 1]), _BIG)


def _eye_sum(E: _Subpaths, t: int, k: np.ndarray, r1, r2) -> np.ndarray:
    """Sum of relative densities^hexp of the strategies moving the join into the eye subpath.
    r1, r2: the join's (ratio^hexp) at z_{t-1} and z_{t-2} (r2 unused for t = 2)."""
    if t <= 1:
        return np.zeros(len(k))
    if t == 2:
        return r1  # the pinhole is not delta: (s + 1, 1), light tracing, counts
    inner = E.cond[t - 2, k] + E.S[t - 3, k]
    with np.errstate(over="ignore"):
        return np.minimum(r1 * ((~E.delta[t - 2, k]) + np.minimum(r2 * inner, _BIG)), _BIG)


def _light_sum(L: _Subpaths, s: int, k: np.ndarray, r1, r2, cond0=None) -> np.ndarray:
    """The same along the light subpath. r1, r2: at y_{s-1}, y_{s-2}. cond0: for s = 1, whether
    the sampled light is not a delta light (s = 0 counts)."""
    if s == 0:
        return np.zeros(len(k))
    if s == 1:
        return r1 * cond0
    inner = (L.cond[s - 2, k] if s >= 2 else 0.0) + (L.S[s - 3, k] if s >= 3 else 0.0)
    with np.errstate(over="ignore"):
        return np.minimum(r1 * ((~L.delta[s - 2, k]) + np.minimum(r2 * inner, _BIG)), _BIG)


def _lambert(sub: _Subpaths, i: int, k: np.ndarray, w: np.ndarray):
    """BSDF at vertices (i, k) for the direction w (K, 3): (f (K, 3), cos of w against the frame
    normal (K,), pdf of sampling w (K,), pdf of sampling wo given w (K,)). Joined vertices are
    Lambertian (render.bsdf.bsdf_eval / bsdf_pdf in the vertex's local frame)."""
    nf = sub.nf[i, k]
    t1, t2 = orthonormal_frame(nf)
    wo_l = to_local(sub.wo[i, k], t1, t2, nf)
    wi_l = to_local(w, t1, t2, nf)
    kind = sub.kind[i, k]
    return (bsdf_eval(kind, sub.alb[i, k], wo_l, wi_l), wi_l[:, 2], bsdf_pdf(kind, wo_l, wi_l),
            bsdf_pdf(kind, wi_l, wo_l))


def _segment(o_p, o_n, t_p, t_n, extent):
    """Shadow rays between surface points o_p and t_p (K, 3) (normals o_n, t_n; None: a point
    not on a surface): both ends offset towards each other. (origins, unit dirs, tmax)."""
    w = t_p - o_p
    w = w / np.maximum(np.linalg.norm(w, axis=1), 1e-300)[:, None]
    o = spawn_origin(o_p, o_n, w, extent)
    tgt = t_p if t_n is None else spawn_origin(t_p, t_n, -w, extent)
    v = tgt - o
    dist = np.linalg.norm(v, axis=1)
    return o, v / np.maximum(dist, 1e-300)[:, None], dist * (1.0 - 1e-6)


# ---------------------------------------------------------------- subpaths
def _walk(ctx: _Ctx, sub: _Subpaths, paths, o, d, beta, pdf_dir, prev_p, prev_n, prev_mode, keys, light: bool,
          escapes: list) -> None:
    """Extend subpaths from their vertex 0 (filled by the caller) to vertices 1 .. nv - 1.

    paths: (M,) indices of the subpaths whose first ray (o, d (M, 3)) is traced; beta (M, 3) the
    throughput arriving at vertex 1; pdf_dir (M,) the density of d (solid angle; per unit area
    perpendicular to d when prev_mode is _INFINITE); prev_p, prev_n, prev_mode: vertex 0.
    Escaping eye rays are appended to ``escapes`` as (paths, beta, vertex index they leave).
    """
    ps = ctx.ps
    geom, mats, accel = ps.geom, ps.mats, ps.accel
    extent = geom.extent
    has_bg = not light and bool(ps.background.max() > 0)
    ref = max3(beta) if light else np.ones(len(paths))
    dim0, step = (_LIGHT_DIM0, _LIGHT_STEP) if light else (_EYE_DIM0, _EYE_STEP)
    floor2 = (1e-9 * extent) ** 2
    for i in range(1, sub.nv):
        if len(paths) == 0:
            break
        h = accel.intersect(o, d)
        ctx.rays += len(paths)
        hit = h.tri >= 0
        if has_bg and not hit.all():
            escapes.append((paths[~hit], beta[~hit], i - 1))
        if not hit.all():
            paths, d, beta, pdf_dir, ref = paths[hit], d[hit], beta[hit], pdf_dir[hit], ref[hit]
            prev_p, prev_n, prev_mode = prev_p[hit], prev_n[hit], prev_mode[hit]
        tri, hu, hv = h.tri[hit], h.u[hit], h.v[hit]
        p, ng = geom.point_normal(tri, hu, hv)
        obj = geom.obj[tri]
        kind = mats.kind[obj]
        w = p - prev_p
        d2 = np.maximum(dot3(w, w), floor2)
        cos_in = np.abs(dot3(d, ng))
        inf = prev_mode == _INFINITE
        fwd = np.where(inf, pdf_dir * cos_in, pdf_dir * cos_in / d2)
        conv = np.where(prev_mode == _SURF, np.abs(dot3(prev_n, d)) / d2, np.where(inf, 1.0, 1.0 / d2))
        flip = (kind != DIELECTRIC) & (dot3(ng, d) > 0)
        nf = np.where(flip[:, None], -ng, ng)
        lamb = kind == LAMBERT
        delta = (kind == MIRROR) | (kind == DIELECTRIC)
        alb = mats.albedo[obj]
        if mats.textures and lamb.any():
            li = np.nonzero(lamb)[0]
            alb[li] = mats.diffuse_albedo(obj[li], lambda m: geom.texcoords(tri[li][m], hu[li][m], hv[li][m]))
        has0, caus0 = sub.has[i - 1, paths], sub.caus[i - 1, paths]
        if light:  # read from the light: a specular vertex, then a diffuse one
            has, caus = has0 | delta, caus0 | (has0 & lamb)
        else:  # read from the eye: a diffuse vertex, then a specular one
            has, caus = has0 | lamb, caus0 | (has0 & delta)
        sub.alive[i, paths] = True
        sub.p[i, paths], sub.ng[i, paths], sub.nf[i, paths], sub.wo[i, paths] = p, ng, nf, -d
        sub.beta[i, paths], sub.alb[i, paths] = beta, alb
        sub.fwd[i, paths], sub.conv[i, paths], sub.delta[i, paths] = fwd, conv, delta
        sub.kind[i, paths], sub.obj[i, paths], sub.tri[i, paths] = kind, obj, tri
        sub.has[i, paths], sub.caus[i, paths] = has, caus
        if i == sub.nv - 1:
            break
        ext = lamb | delta
        if not ctx.caustics:
            ext &= ~caus  # every path through this vertex and beyond would be pruned
        e = np.nonzero(ext)[0]
        if len(e) == 0:
            break
        pe = paths[e]
        u = uniform_block(keys[pe], dim0 + step * (i - 1), 4)
        nfe = nf[e]
        t1, t2 = orthonormal_frame(nfe)
        wo_l = to_local(-d[e], t1, t2, nfe)
        ke = kind[e]
        bs = bsdf_sample(ke, alb[e], mats.ior[obj[e]], wo_l, u[:, 0], u[:, 1:3])
        wi = to_world(bs.wi, t1, t2, nfe)
        weight = bs.weight
        if light:  # importance transport: no (eta_i / eta_t)^2 radiance scaling through glass
            glass = ke == DIELECTRIC
            if glass.any():
                weight[glass] = bs.valid[glass, None].astype(np.float64)
        rev_solid = np.where(bs.delta, 0.0, bsdf_pdf(ke, bs.wi, wo_l))
        sub.rev[i - 1, pe] = rev_solid * conv[e]
        nb = beta[e] * weight
        ok = bs.valid & (max3(nb) > 0)
        if ctx.roulette and i - 1 >= ctx.rr_depth:
            q = np.minimum(1.0, max3(nb) / ref[e])
            ok &= u[:, 3] < q
            nb = nb / np.where(ok, q, 1.0)[:, None]
        s = e[ok]
        paths, beta, d = paths[s], nb[ok], wi[ok]
        pdf_dir = np.where(bs.delta[ok], 0.0, bs.pdf[ok])
        o = spawn_origin(p[s], ng[s], d, extent)
        prev_p, prev_n, prev_mode, ref = p[s], ng[s], np.full(len(s), _SURF), ref[s]


# ---------------------------------------------------------------- one batch of passes
@dataclass
class _Batch:
    """One batch of camera samples: passes sample0 .. of pixels [pix0, pix1), N = n_pass x pixels.

    pixel, sample, pass_local: (N,) int64 per camera sample; keys_e / keys_l: (N,) uint64 hash
    keys of its eye and light subpaths; tgt_eye: (N,) its slot in the batch's images (pass_local
    x H W + pixel). A: the image's area on the plane z = 1; centre, fwd_axis: the pinhole and
    its optical axis (world)."""

    n_pass: int
    N: int
    W: int
    H: int
    pixel: np.ndarray
    sample: np.ndarray
    pass_local: np.ndarray
    keys_e: np.ndarray
    keys_l: np.ndarray
    tgt_eye: np.ndarray
    A: float
    centre: np.ndarray
    fwd_axis: np.ndarray

    @property
    def npix(self) -> int:
        return self.W * self.H


class _Joins:
    """The contributions of a batch's strategies: those needing no shadow ray (s = 0) and those
    behind one (origin, unit direction, tmax), each with its image slot and value (K, 3)."""

    def __init__(self):
        self.direct_t, self.direct_v = [], []
        self.sh_o, self.sh_d, self.sh_t, self.sh_tgt, self.sh_v = [], [], [], [], []

    def add(self, tgt: np.ndarray, val: np.ndarray) -> None:
        self.direct_t.append(tgt)
        self.direct_v.append(val)

    def shadow(self, o, d, t, tgt, val) -> None:
        self.sh_o.append(o), self.sh_d.append(d), self.sh_t.append(t), self.sh_tgt.append(tgt), self.sh_v.append(val)

    def image(self, ctx: _Ctx, size: int) -> np.ndarray:
        """(size, 3) float64: every unoccluded contribution summed into its slot (one occlusion
        query for all shadow rays)."""
        img = np.zeros((size, 3))
        tg, vals = list(self.direct_t), list(self.direct_v)
        if self.sh_o:
            so, sd, st = np.concatenate(self.sh_o), np.concatenate(self.sh_d), np.concatenate(self.sh_t)
            vis = ~ctx.ps.accel.occluded(so, sd, np.maximum(st, 0.0))
            ctx.rays += len(so)
            tg.append(np.concatenate(self.sh_tgt)[vis])
            vals.append(np.concatenate(self.sh_v)[vis])
        if tg:
            tgc = np.concatenate(tg)
            vc = np.concatenate(vals)
            for c in range(3):
                img[:, c] = np.bincount(tgc, weights=vc[:, c], minlength=size)
        return img


def _batch(ctx: _Ctx, seed: int, sample0: int, n_pass: int, pix0: int, pix1: int) -> _Batch:
    k = ctx.camera.intrinsics
    npc = pix1 - pix0
    N = n_pass * npc
    flat = np.arange(N)
    pass_local = flat // npc
    pixel = pix0 + flat % npc
    sample = sample0 + pass_local
    c2w = ctx.camera.cam_to_world
    return _Batch(n_pass, N, k.width, k.height, pixel, sample, pass_local, path_keys(seed, pixel, sample),
                  path_keys(seed, pixel + _LIGHT_STREAM, sample), pass_local * k.width * k.height + pixel,
                  k.width * k.height / (k.fx * k.fy), c2w[:3, 3].copy(), c2w[:3, 2])


def _eye_subpaths(ctx: _Ctx, b: _Batch) -> tuple[_Subpaths, list]:
    """The batch's eye subpaths (vertex 0 the pinhole) and their escaping rays (see :func:`_walk`)."""
    N = b.N
    E = _Subpaths(ctx.max_depth + 2, N)
    E.alive[0] = True
    E.p[0] = b.centre
    E.fwd[0] = 1.0
    u = uniform_block(b.keys_e, 0, 2)
    jit = np.stack([b.pixel % b.W + u[:, 0], b.pixel // b.W + u[:, 1]], axis=1)
    o, d = ctx.camera.pixel_rays(jit)
    cos0 = d @ b.fwd_axis
    escapes = []
    _walk(ctx, E, np.arange(N), o, d, np.ones((N, 3)), 1.0 / (b.A * cos0 ** 3), o, np.zeros((N, 3)),
          np.full(N, _POINTLIKE), b.keys_e, False, escapes)
    return E, escapes


def _light_subpaths(ctx: _Ctx, b: _Batch) -> tuple[_Subpaths, np.ndarray]:
    """The batch's light subpaths (vertex 0 on a light, :func:`render.lights.sample_emission`)
    and (N,) whether each started on a delta (point, spot, directional) light."""
    ps = ctx.ps
    N = b.N
    L = _Subpaths(ctx.max_depth + 1, N)
    lkind = np.full(N, AREA, np.int64)
    if not ps.lights.empty:
        u = uniform_block(b.keys_l, 0, 6)
        es = sample_emission(ps.lights, ps.geom, u[:, 0], u[:, 1:3], u[:, 3:5], u[:, 5])
        lkind = es.kind
        live = np.nonzero(max3(es.flux) > 0)[0]
        dirl = es.kind == DIRECTIONAL
        L.alive[0, live] = True
        L.p[0], L.ng[0] = es.p, es.normal
        L.fwd[0] = np.where(dirl, 0.0, es.pmf * es.pdf_pos)  # pbrt: 0 for a delta-direction light
        mode = np.where(es.kind == AREA, _SURF, np.where(dirl, _INFINITE, _POINTLIKE))
        pdf_dir = np.where(dirl, es.pdf_pos, es.pdf_dir)
        _walk(ctx, L, live, es.o[live], es.d[live], es.flux[live], pdf_dir[live], es.p[live], es.normal[live],
              mode[live], b.keys_l, True, [])
    return L, lkind != AREA


def _connect_s0(ctx: _Ctx, b: _Batch, E: _Subpaths, escapes: list, joins: _Joins) -> None:
    """s = 0: escaping eye rays (the background: their only strategy) and eye subpaths hitting emitters."""
    ps, hexp = ctx.ps, ctx.hexp
    mats, lights = ps.mats, ps.lights
    for paths, beta, i in escapes:  # the ray leaving z_i escaped: strategy (0, i + 2), the only one
        if not ctx.use(0, i + 2):
            continue
        keep = np.ones(len(paths), bool) if ctx.caustics else ~E.caus[i, paths]
        joins.add(b.tgt_eye[paths[keep]], beta[keep] * ps.background)
    for t in range(2, E.nv + 1):
        i = t - 1
        if not ctx.use(0, t):
            continue
        sel = E.alive[i] & mats.emits[E.obj[i]]
        if not ctx.caustics:
            sel &= ~E.caus[i - 1]
        kk = np.nonzero(sel)[0]
        if len(kk) == 0:
            continue
        obj = E.obj[i, kk]
        cos_e = dot3(E.wo[i, kk], E.ng[i, kk])
        two = mats.two_sided[obj]
        front = two | (cos_e > 0)
        kk, obj, cos_e, two = kk[front], obj[front], cos_e[front], two[front]
        C = E.beta[i, kk] * mats.Le[obj]
        if ctx.only is None and t > 2:
            pt_rev = lights.tri_pdf_area[E.tri[i, kk]]
            ptm_rev = np.abs(cos_e) * INV_PI * np.where(two, 0.5, 1.0) * E.conv[i, kk]
            es_ = _eye_sum(E, t, kk, _ratio(pt_rev, E.fwd[i, kk], hexp), _ratio(ptm_rev, E.fwd[i - 1, kk], hexp))
            C = C / (1.0 + es_)[:, None]
        joins.add(b.tgt_eye[kk], C)


def _light_vertex_densities(ctx: _Ctx, wi, ln, ent, is_area, finite, d2):
    """For s = 1: the sampled light vertex's own density (pbrt's pdfFwd), the density of its
    emission towards z_{t-1} (solid angle), and the factor converting a solid-angle density
    leaving z_{t-1} into an area density at the light vertex. (K,) each."""
    lights = ctx.ps.lights
    m = len(wi)
    fwd_q = np.zeros(m)
    pdir = np.zeros(m)
    conv_q = np.where(finite, 1.0 / d2, 1.0)
    a = np.nonzero(is_area)[0]
    if len(a):
        ja = ent[a]
        cos_l = np.abs(dot3(wi[a], ln[a]))
        fwd_q[a] = lights.a_pdf_area[ja]
        pdir[a] = cos_l * INV_PI * np.where(lights.two_sided[ja], 0.5, 1.0)
        conv_q[a] = cos_l / d2[a]
    dl = np.nonzero(~is_area)[0]
    if len(dl):
        li = ent[dl] - lights.n_area
        lk = lights.d_kind[li]
        fwd_q[dl] = np.where(lk == DIRECTIONAL, 0.0, lights.pmf[ent[dl]])
        co = lights.d_cos[li, 1]
        inside = -dot3(wi[dl], lights.d_dir[li]) >= co
        pdir[dl] = np.where(lk == POINT, 0.25 * INV_PI,
                            np.where(lk == SPOT, inside / (2.0 * np.pi * np.maximum(1.0 - co, 1e-300)),
                                     1.0 / (np.pi * ctx.radius ** 2)))
    return fwd_q, pdir, conv_q


def _connect_s1(ctx: _Ctx, b: _Batch, E: _Subpaths, L: _Subpaths, joins: _Joins) -> None:
    """s = 1: next-event estimation at z_{t-1}: a fresh light sample joined by a shadow ray."""
    ps, hexp = ctx.ps, ctx.hexp
    lights, extent = ps.lights, ps.geom.extent
    weighted = ctx.only is None
    if lights.empty:
        return
    for t in range(2, ctx.max_depth + 2):
        i = t - 1
        if not ctx.use(1, t):
            continue
        sel = E.alive[i] & (E.kind[i] == LAMBERT)
        if not ctx.caustics:
            sel &= ~E.caus[i]
        kk = np.nonzero(sel)[0]
        if len(kk) == 0:
            continue
        u = uniform_block(b.keys_e[kk], _EYE_DIM0 + _EYE_STEP * (i - 1) + 4, 3)
        p = E.p[i, kk]
        ls = lights.sample(p, u[:, 0], u[:, 1:3])
        f, cos_p, pdf_l, pdf_r = _lambert(E, i, kk, ls.wi)
        with np.errstate(divide="ignore", invalid="ignore"):
            C = E.beta[i, kk] * f * ls.Li * (cos_p / ls.pdf)[:, None]
        ok = ls.valid & (cos_p > 0) & (ls.pdf > 0) & np.isfinite(ls.pdf)
        ok &= np.all(np.isfinite(C), axis=1) & (max3(np.where(ok[:, None], C, 0.0)) > 0)
        m = np.nonzero(ok)[0]
        if len(m) == 0:
            continue
        kk, p, C, cos_p, pdf_l, pdf_r = kk[m], p[m], C[m], cos_p[m], pdf_l[m], pdf_r[m]
        wi, dist = ls.wi[m], ls.dist[m]
        ent = np.minimum(np.searchsorted(lights.cdf, u[m, 0] * lights.cdf[-1], side="right"), len(lights.pmf) - 1)
        is_area = ent < lights.n_area
        finite = np.isfinite(dist)
        dist_f = np.where(finite, dist, 1.0)
        d2 = dist_f * dist_f
        ln = np.zeros((len(m), 3))  # the light point's normal (area), for the offset and the densities
        if weighted or is_area.any():
            a = np.nonzero(is_area)[0]
            ln[a] = lights.a_normal[ent[a]]
        if weighted:
            fwd_q, pdir, conv_q = _light_vertex_densities(ctx, wi, ln, ent, is_area, finite, d2)
            pt_rev = pdir * cos_p * np.where(finite, 1.0 / d2, 1.0)
            qs_rev = pdf_l * conv_q
            r1 = _ratio(pt_rev, E.fwd[i, kk], hexp)
            r2 = _ratio(pdf_r * E.conv[i, kk], E.fwd[i - 1, kk], hexp)
            tot = _eye_sum(E, t, kk, r1, r2) + _light_sum(L, 1, kk, _ratio(qs_rev, fwd_q, hexp), None, is_area)
            C = C / (1.0 + tot)[:, None]
        o_ = spawn_origin(p, E.ng[i, kk], wi, extent)
        tgt_p = p + wi * dist_f[:, None]
        tgt_p = np.where(is_area[:, None], spawn_origin(tgt_p, ln, -wi, extent), tgt_p)
        v = tgt_p - o_
        dd = np.linalg.norm(v, axis=1)
        dirs = np.where(finite[:, None], v / np.maximum(dd, 1e-300)[:, None], wi)
        tmax = np.where(finite, dd * (1.0 - 1e-6), 3e38)
        joins.shadow(o_, dirs, tmax, b.tgt_eye[kk], C)


def _connect_t1(ctx: _Ctx, b: _Batch, L: _Subpaths, joins: _Joins) -> None:
    """t = 1: light tracing: y_{s-1} joined to the pinhole and splatted to the pixel it projects to."""
    cam, hexp = ctx.camera, ctx.hexp
    W, H, A, centre = b.W, b.H, b.A, b.centre
    for s in range(2, L.nv + 1):
        j = s - 1
        if not ctx.use(s, 1):
            continue
        sel = L.alive[j] & (L.kind[j] == LAMBERT)
        if not ctx.caustics:
            sel &= ~L.caus[j]
        kk = np.nonzero(sel)[0]
        if len(kk) == 0:
            continue
        q = L.p[j, kk]
        uv, z = cam.project(q)
        inside = (z > 0) & np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) \
            & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        m = np.nonzero(inside)[0]
        if len(m) == 0:
            continue
        kk, q, uv, z = kk[m], q[m], uv[m], z[m]
        w = centre - q
        d2 = dot3(w, w)
        dist = np.sqrt(d2)
        wn = w / dist[:, None]
        f, cos_q, pdf_l, pdf_r = _lambert(L, j, kk, wn)
        cos_cam = z / dist
        pdf_cam = 1.0 / (A * cos_cam ** 3)  # the pinhole's direction density (per unit solid angle)
        we = pdf_cam / cos_cam  # We = 1 / (A cos^4)
        C = L.beta[j, kk] * f * (np.maximum(cos_q, 0.0) * we * cos_cam / d2)[:, None]
        ok = (cos_q > 0) & (max3(C) > 0)
        m = np.nonzero(ok)[0]
        if len(m) == 0:
            continue
        kk, q, uv, C, cos_q, pdf_r, d2, wn = kk[m], q[m], uv[m], C[m], cos_q[m], pdf_r[m], d2[m], wn[m]
        if ctx.only is None:
            r1 = _ratio(pdf_cam[m] * cos_q / d2, L.fwd[j, kk], hexp)
            r2 = _ratio(pdf_r * L.conv[j, kk], L.fwd[j - 1, kk], hexp)
            C = C / (1.0 + _light_sum(L, s, kk, r1, r2))[:, None]
        px = np.minimum(np.floor(uv[:, 0]).astype(np.int64), W - 1)
        py = np.minimum(np.floor(uv[:, 1]).astype(np.int64), H - 1)
        o_, d_, t_ = _segment(q, L.ng[j, kk], np.broadcast_to(centre, q.shape), None, ctx.ps.geom.extent)
        joins.shadow(o_, d_, t_, b.pass_local[kk] * b.npix + py * W + px, C)


def _connect_inner(ctx: _Ctx, b: _Batch, E: _Subpaths, L: _Subpaths, joins: _Joins) -> None:
    """s, t >= 2: y_{s-1} and z_{t-1} joined by a shadow ray (f G f)."""
    hexp, extent = ctx.hexp, ctx.ps.geom.extent
    for t in range(2, E.nv + 1):
        i = t - 1
        for s in range(2, L.nv + 1):
            if s + t - 2 > ctx.max_depth or not ctx.use(s, t):
                continue
            j = s - 1
            sel = E.alive[i] & L.alive[j] & (E.kind[i] == LAMBERT) & (L.kind[j] == LAMBERT)
            if not ctx.caustics:
                sel &= ~(E.caus[i] | L.caus[j] | (E.has[i] & L.has[j]))
            kk = np.nonzero(sel)[0]
            if len(kk) == 0:
                continue
            q, p = L.p[j, kk], E.p[i, kk]
            w = p - q
            d2 = np.maximum(dot3(w, w), (1e-9 * extent) ** 2)
            wn = w / np.sqrt(d2)[:, None]
            fq, cos_q, pq_f, pq_r = _lambert(L, j, kk, wn)
            fp, cos_p, pp_f, pp_r = _lambert(E, i, kk, -wn)
            g = np.maximum(cos_q, 0.0) * np.maximum(cos_p, 0.0) / d2
            C = L.beta[j, kk] * fq * fp * E.beta[i, kk] * g[:, None]
            ok = (cos_q > 0) & (cos_p > 0) & (max3(C) > 0)
            m = np.nonzero(ok)[0]
            if len(m) == 0:
                continue
            kk, q, p, C = kk[m], q[m], p[m], C[m]
            if ctx.only is None:
                cq, cp, dd2 = cos_q[m], cos_p[m], d2[m]
                r1e = _ratio(pq_f[m] * cp / dd2, E.fwd[i, kk], hexp)
                r2e = _ratio(pp_r[m] * E.conv[i, kk], E.fwd[i - 1, kk], hexp)
                r1l = _ratio(pp_f[m] * cq / dd2, L.fwd[j, kk], hexp)
                r2l = _ratio(pq_r[m] * L.conv[j, kk], L.fwd[j - 1, kk], hexp)
                C = C / (1.0 + _eye_sum(E, t, kk, r1e, r2e) + _light_sum(L, s, kk, r1l, r2l))[:, None]
            o_, d_, t_ = _segment(q, L.ng[j, kk], p, E.ng[i, kk], extent)
            joins.shadow(o_, d_, t_, b.tgt_eye[kk], C)


def _render_chunk(ctx: _Ctx, seed: int, sample0: int, n_pass: int, pix0: int, pix1: int) -> np.ndarray:
    """Passes sample0 .. sample0 + n_pass - 1 over pixels [pix0, pix1) (all pixels when n_pass > 1).
    Returns (n_pass * H * W, 3) float64: the passes' images (eye contributions + splats).

    Both subpaths are traced, then every strategy family is joined (pbrt's ConnectBDPT, one
    family at a time over the whole batch): s = 0, s = 1, t = 1, s and t >= 2."""
    b = _batch(ctx, seed, sample0, n_pass, pix0, pix1)
    E, escapes = _eye_subpaths(ctx, b)
    L, delta_light = _light_subpaths(ctx, b)
    _prefix(E, ctx.hexp, None)
    _prefix(L, ctx.hexp, ~delta_light)
    joins = _Joins()
    _connect_s0(ctx, b, E, escapes, joins)
    _connect_s1(ctx, b, E, L, joins)
    _connect_t1(ctx, b, L, joins)
    _connect_inner(ctx, b, E, L, joins)
    return joins.image(ctx, n_pass * b.npix)


# ---------------------------------------------------------------- the integrator
def render_bdpt_numpy(scene, camera: Camera, spp: int, max_depth: int = 8, seed: int = 0, prepared=None, *,
                      sample_range: tuple[int, int] | None = None, roulette: bool = True, rr_depth: int = 3,
                      caustics: bool = True, heuristic: str = "power", batch_paths: int = _DEFAULT_BATCH,
                      strategies=None) -> RenderResult:
    """Render ``camera``'s view of ``scene`` by bidirectional path tracing, numpy wavefront (the
    tested reference of the compiled :func:`render_bdpt`: the same estimator and random numbers).

    spp: passes (one eye and one light subpath per pixel each) when no sample_range is given.
    sample_range: half-open range of pass indices [a, b) (renders of disjoint ranges merge).
    max_depth: maximum scattering events of a full path. seed: the render's seed.
    prepared: a :class:`PreparedScene` to reuse. roulette, rr_depth: Russian
    roulette on subpath extension. caustics: False drops caustic paths (module docstring).
    heuristic: "power" (default) or "balance". batch_paths: subpaths per wavefront batch (whole
    passes are batched together; a large image's pass is split over pixels); it does not change
    the per-pass images, only summation order.
    strategies: None (all strategies, MIS-weighted) or a collection of (s, t) pairs to evaluate
    *unweighted*, alone (a diagnostic: each strategy alone is an unbiased estimate of the paths
    it can sample; the background counts as s = 0).

    Returns a :class:`render.film.RenderResult`: mean (H, W, 3) float32 and the variance of the
    mean from the per-pass images, integrator "bdpt", stats (time_s, paths, rays, passes).
    """
    t0 = time.perf_counter()
    a, b = parse_sample_range(spp, sample_range, "bdpt")
    if int(max_depth) < 0 or int(rr_depth) < 0 or int(batch_paths) < 1:
        raise ValueError("bdpt: max_depth and rr_depth must be >= 0, batch_paths >= 1")
    if heuristic not in ("power", "balance"):
        raise ValueError(f"bdpt: heuristic must be power or balance, got {heuristic!r}")
    ps = prepared if prepared is not None else prepare(scene)
    _check_supported(scene, ps.mats, camera)
    only = None if strategies is None else frozenset((int(s), int(t)) for s, t in strategies)
    ctx = _Ctx(ps, camera, int(max_depth), bool(roulette), int(rr_depth), bool(caustics),
               heuristic_exponent(heuristic), only, scene_bounds(ps.geom)[1])
    k = camera.intrinsics
    npix = k.width * k.height
    film = Film(k.width, k.height)
    seed = int(seed)
    batch = int(batch_paths)

    def add(img: np.ndarray) -> None:
        if not np.all(np.isfinite(img)):
            raise FloatingPointError("bdpt produced a non-finite radiance (a bug: please report)")
        x = img.reshape(-1, npix, 3)
        film.add_moments(x.sum(0), (x * x).sum(0), np.full(npix, len(x), np.int64))

    if npix <= batch:
        per = max(1, batch // npix)
        for s0 in range(a, b, per):
            n_pass = min(per, b - s0)
            add(_render_chunk(ctx, seed, s0, n_pass, 0, npix))
    else:
        for s0 in range(a, b):
            img = np.zeros((npix, 3))
            for p0 in range(0, npix, batch):
                img += _render_chunk(ctx, seed, s0, 1, p0, min(p0 + batch, npix))
            add(img)
    stats = {"time_s": time.perf_counter() - t0, "paths": int(2 * npix * (b - a)), "rays": int(ctx.rays),
             "passes": int(b - a)}
    return RenderResult.from_film(film, (a, b), "bdpt", stats)


# ---------------------------------------------------------------- the compiled integrator
def _kernel_config(ctx: _Ctx) -> BdptConfig:
    """The kernels' :class:`render.integrators.bdpt_kernels.BdptConfig` of a render."""
    nv_e, nv_l = ctx.max_depth + 2, ctx.max_depth + 1
    if ctx.only is None:
        use = np.ones((nv_l + 1, nv_e + 1), np.bool_)
    else:
        use = np.zeros((nv_l + 1, nv_e + 1), np.bool_)
        for s, t in ctx.only:
            if 0 <= s <= nv_l and 0 <= t <= nv_e:
                use[s, t] = True
    k = ctx.camera.intrinsics
    centre, radius = scene_bounds(ctx.ps.geom)
    return BdptConfig(ctx.max_depth, nv_e, nv_l, ctx.roulette, ctx.rr_depth, ctx.caustics, float(ctx.hexp),
                      ctx.only is None, use, bool(ctx.ps.background.max() > 0), float(radius),
                      np.ascontiguousarray(centre, dtype=np.float64), int(k.width), int(k.height),
                      float(k.width * k.height / (k.fx * k.fy)))


def _walk_compiled(ks, cfg: BdptConfig, accel, light: bool, m: int, bufs, keys, V, Fl, Iv, img, tgt) -> int:
    """Extend m subpaths whose first rays are in bufs[0] vertex by vertex (one Embree query and
    one :func:`render.integrators.bdpt_kernels.extend` per vertex). Returns the rays traced."""
    cur, nxt = bufs
    rays = 0
    for i in range(1, cfg.nv_l if light else cfg.nv_e):
        if m == 0:
            break
        prim, _, hu, hv = accel.intersect_fast(cur[2][:m], cur[3][:m])
        rays += m
        m = extend(ks, cfg, i, light, prim, hu, hv, m, cur[0], cur[1], keys, V, Fl, Iv, img, tgt, *nxt)
        cur, nxt = nxt, cur
    return rays


class _Workspace:
    """The buffers of one batch of up to ``n`` camera samples (reused batch after batch by one
    thread: fresh zeroed arrays would cost their page faults every batch). Vertex fields that a
    kernel reads are written first (flags are cleared per batch, pdfRev when a vertex is stored),
    so nothing leaks from one batch into the next."""

    def __init__(self, cfg: BdptConfig, n: int):
        self.n = n
        self.E, self.L = np.zeros((n, cfg.nv_e, N_FIELDS)), np.zeros((n, cfg.nv_l, N_FIELDS))
        self.EF, self.LF = np.zeros((n, cfg.nv_e), np.uint8), np.zeros((n, cfg.nv_l), np.uint8)
        self.EI, self.LI = np.zeros((n, cfg.nv_e, 2), np.int64), np.zeros((n, cfg.nv_l, 2), np.int64)
        self.keys_e, self.keys_l, self.tgt = np.empty(n, np.uint64), np.empty(n, np.uint64), np.empty(n, np.int64)
        self.lkind = np.empty(n, np.int64)
        self.bufs = tuple((np.empty(n, np.int64), np.empty((n, N_STATE)), np.empty((n, 3), np.float32),
                           np.empty((n, 3), np.float32)) for _ in range(2))
        cap = max(8 * n, 4 * queue_bound(cfg.max_depth))
        self.queue = (np.empty((cap, 3), np.float32), np.empty((cap, 3), np.float32), np.empty(cap, np.float32),
                      np.empty(cap, np.int64), np.empty((cap, 3)))
        self.hit = (np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32))
        self.occ = np.empty(cap, np.int32)
        self.nbytes = (self.E.nbytes + self.L.nbytes + self.EI.nbytes + self.LI.nbytes + self.queue[4].nbytes
                       + 4 * cap * 8)


#: workspaces not in use, kept across renders: a fresh one's first touch (page faults on ~10 MB
#: at max depth 8) took 4 ms, and two threads faulting at once slowed each other: kept, a 48 x 48,
#: 64-pass render took 0.73-0.88x the time (three interleaved runs, bench_hard_paths' caustic).
#: Only workspaces up to _SPARE_BYTES are kept (max depth 64 makes 100 MB).
_SPARE: queue.SimpleQueue = queue.SimpleQueue()
_SPARE_BYTES = 32 << 20


def _take_workspace(cfg: BdptConfig, shape: tuple) -> _Workspace:
    """A spare workspace of ``shape`` (nv_e, nv_l, n), or a new one; spares of other shapes are
    dropped."""
    while True:
        try:
            s, ws = _SPARE.get_nowait()
        except queue.Empty:
            return _Workspace(cfg, shape[2])
        if s == shape:
            return ws


def _keep_workspaces(mine: queue.SimpleQueue, shape: tuple) -> None:
    """Move a finished render's workspaces to the spares, those up to _SPARE_BYTES."""
    while True:
        try:
            ws = mine.get_nowait()
        except queue.Empty:
            return
        if ws.nbytes <= _SPARE_BYTES:
            _SPARE.put((shape, ws))


def _render_chunk_compiled(ps: PreparedScene, cfg: BdptConfig, cam, seed_mix, ws: _Workspace, sample0: int,
                           n_pass: int, pix0: int, pix1: int) -> tuple[np.ndarray, int]:
    """:func:`_render_chunk` through the compiled kernels in workspace ``ws``: ((n_pass H W, 3)
    float64 pass images, rays traced)."""
    ks = kernel_scene_of(ps)
    accel = ps.accel
    npc = pix1 - pix0
    N = n_pass * npc
    E, L, EF, LF, EI, LI = ws.E[:N], ws.L[:N], ws.EF[:N], ws.LF[:N], ws.EI[:N], ws.LI[:N]
    EF[:] = 0
    LF[:] = 0
    keys_e, keys_l, tgt, lkind = ws.keys_e[:N], ws.keys_l[:N], ws.tgt[:N], ws.lkind[:N]
    lkind[:] = AREA
    bufs = ws.bufs
    img = np.zeros((n_pass * cfg.width * cfg.height, 3))
    if accel.direct is not None and trace_batch is not None:  # the whole batch in one compiled call
        rays = trace_batch(ks, cfg, cam, accel.direct.handle, seed_mix, sample0, pix0, npc, keys_e, keys_l, tgt, lkind,
                           E, EF, EI, L, LF, LI, bufs[0], bufs[1], ws.hit, ws.queue, ws.occ, img)
        return img, int(rays)
    start_camera(cfg, cam, seed_mix, sample0, pix0, npc, keys_e, keys_l, tgt, E, EF, *bufs[0])
    rays = _walk_compiled(ks, cfg, accel, False, N, bufs, keys_e, E, EF, EI, img, tgt)
    m = start_light(ks, cfg, keys_l, L, LF, lkind, *bufs[0])
    rays += _walk_compiled(ks, cfg, accel, True, m, bufs, keys_l, L, LF, LI, img, tgt)
    prefix_sums(E, EF, cfg.hexp, False, lkind)
    prefix_sums(L, LF, cfg.hexp, True, lkind)
    q = ws.queue
    k = 0
    while k < N:
        k, nq = connect(ks, cfg, cam, k, npc, keys_e, tgt, E, EF, EI, L, LF, LI, lkind, img, *q)
        if nq:
            occ = accel.occluded_fast(q[0][:nq], q[1][:nq], q[2][:nq])
            rays += nq
            add_unoccluded(img, q[3], q[4], occ)
    return img, rays


def render_bdpt(scene, camera: Camera, spp: int, max_depth: int = 8, seed: int = 0, prepared=None, *,
                sample_range: tuple[int, int] | None = None, roulette: bool = True, rr_depth: int = 3,
                caustics: bool = True, heuristic: str = "power", batch_paths: int = _COMPILED_BATCH,
                strategies=None, threads: int = 1) -> RenderResult:
    """Render ``camera``'s view of ``scene`` by bidirectional path tracing (compiled kernels,
    :mod:`render.integrators.bdpt_kernels`; the same estimator and random numbers as
    :func:`render_bdpt_numpy`).

    spp: passes (one eye and one light subpath per pixel each) when no sample_range is given.
    sample_range: half-open range of pass indices [a, b) (renders of disjoint ranges merge).
    max_depth: maximum scattering events of a full path. seed: the render's seed.
    prepared: a :class:`PreparedScene` to reuse. roulette, rr_depth: Russian
    roulette on subpath extension. caustics: False drops caustic paths (module docstring).
    heuristic: "power" (default) or "balance". batch_paths: subpaths per wavefront batch (whole
    passes are batched together; a large image's pass is split over pixels); it does not change
    the per-pass images, only summation order. threads: batches traced at once (the film sums
    them in batch order: the same bytes whatever the threads).
    strategies: None (all strategies, MIS-weighted) or a collection of (s, t) pairs to evaluate
    *unweighted*, alone (a diagnostic: each strategy alone is an unbiased estimate of the paths
    it can sample; the background counts as s = 0).

    Returns a :class:`render.film.RenderResult`: mean (H, W, 3) float32 and the variance of the
    mean from the per-pass images, integrator "bdpt", stats (time_s, paths, rays, passes).
    """
    t0 = time.perf_counter()
    a, b = parse_sample_range(spp, sample_range, "bdpt")
    if int(max_depth) < 0 or int(rr_depth) < 0 or int(batch_paths) < 1 or int(threads) < 1:
        raise ValueError("bdpt: max_depth and rr_depth must be >= 0, batch_paths and threads >= 1")
    if heuristic not in ("power", "balance"):
        raise ValueError(f"bdpt: heuristic must be power or balance, got {heuristic!r}")
    ps = prepared if prepared is not None else prepare(scene)
    _check_supported(scene, ps.mats, camera)
    only = None if strategies is None else frozenset((int(s), int(t)) for s, t in strategies)
    ctx = _Ctx(ps, camera, int(max_depth), bool(roulette), int(rr_depth), bool(caustics),
               heuristic_exponent(heuristic), only, scene_bounds(ps.geom)[1])
    cfg = _kernel_config(ctx)
    cam = pinhole_of(camera)
    kernel_scene_of(ps)
    k = camera.intrinsics
    npix = k.width * k.height
    film = Film(k.width, k.height)
    seed_mix = _mix64(np.array([np.uint64(int(seed) & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    batch = int(batch_paths)
    # units: (first pass, passes, pixel range); a unit's image is whole passes, or one pass's pixel slice
    if npix <= batch:
        per = max(1, batch // npix)
        units = [(s0, min(per, b - s0), 0, npix) for s0 in range(a, b, per)]
    else:
        units = [(s0, 1, p0, min(p0 + batch, npix)) for s0 in range(a, b) for p0 in range(0, npix, batch)]

    n_max = max(n_pass * (p1 - p0) for _, n_pass, p0, p1 in units)
    shape = (cfg.nv_e, cfg.nv_l, n_max)

    mine = queue.SimpleQueue()  # this render's workspaces not in use (one per thread at most)

    def work(u):
        try:
            ws = mine.get_nowait()
        except queue.Empty:
            ws = _take_workspace(cfg, shape)
        try:
            return _render_chunk_compiled(ps, cfg, cam, seed_mix, ws, *u)
        finally:
            mine.put(ws)

    def add(img: np.ndarray) -> None:  # compiled: per-unit numpy temporaries cost ~10% of a small image's render
        if not add_pass_moments(img, npix, film.s1, film.s2, film.n):
            raise FloatingPointError("bdpt produced a non-finite radiance (a bug: please report)")

    rays = 0
    pending = None  # a pass's image while its pixel slices arrive (large images)
    pool = ThreadPoolExecutor(int(threads)) if int(threads) > 1 and len(units) > 1 else None
    try:
        results = pool.map(work, units) if pool is not None else map(work, units)
        for (s0, n_pass, p0, p1), (img, nr) in zip(units, results):  # in unit order: the same sums
            rays += nr
            if p0 == 0 and p1 == npix:
                add(img)
                continue
            pending = img if p0 == 0 else pending + img
            if p1 == npix:
                add(pending)
    finally:
        if pool is not None:
            pool.shutdown()
        _keep_workspaces(mine, shape)
    stats = {"time_s": time.perf_counter() - t0, "paths": int(2 * npix * (b - a)), "rays": int(rays),
             "passes": int(b - a)}
    return RenderResult.from_film(film, (a, b), "bdpt", stats)


def render_result(scene, camera: Camera, settings: RenderSettings, options: Options, sample_range: tuple[int, int],
                  effects: frozenset, prepared: PreparedScene, progress=None) -> RenderResult:
    """:func:`render_bdpt` of passes [a, b) = ``sample_range`` (the registry's interface; progress
    unused): settings.max_depth, seed, threads, batch_paths (capped at 2^12 camera samples: larger
    batches spill out of the caches). Caustic paths are dropped when 'caustics' is not among
    ``effects``."""
    return render_bdpt(scene, camera, settings.spp, max_depth=settings.max_depth, seed=settings.seed,
                       prepared=prepared, sample_range=sample_range, roulette=options.roulette,
                       rr_depth=options.rr_depth, caustics="caustics" in effects, heuristic=options.heuristic,
                       batch_paths=min(settings.batch_paths, _COMPILED_BATCH), threads=settings.threads)
