"""GGX microfacet BSDFs: Pearson chi-square of the samplers against their pdf (Mitsuba / pbrt
practice: 4e5 samples, equal-area (cos theta, phi) cells, cells with expected count < 5 pooled,
alpha 0.01 Sidak-corrected over this file's statistical tests). Expected counts are the number
of samples drawn times the pdf's integral over each cell (never rescaled to the observed total),
and the samples the sampler rejects (invalid) form a cell of their own whose expected count is
the pdf's missing mass, also tested alone (binomial z), so a pdf that does not integrate to the
sampler's share of valid samples fails. Sample / eval / pdf consistency, normalization of D and
of the visible normals and Heitz's weak white furnace by deterministic quadrature, the albedo
of a white conductor from the sampler's weights against a quadrature of f cos, energy bounds,
and hard cases (grazing directions at roughness near 0 and 1: finite output). Fixed seeds.

Breaks caught (each checked once, against the former version of this file too): conductor_pdf
scaled by 0.98 (chi-square p 3e-99 and 5e-44) and 1% of conductor samples dropped as invalid
(p 6e-14 and 6e-5) both passed the former helper, which rescaled the expected counts to the
valid samples; D scaled by 1.01 fails every normalization and weak-furnace quadrature (the
former "= 1 exactly" estimators passed it: D cancels in their ratio); the conductor sampler's
weight scaled by 1.01 fails test_conductor_energy at every roughness (formerly at one)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from render.microfacet import (conductor_eval, conductor_pdf, conductor_sample, ggx_d, ggx_g1,
                               ggx_sample_visible, ggx_visible_pdf, rough_dielectric_eval,
                               rough_dielectric_pdf, rough_dielectric_sample)
from render.sampling import uniform_sphere

N = 400_000
N_CHI2 = 10  # five samplers, each a chi-square and an invalid-share test
ALPHA_TEST = 1.0 - (1.0 - 0.01) ** (1.0 / N_CHI2)
NT, NP = 48, 64  # cos-theta cells over [-1, 1], phi cells
GOLD = (np.array([0.143, 0.374, 1.442]), np.array([3.983, 2.385, 1.603]))


def _wo(theta_deg: float, n: int) -> np.ndarray:
    t = np.radians(theta_deg)
    return np.tile([np.sin(t), 0.0, np.cos(t)], (n, 1))


def _cell_directions(cz: np.ndarray, cp: np.ndarray, sz: int, sp: int) -> np.ndarray:
    """(C, sz * sp, 3) unit directions at the sz x sp midpoints of each (cos-theta, phi) cell (cz, cp) (C,)."""
    z = (cz[:, None] + (np.arange(sz) + 0.5) / sz) / NT * 2 - 1
    p = (cp[:, None] + (np.arange(sp) + 0.5) / sp) / NP * 2 * np.pi
    Z, P = np.repeat(z, sp, axis=1), np.tile(p, (1, sz))
    r = np.sqrt(1 - Z ** 2)
    return np.stack([r * np.cos(P), r * np.sin(P), Z], -1)


def _cell_integrals(pdf_fn, n: int) -> np.ndarray:
    """(NT * NP,) integral of pdf_fn over each equal-area cell: midpoint rule with 24 x 6 points,
    cells where 12 x 6 points disagree by more than 0.05 sd of their count redone with 384 x 12
    (the transmission lobe's fold, an integrable spike at its support's edge, needs it: without
    it the missing mass of rough glass at alpha 0.6, 70 deg is off by 1.2e-3, 4.5 sd at n = 4e5).
    Measured against an exact push-forward of the visible normals: totals within 4e-5."""
    cz, cp = np.divmod(np.arange(NT * NP), NP)
    area = 4 * np.pi / (NT * NP)

    def integrate(idx, sz, sp):
        d = _cell_directions(cz[idx], cp[idx], sz, sp)
        return pdf_fn(d.reshape(-1, 3)).reshape(len(idx), -1).mean(axis=1) * area

    every = np.arange(NT * NP)
    coarse, out = integrate(every, 12, 6), integrate(every, 24, 6)
    rough = np.nonzero(n * np.abs(coarse - out) > 0.05 * np.sqrt(np.maximum(n * out, 1.0)))[0]
    if len(rough):
        out[rough] = integrate(rough, 384, 12)
    return out


def _chi2(wi: np.ndarray, valid: np.ndarray, pdf_fn, n: int) -> tuple[float, float]:
    """(chi-square p-value, z of the invalid share) of n sampled directions wi (n, 3) against pdf_fn.

    Cells: the NT x NP equal-area cells of the valid samples, expected n x integral of the pdf
    over the cell, plus one cell of the invalid samples, expected n x (1 - integral over the
    sphere): nothing is rescaled, so a pdf that integrates to more or less than the sampler's
    share of valid samples shows. Expected counts < 5 pooled (a pooled cell expecting nothing
    but holding samples gives p = 0). z: (invalid count - expected) / binomial sd."""
    assert len(wi) == len(valid) == n
    w = wi[valid]
    z = np.clip(w[:, 2], -1, 1 - 1e-12)
    phi = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi)
    obs = np.zeros((NT, NP))
    np.add.at(obs, (((z + 1) / 2 * NT).astype(int), (phi / (2 * np.pi) * NP).astype(int)), 1)
    exp = _cell_integrals(pdf_fn, n) * n
    missing = n - exp.sum()
    assert missing > -1e-3 * n, f"the pdf integrates to {exp.sum() / n:.5f} > 1"
    o = np.append(obs.ravel(), n - valid.sum())
    e = np.append(exp, max(missing, 0.0))
    q = missing / n
    z_invalid = float((o[-1] - missing) / np.sqrt(max(n * q * (1 - q), 1e-300))) if q > 0 else (
        0.0 if o[-1] == 0 else np.inf)
    low = e < 5
    o2, e2 = o[~low], e[~low]
    if low.any() and (e[low].sum() > 0 or o[low].sum() > 0):
        o2, e2 = np.append(o2, o[low].sum()), np.append(e2, e[low].sum())
    if np.any((e2 == 0) & (o2 > 0)):
        return 0.0, z_invalid
    stat = np.sum((o2 - e2) ** 2 / e2)
    return float(stats.chi2.sf(stat, len(e2) - 1)), z_invalid


def _assert_chi2(p: float, z_invalid: float) -> None:
    z_crit = stats.norm.ppf(1 - ALPHA_TEST / 2)
    assert p > ALPHA_TEST, f"chi-square p = {p:.3g} <= {ALPHA_TEST:.3g}"
    assert abs(z_invalid) < z_crit, f"invalid share off the pdf's missing mass: z = {z_invalid:.2f} (|z| >= {z_crit:.2f})"


def _u(seed, n, k):
    return np.random.default_rng(seed).random((n, k))


@pytest.mark.parametrize("alpha,theta", [(0.3, 30.0), (0.7, 75.0)])
def test_conductor_chi2(alpha, theta):
    wo = _wo(theta, N)
    bs = conductor_sample(alpha, *GOLD, wo, _u(1, N, 2))
    _assert_chi2(*_chi2(bs.wi, bs.valid, lambda d: conductor_pdf(alpha, _wo(theta, len(d)), d), N))


@pytest.mark.parametrize("alpha,theta", [(0.3, 40.0), (0.5, 160.0), (0.6, 70.0)])
def test_rough_dielectric_chi2(alpha, theta):
    wo = _wo(theta, N)
    u = _u(2, N, 3)
    bs = rough_dielectric_sample(alpha, 1.5, wo, u[:, 0], u[:, 1:])
    _assert_chi2(*_chi2(bs.wi, bs.valid, lambda d: rough_dielectric_pdf(alpha, 1.5, _wo(theta, len(d)), d), N))


@pytest.mark.parametrize("kind", ["conductor", "dielectric"])
def test_sample_matches_eval_and_pdf(kind):
    """The sampler's pdf equals pdf(wo, wi), and its weight equals f |cos| / pdf."""
    n = 20000
    rng = np.random.default_rng(3)
    wo = uniform_sphere(rng.random((n, 2)))
    if kind == "conductor":
        wo[:, 2] = np.abs(wo[:, 2])
        bs = conductor_sample(0.4, *GOLD, wo, rng.random((n, 2)))
        f, pdf = conductor_eval(0.4, *GOLD, wo, bs.wi), conductor_pdf(0.4, wo, bs.wi)
    else:
        u = rng.random((n, 3))
        bs = rough_dielectric_sample(0.4, 1.5, wo, u[:, 0], u[:, 1:])
        f, pdf = rough_dielectric_eval(0.4, 1.5, wo, bs.wi), rough_dielectric_pdf(0.4, 1.5, wo, bs.wi)
    v = bs.valid & (np.abs(bs.wi[:, 2]) > 1e-4) & (np.abs(wo[:, 2]) > 1e-4)
    assert v.mean() > 0.8
    np.testing.assert_allclose(bs.pdf[v], pdf[v], rtol=1e-6)
    np.testing.assert_allclose(bs.weight[v], f[v] * np.abs(bs.wi[v, 2:3]) / pdf[v, None], rtol=1e-6)


def _ggx_nodes(alpha: float, n_u: int = 2048, n_phi: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature over the upper hemisphere for integrands peaked like GGX of roughness alpha:
    nodes wm (M, 3) and solid-angle weights (M,). tan(theta) = alpha u, u = s / (1 - s), midpoint
    rule in s in (0, 1) and phi: the slope-space substitution turns D cos into the smooth
    2 s (1 - s) / ((1 - s)^2 + s^2)^2 ds, whatever alpha (measured: int D cos = 1 within 4e-8)."""
    s = (np.arange(n_u) + 0.5) / n_u
    u = s / (1 - s)
    theta = np.arctan(alpha * u)
    dtheta = alpha / (1 + (alpha * u) ** 2) / (1 - s) ** 2 / n_u
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    wm = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    return wm, np.repeat(np.sin(theta) * dtheta * 2 * np.pi / n_phi, n_phi)


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_ggx_normalization_and_visible_normals(alpha):
    """int D(wm) cos(wm) dwm = 1 and int D_wo(wm) dwm = 1 for wo at 0, 60 and 85 deg, by the
    deterministic quadrature of _ggx_nodes (within 1e-6; measured 4e-8), and the latter again by
    uniform-sphere Monte Carlo (4 sigma + 1e-3) where it is not too peaked (alpha >= 0.3)."""
    wm, w = _ggx_nodes(alpha)
    assert abs(np.sum(ggx_d(alpha, wm) * wm[:, 2] * w) - 1) < 1e-6
    for theta in (0.0, 60.0, 85.0):
        assert abs(np.sum(ggx_visible_pdf(alpha, _wo(theta, len(wm)), wm) * w) - 1) < 1e-6, theta
    n = 400_000
    rng = np.random.default_rng(4)
    d = uniform_sphere(rng.random((n, 2)))
    d[:, 2] = np.abs(d[:, 2])
    f = ggx_visible_pdf(alpha, _wo(60.0, n), d) * 2 * np.pi
    if alpha >= 0.3:
        assert abs(f.mean() - 1) < 4 * f.std() / np.sqrt(n) + 1e-3


@pytest.mark.parametrize("alpha", [0.1, 0.5, 1.0])
def test_weak_white_furnace(alpha):
    """Heitz 2014: int D(wh) G1(wo) / (4 |cos wo|) dwi over the sphere = 1 for any wo (70 deg),
    wh the half vector of (wo, wi). By quadrature over wh (dwi = 4 (wo . wh) dwh for the
    reflection about wh; within 1e-6, measured 4e-8), and by uniform sampling of wi, independent
    of the half-vector map (4 sigma)."""
    n = 400_000
    rng = np.random.default_rng(5)
    wh, w = _ggx_nodes(alpha)
    wo_q = _wo(70.0, len(wh))
    cos_oh = np.maximum(np.einsum("ij,ij->i", wo_q, wh), 0.0)
    val = ggx_d(alpha, wh) * ggx_g1(alpha, wo_q) / (4 * np.abs(wo_q[:, 2])) * 4 * cos_oh
    assert abs(np.sum(val * w) - 1) < 1e-6
    wo = _wo(70.0, n)
    d = uniform_sphere(rng.random((n, 2)))
    h = wo + d
    h /= np.linalg.norm(h, axis=1)[:, None]
    v2 = ggx_d(alpha, h) * ggx_g1(alpha, wo) / (4 * np.abs(wo[:, 2])) * 4 * np.pi * (h[:, 2] > 0)
    assert abs(v2.mean() - 1) < 4 * v2.std() / np.sqrt(n)


@pytest.mark.parametrize("alpha", [0.05, 0.5, 1.0])
def test_conductor_energy(alpha):
    """White furnace of a perfect conductor (F = 1): its albedo, the mean of the sampler's
    weights f |cos wi| / pdf (200000 samples, seed 6), equals the quadrature of f |cos wi| over
    wi (conductor_eval, reflected about the _ggx_nodes half vectors, dwi = 4 (wo . wh) dwh)
    within 4 standard errors of the weights' mean + 1e-6; albedo <= 1 (single scattering loses
    energy), > 0.98 when smooth and not grazing. A sampler weight off by a factor from f cos /
    pdf fails here (test_sample_matches_eval_and_pdf checks the same per sample)."""
    n = 200_000
    rng = np.random.default_rng(6)
    white = (np.ones(3), np.full(3, 1e6))
    wh, w = _ggx_nodes(alpha, 512, 256)
    for th in (0.0, 60.0, 85.0):
        wo = _wo(th, n)
        bs = conductor_sample(alpha, *white, wo, rng.random((n, 2)))
        alb, se = bs.weight[:, 0].mean(), bs.weight[:, 0].std() / np.sqrt(n)
        assert alb <= 1 + 1e-9 and np.all(np.isfinite(bs.weight))
        if alpha <= 0.05 and th <= 60:
            assert alb > 0.98
        wo_q = _wo(th, len(wh))
        cos_oh = np.einsum("ij,ij->i", wo_q, wh)
        wi = -wo_q + 2 * cos_oh[:, None] * wh
        f_cos = conductor_eval(alpha, *white, wo_q, wi)[:, 0] * np.abs(wi[:, 2])
        quad = np.sum(np.where(cos_oh > 0, f_cos * 4 * cos_oh, 0.0) * w)
        assert abs(alb - quad) < 4 * se + 1e-6, (th, alb, quad, se)


def test_rough_dielectric_energy():
    """Rough glass from outside: reflected + transmitted energy (importance mode, x eta'^2)
    <= 1, near 1 at low roughness; the eval-based estimate agrees with the sampler."""
    n = 200_000
    rng = np.random.default_rng(7)
    for alpha in (0.05, 0.6):
        wo = _wo(30.0, n)
        u = rng.random((n, 3))
        bs = rough_dielectric_sample(alpha, 1.5, wo, u[:, 0], u[:, 1:])
        scale = np.where(bs.wi[:, 2] < 0, 1.5 ** 2, 1.0)  # undo radiance scaling
        alb = (bs.weight[:, 0] * scale).mean()
        assert alb <= 1 + 1e-9
        if alpha == 0.05:
            assert alb > 0.97
        d = uniform_sphere(rng.random((n, 2)))
        e = rough_dielectric_eval(alpha, 1.5, wo, d)[:, 0] * np.abs(d[:, 2]) * 4 * np.pi
        e *= np.where(d[:, 2] < 0, 1.5 ** 2, 1.0)
        if alpha == 0.6:
            assert abs(e.mean() - alb) < 5 * e.std() / np.sqrt(n)


@pytest.mark.parametrize("alpha", [0.0, 1e-4, 2e-3, 0.999, 1.0])
def test_hard_case_grazing_any_roughness(alpha):
    """Grazing wo (cos 1e-7 .. 1e-3) and exactly-at-horizon directions at roughness near 0 and
    1: every sample, eval and pdf finite; weights bounded (<= 1 for reflection)."""
    n = 5000
    rng = np.random.default_rng(8)
    cos = np.array([0.0, 1e-7, 1e-5, 1e-3])[rng.integers(0, 4, n)]
    wo = np.stack([np.sqrt(1 - cos ** 2), np.zeros(n), cos], 1)
    bs = conductor_sample(alpha, *GOLD, wo, rng.random((n, 2)))
    assert np.all(np.isfinite(bs.weight)) and np.all(np.isfinite(bs.pdf)) and bs.weight.max() <= 1 + 1e-9
    u = rng.random((n, 3))
    for w in (wo, -wo):
        bd = rough_dielectric_sample(alpha, 1.5, w, u[:, 0], u[:, 1:])
        assert np.all(np.isfinite(bd.weight)) and np.all(np.isfinite(bd.pdf)) and np.all(np.isfinite(bd.wi))
        assert bd.weight.max() <= 1.5 ** 2 + 1e-9
    d = uniform_sphere(rng.random((n, 2)))
    for arr in (conductor_eval(alpha, *GOLD, wo, d), conductor_pdf(alpha, wo, d),
                rough_dielectric_eval(alpha, 1.5, wo, d), rough_dielectric_pdf(alpha, 1.5, wo, d)):
        assert np.all(np.isfinite(arr)) and np.all(arr >= 0)
