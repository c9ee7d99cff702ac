"""The path tracer's compiled pieces equal their numpy references: the hash RNG, camera rays,
texture lookups, Embree called directly vs through embreex, and renders whatever the threads.

Exact (bitwise) where the operations are the same; float32-ulp tolerances where Embree's two
builds may round differently."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cornell_box import cornell_camera, cornell_scene
from render import embree_direct
from render.accel import Accel, Geometry, spawn_origin
from render.bsdf import MaterialTable
from render.integrators import RenderSettings, prepare, render
from render.integrators.path import pinhole_of
from render.integrators.path_kernels import _albedo, _GOLDEN, SAMPLER_INDEPENDENT, sample_camera_rays, uniform_dims
from render.sampling import _mix64, cosine_hemisphere, orthonormal_frame, path_keys, to_world, uniform_block
from render.scene import Lambertian, Scene, SceneObject


def test_rng_and_camera_rays_match_numpy():
    cam = cornell_camera(32, 24)
    npix, n, sample0, seed = 32 * 24, 3 * 32 * 24, 5, 11
    keys, pix = np.empty(n, np.uint64), np.empty(n, np.int64)
    o32, d32, jit = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 2))
    seed_mix = _mix64(np.array([np.uint64(seed)], dtype=np.uint64) + _GOLDEN)[0]
    sample_camera_rays(0, n, npix, 32, sample0, seed_mix, pinhole_of(cam), True, keys, pix, o32, d32, jit,
                       SAMPLER_INDEPENDENT)  # the Sobol sampler's twin: tests/render/test_sobol.py
    flat = np.arange(n)
    assert np.array_equal(pix, flat % npix)
    assert np.array_equal(keys, path_keys(seed, flat % npix, sample0 + flat // npix))
    assert np.array_equal(uniform_dims(keys, 7, 5), uniform_block(keys, 7, 5))
    u = uniform_block(keys, 0, 2)
    assert np.array_equal(jit, u + np.stack([pix % 32, pix // 32], 1))
    o, d = cam.pixel_rays(jit)
    assert np.allclose(d32, d, atol=1e-7) and np.allclose(o32, o.astype(np.float32))


def test_texture_lookup_matches_material_table():
    rng = np.random.default_rng(3)
    tex = rng.integers(0, 256, (7, 9, 3), dtype=np.uint8)
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array([[-0.3, 0.2], [1.9, 0.3], [0.4, 2.8]]))  # wraps
    tint = np.array([0.5, 1.0, 0.25])
    sc = Scene("tex", [SceneObject("t", mesh, Lambertian(tint, texture=tex))])
    g, mt = Geometry.from_scene(sc), MaterialTable.from_scene(sc)
    ps = prepare(sc, threads=1)
    from render.integrators.path import kernel_scene_of as _kernel_scene
    ks = _kernel_scene(ps)
    u, v = rng.random(200) * 0.5, rng.random(200) * 0.5
    tri = np.zeros(200, np.int64)
    ref = mt.diffuse_albedo(tri, lambda m: g.texcoords(tri[m], u[m], v[m]))
    got = np.array([_albedo(ks.albedo, ks.tex, ks.uv, ks.tex_data, 0, 0, u[i], v[i]) for i in range(200)])
    assert np.allclose(got, ref, rtol=1e-12, atol=1e-15)


@pytest.mark.skipif(not embree_direct.AVAILABLE, reason="embreex's Embree library not found")
def test_direct_embree_matches_embreex():
    sc, cam = cornell_scene(), cornell_camera(96, 96)
    acc = Accel(sc, threads=1)
    g = acc.geometry
    o, d = cam.pixel_rays()
    o32, d32 = np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)
    ref, got = acc.intersect_raw(o32, d32), acc.intersect_fast(o32, d32)
    assert np.array_equal(ref[0], got[0]) and np.mean(got[0] >= 0) > 0.9
    h = got[0] >= 0
    assert np.allclose(got[1][h], ref[1][h], rtol=1e-5) and np.allclose(got[2][h], ref[2][h], atol=1e-5)
    # secondary rays from the hits, and occlusion against random distances
    tri = acc.ids[got[0][h]]
    p = g.point(tri, ref[2][h].astype(float), ref[3][h].astype(float))
    ng = g.normal[tri]
    ng = np.where((np.sum(ng * d[h], 1) > 0)[:, None], -ng, ng)
    s, t = orthonormal_frame(ng)
    wi = to_world(cosine_hemisphere(np.random.default_rng(1).random((len(p), 2))), s, t, ng)
    o2, d2 = np.ascontiguousarray(spawn_origin(p, ng, wi, g.extent), np.float32), np.ascontiguousarray(wi, np.float32)
    assert np.array_equal(acc.intersect_raw(o2, d2)[0], acc.intersect_fast(o2, d2)[0])
    t32 = (np.random.default_rng(2).random(len(o2)) * 600).astype(np.float32)
    occ_ref, occ = acc.occluded_raw(o2, d2, t32.copy()), acc.occluded_fast(o2, d2, t32)
    assert np.array_equal(occ_ref == -1, occ == -1) and 0.2 < np.mean(occ == -1) < 0.9
    acc.close()


@pytest.mark.skipif(not embree_direct.AVAILABLE, reason="embreex's Embree library not found")
def test_render_through_embreex_alone_is_the_same_render():
    """The fallback (embreex's batch queries) traces the same paths: equal images up to the
    rare path whose hit moves by a float32 ulp."""
    sc, cam = cornell_scene(), cornell_camera(16, 16)
    a, b = prepare(sc, threads=1), prepare(sc, threads=1)
    b.accel.direct = b.emit_accel.direct = None
    for integ, eff in (("path", None), ("direct", {"direct", "soft_shadows"})):
        st = RenderSettings(integrator=integ, spp=32, seed=3)
        ra, rb = render(sc, cam, st, effects=eff, prepared=a), render(sc, cam, st, effects=eff, prepared=b)
        diff = np.abs(ra.mean - rb.mean)
        assert np.mean(diff < 1e-5) > 0.99 and diff.mean() < 1e-3 * ra.mean.mean()


def test_renders_do_not_depend_on_threads():
    sc, cam = cornell_scene(), cornell_camera(16, 16)
    ps = prepare(sc, threads=2)
    st = RenderSettings(integrator="path", spp=16, seed=4, batch_paths=1000)
    one = render(sc, cam, RenderSettings(integrator="path", spp=16, seed=4, batch_paths=1000, threads=1), prepared=ps)
    two = render(sc, cam, st, prepared=ps)
    assert np.array_equal(one.film.s1, two.film.s1) and np.array_equal(one.film.s2, two.film.s2)
    assert np.array_equal(one.mean, two.mean) and np.array_equal(one.variance, two.variance)
    # samples are summed per pixel in sample order, so the batch size does not matter either
    big = render(sc, cam, RenderSettings(integrator="path", spp=16, seed=4), prepared=ps)
    assert np.array_equal(big.film.s1, one.film.s1) and np.array_equal(big.film.s2, one.film.s2)


def test_borrowed_view_shares_data_and_leaves_the_reference_count():
    """path_kernels._borrow: the bounce kernel's arrays without reference counting: a view of the
    same memory (writes land in the caller's array, shape and strides kept) that takes no
    reference (the caller's count is unchanged after many borrows)."""
    import sys

    from numba import njit

    from render.integrators.path_kernels import _borrow

    @njit
    def write_through(a, reps):
        for r in range(reps):
            v = _borrow(a)
            v[1, 2] += 1.0
        v = _borrow(a)
        return v.shape[0], v.shape[1], v.strides[0], v[1, 2]

    a = np.zeros((3, 4))
    before = sys.getrefcount(a)
    rows, cols, stride, last = write_through(a, 5)
    assert (rows, cols, stride) == (3, 4, 32)
    assert a[1, 2] == 5.0 and last == 5.0 and a.sum() == 5.0
    assert sys.getrefcount(a) == before
