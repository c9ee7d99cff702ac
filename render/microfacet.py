"""Glossy surfaces: the GGX (Trowbridge-Reitz) microfacet BSDF, conductor and rough dielectric.

The materials themselves (:class:`render.scene.RoughConductor`, :class:`render.scene.RoughDielectric`,
``ALPHA_SMOOTH``) live with the other materials in :mod:`render.scene`; this module is their BSDF.

Vectorized over rays in the z-up local frames of :mod:`render.bsdf` (``w.z = cos theta``), with
the same sample / eval / pdf split and :class:`render.bsdf.BSDFSample` results, so every
integrator that takes Lambertian, mirror and glass takes these as one more (non-delta) lobe.

Formulas follow pbrt-v4 (TrowbridgeReitzDistribution, ConductorBxDF, DielectricBxDF), isotropic:

* D(wm) = 1 / (pi a^2 cos^4 (1 + tan^2 / a^2)^2); Lambda(w) = (sqrt(1 + a^2 tan^2 w) - 1) / 2;
  G1 = 1 / (1 + Lambda); G = 1 / (1 + Lambda(wo) + Lambda(wi)) (height-correlated Smith).
* Visible normals (Heitz 2018, "Sampling the GGX distribution of visible normals"): wm is drawn
  with density D_wo(wm) = G1(wo) / |cos wo| D(wm) |wo . wm|; a reflection's solid-angle density
  is D_wo(wm) / (4 |wo . wm|).
* Conductor: f = D F G / (4 |cos i cos o|) with the complex Fresnel term of eta + i k (per RGB
  channel). Rough dielectric: reflection with probability F, transmission with 1 - F, the
  generalized half vector wm = normalize(eta' wi + wo) (Walter et al. 2007); radiance transport
  divides transmission by eta'^2 as :mod:`render.bsdf`'s smooth dielectric does.

``alpha`` below ALPHA_SMOOTH is a smooth surface (pbrt's EffectivelySmooth): it is sampled as a
delta lobe (mirror with the conductor's Fresnel, or the smooth dielectric), and eval / pdf are 0,
so grazing angles at roughness near 0 never produce 1/0. ``alpha`` is clamped to [ALPHA_SMOOTH, 1].
A conductor's frame faces wo (two-sided, like mirrors); a dielectric's frame is its outward normal.
"""
from __future__ import annotations

import numpy as np

from .bsdf import BSDFSample, fresnel_dielectric
from .scene import ALPHA_SMOOTH

__all__ = [
    "ggx_d", "ggx_lambda", "ggx_g1", "ggx_g", "ggx_sample_visible", "ggx_visible_pdf",
    "fresnel_complex", "conductor_eval", "conductor_pdf", "conductor_sample",
    "rough_dielectric_eval", "rough_dielectric_pdf", "rough_dielectric_sample",
]

_EPS = 1e-12


def _alpha(alpha) -> np.ndarray:
    return np.clip(np.asarray(alpha, dtype=np.float64), ALPHA_SMOOTH, 1.0)


def _tan2(w: np.ndarray) -> np.ndarray:
    c2 = w[:, 2] * w[:, 2]
    s2 = np.maximum(0.0, w[:, 0] * w[:, 0] + w[:, 1] * w[:, 1])
    return np.where(c2 > 0, s2 / np.maximum(c2, _EPS * _EPS), np.inf)


# ---------------------------------------------------------------- the distribution
def ggx_d(alpha, wm: np.ndarray) -> np.ndarray:
    """GGX normal distribution D(wm) (N,) for unit local normals wm (N, 3); 0 at the horizon."""
    a2 = _alpha(alpha) ** 2
    t2 = _tan2(wm)
    c2 = wm[:, 2] ** 2
    ok = np.isfinite(t2) & (c2 > 0)
    t2 = np.where(ok, t2, 0.0)
    e = 1.0 + t2 / a2
    return np.where(ok, 1.0 / np.maximum(np.pi * a2 * c2 * c2 * e * e, 1e-300), 0.0)


def ggx_lambda(alpha, w: np.ndarray) -> np.ndarray:
    """Smith's Lambda(w) (N,) for GGX; inf at the horizon (G1 = 0 there)."""
    a2 = _alpha(alpha) ** 2
    t2 = _tan2(w)
    ok = np.isfinite(t2)
    return np.where(ok, 0.5 * (np.sqrt(1.0 + a2 * np.where(ok, t2, 0.0)) - 1.0), np.inf)


def ggx_g1(alpha, w: np.ndarray) -> np.ndarray:
    """Masking G1(w) = 1 / (1 + Lambda(w)) (N,)."""
    return 1.0 / (1.0 + ggx_lambda(alpha, w))


def ggx_g(alpha, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """Height-correlated masking-shadowing G = 1 / (1 + Lambda(wo) + Lambda(wi)) (N,)."""
    return 1.0 / (1.0 + ggx_lambda(alpha, wo) + ggx_lambda(alpha, wi))


def ggx_visible_pdf(alpha, w: np.ndarray, wm: np.ndarray) -> np.ndarray:
    """Density of visible normals D_w(wm) = G1(w) / |cos w| D(wm) max(0, w . wm) (N,), per unit
    solid angle of wm (wm in the upper hemisphere; w below the surface counts as mirrored)."""
    c = np.abs(w[:, 2])
    # microfacets facing away from w (on w's side of the surface) are not visible
    dot = np.maximum(0.0, np.einsum("ij,ij->i", w, wm) * np.where(w[:, 2] < 0, -1.0, 1.0))
    return np.where(c > 0, ggx_g1(alpha, w) / np.maximum(c, _EPS) * ggx_d(alpha, wm) * dot, 0.0)


def ggx_sample_visible(alpha, w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Visible normals seen from w (N, 3) (either side; mirrored to the upper one), u (N, 2).

    Heitz 2018 / pbrt-v4 Sample_wm: stretch w to the hemisphere configuration, sample a point on
    the projected disk warped for the visible half, unstretch. Returns (N, 3) unit normals, z > 0.
    """
    a = _alpha(alpha) * np.ones(len(w))
    wh = np.stack([a * w[:, 0], a * w[:, 1], w[:, 2]], axis=1)
    wh /= np.maximum(np.linalg.norm(wh, axis=1), _EPS)[:, None]
    wh[wh[:, 2] < 0] *= -1.0
    # T1 = normalize(cross(z, wh)) = normalize(-wh.y, wh.x, 0), or x when wh is (almost) z
    t1 = np.stack([-wh[:, 1], wh[:, 0], np.zeros(len(w))], axis=1)
    ln = np.linalg.norm(t1, axis=1)
    up = (wh[:, 2] >= 0.99999) | (ln < 1e-9)
    t1 = np.where(up[:, None], np.array([1.0, 0.0, 0.0]), t1 / np.maximum(ln, _EPS)[:, None])
    t2 = np.cross(wh, t1)
    r = np.sqrt(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    px, py = r * np.cos(phi), r * np.sin(phi)
    h = np.sqrt(np.maximum(0.0, 1.0 - px * px))
    s = 0.5 * (1.0 + wh[:, 2])
    py = (1.0 - s) * h + s * py
    pz = np.sqrt(np.maximum(0.0, 1.0 - px * px - py * py))
    nh = px[:, None] * t1 + py[:, None] * t2 + pz[:, None] * wh
    wm = np.stack([a * nh[:, 0], a * nh[:, 1], np.maximum(1e-6, nh[:, 2])], axis=1)
    return wm / np.linalg.norm(wm, axis=1)[:, None]


def _reflect(wo: np.ndarray, wm: np.ndarray) -> np.ndarray:
    return -wo + 2.0 * np.einsum("ij,ij->i", wo, wm)[:, None] * wm


# ---------------------------------------------------------------- conductor
def fresnel_complex(cos_i: np.ndarray, eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Unpolarized Fresnel reflectance of a conductor (pbrt-v4 FrComplex), per channel.

    cos_i: (N,) |cosine| to the microfacet normal. eta, k: (N, 3) or (3,). Returns (N, 3) in [0, 1].
    """
    c = np.clip(np.abs(cos_i), 0.0, 1.0)[:, None]
    e = np.broadcast_to(eta, (len(c), 3)) + 1j * np.broadcast_to(k, (len(c), 3))
    s2 = 1.0 - c * c
    ct = np.sqrt(1.0 - s2 / (e * e))
    r_par = (e * c - ct) / (e * c + ct)
    r_perp = (c - e * ct) / (c + e * ct)
    return np.clip(0.5 * (np.abs(r_par) ** 2 + np.abs(r_perp) ** 2), 0.0, 1.0)


def conductor_eval(alpha, eta, k, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """f(wo, wi) (N, 3) of a rough conductor (frame facing wo); 0 for smooth ones or wi below."""
    a = np.asarray(alpha, dtype=np.float64) * np.ones(len(wo))
    co, ci = wo[:, 2], wi[:, 2]
    ok = (co > 0) & (ci > 0) & (a >= ALPHA_SMOOTH)
    wm = wo + wi
    ln = np.linalg.norm(wm, axis=1)
    ok &= ln > _EPS
    wm = wm / np.maximum(ln, _EPS)[:, None]
    F = fresnel_complex(np.einsum("ij,ij->i", wo, wm), eta, k)
    val = ggx_d(a, wm) * ggx_g(a, wo, wi) / np.maximum(4.0 * co * ci, _EPS)
    return np.where(ok[:, None], F * np.where(ok, val, 0.0)[:, None], 0.0)


def conductor_pdf(alpha, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """Solid-angle density (N,) with which :func:`conductor_sample` picks wi; 0 if smooth."""
    a = np.asarray(alpha, dtype=np.float64) * np.ones(len(wo))
    ok = (wo[:, 2] > 0) & (wi[:, 2] > 0) & (a >= ALPHA_SMOOTH)
    wm = wo + wi
    ln = np.linalg.norm(wm, axis=1)
    ok &= ln > _EPS
    wm = wm / np.maximum(ln, _EPS)[:, None]
    dot = np.abs(np.einsum("ij,ij->i", wo, wm))
    return np.where(ok, ggx_visible_pdf(a, wo, wm) / np.maximum(4.0 * dot, _EPS), 0.0)


def conductor_sample(alpha, eta, k, wo: np.ndarray, u: np.ndarray) -> BSDFSample:
    """Sample a rough conductor: visible normal, then mirror reflection about it.

    alpha (N,) or scalar; eta, k (N, 3) or (3,); wo (N, 3) local, frame facing wo; u (N, 2).
    Smooth (alpha < ALPHA_SMOOTH): delta reflection with weight F(cos wo).
    """
    n = len(wo)
    a = np.asarray(alpha, dtype=np.float64) * np.ones(n)
    smooth = a < ALPHA_SMOOTH
    wm = ggx_sample_visible(a, wo, u)
    wm[smooth] = (0.0, 0.0, 1.0)
    wi = _reflect(wo, wm)
    dot = np.einsum("ij,ij->i", wo, wm)
    F = fresnel_complex(dot, eta, k)
    co, ci = wo[:, 2], wi[:, 2]
    valid = (co > 0) & (ci > 0)
    # weight f cos / pdf = F G / G1(wo) (pbrt-v4's estimator with VNDF sampling)
    g_ratio = np.where(valid & ~smooth, ggx_g(a, wo, wi) / np.maximum(ggx_g1(a, wo), _EPS), 1.0)
    pdf = np.where(smooth, 1.0, ggx_visible_pdf(a, wo, wm) / np.maximum(4.0 * np.abs(dot), _EPS))
    valid &= pdf > 0
    weight = F * (g_ratio * valid)[:, None]
    return BSDFSample(wi, weight, np.where(valid, pdf, 0.0), smooth.copy(), valid)


# ---------------------------------------------------------------- rough dielectric
def _gen_half(wo, wi, ior):
    """Generalized half vector of (wo, wi) (upper hemisphere), eta' and the reflect flag."""
    co, ci = wo[:, 2], wi[:, 2]
    reflect = co * ci > 0
    etap = np.where(reflect, 1.0, np.where(co > 0, ior, 1.0 / ior))
    wm = wi * etap[:, None] + wo
    ln = np.linalg.norm(wm, axis=1)
    ok = (co != 0) & (ci != 0) & (ln > _EPS)
    wm = wm / np.maximum(ln, _EPS)[:, None]
    wm[wm[:, 2] < 0] *= -1.0
    dwi, dwo = np.einsum("ij,ij->i", wm, wi), np.einsum("ij,ij->i", wm, wo)
    ok &= (dwi * ci >= 0) & (dwo * co >= 0)  # back-facing microfacets contribute nothing
    return wm, etap, reflect, ok, dwi, dwo


def rough_dielectric_eval(alpha, ior, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """f(wo, wi) (N, 3) of a rough dielectric (frame = outward normal; ior inside / outside);
    reflection and transmission (radiance transport: transmission / eta'^2). 0 if smooth."""
    n = len(wo)
    a = np.asarray(alpha, dtype=np.float64) * np.ones(n)
    ior = np.asarray(ior, dtype=np.float64) * np.ones(n)
    wm, etap, reflect, ok, dwi, dwo = _gen_half(wo, wi, ior)
    ok &= a >= ALPHA_SMOOTH
    F = fresnel_dielectric(dwo, ior)
    D, G = ggx_d(a, wm), ggx_g(a, wo, wi)
    cc = np.abs(wi[:, 2] * wo[:, 2])
    fr = D * G * F / np.maximum(4.0 * cc, _EPS)
    denom = (dwi + dwo / etap) ** 2 * cc
    ft = D * (1.0 - F) * G * np.abs(dwi * dwo / np.where(denom > 0, denom, 1.0)) / (etap * etap)
    ok_t = ok & ~reflect & (denom > 0)
    val = np.where(reflect & ok, fr, np.where(ok_t, ft, 0.0))
    return np.repeat(val[:, None], 3, axis=1)


def rough_dielectric_pdf(alpha, ior, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """Solid-angle density (N,) with which :func:`rough_dielectric_sample` picks wi."""
    n = len(wo)
    a = np.asarray(alpha, dtype=np.float64) * np.ones(n)
    ior = np.asarray(ior, dtype=np.float64) * np.ones(n)
    wm, etap, reflect, ok, dwi, dwo = _gen_half(wo, wi, ior)
    ok &= a >= ALPHA_SMOOTH
    F = fresnel_dielectric(dwo, ior)
    dvis = ggx_visible_pdf(a, wo, wm)
    pr = dvis / np.maximum(4.0 * np.abs(dwo), _EPS) * F
    denom = (dwi + dwo / etap) ** 2
    pt = dvis * np.abs(dwi) / np.where(denom > 0, denom, 1.0) * (1.0 - F)
    return np.where(ok, np.where(reflect, pr, np.where(denom > 0, pt, 0.0)), 0.0)


def rough_dielectric_sample(alpha, ior, wo: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> BSDFSample:
    """Sample a rough dielectric: visible normal, then reflect (probability F) or refract.

    alpha, ior (N,) or scalars; wo (N, 3) local to the outward normal (wo.z < 0: inside);
    u1 (N,) lobe choice; u2 (N, 2). Smooth: the delta dielectric of :mod:`render.bsdf`.
    """
    from .bsdf import dielectric_sample

    n = len(wo)
    a = np.asarray(alpha, dtype=np.float64) * np.ones(n)
    ior = np.asarray(ior, dtype=np.float64) * np.ones(n)
    smooth = a < ALPHA_SMOOTH
    wm = ggx_sample_visible(a, wo, u2)
    dwo = np.einsum("ij,ij->i", wo, wm)
    F = fresnel_dielectric(dwo, ior)
    refl = u1 < F
    # refraction through wm (pbrt-v4 Refract with eta = ior, flipped when arriving from inside)
    inside = dwo < 0
    eta = np.where(inside, 1.0 / ior, ior)
    nrm = np.where(inside[:, None], -wm, wm)
    ci = np.abs(dwo)
    s2t = np.maximum(0.0, 1.0 - ci * ci) / (eta * eta)
    tir = s2t >= 1.0
    ct = np.sqrt(np.maximum(0.0, 1.0 - s2t))
    wt = -wo / eta[:, None] + (ci / eta - ct)[:, None] * nrm
    wr = _reflect(wo, wm)
    wi = np.where(refl[:, None], wr, wt)
    co, cwi = wo[:, 2], wi[:, 2]
    same = co * cwi > 0
    valid = np.where(refl, same, ~same & ~tir & (cwi != 0)) & (co != 0)
    etap = np.where(refl, 1.0, eta)
    dwi = np.einsum("ij,ij->i", wi, wm)
    dvis = ggx_visible_pdf(a, wo, wm)
    denom = (dwi + dwo / etap) ** 2
    pdf = np.where(refl, dvis / np.maximum(4.0 * ci, _EPS) * F,
                   dvis * np.abs(dwi) / np.where(denom > 0, denom, 1.0) * (1.0 - F))
    valid &= (pdf > 0) & (denom > 0)
    # weight f |cos i| / pdf: reflection G / G1(wo), transmission G / G1(wo) / eta'^2
    g_ratio = ggx_g(a, wo, wi) / np.maximum(ggx_g1(a, wo), _EPS)
    w = np.where(valid, g_ratio / (etap * etap), 0.0)
    out = BSDFSample(wi, np.repeat(w[:, None], 3, axis=1), np.where(valid, pdf, 0.0), np.zeros(n, bool), valid)
    if smooth.any():
        s = np.nonzero(smooth)[0]
        bs = dielectric_sample(ior[s], wo[s], u1[s])
        out.wi[s], out.weight[s], out.pdf[s], out.delta[s], out.valid[s] = bs.wi, bs.weight, bs.pdf, True, bs.valid
    return out
