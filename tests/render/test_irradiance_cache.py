"""Ward's irradiance cache (render/integrators/irradiance_cache.py): closed forms, consistency as
the error bound goes to 0, the weight's closed form, no reuse across a normal flip, hard cases.

Statistical tests: fixed seeds; alpha 0.01 per test, Sidak-corrected over the 3 channels
(two-sided normal quantile 2.93), unless a test says otherwise.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import stats

from cornell_box import cornell_camera, cornell_scene
from ptutil import image_mean_and_se
from render.camera import Camera, Intrinsics
from render.effects import scene_effects
from render.integrators import RenderSettings, prepare, render
from render.integrators.irradiance_cache import (IrradianceCache, Options, cache_records, cached_irradiance,
                                                 render_cache, ward_error, ward_weight)
from render.scene import DiffuseEmitter, Lambertian, Scene, SceneObject

ALPHA = 0.01
Z_CRIT = stats.norm.ppf(1 - (1 - (1 - ALPHA) ** (1 / 3)) / 2)  # Sidak over 3 channels: 2.93
LE = np.array([1.0, 2.0, 0.5])
RHO = np.array([0.3, 0.5, 0.7])


def _furnace():
    """A closed sphere of uniform emission LE and albedo RHO: radiance and irradiance are uniform
    inside (any closed enclosure), L = LE sum_{j<=D} RHO^j after D bounces."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    obj = SceneObject("furnace", sphere, DiffuseEmitter(albedo=RHO, radiance=LE, two_sided=True))
    return Scene("furnace", [obj]), Camera(Intrinsics.from_fov(8, 8, 60.0), np.eye(4), "inside")


def _geometric_sum(depth: int) -> np.ndarray:
    return (1 - RHO ** (depth + 1)) / (1 - RHO)


def test_ward_weight_closed_form():
    """w = 1 / (d / R + sqrt(1 - n.n_i)): in-plane distance alone (R / d), tilt alone
    (1 / sqrt(1 - cos t)), both, and a point on its record (floored, finite)."""
    n = np.array([0.0, 0.0, 1.0])
    x0 = np.zeros(3)
    R = 2.0
    assert ward_weight(np.array([0.5, 0, 0]), n, x0, n, R) == pytest.approx(R / 0.5, rel=1e-12)
    t = 0.3
    ni = np.array([np.sin(t), 0.0, np.cos(t)])
    assert ward_weight(x0, n, x0, ni, R) == pytest.approx(1 / np.sqrt(1 - np.cos(t)), rel=1e-12)
    assert ward_error(np.array([0, 0.5, 0]), n, x0, ni, R) == pytest.approx(0.25 + np.sqrt(1 - np.cos(t)), rel=1e-12)
    assert np.isfinite(ward_weight(x0, n, x0, n, R)) and ward_weight(x0, n, x0, n, R) >= 1e8


def test_lookup_is_the_weighted_mean_of_the_serving_records():
    """Two records serving x: E(x) = (w1 E1 + w2 E2) / (w1 + w2) with the closed-form weights; a
    third beyond the error bound does not contribute; a point nobody serves gets 0, unserved."""
    n = np.array([[0.0, 0.0, 1.0]])
    pos = np.array([[0.1, 0, 0], [-0.2, 0, 0], [5.0, 0, 0]])
    E = np.array([[1.0, 2, 3], [4, 5, 6], [100, 100, 100]])
    cache = IrradianceCache(pos, np.repeat(n, 3, 0), E, np.array([1.0, 1.0, 1.0]), 0.5, True)
    got, served = cache.lookup(np.array([[0.0, 0, 0], [50.0, 0, 0]]), np.repeat(n, 2, 0))
    w1, w2 = 1 / 0.1, 1 / 0.2
    assert served.tolist() == [True, False]
    np.testing.assert_allclose(got[0], (w1 * E[0] + w2 * E[1]) / (w1 + w2), rtol=1e-12)
    np.testing.assert_array_equal(got[1], 0.0)


def test_records_never_serve_across_a_normal_flip():
    """A record at x with normal n does not serve x with normal -n, however large the error bound
    (sqrt(1 - n.n_i) = sqrt(2) would pass a >= 1.5 without the facing rule)."""
    n = np.array([[0.0, 1.0, 0.0]])
    cache = IrradianceCache(np.zeros((1, 3)), n, np.ones((1, 3)), np.ones(1), 100.0, True)
    _, served = cache.lookup(np.array([[0.0, 0, 0], [0.01, 0, 0]]), np.array([[0.0, -1, 0], [0.0, 1, 0]]))
    assert served.tolist() == [False, True]


def test_cornell_walls_inside_and_outside_keep_their_own_records():
    """Points on the Cornell box's back wall, half facing into the box, half out (its outside sees
    a black background): with a huge error bound (a = 10) the outward points still read 0 exactly
    (no inside record reused across the flip) and the inward ones are lit."""
    sc = cornell_scene()
    rng = np.random.default_rng(5)
    m = 64
    pts = np.column_stack([rng.uniform(50, 500, m), rng.uniform(50, 500, m), np.full(m, 559.2)])
    nrm = np.tile([0.0, 0.0, -1.0], (m, 1))
    nrm[m // 2:] *= -1.0
    stats_out = {}
    E = cached_irradiance(sc, pts, nrm, error_bound=10.0, record_rays=32, seed=1, stats=stats_out)
    assert np.all(np.isfinite(E))
    np.testing.assert_array_equal(E[m // 2:], 0.0)
    assert np.all(E[: m // 2].sum(axis=1) > 0)
    assert 2 <= stats_out["records"] < m  # both sides got records, fewer than the points


def test_records_in_a_furnace_hold_the_closed_form_irradiance():
    """Inside the furnace each record's total irradiance is pi LE sum_{j<D} RHO^j (D = 3): the
    mean over the M independent records within Z_CRIT standard errors; every interpolated value
    is a convex combination of records, so it lies within their range."""
    sc, _ = _furnace()
    rng = np.random.default_rng(2)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts, nrm = 0.97 * d, -d  # inside the icosphere (inradius ~0.98), facing its centre
    cache = cache_records(sc, pts, nrm, error_bound=0.4, record_rays=64, seed=3, max_depth=3)
    expected = np.pi * LE * (1 - RHO ** 3) / (1 - RHO)
    rec = cache.irradiance
    m = len(rec)
    assert m >= 20
    z = (rec.mean(0) - expected) / (rec.std(0, ddof=1) / np.sqrt(m))
    assert np.all(np.abs(z) < Z_CRIT), (rec.mean(0), expected, z)
    E, served = cache.lookup(pts, nrm)
    assert served.all()
    assert np.all(E >= rec.min(0) - 1e-12) and np.all(E <= rec.max(0) + 1e-12)


def test_integrator_furnace_is_unbiased_at_any_error_bound():
    """The integrator in the furnace (direct light per sample + cached indirect, a = 0.5): pixel
    radiance LE sum_{j<=2} RHO^j at max_depth 2. The GROUPS independent group images give a
    Student t test (GROUPS - 1 dof) at alpha 0.01, Sidak over channels."""
    sc, cam = _furnace()
    ps = prepare(sc, threads=1)
    st = RenderSettings(integrator="irradiance_cache", spp=16, max_depth=2, seed=4, threads=1)
    # effects given: render.effects infers none for a DiffuseEmitter-only scene (no Emissive light)
    effects = frozenset({"direct", "soft_shadows", "interreflection"})
    r = render_cache(sc, cam, st, Options(error_bound=0.5, record_rays=32), (0, 16), effects, ps)
    m, se = image_mean_and_se(r)
    q = stats.t.ppf(1 - (1 - (1 - ALPHA) ** (1 / 3)) / 2, r.stats["groups"] - 1)
    expected = LE * _geometric_sum(2)
    assert np.all(np.abs(m - expected) < q * se), (m, expected, se)
    assert np.all(q * se < 0.03 * expected)  # tight enough to see a 3% bias


def test_error_bound_zero_is_path_tracing_in_expectation():
    """a = 0: every looked-up first hit is its own record, and the image equals path's in expectation
    (Cornell box, 12 x 12, non-emitter pixels): the image means' difference within Z_CRIT of
    both standard errors; the cache made one record per diffuse camera sample."""
    sc, cam = cornell_scene(), cornell_camera(12, 12)
    ps = prepare(sc, threads=1)
    ref = render(sc, cam, RenderSettings(integrator="path", spp=1024, seed=11, threads=1), prepared=ps)
    st = RenderSettings(integrator="irradiance_cache", spp=256, seed=12, threads=1)
    r = render_cache(sc, cam, st, Options(error_bound=0.0, record_rays=2), (0, 256), frozenset(scene_effects(sc)), ps)
    keep = ref.mean.max(axis=2) < 5.0  # the light's pixels: emission alone, the same in both
    d = (r.mean - ref.mean)[keep].astype(np.float64).mean(0)
    se = np.sqrt((r.variance + ref.variance)[keep].astype(np.float64).sum(0)) / keep.sum()
    assert np.all(np.abs(d) < Z_CRIT * se), (d, se)
    # every diffuse looked-up sample its own record (the camera sees walls, and the light in few pixels)
    looked_up = r.stats["groups"] * Options().lookup_spp * 12 * 12
    assert 0.9 * looked_up <= r.stats["records"] <= looked_up


def test_hard_cases_are_finite_and_bounded():
    """A Cornell corner (three walls meet), points on an edge, grazing normals (almost in the
    floor's plane), a normal pointing into the wall: finite, non-negative irradiance below the
    light's pi Le bound times a generous interreflection factor."""
    sc = cornell_scene()
    g = 1e-7
    pts = np.array([[0.0, 0.0, 559.2], [0.0, 0.0, 559.2], [1e-3, 1e-3, 559.2 - 1e-3], [276.0, 0.0, 280.0],
                    [276.0, 0.0, 280.0], [0.0, 274.0, 559.2], [276.0, 0.0, 280.0]])
    nrm = np.array([[1.0, 1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, g, 0.0], [0.0, g, 1.0],
                    [1.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
    E = cached_irradiance(sc, pts, nrm, error_bound=0.3, record_rays=64, seed=9)
    assert E.shape == (len(pts), 3) and np.all(np.isfinite(E)) and np.all(E >= 0)
    assert np.all(E < 10 * np.pi * 17.0)
