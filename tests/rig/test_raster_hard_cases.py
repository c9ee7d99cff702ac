"""Hard cases of the rasterizer (rig/raster.py): degenerate triangles and the camera inside
geometry. Each states the case and asserts finite, bounded output and the closed form where one
exists. Tiny images; the catalogue of every hard case is docs/hard_cases.md."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from render.scene import Lambertian, Scene, SceneObject, SpotLight


def _with_degenerates(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` plus zero-area triangles (repeated vertices, collinear points) in its plane."""
    z = mesh.vertices[0, 2]
    v = np.vstack([mesh.vertices, [[0.1, 0.1, z], [0.2, 0.2, z], [0.3, 0.3, z]]])
    n = len(mesh.vertices)
    f = np.vstack([mesh.faces, [[n, n, n + 1], [0, 0, 0], [0, 1, 1], [n, n + 1, n + 2]]])
    return trimesh.Trimesh(v, f, process=False)


def test_hard_case_degenerate_triangles(geo, render_scene):
    """Hard case: zero-area triangles (repeated vertices, three collinear points) in the
    subject's and the floor's meshes. They cover no sample: radiance, depth and mask equal the
    clean scene's exactly, and are finite."""
    light = SpotLight([0.5, -0.5, 2.0], [-0.25, 0.25, -1], [15.0] * 3)
    floor, box = geo.quad_mesh(-1, 1, -1, 1), geo.box_mesh([-0.2, -0.2, 0.0], [0.2, 0.2, 0.4])
    cam = geo.camera_at([0.3, -2.0, 1.4], [0, 0, 0.2], 48, 36)

    def scene(dirty: bool) -> Scene:
        fix = _with_degenerates if dirty else (lambda m: m)
        return Scene("degenerate", [SceneObject("floor", fix(floor), Lambertian(0.5)),
                                    SceneObject("box", fix(box), Lambertian(0.8), is_subject=True)], lights=[light])

    clean, dirty = render_scene(scene(False), cam), render_scene(scene(True), cam)
    for a in (dirty.rgb, dirty.depth):
        assert np.all(np.isfinite(a))
    assert dirty.rgb.max() > 0 and dirty.mask.any()
    assert np.array_equal(clean.rgb, dirty.rgb) and np.array_equal(clean.depth, dirty.depth)
    assert np.array_equal(clean.mask, dirty.mask)


def _inside_a_box(geo, render_scene):
    box = geo.box_mesh([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5])
    sc = Scene("inside", [SceneObject("box", box, Lambertian(0.8), is_subject=True)],
               lights=[SpotLight([0.0, 0.0, 2.0], [0, 0, -1], [15.0] * 3)])
    return render_scene(sc, geo.camera_at([0.0, 0.0, 0.0], [1.0, 0.2, 0.1], 32, 24, fov_y=80.0))


def test_hard_case_camera_inside_an_object(geo, render_scene):
    """Hard case: the camera inside a closed box (the subject) with the only light, a spot,
    outside aimed at it. Every pixel sees an inner wall, lit only from its far side: radiance
    finite and bounded by the brightest a wall could be (albedo 0.8 x I 15 / 1.5^2 / pi = 1.70),
    black on at least 95% of the pixels (the closed form is black everywhere: see the xfail
    below), depth finite and positive (at most the box's diagonal), mask everywhere."""
    frame = _inside_a_box(geo, render_scene)
    assert np.all(np.isfinite(frame.rgb)) and frame.rgb.min() >= 0 and frame.rgb.max() <= 0.8 * 15 / 1.5 ** 2 / np.pi
    assert (frame.rgb.max(axis=2) == 0).mean() >= 0.95
    assert np.all(np.isfinite(frame.depth)) and np.all(frame.depth > 0) and frame.depth.max() <= np.sqrt(3)
    assert frame.mask.all()


@pytest.mark.xfail(strict=True, reason="rig/raster.py: the shadow map's slope-scaled bias leaks the spot's light "
                                       "into the inner corners where the lid meets the walls (1% of the pixels, up "
                                       "to 0.36 against 0.49 for a lit wall); not fixed here")
def test_hard_case_camera_inside_an_object_is_exactly_black(geo, render_scene):
    """Hard case, closed form: inside the closed box every pixel is exactly black (the path
    tracer's twin, tests/render/test_hard_cases.py, is)."""
    assert np.all(_inside_a_box(geo, render_scene).rgb == 0)
