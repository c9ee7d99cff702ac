"""Participating media and ``volpath``: closed forms (homogeneous transmittance exp(-sigma_t d),
the emitting-absorbing slab L_bg exp(-sigma_a d) + Le (1 - exp(-sigma_a d)), a non-absorbing
medium in an enclosure of constant radiance stays at that radiance for any sigma_s and g, with
and without next-event estimation), Henyey-Greenstein chi-square, the NeRF quadrature of
recon.nerf.volume on the same emission-absorption grid, and named hard cases. Statistical tests:
fixed seeds, z-tests at 4.5 sigma (alpha ~ 1e-5 per test) unless stated."""
from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy import stats

from render.camera import Camera, Intrinsics
from render.media import EV_PASS, MajorantError, MediumSet, hg_pdf, hg_sample
from render.integrators import RenderSettings, prepare
from render.poses import look_at
from render.scene import DirectionalLight, Emissive, Lambertian, Medium, PointLight, Scene, SceneObject
from render.integrators.volpath import render_volpath, trace, volpath_context
from recon.nerf.volume import VoxelField, render_voxels_exact, render_voxels_quadrature

Z = 4.5


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(hi - lo)
    b.apply_translation((lo + hi) / 2)
    return b


def _far():
    """A tiny black box far away (render.accel needs at least one triangle)."""
    return [SceneObject("far", _box([900, 900, 900], [901, 901, 901]), Lambertian(0.0))]


def _camera(eye, target, size=4, fov=20.0, up=(0, 0, 1)):
    return Camera(Intrinsics.from_fov(size, size, fov), look_at(np.asarray(eye, float), np.asarray(target, float),
                                                                  np.asarray(up, float)), "cam")


def _mean_se(res):
    p = res.mean.shape[0] * res.mean.shape[1]
    return res.mean.reshape(-1, 3).mean(0), np.sqrt(res.variance.reshape(-1, 3).sum(0)) / p


# ---------------------------------------------------------------- phase function
@pytest.mark.parametrize("g", [-0.7, 0.0, 0.3, 0.9])
def test_hg_chi2(g):
    """Pearson chi-square of hg_sample against hg_pdf over 50 cos-theta x 20 phi cells, 2e5
    samples, alpha 0.01 Sidak-corrected over the 4 cases; and the pdf integrates to 1."""
    n = 200_000
    rng = np.random.default_rng(11)
    d = np.tile([0.0, 0.6, 0.8], (n, 1))
    wi = hg_sample(g, d, rng.random((n, 2)))
    assert np.allclose(np.linalg.norm(wi, axis=1), 1)
    # coordinates about d
    c = wi @ d[0]
    nt, nphi = 50, 20
    e1 = np.cross(d[0], [1.0, 0, 0]); e1 /= np.linalg.norm(e1)
    e2 = np.cross(d[0], e1)
    phi = np.mod(np.arctan2(wi @ e2, wi @ e1), 2 * np.pi)
    obs = np.zeros((nt, nphi))
    np.add.at(obs, (np.minimum(((c + 1) / 2 * nt).astype(int), nt - 1), (phi / (2 * np.pi) * nphi).astype(int)), 1)
    edges = np.linspace(-1, 1, nt + 1)
    # exact cell integrals of the HG density over cos theta (closed-form CDF), uniform in phi
    cdf = lambda x: (1 - g * g) / (2 * g) * (1 / np.sqrt(1 + g * g - 2 * g * x)) if abs(g) > 1e-9 else 0.5 * x
    mass = np.abs(np.diff([cdf(x) for x in edges]))
    exp = np.repeat(mass[:, None] / nphi, nphi, axis=1) * n
    assert abs(exp.sum() / n - 1) < 1e-9
    low = exp.ravel() < 5
    o = np.append(obs.ravel()[~low], obs.ravel()[low].sum())
    e = np.append(exp.ravel()[~low], exp.ravel()[low].sum())
    if e[-1] == 0:
        o, e = o[:-1], e[:-1]
    p = stats.chi2.sf(np.sum((o - e) ** 2 / e), len(e) - 1)
    assert p > 1 - 0.99 ** 0.25, p
    # density integrates to one over the sphere (uniform MC)
    u = rng.random((n, 2))
    z = 1 - 2 * u[:, 0]
    r = np.sqrt(1 - z * z)
    s = np.stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]), z], 1)
    v = hg_pdf(g, d, s) * 4 * np.pi
    assert abs(v.mean() - 1) < Z * v.std() / np.sqrt(n) + 1e-12


# ---------------------------------------------------------------- tracking estimators
def test_transmittance_closed_form_homogeneous_and_grid():
    """exp(-sigma_t d): exact for homogeneous media; ratio tracking on a constant grid and the
    pass fraction of delta tracking (pure absorber) agree within 4.5 sigma."""
    n = 100_000
    rng = np.random.default_rng(12)
    sig = np.array([0.5, 1.0, 2.0])
    d_len = 0.8
    bounds = _box([0, 0, 0], [1, 1, 1])
    hom = MediumSet([Medium(bounds, sigma_a=sig)])
    grid = MediumSet([Medium(bounds, sigma_a=sig / 2, density=np.full((3, 2, 4), 2.0))])
    o = np.tile([0.1, 0.5, 0.5], (n, 1))
    d = np.tile([1.0, 0.0, 0.0], (n, 1))
    mid, tmax = np.zeros(n, np.int64), np.full(n, d_len)
    exact = np.exp(-sig * d_len)
    np.testing.assert_allclose(hom.transmittance(mid, o, d, tmax, rng), np.tile(exact, (n, 1)))
    T = grid.transmittance(mid, o, d, tmax, rng)
    assert np.all(np.abs(T.mean(0) - exact) < Z * T.std(0) / np.sqrt(n) + 1e-12)
    ev, t, w, em = hom.delta_track(mid, o, d, tmax, rng)
    passed = (ev == EV_PASS)[:, None] * w  # weighted tracking: E[weight on passing] = T per channel
    assert np.all(np.abs(passed.mean(0) - exact) < Z * passed.std(0) / np.sqrt(n))


def _slab_scene(sigma_a, Le, L_bg, d=0.5, sigma_s=0.0, density=None):
    med = Medium(_box([-5, -5, 0], [5, 5, d]), sigma_a=sigma_a, sigma_s=sigma_s, emission=Le, density=density)
    return Scene("slab", _far(), media=[med], background=L_bg)


@pytest.mark.parametrize("sigma_a,label", [(np.array([0.5, 2.0, 6.0]), "moderate"), (np.full(3, 1e4), "dense_1e4")])
def test_emitting_absorbing_slab_closed_form(sigma_a, label):
    """Camera looking down through an emitting, absorbing slab of thickness d onto a uniform
    background: L = L_bg exp(-sigma_a d / cos) + Le (1 - exp(-sigma_a d / cos)) per ray
    (hard case sigma_t = 1e4: finite, equals Le)."""
    Le, L_bg, d = np.array([1.0, 0.5, 2.0]), np.array([0.2, 1.0, 3.0]), 0.5
    sc = _slab_scene(sigma_a, Le, L_bg, d)
    ps = prepare(sc)
    ctx = volpath_context(sc, ps)
    n = 60_000
    rng = np.random.default_rng(13)
    o = np.tile([0.0, 0.0, 3.0], (n, 1))
    dirs = np.array([[0.0, 0.0, -1.0], [0.6, 0.0, -0.8]])
    for dd in dirs:
        L = trace(ctx, o, np.tile(dd, (n, 1)), np.full(n, -1), rng)
        assert np.all(np.isfinite(L))
        T = np.exp(-sigma_a * d / abs(dd[2]))
        exp = L_bg * T + Le * (1 - T)
        assert np.all(np.abs(L.mean(0) - exp) < Z * L.std(0) / np.sqrt(n) + 1e-9 * exp.max()), (label, L.mean(0), exp)


def test_slab_through_render_api():
    """The same slab through render_volpath (pixel jitter, film): the image mean agrees."""
    sigma_a, Le, L_bg = np.array([0.5, 2.0, 6.0]), np.array([1.0, 0.5, 2.0]), np.array([0.2, 1.0, 3.0])
    sc = _slab_scene(sigma_a, Le, L_bg, 0.5)
    cam = _camera([0, 0, 3], [0, 0, 0], size=4, fov=0.5, up=(0, 1, 0))
    res = render_volpath(sc, cam, RenderSettings(spp=512, seed=3))
    m, se = _mean_se(res)
    T = np.exp(-sigma_a * 0.5)
    assert np.all(np.abs(m - (L_bg * T + Le * (1 - T))) < Z * se)


@pytest.mark.parametrize("sigma_s,g,grid", [(0.5, 0.0, False), (4.0, 0.9, False), (3.0, -0.7, True)])
def test_scattering_medium_in_constant_enclosure_background(sigma_s, g, grid):
    """A non-absorbing medium under a uniform environment of radiance 1: every ray sees
    exactly 1 (delta tracking and phase sampling; no NEE since the background is not sampled)."""
    dens = np.random.default_rng(0).random((4, 3, 5)) if grid else None
    med = Medium(_box([-1, -1, -1], [1, 1, 1]), sigma_s=sigma_s, g=g, density=dens)
    sc = Scene("furnace", _far(), media=[med], background=np.ones(3))
    ps = prepare(sc)
    ctx = volpath_context(sc, ps)
    n = 20_000
    rng = np.random.default_rng(14)
    o = np.tile([0.0, 0.0, 4.0], (n, 1))
    dd = np.tile([0.1, 0.05, -1.0] / np.linalg.norm([0.1, 0.05, -1.0]), (n, 1))
    L = trace(ctx, o, dd, np.full(n, -1), rng, max_depth=400)
    np.testing.assert_allclose(L.mean(0), 1.0, atol=2e-3)


@pytest.mark.parametrize("grid", [False, True])
def test_scattering_medium_in_emissive_enclosure_nee(grid):
    """Albedo-one medium inside a closed two-sided emitter of radiance 1: NEE from medium
    vertices (light sampling + phase sampling, MIS, transmittance by exp / ratio tracking) must
    still give exactly 1 per pixel on average (4.5 sigma)."""
    dens = np.random.default_rng(1).random((3, 3, 3)) * 2 if grid else None
    enc = SceneObject("enclosure", _box([-2, -2, -2], [2, 2, 2]), Emissive(np.ones(3), two_sided=True))
    med = Medium(_box([-1, -1, -1], [1, 1, 1]), sigma_s=1.5, g=0.5, density=dens)
    sc = Scene("nee_furnace", [enc], media=[med])
    cam = _camera([0, 0, 1.8], [0, 0, 0], size=4, fov=40, up=(0, 1, 0))
    res = render_volpath(sc, cam, RenderSettings(spp=256, max_depth=64, seed=4, roulette=False))
    m, se = _mean_se(res)
    assert np.all(np.isfinite(res.mean))
    assert np.all(np.abs(m - 1) < Z * se + 1e-3), (m, se)


def test_nee_through_absorbing_medium_point_light():
    """Camera, floor and point light all inside one absorbing fog: a floor point lit by a point
    light of intensity I at height h has radiance rho/pi I/h^2 exp(-sigma_a h), seen through
    exp(-sigma_a r_cam) (camera inside the medium: found by crossing parity)."""
    sig, rho, I, hgt = 0.3, 0.6, 5.0, 2.0
    floor = SceneObject("floor", _box([-10, -10, -0.1], [10, 10, 0]), Lambertian(rho))
    med = Medium(_box([-20, -20, -1], [20, 20, 20]), sigma_a=sig)
    sc = Scene("fog", [floor], lights=[PointLight([0, 0, hgt], np.full(3, I))], media=[med])
    eye = np.array([0.0, -3.0, 4.0])
    cam = _camera(eye, [0, 0, 0], size=2, fov=0.01)
    res = render_volpath(sc, cam, RenderSettings(spp=2048, max_depth=1, seed=5))
    exp = rho / np.pi * I / hgt ** 2 * np.exp(-sig * hgt) * np.exp(-sig * np.linalg.norm(eye))
    m, se = _mean_se(res)
    assert np.all(np.abs(m - exp) < Z * se), (m, se, exp)


# ---------------------------------------------------------------- one integral, two code paths
def test_emission_absorption_grid_matches_nerf_quadrature():
    """An emission-absorption voxel medium (sigma_a = density grid, Le constant) rendered by
    volpath equals recon.nerf.volume's exact voxel integral and its NeRF quadrature on the same grid
    (per ray z-test at 4.5 sigma, Sidak over rays is looser; the quadrature within its O(1/n))."""
    rng = np.random.default_rng(15)
    grid = rng.random((4, 3, 5)) * 3.0
    lo, hi = np.array([-1.0, -0.8, -1.2]), np.array([1.0, 0.7, 1.0])
    Le = np.array([0.9, 0.4, 1.6])
    bg = np.array([0.3, 0.3, 0.3])
    sc = Scene("ea", _far(), media=[Medium(_box(lo, hi), sigma_a=1.0, emission=Le, density=grid)], background=bg)
    ctx = volpath_context(sc, prepare(sc))
    nr, spr = 16, 4000
    dirs = np.stack([rng.uniform(-0.3, 0.3, nr), rng.uniform(-0.3, 0.3, nr), -np.ones(nr)], 1)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    orig = np.tile([0.05, 0.0, 3.0], (nr, 1))
    L = trace(ctx, np.repeat(orig, spr, 0), np.repeat(dirs, spr, 0), np.full(nr * spr, -1), rng)
    L = L.reshape(nr, spr, 3)
    field = VoxelField(torch.tensor(grid), torch.tensor(np.broadcast_to(Le, grid.shape + (3,)).copy()),
                       tuple(lo), tuple(hi))
    to = torch.tensor(orig), torch.tensor(dirs)
    exact = render_voxels_exact(field, *to, background=torch.tensor(bg)).rgb.numpy()
    quad = render_voxels_quadrature(field, *to, 4096, background=torch.tensor(bg)).rgb.numpy()
    m, se = L.mean(1), L.std(1) / np.sqrt(spr)
    assert np.all(np.abs(m - exact) < Z * se + 1e-9)
    assert np.max(np.abs(quad - exact)) < 5e-3
    assert np.all(np.abs(m - quad) < Z * se + 5e-3)


# ---------------------------------------------------------------- hard cases
def test_hard_case_majorant_below_density_is_reported():
    """A majorant below the true extinction is rejected at construction, and a corrupted one is
    detected during tracking: never a silently biased image."""
    med = Medium(_box([0, 0, 0], [1, 1, 1]), sigma_a=1.0, density=np.full((2, 2, 2), 3.0))
    with pytest.raises(MajorantError, match="medium 0"):
        MediumSet([med], majorants={0: 1.0})
    ms = MediumSet([med], majorants={0: 5.0})
    ms.mu[0] = 1.0  # corrupted after construction
    n = 100
    with pytest.raises(MajorantError):
        ms.delta_track(np.zeros(n, np.int64), np.tile([0.0, 0.5, 0.5], (n, 1)), np.tile([1.0, 0, 0], (n, 1)),
                       np.full(n, 1.0), np.random.default_rng(0))
    with pytest.raises(MajorantError):
        ms.transmittance(np.zeros(n, np.int64), np.tile([0.0, 0.5, 0.5], (n, 1)), np.tile([1.0, 0, 0], (n, 1)),
                         np.full(n, 1.0), np.random.default_rng(0))


@pytest.mark.parametrize("albedo", [0.0, 1.0])
def test_hard_case_zero_and_unit_albedo_dense_fog(albedo):
    """Zero-albedo and albedo-one media at sigma_t = 1e4 (a fog block lit by a directional
    light, camera outside): all outputs finite and bounded by the scene's maximum radiance."""
    st = 1e4
    med = Medium(_box([-1, -1, 0], [1, 1, 1]), sigma_a=st * (1 - albedo), sigma_s=st * albedo, g=0.3)
    floor = SceneObject("floor", _box([-5, -5, -0.1], [5, 5, 0]), Lambertian(0.5))
    sc = Scene("dense", [floor], lights=[DirectionalLight([0.2, 0.1, -1.0], np.full(3, 2.0))], media=[med],
               background=np.full(3, 0.1))
    cam = _camera([0, -4, 3], [0, 0, 0.3], size=6, fov=40)
    res = render_volpath(sc, cam, RenderSettings(spp=4, max_depth=32, seed=6))
    assert np.all(np.isfinite(res.mean)) and np.all(np.isfinite(res.variance))
    assert res.mean.max() < 10.0
