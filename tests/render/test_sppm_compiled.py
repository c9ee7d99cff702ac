"""The compiled ``sppm`` (render/integrators/sppm_kernels.py, driven by render_sppm) against its
numpy reference (render_sppm_numpy): the photon emission term by term, the hash-grid gather
against the cKDTree gather exactly, whole renders per pixel within their combined noise at
equal photon counts, and bytes that depend on neither threads nor batch boundaries. Fixed seeds.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import trimesh

from ptutil import assert_images_agree, caustic_scene, quad
from render.camera import Camera, Intrinsics
from render.integrators import prepare
from render.integrators import sppm as sppm_module
from render.integrators.path import kernel_scene_of
from render.integrators.sppm import _gather, render_sppm, render_sppm_numpy
from render.integrators.sppm_kernels import build_grid, emit_photons, gather, photon_keys
from render.lights import sample_emission, scene_bounds
from render.sampling import uniform
from render.scene import DirectionalLight, Lambertian, Mirror, PointLight, Scene, SceneObject, SpotLight


def _lit_caustic_scene() -> Scene:
    """The glass caustic (0.4 m area source) plus a point, a spot and a directional light (every
    kind of emission), a coloured diffuse back wall and a mirror side wall (diffuse
    interreflection, mirror and glass paths for photons and for the eye)."""
    sc, _ = caustic_scene()
    back = quad((0.0, 0.0, 0.0), 3.0, 1.5)
    back.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # normal -y
    back.apply_translation([0.0, 1.5, 1.5])
    side = quad((0.0, 0.0, 0.0), 1.5, 1.5)
    side.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))  # normal +x
    side.apply_translation([-1.5, 0.0, 1.5])
    walls = [SceneObject("back", back, Lambertian([0.8, 0.5, 0.3])), SceneObject("side", side, Mirror([0.9, 0.9, 0.9]))]
    return Scene("caustic_lights", list(sc.objects) + walls,
                 lights=[PointLight([0.8, -0.5, 2.0], [3.0, 2.0, 1.0]),
                         SpotLight([-0.8, 0.3, 2.5], [0.2, -0.1, -1.0], [8.0, 8.0, 8.0], np.radians(20.0),
                                   np.radians(30.0)),
                         DirectionalLight([0.3, 0.2, -1.0], [0.3, 0.4, 0.5])])


def test_emission_matches_sample_emission():
    """emit_photons against render.lights.sample_emission fed the same hash uniforms (dimensions
    0 light pick, 1-2 position, 3-4 direction, 5 side): the same photons survive (non-zero
    flux), with the same origins (to float32), directions and flux (1e-9 relative), for area,
    point, spot and directional lights."""
    ps = prepare(_lit_caustic_scene())
    ks = kernel_scene_of(ps)
    n = 20_000
    seed_mix = np.uint64(0x1234567890ABCDEF)
    keys = photon_keys(seed_mix, 3, n, 0, n)  # pass 3's photons 0 .. n - 1
    ref = sample_emission(ps.lights, ps.geom, uniform(keys, 0), np.stack([uniform(keys, 1), uniform(keys, 2)], 1),
                          np.stack([uniform(keys, 3), uniform(keys, 4)], 1), uniform(keys, 5))
    live = ref.flux.max(axis=1) > 0
    assert len(np.unique(ref.kind[live])) == 4  # every light kind
    o32, d32, flux = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 3))
    centre, radius = scene_bounds(ps.geom)
    k, idx = keys.copy(), np.arange(n)
    m = emit_photons(ks, centre, radius, k, idx, o32, d32, flux)
    assert m == live.sum()
    assert np.array_equal(k[:m], keys[live]) and np.array_equal(idx[:m], np.nonzero(live)[0])
    np.testing.assert_allclose(flux[:m], ref.flux[live], rtol=1e-9)
    np.testing.assert_allclose(d32[:m], ref.d[live].astype(np.float32), atol=1e-6)
    np.testing.assert_allclose(o32[:m], ref.o[live].astype(np.float32), atol=1e-5)


def test_hash_grid_gather_equals_kdtree_gather():
    """gather over build_grid against the numpy reference's cKDTree gather (_gather) on random
    points: clustered photons, radii spanning 100x (the grid's cell is the largest), negative
    coordinates, photons from both sides and of every depth: identical counts per visible point
    and the same weighted flux to rounding."""
    rng = np.random.default_rng(5)
    nv, nph, max_depth = 400, 30_000, 5
    vp_p = rng.uniform(-1.0, 1.0, (nv, 3))
    vp_n = rng.normal(size=(nv, 3))
    vp_n /= np.linalg.norm(vp_n, axis=1, keepdims=True)
    vp = {"pix": np.arange(nv), "depth": rng.integers(0, 3, nv), "p": vp_p, "n": vp_n,
          "w": rng.uniform(0.0, 1.0, (nv, 3))}
    ph_p = np.concatenate([rng.uniform(-1.1, 1.1, (nph // 2, 3)), vp_p[rng.integers(0, nv, nph // 2)]
                           + rng.normal(scale=0.02, size=(nph // 2, 3))])
    wi = rng.normal(size=(nph, 3))
    ph = {"p": ph_p, "wi": wi / np.linalg.norm(wi, axis=1, keepdims=True), "flux": rng.uniform(0.0, 2.0, (nph, 3)),
          "depth": rng.integers(1, 5, nph)}
    radius = np.exp(rng.uniform(np.log(0.002), np.log(0.2), nv))
    phi_ref, cnt_ref = _gather(vp, radius, ph, max_depth)
    cell = float(radius.max())
    cells, start, order = build_grid(ph["p"], cell)
    phi, cnt = np.zeros((nv, 3)), np.zeros(nv, np.int64)
    gather(np.arange(nv), vp["p"], vp["n"], vp["w"], vp["depth"], radius, cell, cells, start, order, ph["p"],
           ph["wi"], ph["flux"], ph["depth"], max_depth, phi, cnt)
    assert cnt_ref.sum() > 2000
    assert np.array_equal(cnt, cnt_ref)
    np.testing.assert_allclose(phi, phi_ref, rtol=1e-12, atol=1e-12)


def _group_images(fn, sc, cam, ps, groups: int, passes: int, photons: int):
    """SimpleNamespace(mean, variance, film) of ``groups`` independent progressive runs of
    ``passes`` passes each (their own streams: first_pass = g x passes), as render() groups sppm:
    the mean image and the variance of that mean across groups (groups - 1 degrees of freedom)."""
    imgs = np.stack([fn(sc, cam, passes, photons, initial_radius=0.03, seed=41, prepared=ps,
                        first_pass=g * passes).mean for g in range(groups)])
    h, w = imgs.shape[1:3]
    film = SimpleNamespace(r1=None, n=np.full(h * w, groups))
    return SimpleNamespace(mean=imgs.mean(0), variance=imgs.var(0, ddof=1) / groups, film=film)


def test_compiled_agrees_with_numpy_per_pixel():
    """Compiled and numpy SPPM at equal photon counts (10 groups of 3 passes of 20000 photons,
    the same initial radius, 24 x 24) on the caustic scene with an area, a point, a spot and a
    directional light: per pixel, |a - b| / sqrt(var_a + var_b) within Student's t at the
    Welch degrees of freedom, alpha 0.01 Sidak-corrected over pixel channels (ptutil's
    per-pixel test: >= 99.75% of pixel channels and the global test of the image means).
    The two share the estimator and so the blur bias (same radii schedule in distribution):
    only noise separates them, which the group spread measures. The caustic region holds
    photon light through the glass, the floor diffuse interreflection, the ball the eye pass's
    specular chains."""
    sc = _lit_caustic_scene()
    _, cam = caustic_scene()
    cam = Camera(Intrinsics.from_fov(24, 24, 45.0), cam.cam_to_world, "c24")
    ps = prepare(sc)
    a = _group_images(render_sppm, sc, cam, ps, 10, 3, 20_000)
    b = _group_images(render_sppm_numpy, sc, cam, ps, 10, 3, 20_000)
    assert np.all(np.isfinite(a.mean)) and a.mean.min() >= 0 and a.variance.max() > 0
    assert_images_agree(a, b)


def test_bytes_independent_of_threads_and_batches(monkeypatch):
    """The compiled render is a pure function of (scene, camera, passes, photons, seed, first
    pass): one thread or two, batches of 37 rays instead of _BATCH, passes traced one at a time
    (as with a callback) instead of in blocks, give the same bytes; and the photon keys of a
    block of passes are those of each pass alone."""
    sc, cam = caustic_scene()
    cam = Camera(Intrinsics.from_fov(12, 12, 45.0), cam.cam_to_world, "c12")
    ps = prepare(sc)
    one = render_sppm(sc, cam, 3, 3_000, seed=9, prepared=ps, threads=1)
    two = render_sppm(sc, cam, 3, 3_000, seed=9, prepared=ps, threads=2)
    passes = render_sppm(sc, cam, 3, 3_000, seed=9, prepared=ps, callback=lambda *a: None)
    monkeypatch.setattr(sppm_module, "_BATCH", 37)
    small = render_sppm(sc, cam, 3, 3_000, seed=9, prepared=ps, threads=2)
    assert one.mean.max() > 0
    for r in (two, passes, small):
        assert r.mean.tobytes() == one.mean.tobytes() and r.radius.tobytes() == one.radius.tobytes()
    seed_mix = np.uint64(77)
    block = photon_keys(seed_mix, 5, 100, 0, 300)
    assert np.array_equal(block[100:200], photon_keys(seed_mix, 6, 100, 0, 100))
