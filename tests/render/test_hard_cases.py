"""Hard cases: each states the case and asserts finite, bounded output (and the closed form
where one exists, within 3 standard errors of the render's variance image; fixed seeds)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ptutil import image_mean_and_se, probe_camera, quad, receiver_box
from test_pathtracer_closed_forms import polygon_irradiance
from render.bsdf import dielectric_sample
from render.scene import DiffuseEmitter
from render.camera import Camera, Intrinsics
from render.accel import offset_eps
from render.integrators import RenderSettings, prepare, render
from render.poses import look_at
from render.scene import Dielectric, Emissive, Lambertian, PointLight, Scene, SceneObject

RHO = 0.5
LE = np.array([2.0, 2.0, 2.0])


def _finite_bounded(r, bound):
    assert np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.variance))
    assert np.all(r.mean >= 0) and np.all(r.variance >= 0)
    assert np.all(r.mean <= bound), f"max {r.mean.max()} exceeds bound {bound}"


def _lit_floor(light_height=1.0, light_half=0.5, normal_sign=-1.0):
    return Scene("floor", [receiver_box([RHO] * 3),
                           SceneObject("light", quad((0, 0, light_height), light_half, light_half, normal_sign),
                                       Emissive(LE))])


def test_grazing_camera_rays():
    """Camera 1e-4 above a lit floor looking along it: rays meet the floor at ~1e-4 rad."""
    sc = _lit_floor()
    cam = Camera(Intrinsics.from_fov(16, 16, 0.5), look_at([-9.0, 0, 1e-4], [0.5, 0, 0], [0, 0, 1]), "graze")
    r = render(sc, cam, RenderSettings(spp=64, seed=1))
    _finite_bounded(r, 2 * RHO * LE.max())  # a Lambertian under any such source: <= rho Le


def test_grazing_secondary_rays_at_millimetre_scale(cornell):
    """The Cornell box (coordinates ~ 500 mm): all bounces finite and bounded by the light's radiance."""
    sc, ps, cam = cornell
    r = render(sc, cam, RenderSettings(integrator="path", spp=16, seed=2), prepared=ps)
    _finite_bounded(r, 17.0 * 1.0001)


@pytest.mark.parametrize("h", [1e-3, 1e-4, 1e-7])
def test_shading_point_almost_touching_an_area_source(h):
    """A light h above the floor; the floor point h beside its edge sees it at r -> 0.
    Finite and bounded always; Lambert's polygon formula while h exceeds the ray-offset bound
    (render.accel.offset_eps, 7.8e-7 here: below it the gap between surfaces is not resolved).
    Rays leave from q raised by that offset, so BSDF-sampled rays see the light as from
    q + eps n: the render lies between the closed forms at q and there (1% apart at h = 1e-4:
    the geometry is resolved to eps / h), within 3 standard errors plus 1e-3. Shadow rays are
    aimed from the raised origin at the light point (path_kernels._queue_shadow_to): aimed
    along the unraised direction they crossed the light's own plane before their end, and
    every light sample from q was occluded (the render 1.3% low at h = 1e-4, 0.9% at 1e-3)."""
    sc = _lit_floor(light_height=h)
    q = np.array([0.5 + h, 0.0, 0.0])
    cam = probe_camera(q, q + [1.0, 0.0, 0.3], fov_deg=1e-4)
    r = render(sc, cam, RenderSettings(spp=4096, seed=3))
    _finite_bounded(r, RHO * LE.max())
    if h < 1e-5:
        return
    corners = np.array([[-0.5, -0.5, h], [0.5, -0.5, h], [0.5, 0.5, h], [-0.5, 0.5, h]])
    expected = RHO * polygon_irradiance(corners, q, np.array([0, 0, 1.0]), LE) / np.pi
    eps = offset_eps(q[None], prepare(sc).geom.extent)[0]
    raised = RHO * polygon_irradiance(corners, q + [0.0, 0.0, eps], np.array([0, 0, 1.0]), LE) / np.pi
    lo, hi = np.minimum(expected, raised), np.maximum(expected, raised)
    m, se = image_mean_and_se(r)
    slack = 3 * se + 1e-3 * expected
    assert np.all((m >= lo - slack) & (m <= hi + slack)), (m, expected, raised, se)


def test_degenerate_triangles_in_meshes():
    """Zero-area triangles inside the receiver and the light mesh change nothing."""
    def with_degenerates(mesh):
        v = np.vstack([mesh.vertices, [[0.1, 0.1, mesh.vertices[0, 2]]] * 2])
        n = len(mesh.vertices)
        f = np.vstack([mesh.faces, [[n, n, n + 1], [0, 0, 0], [0, 1, 1]]])
        return trimesh.Trimesh(v, f, process=False)

    clean = _lit_floor()
    dirty = Scene("dirty", [SceneObject("receiver", with_degenerates(clean.objects[0].mesh), clean.objects[0].material),
                            SceneObject("light", with_degenerates(clean.objects[1].mesh), clean.objects[1].material)])
    cam = Camera(Intrinsics.from_fov(8, 8, 60.0), look_at([0, -2.0, 0.5], [0, 0, 0], [0, 0, 1]), "v")
    a = render(clean, cam, RenderSettings(spp=64, seed=4))
    b = render(dirty, cam, RenderSettings(spp=64, seed=4))
    _finite_bounded(b, LE.max())
    assert np.allclose(a.mean, b.mean, rtol=1e-5, atol=1e-7)


def test_total_internal_reflection():
    """Camera inside a glass ball under a light: most rays meet the surface beyond the critical
    angle from inside. Finite, bounded; the BSDF never refracts beyond the critical angle."""
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    sc = Scene("tir", [SceneObject("ball", ball, Dielectric(1.5)),
                       SceneObject("light", quad((0, 0, 1.5), 0.5, 0.5, -1), Emissive(LE)),
                       receiver_box([RHO] * 3)])
    sc.objects[2].mesh.apply_translation([0, 0, -0.6])
    cam = Camera(Intrinsics.from_fov(8, 8, 120.0), look_at([0.3, 0, 0], [1, 0, 0.2], [0, 0, 1]), "inside")
    r = render(sc, cam, RenderSettings(spp=128, max_depth=12, seed=5))
    assert r.integrator == "path"
    _finite_bounded(r, 1.5 ** 2 * LE.max() * 1.0001)  # radiance inside glass is at most eta^2 Le
    wo = np.tile([np.sqrt(1 - 0.3 ** 2), 0.0, -0.3], (1000, 1))  # inside, cos 0.3 < critical 0.745
    s = dielectric_sample(np.full(1000, 1.5), wo, np.linspace(0, 1, 1000, endpoint=False))
    assert np.all(s.wi[:, 2] < 0) and np.all(np.isfinite(s.weight))


def _furnace(rho, le=1.0):
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    sc = Scene("furnace", [SceneObject("s", sphere, DiffuseEmitter(albedo=rho, radiance=le, two_sided=True))])
    return sc, Camera(Intrinsics.from_fov(4, 4, 60.0), np.eye(4), "inside")


def test_albedo_exactly_zero_with_roulette():
    """rho = 0: every path ends at the first hit; radiance is exactly Le, with zero variance."""
    sc, cam = _furnace(0.0)
    r = render(sc, cam, RenderSettings(integrator="path", spp=64, rr_depth=0, seed=6))
    assert np.allclose(r.mean, 1.0, rtol=1e-6) and np.all(r.variance < 1e-10)


def test_albedo_exactly_one_with_roulette():
    """rho = 1: roulette never kills (throughput stays 1), the depth cap ends paths; the
    truncated furnace is Le (N + 1)."""
    n = 10
    sc, cam = _furnace(1.0)
    r = render(sc, cam, RenderSettings(integrator="path", spp=256, max_depth=n, rr_depth=0, seed=7))
    _finite_bounded(r, 2 * (n + 1))
    m, se = image_mean_and_se(r)
    assert np.all(np.abs(m - (n + 1)) <= 3 * se + 1e-6)


def test_camera_inside_an_object():
    """Camera inside a closed diffuse box with the only light outside: exactly black."""
    box = trimesh.creation.box([1, 1, 1])
    sc = Scene("inside", [SceneObject("box", box, Lambertian([0.8] * 3)),
                          SceneObject("light", quad((0, 0, 2.0), 0.5, 0.5, -1), Emissive(LE))],
               lights=[PointLight([0, 0, 3.0], [5, 5, 5])])
    sc.effects = frozenset({"direct", "soft_shadows", "shadows", "interreflection"})
    cam = Camera(Intrinsics.from_fov(8, 8, 90.0), look_at([0, 0, 0], [1, 0, 0], [0, 0, 1]), "inside")
    r = render(sc, cam, RenderSettings(integrator="path", spp=32, seed=8))
    assert np.all(r.mean == 0) and np.all(r.variance == 0)


def test_light_facing_away():
    """A one-sided source facing up, above the floor: the floor stays black, and so does the
    source's back seen from below."""
    sc = _lit_floor(normal_sign=+1.0)
    cam = Camera(Intrinsics.from_fov(8, 8, 70.0), look_at([0, -1.5, 0.5], [0, 0, 0.5], [0, 0, 1]), "v")
    r = render(sc, cam, RenderSettings(integrator="path", spp=32, seed=9))
    assert np.all(r.mean == 0) and np.all(np.isfinite(r.variance))
    # the same source flipped lights the floor: the scene itself is not broken
    assert render(_lit_floor(), cam, RenderSettings(spp=8, seed=9)).mean.max() > 0


def test_point_light_on_the_surface():
    """A point light lying on the receiver (r -> 0 for nearby points): finite output."""
    sc = Scene("pt", [receiver_box([RHO] * 3)], lights=[PointLight([0, 0, 0.0], [1, 1, 1])])
    cam = Camera(Intrinsics.from_fov(8, 8, 10.0), look_at([0, -1.0, 1.0], [0, 0, 0], [0, 0, 1]), "v")
    r = render(sc, cam, RenderSettings(spp=8, seed=10))
    assert np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.variance))
