"""pssmlt's compiled path sampler (render.integrators.pssmlt.sample_paths, volpath's kernels read
from the primary samples) against its numpy reference (sample_paths_numpy), row by row: both are
deterministic functions of the primary sample U, so they agree value for value up to rounding
(the kernels trace float32 directions where the numpy code keeps float64). Fixed seeds."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ptutil import cornell_camera, cornell_scene, quad
from render.camera import Camera, Intrinsics
from render.integrators import prepare
from render.integrators.pssmlt import primary_dims, sample_paths, sample_paths_numpy
from render.lights import PointLight
from render.poses import look_at
from render.scene import Dielectric, Emissive, Lambertian, Mirror, Scene, SceneObject


def _glass_scene() -> Scene:
    """Glass ball and mirror block on a diffuse floor; an area light, a point light and a
    background: every event of the sampler (glass lobes, mirror, delta-light NEE, escapes)."""
    ball = trimesh.creation.icosphere(2, 0.5)
    ball.apply_translation([0, 0, 0.8])
    block = trimesh.creation.box([0.6, 0.1, 0.6])
    block.apply_translation([-0.9, 0.5, 0.3])
    objs = [SceneObject("floor", quad((0, 0, 0), 3, 3), Lambertian(0.6)), SceneObject("ball", ball, Dielectric(1.5)),
            SceneObject("mirror", block, Mirror(np.full(3, 0.9))),
            SceneObject("light", quad((0, 0, 3.0), 0.4, 0.4, normal_sign=-1), Emissive(np.full(3, 20.0)))]
    return Scene("glass", objs, lights=[PointLight([1, -1, 2], np.full(3, 3.0))], background=np.full(3, 0.1))


def _glass_camera() -> Camera:
    return Camera(Intrinsics.from_fov(16, 16, 50.0),
                  look_at(np.array([0, -3.5, 2.5]), np.array([0, 0, 0.5]), np.array([0, 0, 1.0])), "c")


@pytest.mark.parametrize("scene_name, caustics", [("cornell", True), ("glass", True), ("glass", False)])
def test_compiled_sampler_equals_numpy_row_by_row(scene_name, caustics):
    """20000 uniform primary samples (seed 51), max depth 6: the same pixels; >= 99.9% of rows
    within 1e-3 relative (measured: Cornell box 99.985%, rounding of float32 directions at a few
    grazing vertices; the glass scene 100% within 1e-5, with and without caustics); the sums of
    the contributions (the image mean) within 1e-6 relative (measured 4e-8). Emission pruned
    after any specular vertex without caustics (the diffuse vertex behind it ignored) fails the
    glass scene's case (65% of rows agree)."""
    if scene_name == "cornell":
        sc, cam = cornell_scene(), cornell_camera(16, 16)
    else:
        sc, cam = _glass_scene(), _glass_camera()
    ps = prepare(sc)
    U = np.random.default_rng(51).random((20_000, primary_dims(6)))
    pix_c, f_c = sample_paths(ps, cam, U, 6, caustics)
    pix_n, f_n = sample_paths_numpy(ps, cam, U, 6, caustics)
    assert np.array_equal(pix_c, pix_n)
    assert np.all(np.isfinite(f_c)) and (f_c > 0).any(axis=1).mean() > 0.5
    rows = np.isclose(f_c, f_n, rtol=1e-3, atol=1e-12).all(axis=1)
    assert rows.mean() >= 0.999, f"only {rows.mean():.5f} of rows agree"
    np.testing.assert_allclose(f_c.sum(0), f_n.sum(0), rtol=1e-6)
