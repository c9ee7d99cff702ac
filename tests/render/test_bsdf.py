"""BSDFs: dielectric lobe choice by Pearson chi-square (1e6 samples per angle, alpha 0.01 Sidak-
corrected over the angles), Snell's law, Fresnel limits, total internal reflection, Lambertian
and mirror consistency, textured albedo through render.texture. Fixed seeds."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import stats

from render.accel import Geometry
from render.bsdf import (MaterialTable, dielectric_sample, fresnel_dielectric, lambert_eval, lambert_pdf,
                         lambert_sample, mirror_sample)
from render.sampling import path_keys, uniform, uniform_sphere
from render.scene import Lambertian, Scene, SceneObject
from render.texture import decode_texture, sample_bilinear

N = 1_000_000
COS_ANGLES = [0.95, 0.5, 0.1, -0.95, -0.8, -0.5]  # negative: arriving from inside the glass
ALPHA = 1.0 - (1.0 - 0.01) ** (1.0 / len(COS_ANGLES))
IOR = 1.5


def _wo(cos_o: float, n: int) -> np.ndarray:
    s = np.sqrt(1 - cos_o * cos_o)
    return np.tile([s * np.cos(0.3), s * np.sin(0.3), cos_o], (n, 1))


def _u(seed, n, dims=1):
    k = path_keys(seed, np.arange(n), np.zeros(n, np.int64))
    return np.stack([uniform(k, d) for d in range(dims)], 1).squeeze()


@pytest.mark.parametrize("cos_o", COS_ANGLES)
def test_dielectric_lobe_chi2(cos_o):
    """Reflection is chosen with probability F, refraction with 1 - F (a two-cell chi-square; a
    TIR angle must always reflect). The discrete pdf sums to 1."""
    wo = _wo(cos_o, N)
    s = dielectric_sample(np.full(N, IOR), wo, _u(20, N))
    F = fresnel_dielectric(np.array([cos_o]), IOR)[0]
    refl = np.sign(s.wi[:, 2]) == np.sign(cos_o)
    assert s.delta.all() and s.valid.all()
    assert np.allclose(np.where(refl, s.pdf, 0) + np.where(refl, 0, s.pdf), np.where(refl, F, 1 - F))
    if F >= 1.0:
        assert refl.all()
        return
    obs = np.array([refl.sum(), (~refl).sum()])
    exp = N * np.array([F, 1 - F])
    assert stats.chi2.sf(np.sum((obs - exp) ** 2 / exp), 1) > ALPHA
    assert F + (1 - F) == pytest.approx(1.0)


def test_snell_and_weights():
    wo = uniform_sphere(np.stack([_u(21, 5000, 2)[:, 0], _u(21, 5000, 2)[:, 1]], 1))
    wo = wo[np.abs(wo[:, 2]) > 1e-3]
    s = dielectric_sample(np.full(len(wo), IOR), wo, np.full(len(wo), 0.999999))  # prefer refraction
    refr = np.sign(s.wi[:, 2]) != np.sign(wo[:, 2])
    assert refr.sum() > 100
    eta_i = np.where(wo[:, 2] > 0, 1.0, IOR)
    eta_t = np.where(wo[:, 2] > 0, IOR, 1.0)
    sin_i = np.linalg.norm(wo[:, :2], axis=1)
    sin_t = np.linalg.norm(s.wi[:, :2], axis=1)
    assert np.allclose((eta_i * sin_i)[refr], (eta_t * sin_t)[refr], atol=1e-12)
    assert np.allclose(np.linalg.norm(s.wi, axis=1), 1.0)
    # tangential directions are opposite (the refracted ray continues through the surface)
    assert np.all(np.einsum("ij,ij->i", wo[refr, :2], s.wi[refr, :2]) <= 1e-12)
    assert np.allclose(s.weight[refr, 0], ((eta_i / eta_t) ** 2)[refr])
    assert np.allclose(s.weight[~refr], 1.0)


def test_fresnel_limits_and_total_internal_reflection():
    assert fresnel_dielectric(np.array([1.0]), IOR)[0] == pytest.approx(((IOR - 1) / (IOR + 1)) ** 2)
    assert fresnel_dielectric(np.array([-1.0]), IOR)[0] == pytest.approx(((IOR - 1) / (IOR + 1)) ** 2)
    assert fresnel_dielectric(np.array([1e-9]), IOR)[0] == pytest.approx(1.0, abs=1e-6)
    crit = np.sqrt(1 - 1 / IOR ** 2)  # cosine at the critical angle, inside
    c = -np.array([crit * 0.999, crit * 0.5, 1e-12])
    assert np.all(fresnel_dielectric(c, IOR) == 1.0)
    s = dielectric_sample(np.full(3, IOR), _wo(-crit * 0.5, 3), np.array([0.0, 0.5, 0.999999]))
    assert np.all(s.wi[:, 2] < 0) and np.all(np.isfinite(s.wi)) and np.allclose(s.weight, 1.0)
    # index matching: no reflection at all
    assert fresnel_dielectric(np.array([0.3, -0.7]), 1.0) == pytest.approx([0.0, 0.0])


def test_lambert_and_mirror_consistency():
    n = 10000
    wo = _wo(0.6, n)
    albedo = np.tile([0.2, 0.5, 0.9], (n, 1))
    s = lambert_sample(albedo, wo, _u(22, n, 2))
    f = lambert_eval(albedo, wo, s.wi)
    pdf = lambert_pdf(wo, s.wi)
    ok = pdf > 0
    assert np.allclose((f * s.wi[:, 2:3] / np.where(ok, pdf, 1)[:, None])[ok], s.weight[ok])
    assert np.allclose(pdf, s.pdf)
    below = s.wi * np.array([1, 1, -1])
    assert np.all(lambert_eval(albedo, wo, below) == 0) and np.all(lambert_pdf(wo, below) == 0)
    m = mirror_sample(np.tile([0.9, 0.8, 0.7], (n, 1)), wo)
    assert np.allclose(m.wi, wo * [-1, -1, 1]) and m.delta.all() and np.allclose(m.weight, [0.9, 0.8, 0.7])


def test_textured_albedo_uses_shared_lookup():
    tex = (np.arange(4 * 5 * 3) * 7 % 256).astype(np.uint8).reshape(4, 5, 3)
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array([[0.1, 0.2], [0.9, 0.3], [0.4, 0.8]]))
    tint = np.array([0.5, 1.0, 0.25])
    sc = Scene("tex", [SceneObject("t", mesh, Lambertian(tint, texture=tex))])
    g = Geometry.from_scene(sc)
    mt = MaterialTable.from_scene(sc)
    u, v = np.array([0.2, 0.5, 0.0]), np.array([0.3, 0.1, 0.0])
    tri = np.zeros(3, np.int64)
    a = mt.diffuse_albedo(np.zeros(3, np.int64), lambda m: g.texcoords(tri[m], u[m], v[m]))
    uv = (1 - u - v)[:, None] * [0.1, 0.2] + u[:, None] * [0.9, 0.3] + v[:, None] * [0.4, 0.8]
    assert np.allclose(a, sample_bilinear(decode_texture(tex), uv) * tint)


def test_mixed_material_dispatch():
    """bsdf_sample / bsdf_eval / bsdf_pdf over rays of mixed kinds equal the per-kind functions."""
    from render.bsdf import DIELECTRIC, EMISSIVE, LAMBERT, MIRROR, bsdf_eval, bsdf_pdf, bsdf_sample
    n = 4000
    kind = np.array([LAMBERT, MIRROR, DIELECTRIC, EMISSIVE])[np.arange(n) % 4]
    u = _u(23, n, 3)
    wo = _wo(0.7, n)
    albedo = np.tile([0.3, 0.6, 0.9], (n, 1))
    ior = np.full(n, 1.5)
    s = bsdf_sample(kind, albedo, ior, wo, u[:, 0], u[:, 1:3])
    lam, mir, die = (np.nonzero(kind == k)[0] for k in (LAMBERT, MIRROR, DIELECTRIC))
    ref_l = lambert_sample(albedo[lam], wo[lam], u[lam, 1:3])
    ref_d = dielectric_sample(ior[die], wo[die], u[die, 0])
    assert np.allclose(s.wi[lam], ref_l.wi) and np.allclose(s.weight[lam], ref_l.weight)
    assert np.allclose(s.wi[mir], mirror_sample(albedo[mir], wo[mir]).wi) and s.delta[mir].all()
    assert np.allclose(s.wi[die], ref_d.wi) and np.allclose(s.pdf[die], ref_d.pdf)
    assert not s.valid[kind == EMISSIVE].any()
    f, pdf = bsdf_eval(kind, albedo, wo, s.wi), bsdf_pdf(kind, wo, s.wi)
    assert np.all(f[kind != LAMBERT] == 0) and np.all(pdf[kind != LAMBERT] == 0)
    assert np.allclose(pdf[lam], s.pdf[lam])
