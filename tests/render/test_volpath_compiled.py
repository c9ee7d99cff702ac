"""The compiled ``volpath`` (render/integrators/volpath_kernels.py) against its numpy reference
(render_volpath(numpy_reference=True)): its BSDF and phase-function pieces value for value, whole
images per pixel within their combined noise on a scene with every event the kernels handle
(two media, one a grid with emission, glossy and smooth surfaces, area and point lights, a
background), bytes independent of threads and batches, and the majorant check inside the kernel.
Fixed seeds."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ptutil import assert_images_agree, quad
from render.bsdf import MaterialTable
from render.camera import Camera, Intrinsics
from render.integrators import RenderSettings, prepare
from render.integrators.volpath import render_volpath, surface_eval, surface_sample, volpath_context
from render.integrators.volpath_kernels import hg_pdf_k, hg_sample_k, surface_eval_local, surface_sample_local
from render.lights import PointLight
from render.media import MajorantError, hg_pdf, hg_sample
from render.poses import look_at
from render.scene import (Dielectric, Emissive, Lambertian, Medium, Mirror, RoughConductor, RoughDielectric, Scene,
                          SceneObject)


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(hi - lo)
    b.apply_translation((lo + hi) / 2)
    return b


def _every_event_scene() -> Scene:
    """Rough gold floor, rough glass ball, diffuse block, mirror panel; an area light and a point
    light (above the media: inside a scattering medium its 1/r^2 at nearby medium vertices has
    infinite variance); a grid medium (absorbing, scattering, emitting, g = 0.4) over the floor
    and a homogeneous one (g = -0.3) above it; a dim background for escaping rays."""
    ball = trimesh.creation.icosphere(2, 0.4)
    ball.apply_translation([0.5, 0.0, 0.5])
    objs = [SceneObject("floor", quad((0, 0, 0), 1.5, 1.5), RoughConductor(alpha=0.3)),
            SceneObject("ball", ball, RoughDielectric(alpha=0.2, ior=1.5)),
            SceneObject("block", _box([-0.9, 0.0, 0.0], [-0.4, 0.5, 0.5]), Lambertian(np.array([0.7, 0.5, 0.3]))),
            SceneObject("panel", _box([-1.4, 0.8, 0.0], [1.4, 0.9, 1.0]), Mirror(np.full(3, 0.8))),
            SceneObject("glass", _box([0.9, -0.8, 0.0], [1.2, -0.5, 0.3]), Dielectric(1.5)),
            SceneObject("light", quad((0, 0, 2.5), 0.5, 0.5, normal_sign=-1), Emissive(np.full(3, 12.0)))]
    dens = np.random.default_rng(7).random((4, 4, 3)) * 1.5
    media = [Medium(_box([-1.5, -1.5, 0.01], [1.5, 1.5, 1.2]), sigma_a=0.2, sigma_s=0.6,
                    emission=np.array([0.3, 0.1, 0.05]), g=0.4, density=dens),
             Medium(_box([-1.5, -1.5, 1.3], [1.5, 1.5, 2.0]), sigma_a=0.1, sigma_s=0.3, g=-0.3)]
    return Scene("every_event", objs, lights=[PointLight([1.0, -1.0, 2.3], np.full(3, 2.0))], media=media,
                 background=np.full(3, 0.05))


def _cam(size: int = 12) -> Camera:
    return Camera(Intrinsics.from_fov(size, size, 55.0),
                  look_at(np.array([0.0, -3.5, 1.6]), np.array([0.0, 0.0, 0.5]), np.array([0, 0, 1.0])), "c")


# ---------------------------------------------------------------- pieces
def _unit(v):
    return v / np.linalg.norm(v, axis=1)[:, None]


_MATERIALS = [Lambertian(np.array([0.6, 0.4, 0.2])), Mirror(np.array([0.9, 0.8, 0.7])), Dielectric(1.5),
              RoughConductor(alpha=0.35), RoughConductor(alpha=0.0), RoughDielectric(alpha=0.3, ior=1.4),
              RoughDielectric(alpha=0.0, ior=1.4)]


@pytest.mark.parametrize("mat", _MATERIALS, ids=lambda m: f"{type(m).__name__}-{getattr(m, 'alpha', '')}")
def test_compiled_bsdf_equals_numpy(mat):
    """surface_eval_local / surface_sample_local equal volpath's numpy surface_eval /
    surface_sample (render.bsdf, render.microfacet) on 400 random (wo, wi, u) triples, wo on
    both sides (dielectrics are entered from inside too): f, pdf, validity, delta flag, wi and
    weight to 1e-9 relative (closed forms both; only rounding differs). A rough dielectric's
    transmission weight missing its 1 / eta'^2 fails it."""
    rng = np.random.default_rng(31)
    n = 400
    mats = MaterialTable.from_scene(Scene("m", [SceneObject("o", _box([0, 0, 0], [1, 1, 1]), mat)]))
    obj = np.zeros(n, np.int64)
    diel = isinstance(mat, (Dielectric, RoughDielectric))
    wo, wi = _unit(rng.normal(size=(n, 3))), _unit(rng.normal(size=(n, 3)))
    if not diel:
        wo[:, 2] = np.abs(wo[:, 2])  # two-sided: the frame faces wo
    u0, u12 = rng.random(n), rng.random((n, 2))
    alb = np.tile(mats.albedo[0], (n, 1))
    f_np, pdf_np = surface_eval(mats, obj, alb, wo, wi)
    bs = surface_sample(mats, obj, alb, wo, u0, u12)
    a, e, k = mats.alpha[0], mats.eta[0], mats.k[0]
    args = (int(mats.kind[0]), *mats.albedo[0], float(a), float(mats.ior[0]), *e, *k)
    for i in range(n):
        f0, f1, f2, pdf = surface_eval_local(*args, *wo[i], *wi[i])
        np.testing.assert_allclose([f0, f1, f2, pdf], [*f_np[i], pdf_np[i]], rtol=1e-9, atol=1e-12)
        ok, x, y, z, w0, w1, w2, spdf, delta = surface_sample_local(*args, *wo[i], u0[i], *u12[i])
        assert ok == bs.valid[i]
        if ok:
            assert delta == bs.delta[i]
            np.testing.assert_allclose([x, y, z, w0, w1, w2, spdf], [*bs.wi[i], *bs.weight[i], bs.pdf[i]],
                                       rtol=1e-9, atol=1e-12)


def test_compiled_phase_function_equals_numpy():
    """hg_pdf_k / hg_sample_k equal render.media.hg_pdf / hg_sample (g from back- to forward-
    scattering and the isotropic branch), 1e-12 absolute. The pdf with g's sign flipped fails it."""
    rng = np.random.default_rng(32)
    n = 200
    d = _unit(rng.normal(size=(n, 3)))
    u = rng.random((n, 2))
    for g in (-0.7, 0.0, 5e-4, 0.3, 0.9):
        wi = hg_sample(g, d, u)
        pdf = hg_pdf(g, d, wi)
        for i in range(n):
            w = hg_sample_k(g, *d[i], *u[i])
            np.testing.assert_allclose(w, wi[i], atol=1e-12)
            assert abs(hg_pdf_k(g, *d[i], *w) - pdf[i]) <= 1e-12 * max(1.0, pdf[i])


# ---------------------------------------------------------------- whole images
def test_compiled_volpath_agrees_with_numpy_per_pixel():
    """Compiled (seed 41, 512 spp) and numpy (seed 42, 512 spp) renders of the every-event scene at
    12 x 12, max depth 8: per pixel-channel two-sample tests at alpha 0.01 Sidak-corrected over
    all pixel channels (>= 99.75% pass) and the global test of the image means
    (ptutil.assert_images_agree). The image mean's standard error is ~0.7% per channel. Measured:
    every pixel channel passes, global z 1.0; shadow rays through the homogeneous medium attenuated
    by sigma_a alone (sigma_s forgotten in the kernel) fail it at global z 14.6."""
    sc = _every_event_scene()
    ps = prepare(sc)
    cam = _cam()
    s = dict(integrator="volpath", spp=512, max_depth=8)
    a = render_volpath(sc, cam, RenderSettings(seed=41, **s), prepared=ps)
    b = render_volpath(sc, cam, RenderSettings(seed=42, **s), prepared=ps, numpy_reference=True)
    assert np.all(np.isfinite(a.mean)) and np.all(np.isfinite(a.variance)) and a.mean.max() > 0
    assert_images_agree(a, b)


def test_compiled_volpath_bytes_do_not_depend_on_threads_or_batches():
    """The same render with 1 thread and batches of 97 paths, and with 2 threads and batches of
    1000: identical mean and variance bytes (every random number is a function of (seed,
    pixel, sample, dimension)). A shadow ray's key taken from its place in the batch's queue
    instead of (path key, dimension) fails it (ratio tracking through the grid medium)."""
    sc = _every_event_scene()
    ps = prepare(sc)
    cam = _cam(8)
    r1 = render_volpath(sc, cam, RenderSettings(integrator="volpath", spp=16, seed=5, threads=1, batch_paths=97),
                        prepared=ps)
    r2 = render_volpath(sc, cam, RenderSettings(integrator="volpath", spp=16, seed=5, threads=2, batch_paths=1000),
                        prepared=ps)
    assert r1.mean.tobytes() == r2.mean.tobytes() and r1.variance.tobytes() == r2.variance.tobytes()


def test_compiled_volpath_refuses_a_majorant_below_the_extinction():
    """A majorant lowered after construction (bypassing MediumSet's check) is caught at the first
    collision inside the kernel: MajorantError naming the medium, not a biased image (the
    kernel's check removed: no error, the test fails)."""
    sc = _every_event_scene()
    ps = prepare(sc)
    ctx = volpath_context(sc, ps)
    ctx.media.mu[0] *= 0.5
    with pytest.raises(MajorantError, match="medium 0"):
        render_volpath(sc, _cam(4), RenderSettings(integrator="volpath", spp=4, seed=6), prepared=ps, ctx=ctx)


def test_surface_wavefront_in_one_call_equals_the_python_driver(monkeypatch):
    """Without media, volpath's rounds run in one compiled call (volpath_kernels.trace_surfaces,
    Embree queried from it); the Python driver (one Embree query and one kernel call per round, what
    scenes with media and machines without Embree's library use) gives the same bytes. The
    every-event scene without its media, 8 x 8, 16 spp."""
    sc = _every_event_scene()
    sc = Scene(sc.name, sc.objects, lights=sc.lights, background=sc.background)
    ps = prepare(sc)
    cam = _cam(8)
    settings = RenderSettings(integrator="volpath", spp=16, seed=9, threads=2)
    one_call = render_volpath(sc, cam, settings, prepared=ps)
    with monkeypatch.context() as m:
        m.setattr("render.integrators.volpath.trace_surfaces", None)
        driver = render_volpath(sc, cam, settings, prepared=ps)
    assert one_call.mean.max() > 0 and one_call.stats["rays"] == driver.stats["rays"]
    assert one_call.mean.tobytes() == driver.mean.tobytes()
    assert one_call.variance.tobytes() == driver.variance.tobytes()
