"""Samplers: Pearson chi-square tests (1e6 samples, cells with expected count < 5 pooled, alpha
0.01 Sidak-corrected over this file's chi-square tests), densities integrating to 1, the
counter-based RNG, MIS weights. Fixed seeds."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from ptutil import quad
from render.accel import Accel, Geometry
from render.bsdf import MaterialTable
from render.lights import LightSet
from render.sampling import (balance_heuristic, concentric_disk, cosine_hemisphere, cosine_hemisphere_pdf,
                             mis_weight, orthonormal_frame, path_keys, power_heuristic, to_local, to_world,
                             uniform, uniform_sphere)
from render.scene import Emissive, Scene, SceneObject

N = 1_000_000
N_CHI2_TESTS = 4  # chi-square tests in this file
ALPHA = 1.0 - (1.0 - 0.01) ** (1.0 / N_CHI2_TESTS)  # Sidak


def chi2_pvalue(observed: np.ndarray, expected: np.ndarray) -> float:
    """Pearson chi-square p-value; cells with expected count < 5 are pooled into one."""
    o, e = observed.ravel().astype(float), expected.ravel().astype(float)
    low = e < 5
    if low.any():
        o = np.append(o[~low], o[low].sum())
        e = np.append(e[~low], e[low].sum())
        if e[-1] == 0:
            assert o[-1] == 0, "samples fell where the density is zero"
            o, e = o[:-1], e[:-1]
    stat = np.sum((o - e) ** 2 / e)
    return float(stats.chi2.sf(stat, len(e) - 1))


def _u2(seed: int, n: int = N) -> np.ndarray:
    k = path_keys(seed, np.arange(n), np.zeros(n, np.int64))
    return np.stack([uniform(k, 0), uniform(k, 1)], axis=1)


def test_rng_uniform_chi2_and_deterministic():
    k = path_keys(5, np.arange(N), np.full(N, 3))
    u = uniform(k, 7)
    assert np.all((u >= 0) & (u < 1))
    counts = np.bincount((u * 100).astype(int), minlength=100)
    assert chi2_pvalue(counts, np.full(100, N / 100)) > ALPHA
    assert np.array_equal(u, uniform(path_keys(5, np.arange(N), np.full(N, 3)), 7))
    # a sample's numbers do not depend on which batch it was drawn in
    sub = np.arange(1000, 2000)
    assert np.array_equal(uniform(path_keys(5, sub, np.full(1000, 3)), 7), u[sub])
    # dimensions, samples and seeds are decorrelated
    for other in (uniform(k, 8), uniform(path_keys(5, np.arange(N), np.full(N, 4)), 7),
                  uniform(path_keys(6, np.arange(N), np.full(N, 3)), 7)):
        assert abs(np.corrcoef(u, other)[0, 1]) < 5e-3
        assert not np.array_equal(u, other)


def test_cosine_hemisphere_chi2():
    w = cosine_hemisphere(_u2(1))
    assert np.allclose(np.linalg.norm(w, axis=1), 1.0) and np.all(w[:, 2] >= 0)
    nt, nphi = 16, 32
    theta = np.arccos(np.clip(w[:, 2], -1, 1))
    phi = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi)
    obs, _, _ = np.histogram2d(theta, phi, bins=[nt, nphi], range=[[0, np.pi / 2], [0, 2 * np.pi]])
    t_edges = np.linspace(0, np.pi / 2, nt + 1)
    band = 0.5 * (np.sin(t_edges[1:]) ** 2 - np.sin(t_edges[:-1]) ** 2)  # int cos sin dtheta
    expected = N * np.outer(band, np.full(nphi, 2 * np.pi / nphi)) / np.pi
    assert expected.sum() == pytest.approx(N)
    assert chi2_pvalue(obs, expected) > ALPHA


def test_uniform_sphere_chi2_and_disk():
    w = uniform_sphere(_u2(2))
    obs, _, _ = np.histogram2d(w[:, 2], np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi), bins=[20, 20],
                               range=[[-1, 1], [0, 2 * np.pi]])
    assert chi2_pvalue(obs, np.full((20, 20), N / 400)) > ALPHA
    d = concentric_disk(_u2(3, 10000))
    assert np.all(np.linalg.norm(d, axis=1) <= 1 + 1e-12)


def test_densities_integrate_to_one():
    """Cosine density over the hemisphere (midpoint rule in (cos theta, phi), equal-area cells)."""
    n = 2000
    c = (np.arange(n) + 0.5) / n
    assert np.sum(cosine_hemisphere_pdf(c)) * (1.0 / n) * 2 * np.pi == pytest.approx(1.0, abs=1e-6)
    assert np.all(cosine_hemisphere_pdf(np.array([-0.5, -1e-9])) == 0)


# ------------------------------------------------------------------ area-source sampling
def _two_lights():
    """Two rectangle sources, neither hiding the other from the shading point used below."""
    a = SceneObject("a", quad((0.0, 0.0, 1.0), 0.5, 0.5, -1), Emissive([1, 1, 1]))
    b = SceneObject("b", quad((1.8, 0.5, 1.5), 1.0, 0.25, -1), Emissive([3, 3, 3]))
    sc = Scene("lights", [a, b])
    g = Geometry.from_scene(sc)
    return sc, g, LightSet(sc, g, MaterialTable.from_scene(sc))


def test_area_light_sampling_chi2():
    """Triangles picked by power (here 1 : 3), points uniform by area: chi-square over a grid on
    each rectangle source (each made of two triangles)."""
    sc, g, ls = _two_lights()
    p = np.tile([0.2, -0.3, 0.0], (N, 1))
    k = path_keys(9, np.arange(N), np.zeros(N, np.int64))
    s = ls.sample(p, uniform(k, 0), np.stack([uniform(k, 1), uniform(k, 2)], 1))
    assert s.valid.all() and not s.delta.any()
    y = p + s.wi * s.dist[:, None]
    on_a = np.abs(y[:, 2] - 1.0) < 1e-6
    on_b = np.abs(y[:, 2] - 1.5) < 1e-6
    assert np.all(on_a | on_b)
    oa, _, _ = np.histogram2d(y[on_a, 0], y[on_a, 1], bins=[10, 10], range=[[-0.5, 0.5], [-0.5, 0.5]])
    ob, _, _ = np.histogram2d(y[on_b, 0], y[on_b, 1], bins=[20, 5], range=[[0.8, 2.8], [0.25, 0.75]])
    obs = np.concatenate([oa.ravel(), ob.ravel()])
    exp = np.concatenate([np.full(100, 0.25 * N / 100), np.full(100, 0.75 * N / 100)])
    assert obs.sum() == N
    assert chi2_pvalue(obs, exp) > ALPHA


def test_area_light_solid_angle_pdf_integrates_to_one_and_matches_mis_lookup():
    """p_omega = p_area r^2 / |cos| integrates to 1 over the sphere of directions (quadrature in
    (cos theta, phi) with rays traced through Embree and the MIS lookup), and the density of each
    NEE sample equals what the MIS lookup gives for the same direction."""
    sc, g, ls = _two_lights()
    accel = Accel(sc, threads=2, geometry=g)
    p = np.array([0.2, -0.3, 0.0])
    nz, nphi = 1200, 2400
    z = (np.arange(nz) + 0.5) / nz  # upper hemisphere only: both lights lie above
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * np.pi
    Z, PHI = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - Z ** 2)
    d = np.stack([r * np.cos(PHI), r * np.sin(PHI), Z], -1).reshape(-1, 3)
    h = accel.intersect(np.broadcast_to(p, d.shape), d)
    hit = h.tri >= 0
    cos_l = -np.einsum("ij,ij->i", d[hit], g.normal[h.tri[hit]])
    pdf = ls.pdf_hit(h.tri[hit], h.t[hit], cos_l)
    integral = pdf.sum() * (2 * np.pi / (nz * nphi))
    assert integral == pytest.approx(1.0, abs=3e-3)
    # per-sample consistency with the lookup
    n = 20000
    k = path_keys(10, np.arange(n), np.zeros(n, np.int64))
    s = ls.sample(np.tile(p, (n, 1)), uniform(k, 0), np.stack([uniform(k, 1), uniform(k, 2)], 1))
    h = accel.intersect(np.tile(p, (n, 1)), s.wi)
    assert np.all(h.tri >= 0)
    cos_l = -np.einsum("ij,ij->i", s.wi, g.normal[h.tri])
    assert np.allclose(ls.pdf_hit(h.tri, h.t, cos_l), s.pdf, rtol=1e-4)
    accel.close()


def test_mis_weights():
    a = np.array([0.0, 1.0, 2.0, 1e200, 1.0, 0.0])
    b = np.array([1.0, 1.0, 1.0, 1.0, 1e200, 0.0])
    for h in (balance_heuristic, power_heuristic):
        wa, wb = h(a, b), h(b, a)
        assert np.all(np.isfinite(wa)) and np.all((wa >= 0) & (wa <= 1))
        assert np.allclose((wa + wb)[:5], 1.0)
        assert wa[0] == 0 and wa[5] == 0
    assert power_heuristic(np.array([2.0]), np.array([1.0]))[0] == pytest.approx(0.8)
    assert balance_heuristic(np.array([2.0]), np.array([1.0]))[0] == pytest.approx(2 / 3)
    assert mis_weight(np.array([1.0]), np.array([3.0]), 3.0)[0] == pytest.approx(1 / 28)


def test_frames_are_orthonormal():
    n = uniform_sphere(_u2(4, 10000))
    n[0] = [0, 0, -1]
    n[1] = [0, 0, 1]
    s, t = orthonormal_frame(n)
    for a, b in ((s, t), (s, n), (t, n)):
        assert np.allclose(np.einsum("ij,ij->i", a, b), 0, atol=1e-12)
    assert np.allclose(np.cross(s, t), n, atol=1e-12)
    w = uniform_sphere(_u2(5, 10000))
    assert np.allclose(to_world(to_local(w, s, t, n), s, t, n), w)
