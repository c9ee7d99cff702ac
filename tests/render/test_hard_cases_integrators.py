"""Hard cases of the integrators beyond `path` (render/volpath.py, render/bdpt.py, render/sppm.py,
render/pssmlt.py, and `path` where it lacked one): an absent or zero-area light, degenerate
triangles, the camera inside geometry. Each states the case and asserts finite, bounded output,
and the closed form where one exists (exactly black when no light can reach the camera). Toy
sizes, fixed seeds. The catalogue of every hard case is docs/hard_cases.md (tests/hard_cases.py)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ptutil import assert_images_agree, quad, receiver_box
from render.camera import Camera, Intrinsics
from render.integrators import RenderSettings, prepare, render
from render.poses import look_at
from render.scene import Emissive, Lambertian, PointLight, Scene, SceneObject

LE = np.array([2.0, 2.0, 2.0])
UP = np.array([0.0, 0.0, 1.0])


def _view(size: int = 6) -> Camera:
    return Camera(Intrinsics.from_fov(size, size, 60.0), look_at([0, -2.0, 0.8], [0, 0, 0], UP), "v")


def _settings(integrator: str, spp: int, seed: int) -> RenderSettings:
    return RenderSettings(integrator=integrator, spp=spp, max_depth=4, seed=seed)


def _black(r) -> None:
    assert np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.variance))
    assert np.all(r.mean == 0) and np.all(r.variance == 0)


def _zero_area_light() -> trimesh.Trimesh:
    """An emitter mesh whose every triangle has zero area (repeated and collinear vertices)."""
    v = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [1.0, 0.0, 1.0]])
    return trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 0, 1], [2, 2, 2]]), process=False)


@pytest.mark.parametrize("integrator", ["path", "volpath", "bdpt"])
def test_hard_case_absent_light(integrator):
    """Hard case: no light at all (no emitter, no light, black background). Closed form: black,
    zero variance, finite."""
    sc = Scene("dark", [receiver_box([0.5] * 3)])
    _black(render(sc, _view(), _settings(integrator, 4, 50)))


@pytest.mark.parametrize("integrator", ["path", "volpath", "bdpt"])
def test_hard_case_zero_area_light(integrator):
    """Hard case: the only light is an emitter of zero area (every triangle degenerate). It
    emits no power: black, zero variance, finite."""
    sc = Scene("zero_area", [receiver_box([0.5] * 3), SceneObject("light", _zero_area_light(), Emissive(LE))])
    _black(render(sc, _view(), _settings(integrator, 4, 51)))


def _with_degenerates(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` plus zero-area triangles (repeated vertices, a collinear one) lying in its plane."""
    z = mesh.vertices[0, 2]
    v = np.vstack([mesh.vertices, [[0.1, 0.1, z], [0.2, 0.2, z]]])
    n = len(mesh.vertices)
    f = np.vstack([mesh.faces, [[n, n, n + 1], [0, 0, 0], [0, 1, 1], [n, n + 1, n + 1]]])
    return trimesh.Trimesh(v, f, process=False)


def _lit_floor(degenerate: bool) -> Scene:
    floor = quad((0, 0, 0), 1.0, 1.0)
    light = quad((0, 0, 1.0), 0.3, 0.3, normal_sign=-1)
    if degenerate:
        floor, light = _with_degenerates(floor), _with_degenerates(light)
    return Scene("floor", [SceneObject("floor", floor, Lambertian([0.5] * 3)), SceneObject("light", light, Emissive(LE))])


@pytest.mark.parametrize("integrator, spp", [("volpath", 256), ("bdpt", 128), ("sppm", 16)])
def test_hard_case_degenerate_triangles(integrator, spp):
    """Hard case: zero-area triangles inside the receiver's and the light's meshes. They are
    never hit and carry no emitted power: the image is finite and agrees with the clean
    scene's (the same seed: equal to float rounding where the random streams coincide, else
    ptutil's per-pixel test, alpha 0.01; sppm, whose variance image is zero, within 2% of the
    clean render's mean)."""
    cam = _view(8)
    clean = render(_lit_floor(False), cam, _settings(integrator, spp, 52))
    dirty = render(_lit_floor(True), cam, _settings(integrator, spp, 52))
    assert np.all(np.isfinite(dirty.mean)) and np.all(np.isfinite(dirty.variance)) and dirty.mean.min() >= 0
    assert dirty.mean.max() > 0
    if np.allclose(clean.mean, dirty.mean, rtol=1e-5, atol=1e-7):
        return
    if integrator == "sppm":
        assert abs(dirty.mean.mean() / clean.mean.mean() - 1) < 0.02
    else:
        assert_images_agree(dirty, clean)


def _inside_box_scene() -> Scene:
    box = trimesh.creation.box([1, 1, 1])
    sc = Scene("inside", [SceneObject("box", box, Lambertian([0.8] * 3)),
                          SceneObject("light", quad((0, 0, 2.0), 0.5, 0.5, -1), Emissive(LE))],
               lights=[PointLight([0, 0, 3.0], [5, 5, 5])])
    return sc


@pytest.mark.parametrize("integrator", ["volpath", "sppm", "pssmlt"])
def test_hard_case_camera_inside_an_object(integrator):
    """Hard case: the camera inside a closed diffuse box, an area and a point light outside:
    no light reaches the inside. Closed form: black, zero variance, finite."""
    cam = Camera(Intrinsics.from_fov(6, 6, 90.0), look_at([0, 0, 0], [1, 0, 0], UP), "inside")
    _black(render(_inside_box_scene(), cam, _settings(integrator, 4, 53)))
