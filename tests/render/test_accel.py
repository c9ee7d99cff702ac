"""Embree intersection: hits against analytic geometry, degenerate triangles, occlusion, thread
splitting, and ray offsets at millimetre scale."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cornell_box import cornell_camera, cornell_scene
from ptutil import quad
from render.accel import Accel, Geometry, spawn_origin
from render.sampling import cosine_hemisphere, orthonormal_frame, path_keys, to_world, uniform
from render.scene import Lambertian, Scene, SceneObject


def _plane_scene():
    return Scene("p", [SceneObject("q", quad((0, 0, 1.0), 1.0, 1.0), Lambertian(0.5))])


def test_hits_match_analytic_plane():
    acc = Accel(_plane_scene(), threads=2)
    rng = np.random.default_rng(0)
    o = np.column_stack([rng.uniform(-2, 2, (50000, 2)), np.zeros(50000)])
    d = np.tile([0, 0, 1.0], (50000, 1))
    h = acc.intersect(o, d)
    inside = np.all(np.abs(o[:, :2]) < 1 - 1e-6, axis=1)
    outside = np.any(np.abs(o[:, :2]) > 1 + 1e-6, axis=1)
    assert np.all(h.tri[inside] >= 0) and np.all(h.tri[outside] == -1)
    assert np.allclose(h.t[inside], 1.0, atol=1e-6) and np.all(np.isinf(h.t[outside]))
    p = acc.geometry.point(h.tri[inside], h.u[inside], h.v[inside])
    assert np.allclose(p[:, :2], o[inside, :2], atol=1e-5)
    # tmax cuts hits off; occlusion agrees with intersection
    assert np.all(acc.intersect(o[inside], d[inside], tmax=0.99).tri == -1)
    assert np.all(acc.occluded(o[inside], d[inside], 1.01)) and not np.any(acc.occluded(o[inside], d[inside], 0.99))
    acc.close()


def test_thread_split_equals_single_thread():
    sc, cam = cornell_scene(), cornell_camera(128, 128)
    acc = Accel(sc, threads=2)
    o, d = cam.pixel_rays()
    a, b = acc.intersect(o, d, threads=1), acc.intersect(o, d, threads=2)
    assert np.array_equal(a.tri, b.tri) and np.array_equal(a.t, b.t)
    assert np.mean(a.tri >= 0) > 0.9  # the open front lets a few edge rows escape
    acc.close()


def test_degenerate_triangles_are_guarded():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 0], [3, 3, 0], [4, 4, 0]], float)
    f = np.array([[0, 1, 2], [0, 0, 1], [3, 4, 5], [1, 1, 1]])  # one good, three zero-area
    sc = Scene("deg", [SceneObject("m", trimesh.Trimesh(v, f, process=False), Lambertian(0.5))])
    g = Geometry.from_scene(sc)
    assert g.valid.tolist() == [True, False, False, False]
    assert np.all(np.isfinite(g.normal)) and np.all(g.normal[1:] == 0) and np.all(g.area[1:] == 0)
    acc = Accel(sc, threads=1, geometry=g)
    o = np.array([[0.2, 0.2, 1.0], [3.0, 3.0, 1.0], [0.5, 0.0, 1.0]])
    h = acc.intersect(o, np.tile([0, 0, -1.0], (3, 1)))
    assert h.tri[0] == 0 and h.tri[1] == -1


@pytest.mark.parametrize("shift", [0.0, 1e5])
def test_offsets_prevent_self_intersection_at_millimetre_scale(shift):
    """Rays leaving Cornell-box surfaces (coordinates ~500 mm, or shifted 100 m off the origin),
    including at grazing angles (1e-4 rad), never hit the surface they leave."""
    sc = cornell_scene()
    for o in sc.objects:
        o.mesh.apply_translation([shift, 0, 0])
    acc = Accel(sc, threads=2)
    g = acc.geometry
    n = 1_000_000
    k = path_keys(0, np.arange(n), np.zeros(n, np.int64))
    valid_tris = np.nonzero(g.valid)[0]
    tri = valid_tris[(uniform(k, 0) * len(valid_tris)).astype(int)]
    b1, b2 = uniform(k, 1), uniform(k, 2)
    flip = b1 + b2 > 1
    b1, b2 = np.where(flip, 1 - b1, b1), np.where(flip, 1 - b2, b2)
    p = g.point(tri, b1, b2)
    ng = g.normal[tri]
    side = np.where(uniform(k, 3) < 0.5, 1.0, -1.0)[:, None]
    nrm = ng * side
    s, t = orthonormal_frame(nrm)
    w = to_world(cosine_hemisphere(np.stack([uniform(k, 4), uniform(k, 5)], 1)), s, t, nrm)
    graze = uniform(k, 6) < 0.3  # 30% of rays almost parallel to the surface
    tang = s[graze]
    w[graze] = tang * np.cos(1e-4) + nrm[graze] * np.sin(1e-4)
    o = spawn_origin(p, ng, w, g.extent)
    h = acc.intersect(o, w)
    assert not np.any(h.tri == tri), f"{np.sum(h.tri == tri)} self-intersections"
    acc.close()


def test_compiled_packet_queries_equal_embreex_ray_by_ray():
    """render.embree_direct traces packets of PACKET rays (the last one padded with invalid
    lanes): every ray's hit is the same bits whatever the batch length (not a multiple of the
    packet) and whichever rays share its packet, the same triangle as embreex's (t, u, v to
    float32 rounding), and its occlusion equals embreex's."""
    from render import embree_direct

    if not embree_direct.AVAILABLE:
        pytest.skip("embreex's Embree library not found")
    sc, cam = cornell_scene(), cornell_camera(9, 7)
    acc = Accel(sc, threads=1)
    rng = np.random.default_rng(5)
    o, d = cam.pixel_rays(rng.random((301, 2)) * [9, 7])
    # half camera rays, half rays from inside the box in random directions (hits on every wall)
    o[150:] = acc.geometry.v0.mean(0) + 0.1 * rng.standard_normal((151, 3))
    d[150:] = rng.standard_normal((151, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o32, d32 = np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)
    t32 = (rng.random(len(o)) * acc.geometry.extent).astype(np.float32)
    ref, ref_occ = acc.intersect_raw(o32, d32), acc.occluded_raw(o32, d32, t32.copy())
    assert 0.6 < np.mean(ref[0] >= 0) < 1.0 and 0.2 < np.mean(ref_occ == -1) < 0.9  # misses too (open front)
    full = acc.intersect_fast(o32, d32)
    h = full[0] >= 0
    assert np.array_equal(full[0], ref[0])  # embreex's own ray struct path: t, u, v to float32 rounding
    assert np.allclose(full[1][h], ref[1][h], rtol=1e-5) and np.allclose(full[2][h], ref[2][h], atol=1e-5)
    for a, b in ((0, 1), (3, 12), (5, 300), (17, 40)):  # lengths 1, 9, 295, 23: other packets, padded ends
        got = acc.intersect_fast(o32[a:b], d32[a:b])
        hh = got[0] >= 0
        assert np.array_equal(got[0], full[0][a:b])
        for k in (1, 2, 3):
            assert np.array_equal(got[k][hh], full[k][a:b][hh])
        assert np.array_equal(acc.occluded_fast(o32[a:b], d32[a:b], t32[a:b]), ref_occ[a:b])
    acc.close()
