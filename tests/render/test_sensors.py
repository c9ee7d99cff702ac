"""Irradiance sensors (render/sensors.py) against closed forms, and their confidence interval's coverage.

Closed forms: a point light (E = I cos(theta) / r^2, exact: its estimator has no variance), a
coaxial Lambertian disk (E = pi L R^2 / (h^2 + R^2)), a rectangle off axis and tilted (Lambert's
polygon formula), the white furnace truncated at max_depth (E = pi Le (1 - rho^D) / (1 - rho):
the sensor is the paths' first scattering event), the same furnace by photon mapping (a uniform
photon density: the density estimate has no blur bias there). Statistical checks: |z| < 4
(two-sided alpha 6.3e-5 per check) with fixed seeds; the 95% interval's coverage over 400 seeds
by an exact binomial test at alpha 0.01.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import stats

from ptutil import disk, quad, receiver_box
from render.integrators import prepare
from render.scene import DiffuseEmitter, Emissive, PointLight, Scene, SceneObject
from render.sensors import LUMINANCE, Sensor, SensorArray, lux_like, photon_irradiance, unbiased_irradiance

LE = np.array([1.0, 2.0, 0.5])
Z_MAX = 4.0  # two-sided alpha 6.3e-5 per check


def polygon_irradiance(vertices: np.ndarray, point: np.ndarray, normal: np.ndarray, L) -> np.ndarray:
    """Lambert's formula for a uniform Lambertian polygon wholly above the receiver's horizon:
    E = (L / 2) |sum_i beta_i cos(gamma_i)| (beta_i the angle edge i subtends at the point,
    gamma_i the angle between the plane through edge and point and the receiver normal)."""
    a = vertices - point
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.roll(a, -1, axis=0)
    beta = np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1, 1))
    g = np.cross(a, b)
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    return 0.5 * np.asarray(L, float) * abs(np.sum(beta * (g @ normal)))


def _assert_z(est, expected: np.ndarray, rel_se_max: float):
    """Mean within Z_MAX standard errors of ``expected`` (N, 3), and precise enough to matter."""
    m, se = est.mean, est.standard_error()[:, :3]
    assert np.all(np.isfinite(m)) and np.all(se > 0)
    assert np.all(se < rel_se_max * expected), f"too noisy to test: se {se} vs {expected}"
    z = np.abs(m - expected) / se
    assert np.all(z < Z_MAX), f"mean {m} vs closed form {expected}: |z| {z}"


def test_point_light_irradiance_closed_form():
    """E = I cos(theta) / r^2 at sensors facing, tilted from and turned away from a point light
    (a delta light through NEE alone: every sample equals the closed form; the black receiver
    below adds nothing)."""
    I, pos = np.array([2.0, 1.0, 3.0]), np.array([0.3, 0.2, 1.5])
    normals = np.array([[0, 0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.8, 0.6], [0, 0, -1.0]])
    points = np.array([[0, 0, 0.0], [-0.5, 0.4, 0.0], [1.0, 1.0, 0.0], [0.2, 0.1, 0.5]])
    sc = Scene("point", [receiver_box([0.0] * 3)], lights=[PointLight(pos, I)])
    sensors = SensorArray.of(Sensor(f"s{i}", p, n) for i, (p, n) in enumerate(zip(points, normals)))
    est = unbiased_irradiance(sc, sensors, 64, seed=3)
    d = pos - points
    r2 = np.sum(d * d, axis=1)
    cos = np.maximum(np.sum(d * normals, axis=1) / np.sqrt(r2), 0.0)
    expected = I[None] * (cos / r2)[:, None]
    np.testing.assert_allclose(est.mean, expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(est.lux, expected @ LUMINANCE, rtol=1e-9, atol=1e-12)
    assert np.all(est.standard_error()[:, :3] <= 1e-7 * expected)  # zero up to the moments' rounding


def test_disk_emitter_irradiance_closed_form():
    """A Lambertian disk (a 1024-gon: area deficit 6e-6) of radius R at height h on the axis:
    E = pi L R^2 / (h^2 + R^2), through light sampling, the cosine lobe and their MIS."""
    R, h = 0.5, 1.0
    sc = Scene("disk", [receiver_box([0.0] * 3), SceneObject("light", disk((0, 0, h), R, 1024), Emissive(LE))])
    sensors = SensorArray.of([Sensor("axis", (0, 0, 0), (0, 0, 1))])
    est = unbiased_irradiance(sc, sensors, 40000, seed=5)
    _assert_z(est, (np.pi * LE * R * R / (h * h + R * R))[None], rel_se_max=2e-3)


def test_rectangle_emitter_irradiance_off_axis_and_tilted():
    """A 1.0 x 0.6 rectangle at height 0.8: Lambert's polygon formula at two sensors off axis,
    one tilted (the whole rectangle above its horizon in both cases)."""
    sc = Scene("rect", [receiver_box([0.0] * 3), SceneObject("light", quad((0, 0, 0.8), 0.5, 0.3, -1.0),
                                                             Emissive(LE))])
    corners = np.array([[-0.5, -0.3, 0.8], [0.5, -0.3, 0.8], [0.5, 0.3, 0.8], [-0.5, 0.3, 0.8]])
    tilt = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])
    sensors = SensorArray.of([Sensor("off", (0.6, 0.3, 0.0), (0, 0, 1)), Sensor("tilted", (-0.2, 0.1, 0.0), tilt)])
    est = unbiased_irradiance(sc, sensors, 40000, seed=6)
    expected = np.stack([polygon_irradiance(corners, sensors.points[i], sensors.normals[i], LE) for i in range(2)])
    _assert_z(est, expected, rel_se_max=3e-3)


def _furnace(rho: float, subdivisions: int = 2):
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return Scene("furnace", [SceneObject("furnace", sphere, DiffuseEmitter(albedo=rho, radiance=LE, two_sided=True))])


def _face_sensor(scene, face: int = 0) -> SensorArray:
    """A sensor at the centroid of an inner face of the furnace sphere, facing inwards."""
    m = scene.objects[0].mesh
    return SensorArray.of([Sensor("inner", m.triangles_center[face], -m.face_normals[face])])


@pytest.mark.parametrize("max_depth", [1, 3])
def test_white_furnace_truncated(max_depth):
    """Inside a closed emitting sphere of albedo rho, paths of at most D scattering events (the
    sensor the first) bring E = pi Le (1 - rho^D) / (1 - rho), with roulette from vertex 1."""
    rho = 0.5
    sc = _furnace(rho)
    est = unbiased_irradiance(sc, _face_sensor(sc), 20000, seed=7 + max_depth, max_depth=max_depth, rr_depth=1)
    _assert_z(est, (np.pi * LE * (1 - rho ** max_depth) / (1 - rho))[None], rel_se_max=3e-3)


def test_white_furnace_photon_mapping():
    """Photon mapping in the same furnace (D = 3): the photon density is uniform, so the density
    estimate sum(Phi) / (pi R^2 P N_e) has no blur bias while the gather disk (radius 0.15 at a
    face centroid of an 80-face icosphere, inradius 0.17) stays within one face: it checks the photons' flux, the gather and the progressive
    normalization. Noise from 8 independent groups (Student t, 7 dof, alpha 6.3e-5)."""
    rho = 0.5
    sc = _furnace(rho, subdivisions=1)
    est = photon_irradiance(sc, _face_sensor(sc), passes=32, photons_per_pass=4000, initial_radius=0.15, seed=2,
                            max_depth=3, groups=8)
    m, se = est.at(32)
    expected = np.pi * LE * (1 - rho ** 3) / (1 - rho)
    expected = np.append(expected, expected @ LUMINANCE)[None]
    assert np.all(np.isfinite(m)) and np.all(se > 0) and np.all(se < 0.02 * expected)
    q = stats.t.ppf(1 - 6.3e-5 / 2, 7)
    assert np.all(np.abs(m - expected) < q * se), f"photon mapping {m} vs {expected} (se {se})"
    assert np.all(np.diff(est.radius[0, :, 0]) <= 0) and est.radius[0, -1, 0] < 0.15


def test_interval_coverage():
    """The 95% normal interval covers the closed form in about 95% of 400 independent runs of
    256 samples each (an off-axis sensor under the disk: its estimator has variance). Exact
    two-sided binomial test of coverage 0.95, alpha 0.01, per channel and for Y."""
    R, h = 0.5, 1.0
    sc = Scene("disk", [receiver_box([0.0] * 3), SceneObject("light", disk((0, 0, h), R, 1024), Emissive(LE))])
    ps = prepare(sc)
    sensors = SensorArray.of([Sensor("off", (0.7, 0.2, 0.0), (0, 0, 1))])
    ring = sc.objects[1].mesh.vertices[1:]
    expected = polygon_irradiance(ring, sensors.points[0], sensors.normals[0], LE)
    expected = np.append(expected, lux_like(expected))
    runs = 400
    covered = np.zeros(4, int)
    for seed in range(runs):
        lo, hi = unbiased_irradiance(None, sensors, 256, seed=1000 + seed, prepared=ps).interval(0.95)
        covered += (lo[0] <= expected) & (expected <= hi[0])
    for c in covered:
        p = stats.binomtest(int(c), runs, 0.95).pvalue
        assert p > 0.01, f"coverage {covered / runs} of the 95% interval (binomial p {p:.2g})"


def test_disjoint_ranges_merge_exactly():
    """Two disjoint sample ranges merge into exactly the estimate of their union."""
    sc = Scene("rect", [receiver_box([0.5] * 3), SceneObject("light", quad((0, 0, 0.8), 0.5, 0.3, -1.0),
                                                             Emissive(LE))])
    ps = prepare(sc)
    sensors = SensorArray.of([Sensor("a", (0.1, 0.0, 0.0), (0, 0, 1)), Sensor("b", (0.5, 0.5, 0.0), (0, 0, 1))])
    whole = unbiased_irradiance(None, sensors, 300, seed=4, prepared=ps, batch_paths=128)
    parts = unbiased_irradiance(None, sensors, 100, seed=4, prepared=ps).merge(
        unbiased_irradiance(None, sensors, 200, seed=4, first_sample=100, prepared=ps))
    assert parts.n == whole.n == 300
    np.testing.assert_allclose(parts.s1, whole.s1, rtol=1e-12)
    np.testing.assert_allclose(parts.s2, whole.s2, rtol=1e-12)


def test_bad_sensor_named():
    """A zero normal or a non-finite position is refused naming the sensor."""
    with pytest.raises(ValueError, match="'flat'"):
        SensorArray.of([Sensor("ok", (0, 0, 0), (0, 0, 1)), Sensor("flat", (0, 0, 0), (0, 0, 0))])
    with pytest.raises(ValueError, match="'far'"):
        SensorArray.of([Sensor("far", (np.inf, 0, 0), (0, 0, 1))])
