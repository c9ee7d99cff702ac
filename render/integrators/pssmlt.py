"""``pssmlt``: Metropolis light transport in primary sample space (Kelemen et al. 2002), compiled path sampler.

**The path sampler.** :func:`sample_paths` is a unidirectional path tracer written as a
deterministic function of a point U in the primary sample space [0, 1)^D, D = 2 +
:data:`DIMS_PER_BOUNCE` x max_depth (:func:`primary_dims`). Columns 0, 1 place the camera
sample on the image plane (x = W u0, y = H u1, so the pixel is (floor(y), floor(x)) and the
jitter inside it the fractional parts); scattering vertex k (0 = the first hit) owns the seven
columns 2 + 7k .. 2 + 7k + 6: light pick, light uv (2) for next-event estimation, BSDF lobe
(glass: reflect or refract), BSDF uv (2), Russian roulette. It follows render.integrators.path's
conventions and its compiled kernel (render.integrators.path_kernels.shade_bounce) exactly: the same radiometry and light units,
max_depth counts scattering events, the camera ray counts as specular (emission seen directly
has weight 1), one-sided emitters, two-sided Lambert and mirror frames, outward dielectric
frames, background radiance for escaping rays, next-event estimation and cosine BSDF sampling
at Lambertian vertices combined by MIS (power heuristic by default), delta lights by NEE only,
and without 'caustics' among the effects, emission and background reached through a specular
chain that follows a diffuse vertex are dropped. Russian roulette is optional (``roulette=True``
/ rr_depth not None; off by default, see below): path's policy, leaving vertex k >= rr_depth
(3 when on, path's) the path survives with probability q = min(1, max(beta)) and is divided by
it, the survival decided by u < q with u vertex k's roulette column (read only there). Roulette
keeps f(U) a deterministic function of U, as every other random decision of the path (pbrt-v4's
MLT draws its walk's roulette from its MLT sampler too), and unbiased (E over that column of the
survivor's f / q is f). Why off by default (measured, 48 x 48, 256 mutations per pixel, variance
x time of the render, one-off script): roulette's 1/q factors put spikes into I(U) that the
chains find and dwell on; on the open caustic scenes of bench/bench_hard_paths.py it saves no
time (2.43 segments per proposal either way: those paths escape, or stay in glass with beta ~1)
and multiplies variance x time by 2.2 (0.4 m source) and 6.1 (0.1 m); on the closed Cornell box
it cuts the time 18% for 7% more variance (13% better); on the furnace (albedo 0.5, max_depth
16) 6.4x faster for 1.9x the variance. Either way a uniform U gives an unbiased estimate of the
same box-filtered pixel measurement as `path`:

    I_p = W H E_U[ f(U) 1{pixel(U) = p} ],   f(U) the path's (3,) RGB radiance contribution.

The sampler runs compiled: volpath's kernels (render.integrators.volpath_kernels, through
render.integrators.volpath.trace_primary) read every random number from U instead of their hash,
with render.integrators.path's pruning and shadow-ray rules; a wavefront, one Embree query per
bounce for all rows and one occlusion query for their shadow rays. :func:`sample_paths_numpy` is
the same function in numpy (render.bsdf's samplers, render.lights.LightSet,
render.accel.spawn_origin), kept as the tested reference (tests/render/test_pssmlt_compiled.py:
row by row). The Metropolis chains run compiled too (render.integrators.pssmlt_kernels: proposals,
acceptance, splats and counters), a wavefront over every chain of every group of a thread: one
path sampler call per step for all of them, and with a pinhole camera every step of a thread in
one compiled call (pssmlt_kernels.run_chains, Embree called from compiled code: the per-step
Python calls cost about a fifth of a render); :func:`_run_group_numpy` is the same chain in numpy,
value for value (the tested reference: tests/render/test_pssmlt_compiled.py).

**Metropolis.** The scalar importance is I(U) = luminance (Rec. 709: 0.2126, 0.7152, 0.0722)
of f(U) >= 0. Its integral b = E_U[I(U)] (the mean image luminance) is estimated by a bootstrap
of uniform samples; C chains are started by resampling the bootstrap samples in proportion to I
(so each starts, approximately, in the stationary density I / b, and always with I > 0: a chain
never moves to a zero-importance state since those are always rejected). Every step advances
all chains together. With probability p_large a chain proposes a *large step*, a fresh uniform
U; otherwise a *small step* perturbs every coordinate by +-s2 exp(-ln(s2 / s1) xi) (s1 = 1/1024,
s2 = 1/64, random sign; Kelemen's mutation, its magnitudes quantized to 4096 log-spaced levels, a
table lookup instead of an exp per coordinate), wrapped into [0, 1). Both proposals are symmetric,
so the proposal Y is accepted with a = min(1, I(Y) / I(X)).

**The estimator** (Kelemen et al. 2002, section 5; the one of smallpssmlt and Mitsuba's PSSMLT,
with the bootstrap as a third technique). Three sampling techniques produce paths: the
Metropolis chain (expected-value splatting: each step adds the proposal with weight a and the
current state with weight 1 - a, which is the expectation of the state after the step, so each
step is one sample of density I / b), the large steps (with probability p_large per step, a
uniform sample of density 1) and the bootstrap (N uniform samples, traced anyway to estimate b
and to start the chains). Combining them by the balance heuristic (Veach's multi-sample form:
n_t p_t over the sum of n_s p_s), with M steps in all a path of importance I is drawn with
density M (I / b + c), c = p_large + N / M (the uniform samples per step), and

    proposal Y:   f(Y) (a + [large step]) / (I(Y) / b + c)
    current  X:   f(X) (1 - a)            / (I(X) / b + c)
    bootstrap Z:  f(Z)                    / (I(Z) / b + c)

are splatted to their pixels. The image is W H / M x the sum of the splats over all M steps of
all chains and the N bootstrap samples (M = spp x W x H mutations: ``spp`` is mutations per
pixel on average; C chains advance ceil(M / C) steps each, so M is rounded up to whole steps),
an estimate of the same I_p as `path` (expected splat density over the techniques: M I / b +
M p_large + N = M (I / b + c)): consistent, with the start-up bias that resampling the bootstrap
leaves (none in the limit of a large bootstrap). With N = 0 these are Kelemen's weights, with
p_large = 0 too pbrt-v3's MLTIntegrator's (splat a f / I and (1 - a) f / I, scale by b; pbrt keeps
large steps but does not weight them); the uniform terms add what independent sampling finds
well (dark regions) and cut the variance there. The bootstrap's paths were thrown away before
session 33 (a fixed ~30% of a render's time at the defaults, 100 000 paths beside 147 456
mutations at 48 x 48 and 64 spp); they are samples now, so its cost buys image too, and when
mutations are few (N / M large) the estimate tends to the bootstrap's own path tracer. The
chains start from resampled bootstrap samples whose pixels and contributions are kept (no path
is traced twice). A wrong b biases every pixel by up to its relative error.

**Variance.** Metropolis samples are correlated, so the per-sample variance is meaningless. The
chains are split into K >= 8 *independent groups* (``groups``, default 16), each with its own
bootstrap (its own b: n_bootstrap / K uniform samples), its own chains and its own image; the
render is the mean of the K group images and its variance image is the sample variance of the
K group images / K (an honest variance of the mean: it includes the bootstrap's error and the
chains' correlation; with K = 16 a pixel's variance estimate has 15 degrees of freedom, so
compare per-pixel errors with Student's t_15, not the normal). Pixels of one group share its b
and its chains, so their errors are correlated: an aggregate over pixels (the image mean, a
region's mean) takes its variance from the group images (``PSSMLTResult.groups``), not from
the sum of the variance image. The RenderResult's film holds the K group images as K "samples"
per pixel, so Film.mean and Film.variance reproduce both.

**Units of work.** A group is a pure function of (scene, camera, seed, group index, its
mutations) (:func:`_run_groups`: its chains' random numbers are a hash of their keys, every path
a function of its primary sample alone), so its bytes do not depend on what else is rendered,
although the groups of a render share one wavefront (per thread). Through :func:`render.integrators.render` a render
of ``spp`` is split into K = min(:data:`GROUPS`, spp) groups over its sample range
(:func:`render.film.group_ranges`; fewer than 8 groups, and a zero variance image for one, when
spp < 8), and a ``sample_range`` of whole groups renders just those: renders of whole groups
merge exactly in group order, so the ``reference`` stage's batches and workers give the same
bytes.

**Hard cases.** A chain in a tiny bright region rejects almost every proposal (small steps leave
the region, large steps land in darker ones): it stays, splatting (1 - a) onto that pixel; the
estimator stays finite and unbiased, and the group variance reports the resulting noise
(:class:`PSSMLTResult` records acceptance rates by importance and the longest rejection run).
If a group's bootstrap finds no light (b = 0) the group runs no chain and its image is black (a
bias of P(b_g = 0) x the image, negligible unless light is found by under ~5 bootstrap samples
per group, and visible in the group spread); if no group finds any, the render is black and
finite and says so (``found_light`` False, stats["no_light"] True), never NaN.

Supported: Lambertian (textured too), mirror, dielectric, area lights, point / spot /
directional lights (next-event estimation only), background radiance; pinhole cameras and
distorted ones (rays through :meth:`render.camera.Camera.pixel_rays`). GGX materials and
participating media raise ValueError naming pssmlt. Inside a group the mutations are a Markov
chain, not independent samples: a ``sample_range`` that splits a group, and refine(), raise.

Random numbers: bootstrap samples are the counter-based hash of render.sampling (seed, group,
index, dimension); chain selection comes from a numpy Generator seeded by (seed, stream, group);
each chain's mutations and acceptances from the hash of its own key (seed, group, chain), step s
reading dimensions s (D + 2) .. s (D + 2) + D + 1. Same seed, same bytes, whatever the threads.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..accel import offset_eps, spawn_origin
from ..bsdf import DIELECTRIC, EMISSIVE, LAMBERT, bsdf_sample
from ..camera import Camera
from ..effects import scene_effects
from ..film import Film, RenderResult, group_ranges, whole_groups
from ..sampling import INV_PI, dot3, max3, mis_weight, orthonormal_frame, path_keys, to_local, to_world, uniform_block
from .prepared import PreparedScene, prepare
from .settings import RenderSettings, check_heuristic, heuristic_exponent
from .pssmlt_kernels import (LUM_B, LUM_G, LUM_R, S1, S2, SMALL_STEP_LEVELS, SMALL_STEPS, accept_and_splat,
                             pinhole_rays, propose, run_chains, sanitize_rows, splat_uniform, uniform_rows)
from .volpath import VolContext, primary_config, surface_tracer, trace_primary, vol_buffers

__all__ = ["Options", "DIMS_PER_BOUNCE", "RR_DEPTH", "LUMINANCE", "primary_dims", "luminance", "sample_paths",
           "sample_paths_numpy", "small_step",
           "bootstrap", "PSSMLTResult", "render_pssmlt", "render_result", "GROUPS"]

#: primary-sample columns per scattering vertex: light pick, light uv (2), BSDF lobe, BSDF uv (2), roulette
DIMS_PER_BOUNCE = 7
#: with roulette on, it applies when leaving vertices of index >= RR_DEPTH (path's default); the
#: samplers' rr_depth None (their default) means no roulette
RR_DEPTH = 3
#: Rec. 709 / sRGB luminance weights of linear RGB
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
#: a tag mixed into the seed of the chains' random streams (apart from the bootstrap's keys)
_CHAIN_STREAM = 0x50534D4C54
_TMAX_CAP = 3e38
_BOOT_CHUNK = 1 << 15
_IMPORTANCE_BINS = np.array([0.1, 1.0, 10.0, 100.0])  # I / b bin edges of the acceptance statistics


@dataclass(frozen=True)
class Options:
    """Options of ``pssmlt`` (RenderSettings fields of the same names; no strategy: NEE + BSDF
    sampling always MIS-weighted).

    Chains, bootstrap samples and the large-step probability per group are the module's
    GROUP_CHAINS, GROUP_BOOTSTRAP and LARGE_STEP (render_pssmlt takes others)."""

    #: MIS weights of the path sampler: "power" or "balance" (Veach and Guibas)
    heuristic: str = "power"
    #: Russian roulette (path's policy, its number read from the vertex's roulette column; off by
    #: default: on the open caustic scenes it adds variance and saves no time, see the module docstring)
    roulette: bool = False
    #: first vertex index (0: the first hit) whose outgoing path roulette may end (with roulette on)
    rr_depth: int = RR_DEPTH

    def __post_init__(self):
        check_heuristic(self.heuristic)
        if self.rr_depth < 0:
            raise ValueError(f"pssmlt: rr_depth must be >= 0, got {self.rr_depth}")

    @property
    def rr(self) -> int | None:
        """The samplers' ``rr_depth`` argument: None without roulette."""
        return int(self.rr_depth) if self.roulette else None


def primary_dims(max_depth: int) -> int:
    """Number D of primary-sample columns :func:`sample_paths` reads for ``max_depth``."""
    return 2 + DIMS_PER_BOUNCE * int(max_depth)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """(N,) Rec. 709 luminance of (N, 3) linear RGB (summed in the compiled chains' order, so both
    give the same bits)."""
    return LUM_R * rgb[:, 0] + LUM_G * rgb[:, 1] + LUM_B * rgb[:, 2]


# ---------------------------------------------------------------- the primary-sample path sampler
def sample_paths(ps: PreparedScene, camera: Camera, U: np.ndarray, max_depth: int, caustics: bool = True,
                 heuristic: str = "power", ctx: VolContext | None = None,
                 rr_depth: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Trace one camera path per row of U (N, D) float64 in [0, 1) (D >= primary_dims(max_depth)),
    in compiled code (render.integrators.volpath_kernels, every random number read from U:
    :func:`render.integrators.volpath.trace_primary`).

    Returns ((N,) int64 row-major pixel index, (N, 3) float64 radiance contribution f(U)):
    with U uniform, W H f(U) 1{pixel = p} is an unbiased estimate of pixel p's box-filtered
    radiance (render.integrators.path's measurement). heuristic: MIS weights, "power" or "balance".
    rr_depth: Russian roulette when leaving vertices of index >= rr_depth (None: none).
    See the module docstring for the column layout and conventions; :func:`sample_paths_numpy`
    is the same function in numpy (the tested reference: tests/render/test_pssmlt_compiled.py).
    ctx: a ``VolContext(ps, None)`` to reuse across calls (saves re-packing the materials).
    """
    U = np.asarray(U, dtype=np.float64)
    if U.ndim != 2 or U.shape[1] < primary_dims(max_depth):
        raise ValueError(f"pssmlt: U must be (N, >= {primary_dims(max_depth)}), got {U.shape}")
    heuristic_exponent(heuristic)
    k = camera.intrinsics
    if not k.has_distortion:  # the pinhole rays in one compiled pass (pixel_rays' arithmetic)
        c2w = np.asarray(camera.cam_to_world, dtype=np.float64)
        pix, o, d = pinhole_rays(U, k.width, k.height, float(k.fx), float(k.fy), float(k.cx), float(k.cy),
                                 np.ascontiguousarray(c2w[:3, :3]), np.ascontiguousarray(c2w[:3, 3]))
    else:
        x, y = U[:, 0] * k.width, U[:, 1] * k.height
        pix = np.minimum(y.astype(np.int64), k.height - 1) * k.width + np.minimum(x.astype(np.int64), k.width - 1)
        if len(U) == 0:
            return pix, np.zeros((0, 3))
        o, d = camera.pixel_rays(np.stack([x, y], axis=1))
    if len(U) == 0:
        return pix, np.zeros((0, 3))
    return pix, trace_primary(ps, o, d, U, max_depth, caustics, heuristic, ctx, rr_depth)


def sample_paths_numpy(ps: PreparedScene, camera: Camera, U: np.ndarray, max_depth: int, caustics: bool = True,
                       heuristic: str = "power", rr_depth: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sample_paths` in numpy (a wavefront: one Embree query per bounce for all rows, one
    occlusion query for their shadow rays), kept as the tested reference."""
    U = np.asarray(U, dtype=np.float64)
    if U.ndim != 2 or U.shape[1] < primary_dims(max_depth):
        raise ValueError(f"pssmlt: U must be (N, >= {primary_dims(max_depth)}), got {U.shape}")
    hexp = heuristic_exponent(heuristic)
    geom, mats, lights, accel = ps.geom, ps.mats, ps.lights, ps.accel
    k = camera.intrinsics
    n = len(U)
    x, y = U[:, 0] * k.width, U[:, 1] * k.height
    pix = np.minimum(y.astype(np.int64), k.height - 1) * k.width + np.minimum(x.astype(np.int64), k.width - 1)
    L = np.zeros((n, 3))
    if n == 0:
        return pix, L
    o, d = camera.pixel_rays(np.stack([x, y], axis=1))
    extent = geom.extent
    bg = ps.background
    has_bg = bool(bg.max() > 0)
    can_nee = not lights.empty
    mis_on_hits = lights.has_area
    idx = np.arange(n)
    beta = np.ones((n, 3))
    pdf_prev = np.zeros(n)
    delta_prev = np.ones(n, bool)  # the camera ray counts as specular: emission seen directly has weight 1
    after_diff = np.zeros(n, bool)
    for depth in range(max_depth + 1):
        if len(idx) == 0:
            break
        h = accel.intersect(o, d)
        hit = h.tri >= 0
        pruned = (delta_prev & after_diff) if not caustics else np.zeros(len(idx), bool)
        if has_bg:
            esc = ~hit & ~pruned
            L[idx[esc]] += beta[esc] * bg  # one live path per row: indices are unique
        s = np.nonzero(hit)[0]
        idx, beta, pdf_prev, delta_prev, after_diff, pruned = (idx[s], beta[s], pdf_prev[s], delta_prev[s],
                                                               after_diff[s], pruned[s])
        d, tri, t, hu, hv = d[s], h.tri[s], h.t[s], h.u[s], h.v[s]
        p, ng = geom.point_normal(tri, hu, hv)
        obj = geom.obj[tri]
        kind = mats.kind[obj]
        cos_o = -dot3(d, ng)
        # ---- emission found by the ray (MIS against light sampling unless the previous vertex was delta)
        em = mats.emits[obj] & (mats.two_sided[obj] | (cos_o > 0)) & ~pruned
        if em.any():
            e = np.nonzero(em)[0]
            w = np.ones(len(e))
            nd = ~delta_prev[e]
            if mis_on_hits and nd.any():
                en = e[nd]
                w[nd] = mis_weight(pdf_prev[en], lights.pdf_hit(tri[en], t[en], cos_o[en]), hexp)
            L[idx[e]] += beta[e] * mats.Le[obj[e]] * w[:, None]
        if depth == max_depth:
            break
        s = np.nonzero(kind != EMISSIVE)[0]
        if len(s) == 0:
            break
        idx, beta, after_diff = idx[s], beta[s], after_diff[s]
        d, tri, hu, hv, p, ng, obj, kind, cos_o = d[s], tri[s], hu[s], hv[s], p[s], ng[s], obj[s], kind[s], cos_o[s]
        # shading normal: facing wo for two-sided materials, the outward normal for dielectrics
        nrm = np.where(((cos_o < 0) & (kind != DIELECTRIC))[:, None], -ng, ng)
        base = 2 + DIMS_PER_BOUNCE * depth
        cols = U[idx, base:base + DIMS_PER_BOUNCE]
        lam = kind == LAMBERT
        alb = mats.albedo[obj]
        if lam.any() and mats.textures:
            li = np.nonzero(lam)[0]
            alb[li] = mats.diffuse_albedo(obj[li], lambda m: geom.texcoords(tri[li][m], hu[li][m], hv[li][m]))
        # ---- next-event estimation at Lambertian vertices
        li = np.nonzero(lam)[0]
        if can_nee and len(li):
            ls = lights.sample(p[li], cols[li, 0], cols[li, 1:3])
            cos_i = dot3(ls.wi, nrm[li])
            ok = ls.valid & (cos_i > 0)
            if ok.any():
                j = np.nonzero(ok)[0]
                v = li[j]
                wi = ls.wi[j]
                w = np.where(ls.delta[j], 1.0, mis_weight(ls.pdf[j], cos_i[j] * INV_PI, hexp))
                eps = offset_eps(p[v], extent)
                side = np.where(dot3(wi, ng[v]) >= 0.0, eps, -eps)
                tmax = np.minimum(np.maximum(ls.dist[j] * (1.0 - 1e-4) - 2.0 * eps, 0.0), _TMAX_CAP)
                vis = ~accel.occluded(p[v] + side[:, None] * ng[v], wi, tmax)
                scale = INV_PI * cos_i[j] * w / ls.pdf[j] * vis
                L[idx[v]] += beta[v] * alb[v] * ls.Li[j] * scale[:, None]
        # ---- continue: sample the BSDF (Lambert: cosine; mirror; glass: Fresnel lobe choice)
        t1, t2 = orthonormal_frame(nrm)
        wo = to_local(-d, t1, t2, nrm)
        bs = bsdf_sample(kind, alb, mats.ior[obj], wo, cols[:, 3], cols[:, 4:6])
        beta = beta * bs.weight
        ok = bs.valid
        if rr_depth is not None and depth >= rr_depth:  # path's roulette, its number from column 6
            q = np.minimum(1.0, max3(beta))
            live = cols[:, 6] < q
            beta = beta / np.where(live, q, 1.0)[:, None]
            ok = ok & live
        ok = ok & (max3(beta) > 0)
        s = np.nonzero(ok)[0]
        wi = to_world(bs.wi[s], t1[s], t2[s], nrm[s])
        o = spawn_origin(p[s], ng[s], wi, extent)
        d = wi
        idx, beta = idx[s], beta[s]
        pdf_prev, delta_prev = bs.pdf[s], bs.delta[s]
        after_diff = after_diff[s] | lam[s]
    return pix, L


# ---------------------------------------------------------------- mutations and the bootstrap
def small_step(U: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Kelemen's small step: every coordinate of U (N, D) moved by +-S2 exp(-ln(S2 / S1) xi),
    xi uniform (quantized to SMALL_STEP_LEVELS log-spaced magnitudes), wrapped into [0, 1), from
    uniforms u (N, D): the sign + where u >= 1/2, the level floor(2 L u) mod L (the compiled
    chains' arithmetic: render.integrators.pssmlt_kernels.propose). A symmetric proposal.
    Returns a new array."""
    sign = np.where(u >= 0.5, 1.0, -1.0)
    v = U + sign * SMALL_STEPS[(u * (2.0 * SMALL_STEP_LEVELS)).astype(np.int64) & (SMALL_STEP_LEVELS - 1)]
    v = v - np.floor(v)
    v[v >= 1.0] = 0.0  # a tiny negative number wraps to 1.0 in rounding
    return v


def _sanitize(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contributions (N, 3) with non-finite or negative rows zeroed (in place), and (N,) bool
    which rows were (compiled: pssmlt_kernels.sanitize_rows, 3% of a small render's time in numpy)."""
    bad = np.zeros(len(f), bool)
    if f.dtype == np.float64 and f.ndim == 2 and f.shape[1] == 3 and f.flags.c_contiguous:
        sanitize_rows(f, bad)
        return f, bad
    if len(f):
        bad = ~np.all(np.isfinite(f), axis=1) | (f.min(axis=1) < 0)
    if bad.any():
        f[bad] = 0.0
    return f, bad


def _evaluate(ps, camera, U, max_depth, caustics, heuristic, ctx=None, rr_depth=None):
    """sample_paths plus the importance, with non-finite contributions zeroed (and counted)."""
    pix, f = sample_paths(ps, camera, U, max_depth, caustics, heuristic, ctx, rr_depth)
    f, bad = _sanitize(f)
    return pix, f, luminance(f), int(bad.sum())


def _bootstrap_keys(seed: int, group: int, n: int) -> np.ndarray:
    return path_keys(seed, np.full(n, group, np.int64), np.arange(n))


def _bootstraps(ps: PreparedScene, camera: Camera, groups, n: int, max_depth: int, seed: int, caustics: bool,
                heuristic: str, ctx: VolContext | None = None,
                rr_depth: int | None = None) -> tuple[np.ndarray, ...]:
    """The bootstraps of several groups, traced together in chunks (every row is a pure function
    of its primary sample, so a group's values do not depend on the others). Returns
    ((G, n) uint64 keys, (G, n) float64 importance, (G, n) int64 pixels, (G, n, 3) float64
    contributions (non-finite ones zeroed), (G,) int64 how many were): the samples are splatted
    into the image and the chains start from them (no path is traced twice)."""
    D = primary_dims(max_depth)
    G = len(groups)
    keys = np.concatenate([_bootstrap_keys(seed, g, n) for g in groups]) if G else np.zeros(0, np.uint64)
    nk = len(keys)
    imp, pix, f, bad = np.zeros(nk), np.zeros(nk, np.int64), np.zeros((nk, 3)), np.zeros(nk, bool)
    for c in range(0, len(keys), _BOOT_CHUNK):
        kk = keys[c:c + _BOOT_CHUNK]
        pc, fc = sample_paths(ps, camera, uniform_rows(kk, 0, D), max_depth, caustics, heuristic, ctx, rr_depth)
        fc, bc = _sanitize(fc)
        imp[c:c + len(kk)], pix[c:c + len(kk)], f[c:c + len(kk)], bad[c:c + len(kk)] = luminance(fc), pc, fc, bc
    return (keys.reshape(G, n), imp.reshape(G, n), pix.reshape(G, n), f.reshape(G, n, 3),
            bad.reshape(G, n).sum(axis=1))


def bootstrap(ps: PreparedScene, camera: Camera, n: int, max_depth: int, seed: int = 0, group: int = 0,
              caustics: bool = True, heuristic: str = "power",
              rr_depth: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The bootstrap of one group: n uniform primary samples (the counter-based hash of
    render.sampling keyed by (seed, group, index)). Returns ((n,) uint64 keys, (n,) float64
    importance I). b = I.mean() estimates E_U[I] = the mean image luminance; row i's sample is
    ``uniform_block(keys[i:i+1], 0, primary_dims(max_depth))``."""
    keys, imp = _bootstraps(ps, camera, [group], n, max_depth, seed, caustics, heuristic, rr_depth=rr_depth)[:2]
    return keys[0], imp[0]


def _chain_starts(imp: np.ndarray, group: int, seed: int, cpg: int) -> np.ndarray:
    """(cpg,) int64 indices of a group's bootstrap samples where its chains start: resampled in
    proportion to their importance (a Generator keyed by (seed, group)). Chain c's state is
    ``uniform_rows(keys[j[c:c+1]], 0, D)``, its pixel and contribution the bootstrap's."""
    rng_sel = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x5053, 1, group])
    cdf = np.cumsum(imp)
    return np.minimum(np.searchsorted(cdf, rng_sel.random(cpg) * cdf[-1], side="right"), len(imp) - 1)


def _uniform_share(large_step: float, n_bootstrap: int, cpg: int, steps: int) -> float:
    """c of the estimator: a group's uniform samples per chain step, p_large + n_bootstrap / M
    (M = cpg x steps mutations): the large steps and the bootstrap's samples."""
    return float(large_step) + int(n_bootstrap) / float(cpg * steps)


def _splat_bootstrap_numpy(image: np.ndarray, pix: np.ndarray, f: np.ndarray, imp: np.ndarray, b: float,
                           c: float) -> None:
    """pssmlt_kernels.splat_uniform in numpy: f / (I / b + c) added to image (npix, 3) at pix."""
    lit = imp > 0
    w = np.where(lit, 1.0 / (np.where(lit, imp, 0.0) / b + c), 0.0)
    for ch in range(3):
        image[:, ch] += np.bincount(pix, weights=f[:, ch] * w, minlength=len(image))


def _chain_keys(seed: int, group: int, chains: np.ndarray) -> np.ndarray:
    """(N,) uint64 hash keys of a group's chains (their indices ``chains`` before dropping dark
    starts): step s of a chain reads dimensions s (D + 2) .. s (D + 2) + D + 1 of its key."""
    return path_keys(int(seed) ^ _CHAIN_STREAM, np.full(len(chains), group, np.int64), chains)


# ---------------------------------------------------------------- the integrator
@dataclass
class PSSMLTResult:
    """A PSSMLT render.

    mean: (H, W, 3) float64 radiance estimate (mean of the group images). variance: (H, W, 3)
    float64 variance of that mean (sample variance of the K group images / K). groups: (K, H, W, 3)
    float64 the group images. b: (K,) float64 each group's bootstrap normalisation (mean
    luminance); b_mean their mean. found_light: False when no bootstrap sample carried light (the
    image is black). chains, steps, mutations (= chains x steps), bootstrap (samples over all
    groups), large_step: what was run. acceptance: accepted / proposed over all steps;
    acceptance_small, acceptance_large: per kind of step. acceptance_by_importance: list of
    (I / b lower edge, proposals, acceptance rate) of the current state's importance bins
    (edges 0, 0.1, 1, 10, 100). longest_rejection_run: the most consecutive rejections of any
    chain; stuck_fraction: fraction of the running chains whose state never changed. stats: time_s, paths
    (traced: bootstrap + proposals, all splatted), nonfinite (contributions zeroed).
    """

    mean: np.ndarray
    variance: np.ndarray
    groups: np.ndarray
    b: np.ndarray
    b_mean: float
    found_light: bool
    chains: int
    steps: int
    mutations: int
    bootstrap: int
    large_step: float
    acceptance: float
    acceptance_small: float
    acceptance_large: float
    acceptance_by_importance: list = field(default_factory=list)
    longest_rejection_run: int = 0
    stuck_fraction: float = 0.0
    stats: dict = field(default_factory=dict)


def _check_supported(scene, ps: PreparedScene, effects) -> None:
    if getattr(scene, "media", None):
        raise ValueError("integrator 'pssmlt' cannot reach effect 'media' (participating media); use 'volpath'")
    if ps.mats.has_glossy:
        raise ValueError("integrator 'pssmlt' cannot shade glossy (GGX) materials; use 'volpath'")
    ps.choose(effects, "pssmlt")  # caustics from delta lights


@dataclass
class _GroupRun:
    """One independent group of chains: image (npix, 3) float64, its bootstrap b, and counters."""

    image: np.ndarray
    b: float
    chains: int
    steps: int
    bootstrap: int
    proposed: int = 0
    accepted: int = 0
    large: int = 0
    accepted_large: int = 0
    bins_proposed: np.ndarray = None
    bins_accepted: np.ndarray = None
    longest_rejection_run: int = 0
    running: int = 0  # chains that ran (their group found light, their start carried light)
    moved: int = 0  # running chains whose state changed at least once
    nonfinite: int = 0


def _group_shape(chains: int, mutations: int) -> tuple[int, int]:
    """(chains, steps) of a group: min(chains, mutations) chains of ceil(mutations / chains) steps."""
    cpg = max(1, min(int(chains), int(mutations)))
    return cpg, -(-int(mutations) // cpg)


def _new_run(b: float, cpg: int, steps: int, n_bootstrap: int, npix: int) -> _GroupRun:
    return _GroupRun(np.zeros((npix, 3)), b, cpg, steps, n_bootstrap,
                     bins_proposed=np.zeros(len(_IMPORTANCE_BINS) + 1), bins_accepted=np.zeros(len(_IMPORTANCE_BINS) + 1))


def _run_group_numpy(ps: PreparedScene, camera: Camera, group: int, mutations: int, chains: int, n_bootstrap: int,
                     max_depth: int, seed: int, large_step: float, caustics: bool, heuristic: str,
                     rr_depth: int | None = None) -> _GroupRun:
    """Group ``group`` with its chains in numpy, vectorized over them: the tested reference of the
    compiled chains (:func:`_run_groups`), the same random numbers and arithmetic (equal images up
    to the order of the splat sums). Its bootstrap (n_bootstrap samples keyed by (seed, group)),
    min(chains, mutations) chains started by resampling it, advanced ceil(mutations / chains)
    steps, each chain's random numbers the hash of its key (:func:`_chain_keys`); the bootstrap's
    samples splatted too (the estimator of the module docstring). The image is scaled to an
    estimate of the whole image."""
    k = camera.intrinsics
    npix = k.width * k.height
    D = primary_dims(max_depth)
    cpg, steps = _group_shape(chains, mutations)
    keys, imp, bpix, bf, bbad = (a[0] for a in _bootstraps(ps, camera, [group], n_bootstrap, max_depth, seed,
                                                           caustics, heuristic, rr_depth=rr_depth))
    run = _new_run(float(imp.mean()), cpg, steps, n_bootstrap, npix)
    run.nonfinite += int(bbad)
    if run.b <= 0:  # no light found: the group runs no chain and its image is black
        return run
    b = run.b
    share = _uniform_share(large_step, n_bootstrap, cpg, steps)
    acc = run.image
    _splat_bootstrap_numpy(acc, bpix, bf, imp, b, share)
    j = _chain_starts(imp, group, seed, cpg)
    X, pix_x, f_x, I_x = uniform_rows(keys[j], 0, D), bpix[j], bf[j], imp[j]
    ok = I_x > 0  # resampled states carry light (I > 0); guard anyway
    X, pix_x, f_x, I_x = X[ok], pix_x[ok], f_x[ok], I_x[ok]
    ckeys = _chain_keys(seed, group, np.nonzero(ok)[0])
    nc = len(X)
    rejections = np.zeros(nc, np.int64)
    moved = np.zeros(nc, bool)
    for step in range(steps if nc else 0):
        u = uniform_block(ckeys, step * (D + 2), D + 2)
        large = u[:, 0] < large_step
        Y = np.where(large[:, None], u[:, 1:D + 1], small_step(X, u[:, 1:D + 1]))
        pix_y, f_y, I_y, bad = _evaluate(ps, camera, Y, max_depth, caustics, heuristic, rr_depth=rr_depth)
        run.nonfinite += bad
        a = np.minimum(1.0, I_y / I_x)  # I_x > 0 always: a zero-importance proposal is never accepted
        # Kelemen's estimator: expected-value splats, balance heuristic with the uniform samples
        den_y = I_y / b + share
        w_y = np.where(den_y > 0, (a + large) / np.where(den_y > 0, den_y, 1.0), 0.0)
        w_x = (1.0 - a) / (I_x / b + share)
        slots = np.concatenate([pix_y, pix_x])
        vals = np.concatenate([f_y * w_y[:, None], f_x * w_x[:, None]])
        for c in range(3):
            acc[:, c] += np.bincount(slots, weights=vals[:, c], minlength=npix)
        accept = u[:, D + 1] < a
        bi = np.searchsorted(_IMPORTANCE_BINS, I_x / b, side="right")
        run.bins_proposed += np.bincount(bi, minlength=len(run.bins_proposed))
        run.bins_accepted += np.bincount(bi, weights=accept, minlength=len(run.bins_proposed))
        run.proposed += nc
        run.accepted += int(accept.sum())
        run.large += int(large.sum())
        run.accepted_large += int((accept & large).sum())
        rejections = np.where(accept, 0, rejections + 1)
        run.longest_rejection_run = max(run.longest_rejection_run, int(rejections.max()))
        moved |= accept
        s = np.nonzero(accept)[0]
        X[s], pix_x[s], f_x[s], I_x[s] = Y[s], pix_y[s], f_y[s], I_y[s]
    run.running, run.moved = nc, int(moved.sum())
    run.image = acc * (npix / float(cpg * steps))
    return run


def _run_groups(ps: PreparedScene, camera: Camera, specs: list[tuple[int, int]], chains: int, n_bootstrap: int,
                max_depth: int, seed: int, large_step: float, caustics: bool, heuristic: str,
                rr_depth: int | None = None) -> list[_GroupRun]:
    """Groups ``specs`` = [(group, mutations), ...] with compiled chains
    (render.integrators.pssmlt_kernels), a wavefront over every chain of every group: one path
    sampler call per step for all of them (all steps in one compiled call, run_chains, when the
    camera is a pinhole and Embree is callable from compiled code). Each group is the pure function of its arguments that
    :func:`_run_group_numpy` computes (the same bootstrap, starts and chain random numbers), so
    its bytes do not depend on which groups share the batch. Returns one run per spec, in order."""
    k = camera.intrinsics
    npix = k.width * k.height
    D = primary_dims(max_depth)
    ctx = VolContext(ps, None)
    groups = [int(g) for g, _ in specs]
    keys, imp, bpix, bf, bbad = _bootstraps(ps, camera, groups, n_bootstrap, max_depth, seed, caustics, heuristic,
                                            ctx, rr_depth)
    G = len(specs)
    image = np.zeros((G, npix, 3))
    uniform_share = np.ones(G)
    runs, starts = [], []
    for i, (g, mutations) in enumerate(specs):
        cpg, steps = _group_shape(chains, mutations)
        runs.append(_new_run(float(imp[i].mean()), cpg, steps, n_bootstrap, npix))
        runs[-1].nonfinite += int(bbad[i])
        if runs[-1].b > 0:
            uniform_share[i] = _uniform_share(large_step, n_bootstrap, cpg, steps)
            splat_uniform(image[i], bpix[i], bf[i], imp[i], runs[-1].b, uniform_share[i])
            starts.append(_chain_starts(imp[i], g, seed, cpg))
        else:
            starts.append(np.zeros(0, np.int64))
    owner = np.repeat(np.arange(G), [len(j) for j in starts])
    index_in_group = np.concatenate([np.arange(len(j)) for j in starts]) if starts else np.zeros(0, np.int64)
    # the chains start from bootstrap samples: their states, pixels and contributions are the bootstrap's
    X = np.concatenate([uniform_rows(keys[i][j], 0, D) for i, j in enumerate(starts)]) if starts else np.zeros((0, D))
    pix_x = np.concatenate([bpix[i][j] for i, j in enumerate(starts)]) if starts else np.zeros(0, np.int64)
    f_x = np.concatenate([bf[i][j] for i, j in enumerate(starts)]) if starts else np.zeros((0, 3))
    I_x = np.concatenate([imp[i][j] for i, j in enumerate(starts)]) if starts else np.zeros(0)
    ok = I_x > 0  # resampled states carry light (I > 0); guard anyway
    X, pix_x, f_x, I_x = np.ascontiguousarray(X[ok]), pix_x[ok], np.ascontiguousarray(f_x[ok]), I_x[ok]
    owner, index_in_group = owner[ok], index_in_group[ok]
    ckeys = np.zeros(len(X), np.uint64)
    for i, g in enumerate(groups):
        mine = owner == i
        ckeys[mine] = _chain_keys(seed, g, index_in_group[mine])
    nc = len(X)
    b = np.array([r.b if r.b > 0 else 1.0 for r in runs])
    rejections, moved = np.zeros(nc, np.int64), np.zeros(nc, np.bool_)
    counters = [np.zeros(G, np.int64) for _ in range(5)]  # proposed, accepted, large, accepted_large, longest
    bins = [np.zeros((G, len(_IMPORTANCE_BINS) + 1)) for _ in range(2)]
    nonfinite = np.zeros(G, np.int64)
    steps_of = np.array([r.steps for r in runs], np.int64)
    Y, large = np.zeros((nc, D)), np.zeros(nc, np.bool_)
    active = np.arange(nc)
    tracer = surface_tracer(ctx, primary_config(ps, max_depth, caustics, heuristic, rr_depth))
    fused = tracer is not None and run_chains is not None and not k.has_distortion
    if fused and nc:  # every step in one compiled call
        c2w = np.asarray(camera.cam_to_world, dtype=np.float64)
        cam = (int(k.width), int(k.height), float(k.fx), float(k.fy), float(k.cx), float(k.cy),
               np.ascontiguousarray(c2w[:3, :3]), np.ascontiguousarray(c2w[:3, 3]))
        run_chains(tracer, cam, float(large_step), X, active, owner, steps_of, ckeys, Y, large, np.empty(nc, np.int64),
                   vol_buffers(nc), np.empty((nc, 3)), np.zeros(1, np.int64), uniform_share, b, pix_x, f_x, I_x, image,
                   rejections, moved, *counters, *bins, nonfinite)
    for step in range(int(steps_of.max()) if nc and not fused else 0):
        if np.any(steps_of[owner[active]] <= step):  # groups with fewer steps have finished
            active = active[steps_of[owner[active]] > step]
        m = len(active)
        propose(X, active, ckeys, step, large_step, Y, large)
        pix_y, f_y = sample_paths(ps, camera, Y[:m], max_depth, caustics, heuristic, ctx, rr_depth)
        accept_and_splat(active, ckeys, step, uniform_share, owner, b, X, pix_x, f_x, I_x, Y, large, pix_y,
                         np.ascontiguousarray(f_y), image, rejections, moved, *counters, *bins, nonfinite)
    for i, r in enumerate(runs):
        if r.b <= 0:
            continue
        mine = owner == i
        r.proposed, r.accepted, r.large, r.accepted_large, r.longest_rejection_run = (int(c[i]) for c in counters)
        r.bins_proposed, r.bins_accepted = bins[0][i].copy(), bins[1][i].copy()
        r.nonfinite += int(nonfinite[i])
        r.running, r.moved = int(mine.sum()), int(moved[mine].sum())
        r.image = image[i] * (npix / float(r.chains * r.steps))
    return runs


def _run_groups_threaded(ps: PreparedScene, camera: Camera, specs: list[tuple[int, int]], chains: int,
                         n_bootstrap: int, max_depth: int, seed: int, large_step: float, caustics: bool,
                         heuristic: str, threads: int, rr_depth: int | None = None) -> list[_GroupRun]:
    """:func:`_run_groups` with the groups dealt round-robin to ``threads`` threads (each its own
    wavefront; the kernels and Embree release the GIL). The same runs, in spec order, whatever
    the threads."""
    parts = [specs[i::threads] for i in range(min(max(int(threads), 1), len(specs)))]
    if len(parts) <= 1:
        return _run_groups(ps, camera, specs, chains, n_bootstrap, max_depth, seed, large_step, caustics, heuristic,
                           rr_depth)
    with ThreadPoolExecutor(len(parts)) as pool:
        done = list(pool.map(lambda part: _run_groups(ps, camera, part, chains, n_bootstrap, max_depth, seed,
                                                      large_step, caustics, heuristic, rr_depth), parts))
    runs = [None] * len(specs)
    for i, part_runs in enumerate(done):
        runs[i::len(parts)] = part_runs
    return runs


def _check_arguments(spp: int, max_depth: int, large_step: float) -> None:
    if spp < 1 or max_depth < 0:
        raise ValueError(f"pssmlt: spp must be >= 1 and max_depth >= 0, got {spp}, {max_depth}")
    if not 0.0 <= large_step <= 1.0:
        raise ValueError(f"pssmlt: large_step must lie in [0, 1], got {large_step}")


def render_pssmlt(scene, camera: Camera, spp: int, max_depth: int = 8, seed: int = 0,
                  prepared: PreparedScene | None = None, chains: int = 4096, large_step: float = 0.3,
                  n_bootstrap: int = 100_000, groups: int = 16, effects=None, heuristic: str = "power",
                  threads: int = 2, rr_depth: int | None = None) -> PSSMLTResult:
    """Render ``camera``'s view of ``scene`` by primary-sample-space Metropolis light transport.

    spp: mutations per pixel on average (spp x W x H proposals in all, split evenly over the
    groups and rounded up to a whole number of steps of each group's chains). max_depth:
    maximum scattering events. chains: Markov chains in all (chains / K per group, at most its
    mutations). groups: K >= 8 independent groups (:func:`_run_groups`: each its own bootstrap of
    n_bootstrap / K samples, splatted into its image too, its own chains and random streams). threads: worker threads over the
    groups (the bytes do not depend on them). large_step: probability
    p_large of a large step (0 <= p_large <= 1). effects: effects to simulate (default
    scene_effects(scene)); without 'caustics', caustic paths are dropped as in
    render.integrators.path. heuristic: MIS weights, "power" or "balance". rr_depth: Russian
    roulette when leaving vertices of index >= rr_depth (None: none). Returns a :class:`PSSMLTResult`.
    """
    t0 = time.perf_counter()
    spp, max_depth, groups = int(spp), int(max_depth), int(groups)
    _check_arguments(spp, max_depth, large_step)
    if groups < 8:
        raise ValueError(f"pssmlt: groups must be >= 8 (the variance image needs them), got {groups}")
    if int(n_bootstrap) < groups:
        raise ValueError(f"pssmlt: n_bootstrap must be >= groups ({groups}), got {n_bootstrap}")
    eff = scene_effects(scene) if effects is None else frozenset(effects)
    ps = prepared if prepared is not None else prepare(scene)
    _check_supported(scene, ps, eff)
    k = camera.intrinsics
    total = spp * k.width * k.height
    specs = [(g, max(1, (g + 1) * total // groups - g * total // groups)) for g in range(groups)]
    runs = _run_groups_threaded(ps, camera, specs, max(1, int(chains) // groups), int(n_bootstrap) // groups,
                                max_depth, seed, float(large_step), "caustics" in eff, heuristic, threads, rr_depth)
    return _result(runs, k.height, k.width, float(large_step), t0)


def _result(runs: list[_GroupRun], h: int, w: int, large_step: float, t0: float) -> PSSMLTResult:
    """The :class:`PSSMLTResult` of independent group runs: the mean of their images, the
    variance of that mean, and the chains' statistics summed over the groups."""
    groups = len(runs)
    imgs = np.stack([r.image for r in runs])
    mean = imgs.mean(axis=0)
    var = imgs.var(axis=0, ddof=1) / groups
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var))):
        raise FloatingPointError("pssmlt produced a non-finite radiance (a bug: please report)")
    n_prop, n_acc = sum(r.proposed for r in runs), sum(r.accepted for r in runs)
    n_large, n_acc_large = sum(r.large for r in runs), sum(r.accepted_large for r in runs)
    n_small = n_prop - n_large
    bins_prop, bins_acc = sum(r.bins_proposed for r in runs), sum(r.bins_accepted for r in runs)
    by_imp = [(float(lo), int(bins_prop[i]), float(bins_acc[i] / bins_prop[i]) if bins_prop[i] else float("nan"))
              for i, lo in enumerate(np.concatenate([[0.0], _IMPORTANCE_BINS]))]
    b = np.array([r.b for r in runs])
    running = sum(r.running for r in runs)
    found = bool(np.any(b > 0))
    C = sum(r.chains for r in runs)
    nboot = sum(r.bootstrap for r in runs)
    stats = {"time_s": time.perf_counter() - t0, "paths": int(nboot + n_prop),
             "nonfinite": sum(r.nonfinite for r in runs), "no_light": not found}
    return PSSMLTResult(
        mean.reshape(h, w, 3), var.reshape(h, w, 3), imgs.reshape(groups, h, w, 3), b, float(b.mean()), found,
        C, max(r.steps for r in runs), sum(r.chains * r.steps for r in runs), nboot, large_step,
        n_acc / n_prop if n_prop else 0.0,
        (n_acc - n_acc_large) / n_small if n_small else 0.0,
        n_acc_large / n_large if n_large else 0.0,
        by_imp, max(r.longest_rejection_run for r in runs),
        float(1.0 - sum(r.moved for r in runs) / running) if running else 1.0, stats)


#: independent chain groups of a render through render.integrators.render (fewer when spp < GROUPS),
#: and each group's chains and bootstrap samples (render_pssmlt's defaults divided by 16 groups)
GROUPS = 16
GROUP_CHAINS = 4096 // GROUPS
GROUP_BOOTSTRAP = 100_000 // GROUPS  # not to be cut for speed: see the note below
# The bootstrap is a fixed cost (16 x 6250 paths; beside 147 456 mutations at 48 x 48 and 64
# spp, ~30% of the render; its paths are splatted into the image since session 33, so the cost
# contributes samples), but b's error dominates a group image's error on the caustic scenes
# of bench/bench_hard_paths.py: a group image's mean tracks its b (CV of the 16 group means =
# CV of the b_g, 0.05-0.11 at 6250 samples per group, 0.22-0.29 at 1152; 256 mutations per
# pixel, seeds 11-14, one-off script), so 1152 per group multiplied the variance 3-8x at equal
# spp (measured, session 32).
#: probability of a large step (Kelemen's p_large; render_pssmlt's default)
LARGE_STEP = 0.3
def render_result(scene, camera: Camera, settings: RenderSettings, options: Options, sample_range: tuple[int, int],
                  effects: frozenset, prepared: PreparedScene, progress=None) -> RenderResult:
    """PSSMLT as a :class:`render.film.RenderResult` (the registry's interface; progress unused):
    spp = mutations per pixel, settings.max_depth and .seed, options.heuristic, .roulette and .rr_depth.

    A render of settings.spp is split into K = min(:data:`GROUPS`, spp) independent chain groups
    over its sample range (:func:`render.film.group_ranges`); group g of samples [a_g, b_g)
    runs (b_g - a_g) W H mutations with :data:`GROUP_CHAINS` chains and its own bootstrap of
    :data:`GROUP_BOOTSTRAP` samples. ``sample_range`` must start and end on group boundaries (ValueError naming pssmlt otherwise,
    which also refuses refine()). The film holds each
    group's image as one sample per pixel (n = groups), so its mean and variance are the mean of
    the group images and the variance of that mean, and renders of whole groups merge exactly in
    group order. stats (additive): time_s, paths (traced: bootstrap + proposed, every one of them
    splatted), bootstrap, nonfinite, groups, groups_without_light, chains, mutations, proposed,
    accepted."""
    a, b = sample_range
    ranges = whole_groups((a, b), settings.spp, GROUPS, "pssmlt")
    t0 = time.perf_counter()
    ps = prepared
    _check_supported(scene, ps, effects)
    _check_arguments(settings.spp, settings.max_depth, LARGE_STEP)
    k = camera.intrinsics
    npix = k.width * k.height
    first = [r[0] for r in group_ranges(settings.spp, GROUPS)]
    film = Film(k.width, k.height)
    stats = {"paths": 0, "bootstrap": 0, "nonfinite": 0, "groups": 0, "groups_without_light": 0, "chains": 0,
             "mutations": 0, "proposed": 0, "accepted": 0}
    specs = [(first.index(g0), (g1 - g0) * npix) for g0, g1 in ranges]
    runs = _run_groups_threaded(ps, camera, specs, GROUP_CHAINS, GROUP_BOOTSTRAP, settings.max_depth, settings.seed,
                                LARGE_STEP, "caustics" in effects, options.heuristic, settings.threads, options.rr)
    for run in runs:
        if not np.all(np.isfinite(run.image)):
            raise FloatingPointError("pssmlt produced a non-finite radiance (a bug: please report)")
        film.add_moments(run.image, run.image * run.image, np.ones(npix, np.int64))
        stats["paths"] += run.bootstrap + run.proposed
        stats["bootstrap"] += run.bootstrap
        stats["nonfinite"] += run.nonfinite
        stats["groups"] += 1
        stats["groups_without_light"] += int(run.b <= 0)
        stats["chains"] += run.chains
        stats["mutations"] += run.chains * run.steps
        stats["proposed"] += run.proposed
        stats["accepted"] += run.accepted
    stats["time_s"] = time.perf_counter() - t0
    return RenderResult.from_film(film, (a, b), "pssmlt", stats)
