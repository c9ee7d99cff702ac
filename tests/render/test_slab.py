"""Light-slab geometry, lookup and interpolation (render/lightfield/).

Analytic light fields: a Lambertian plane parallel to the slab planes at distance ``zeta`` from
the uv plane, textured by a known function f(x, y). The radiance of the line through uv point U
and st point S is f at P = U + (zeta / D) (S - U) (frame coordinates), so every interpolation
mode has an exact answer to compare with.
"""
import numpy as np
import pytest

from render.camera import Camera, Intrinsics
from render.poses import look_at
from render.lightfield import (MODES, LightSlab, SlabGeometry, lookup, render_rays, render_pinhole, select_slabs,
                         sheared_camera, slab_coordinates)
from render.lightfield import create_slab_arrays, load_slabs, save_slabs, write_slab_index

D = 1.0  # uv -> st distance of the test slab


def make_geometry(shape=(8, 8, 32, 32), name="slab", z0=0.0) -> SlabGeometry:
    """uv quad 1 x 1 at z = z0 (world), st quad 0.6 x 0.6 at z0 + D, forward = +z.

    e_s = +x, e_t = +y, e_s x e_t = +z: s right, t down seen from the uv side (looking along +z)."""
    uv = np.array([[-0.5, -0.5, z0], [0.5, -0.5, z0], [0.5, 0.5, z0], [-0.5, 0.5, z0]])
    st = np.array([[-0.3, -0.3, z0 + D], [0.3, -0.3, z0 + D], [0.3, 0.3, z0 + D], [-0.3, 0.3, z0 + D]])
    return SlabGeometry(uv, st, shape, name)


def texture_linear(p):
    """(N, 2) frame points -> (N, 3) radiance linear in x, y."""
    x, y = p[..., 0], p[..., 1]
    return np.stack([0.5 + 0.4 * x, 0.5 - 0.3 * y, 0.3 + 0.2 * x + 0.2 * y], axis=-1)


def texture_wavy(p):
    x, y = p[..., 0], p[..., 1]
    return np.stack([0.5 + 0.4 * np.sin(25 * x), 0.5 + 0.4 * np.cos(21 * y), 0.5 + 0.3 * np.sin(17 * (x + y))], axis=-1)


def analytic_slab(geom: SlabGeometry, zeta: float, texture, with_depth=True, focal=None) -> LightSlab:
    """Sample the light field of the textured plane at distance ``zeta`` from the uv plane."""
    nu, nv, ns, nt = geom.shape
    U = np.stack(np.meshgrid((np.arange(nu) + 0.5) / nu * geom.uv_size[0],
                             (np.arange(nv) + 0.5) / nv * geom.uv_size[1]), axis=-1)  # (Nv, Nu, 2)
    S = np.stack(np.meshgrid(geom.st_offset[0] + (np.arange(ns) + 0.5) / ns * geom.st_size[0],
                             geom.st_offset[1] + (np.arange(nt) + 0.5) / nt * geom.st_size[1]), axis=-1)  # (Nt, Ns, 2)
    P = U[:, :, None, None] + (zeta / geom.distance) * (S[None, None] - U[:, :, None, None])
    rad = texture(P).astype(np.float32)
    depth = np.full(geom.array_shape[:4], zeta, np.float32) if with_depth else None
    return LightSlab(geom, rad, depth, focal)


def exact_radiance(geom, hits, zeta, texture):
    P = hits.uv + (zeta / geom.distance) * (hits.st - hits.uv)
    return texture(P)


def random_rays(geom, n, seed, margin=0.1):
    """Rays from eyes behind the uv plane through points well inside both quads."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(margin, 1 - margin, (n, 2))
    b = rng.uniform(margin, 1 - margin, (n, 2))
    U = geom.uv_point(a[:, 0], a[:, 1])
    c = geom.st_corners
    S = c[0] + b[:, :1] * (c[1] - c[0]) + b[:, 1:] * (c[3] - c[0])
    d = S - U
    return U - 0.3 * d, d / np.linalg.norm(d, axis=1, keepdims=True)


# ---------------------------------------------------------------------------- geometry


def test_geometry_frame_and_sizes():
    g = make_geometry()
    assert g.distance == pytest.approx(D)
    np.testing.assert_allclose(g.forward, [0, 0, 1])
    assert g.uv_size == pytest.approx((1.0, 1.0)) and g.st_size == pytest.approx((0.6, 0.6))
    assert g.st_offset == pytest.approx((0.2, 0.2))
    assert g.array_shape == (8, 8, 32, 32, 3)
    np.testing.assert_allclose(g.uv_sample_points()[0, 0], [-0.5 + 1 / 16, -0.5 + 1 / 16, 0])
    assert SlabGeometry.from_dict(g.to_dict()).to_dict() == g.to_dict()


@pytest.mark.parametrize("case", ["not_rectangle", "not_parallel", "st_behind", "zero_edge", "bad_shape", "nan"])
def test_geometry_rejects_bad_input(case):
    g = make_geometry()
    uv, st, shape = g.uv_corners.copy(), g.st_corners.copy(), g.shape
    if case == "not_rectangle":
        uv[2, 0] += 0.1
    elif case == "not_parallel":
        st[:, 2] += np.array([0, 0.1, 0.1, 0])
    elif case == "st_behind":
        st[:, 2] = -1.0
    elif case == "zero_edge":
        st[1] = st[0]
        st[2] = st[3]
    elif case == "bad_shape":
        shape = (8, 0, 4, 4)
    elif case == "nan":
        uv[0, 0] = np.nan
    with pytest.raises(ValueError):
        SlabGeometry(uv, st, shape)


def test_lightslab_checks_array_shapes():
    g = make_geometry((2, 2, 4, 4))
    with pytest.raises(ValueError):
        LightSlab(g, np.zeros((2, 2, 4, 4, 3), np.float64))
    with pytest.raises(ValueError):
        LightSlab(g, np.zeros(g.array_shape, np.float32), np.zeros((2, 2, 4, 3), np.float32))
    with pytest.raises(ValueError):
        LightSlab(g, np.zeros(g.array_shape, np.float32), focal_depth=-1.0)


# ---------------------------------------------------------------------------- sheared cameras


@pytest.mark.parametrize("u,v", [(0.5, 0.5), (0.0625, 0.9375), (1.0, 0.0)])
def test_sheared_camera_image_plane_is_the_st_quad(u, v):
    g = make_geometry((8, 8, 16, 12))
    cam = sheared_camera(g, u, v, st_supersample=2)
    k = cam.intrinsics
    assert (k.width, k.height) == (32, 24)
    np.testing.assert_allclose(cam.center, g.uv_point(u, v), atol=1e-12)
    # st corners project to the image corners; the centre of st sample (l, k) to pixel centres
    px, z = cam.project(g.st_corners)
    np.testing.assert_allclose(px, [[0, 0], [32, 0], [32, 24], [0, 24]], atol=1e-9)
    np.testing.assert_allclose(z, D)
    # its pixel rays cross the slab at the sample they image
    o, d = cam.pixel_rays(np.array([[0.5, 0.5], [31.5, 23.5], [10.5, 7.5]]))
    h = slab_coordinates(g, o, d)
    assert h.valid.all()
    np.testing.assert_allclose(h.coords[:, :2], [[u, v]] * 3, atol=1e-12)
    np.testing.assert_allclose(h.coords[:, 2:], [[0.5 / 32, 0.5 / 24], [31.5 / 32, 23.5 / 24], [10.5 / 32, 7.5 / 24]],
                               atol=1e-12)


# ---------------------------------------------------------------------------- interpolation, closed forms


def test_plane_on_st_is_exact_for_st_interpolation():
    """A linear texture on the st plane: every uv sample sees the same image, so st-bilinear and
    quadrilinear reproduce it exactly (bilinear reproduces linear functions; edge rays excluded)."""
    g = make_geometry()
    slab = analytic_slab(g, D, texture_linear)
    o, d = random_rays(g, 2000, seed=1, margin=1 / 32 + 1e-3)
    h = slab_coordinates(g, o, d)
    assert h.valid.all()
    ref = exact_radiance(g, h, D, texture_linear)
    for mode in ("st", "quadrilinear"):
        np.testing.assert_allclose(lookup(slab, h, mode), ref, atol=2e-6)
    # nearest st sampling errs by up to half a sample of the gradient: 0.4 * 0.6 / 32 / 2 in red
    err = np.abs(lookup(slab, h, "nearest") - ref).max()
    assert 1e-3 < err <= 0.5 * 0.6 / 32 * 0.4 + 1e-6


@pytest.mark.parametrize("zeta", [0.6, 1.3])
def test_linear_light_field_quadrilinear_exact_and_depth_mode_exact(zeta):
    """Off the st plane the radiance is linear in (u, v, s, t) for a linear texture: quadrilinear
    is exact. The depth-corrected lookup with the true depth is exact too (it re-projects onto st
    where each uv sample sees the focal point, then st-bilinear)."""
    g = make_geometry()
    slab = analytic_slab(g, zeta, texture_linear)
    o, d = random_rays(g, 2000, seed=2, margin=0.2)
    h = slab_coordinates(g, o, d)
    ref = exact_radiance(g, h, zeta, texture_linear)
    np.testing.assert_allclose(lookup(slab, h, "quadrilinear"), ref, atol=2e-6)
    np.testing.assert_allclose(lookup(slab, h, "depth"), ref, atol=2e-6)
    # without depth samples, the focal plane at the true depth gives the same answer
    focal = analytic_slab(g, zeta, texture_linear, with_depth=False, focal=zeta)
    np.testing.assert_allclose(lookup(focal, h, "depth"), ref, atol=2e-6)


def test_fig13_ordering_on_an_off_plane_texture():
    """Levoy-Hanrahan Fig. 13 on an analytic light field: a detailed texture 0.35 D in front of
    the st plane. Mean absolute error over 20000 random rays (seed 3):
    depth-corrected < quadrilinear < uv-only, st-only < nearest."""
    g = make_geometry((8, 8, 48, 48))
    zeta = 0.65
    slab = analytic_slab(g, zeta, texture_wavy)
    o, d = random_rays(g, 20000, seed=3, margin=0.15)
    h = slab_coordinates(g, o, d)
    ref = exact_radiance(g, h, zeta, texture_wavy)
    err = {m: float(np.abs(lookup(slab, h, m) - ref).mean()) for m in MODES}
    assert err["depth"] < err["quadrilinear"] < min(err["uv"], err["st"])
    assert max(err["uv"], err["st"]) < err["nearest"]


# ---------------------------------------------------------------------------- hard cases


def _two_slabs():
    """Slab "a" faces +z (uv at z = -1, st at z = 0.5), slab "b" faces +x (uv at x = -1, st at
    x = 0.5); uv quads 3 x 3, st quads 2 x 2, both centred on the axis through the origin."""
    a_uv = np.array([[-1.5, -1.5, -1], [1.5, -1.5, -1], [1.5, 1.5, -1], [-1.5, 1.5, -1]])
    a_st = np.array([[-1, -1, 0.5], [1, -1, 0.5], [1, 1, 0.5], [-1, 1, 0.5]], float)
    # e_s = +z, e_t = -y: e_s x e_t = +x
    b_uv = np.array([[-1, 1.5, -1.5], [-1, 1.5, 1.5], [-1, -1.5, 1.5], [-1, -1.5, -1.5]], float)
    b_st = np.array([[0.5, 1, -1], [0.5, 1, 1], [0.5, -1, 1], [0.5, -1, -1]], float)
    g1, g2 = SlabGeometry(a_uv, a_st, (4, 4, 8, 8), "a"), SlabGeometry(b_uv, b_st, (4, 4, 8, 8), "b")
    return [LightSlab(g1, np.full(g1.array_shape, 0.25, np.float32)),
            LightSlab(g2, np.full(g2.array_shape, 0.75, np.float32))]


def test_second_slab_geometry_faces_plus_x():
    np.testing.assert_allclose(_two_slabs()[1].geometry.forward, [1, 0, 0], atol=1e-12)


def test_ray_uses_the_slab_it_crosses_most_steeply():
    slabs = _two_slabs()
    d = np.array([[1.0, 0.0, 1.2], [1.2, 0.0, 1.0]])  # both cross both slabs, through the origin
    o = -2 * d
    best, hits = select_slabs(slabs, o, d)
    assert all(h.valid.all() for h in hits)
    np.testing.assert_array_equal(best, [0, 1])
    np.testing.assert_allclose(render_rays(slabs, o, d), [[0.25] * 3, [0.75] * 3])


@pytest.mark.parametrize("mode", MODES)
def test_hard_case_rays_parallel_to_the_planes(mode):
    """Directions perpendicular to forward (denominator exactly 0) and within 1e-9 of it miss
    every slab and get the background; outputs finite."""
    g = make_geometry()
    slab = analytic_slab(g, 0.7, texture_wavy)
    o = np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, -1.0], [0.1, 0.1, 0.5]])
    d = np.array([[1, 0, 0], [0, 1, 1e-9], [1, 1, 0], [0, 0, 0]], float)  # the last one is a zero vector
    h = slab_coordinates(g, o, d)
    assert not h.valid.any()
    for a in (h.uv, h.st, h.coords, h.cos):
        assert np.all(np.isfinite(a))
    out = render_rays([slab], o, d, mode, background=(0.1, 0.2, 0.3))
    np.testing.assert_array_equal(out, np.tile(np.float32([0.1, 0.2, 0.3]), (4, 1)))


@pytest.mark.parametrize("mode", MODES)
def test_hard_case_rays_from_behind_the_planes(mode):
    """An eye beyond the st plane, or looking back from st towards uv, sees the background."""
    g = make_geometry()
    slab = analytic_slab(g, 0.7, texture_wavy)
    o = np.array([[0, 0, 1.5], [0, 0, 1.5], [0, 0, 0.5], [0, 0, -0.5]])
    d = np.array([[0, 0, 1], [0, 0, -1], [0.05, 0, -1], [0, 0, -1]], float)
    assert not slab_coordinates(g, o, d).valid.any()
    out = render_rays([slab], o, d, mode, background=(0.0, 0.5, 0.0))
    np.testing.assert_array_equal(out, np.tile(np.float32([0, 0.5, 0]), (4, 1)))


@pytest.mark.parametrize("mode", MODES)
def test_hard_case_rays_outside_the_slab_extents(mode):
    """Crossing uv inside but st outside, st inside but uv outside, and both far outside: background;
    the same rays hit when the quads are large enough (so the test can fail)."""
    g = make_geometry()
    slab = analytic_slab(g, 0.7, texture_wavy)
    o = np.array([[0, 0, 0.0], [2.0, 0, 0.0], [50, -80, -3]])
    d = np.array([[0.5, 0, 1], [-1.9, 0, 1], [0, 0, 1]], float)
    h = slab_coordinates(g, o, d)
    assert not h.valid.any() and np.all(np.isfinite(h.coords))
    out = render_rays([slab], o, d, mode, background=(1, 1, 1))
    np.testing.assert_array_equal(out, np.ones((3, 3), np.float32))
    big = make_geometry()
    big = SlabGeometry(big.uv_corners * [10, 10, 1], big.st_corners * [10, 10, 1], big.shape)
    assert slab_coordinates(big, o[:2], d[:2]).valid.all()


@pytest.mark.parametrize("mode", MODES)
def test_hard_case_camera_exactly_on_the_uv_plane(mode):
    """A camera whose centre is a uv sample, looking along forward: its view is finite and, for
    a texture on the st plane, equals the texture through st interpolation."""
    g = make_geometry((8, 8, 32, 32))
    slab = analytic_slab(g, D, texture_linear)
    centre = g.uv_sample_points()[3, 4]
    cam = Camera(Intrinsics.from_fov(24, 24, 20.0), look_at(centre, centre + [0, 0, 1], [0, -1, 0]), "on_uv")
    img = render_pinhole([slab], cam, mode)
    assert img.shape == (24, 24, 3) and np.all(np.isfinite(img))
    o, d = cam.pixel_rays()
    h = slab_coordinates(g, o, d)
    assert h.valid.all()
    np.testing.assert_allclose(h.coords[:, :2], np.tile((g.uv_sample_points()[3, 4, :2] + 0.5), (len(o), 1)), atol=1e-12)
    if mode in ("st", "quadrilinear", "depth"):
        np.testing.assert_allclose(img.reshape(-1, 3), exact_radiance(g, h, D, texture_linear), atol=2e-6)


def test_render_rejects_nonfinite_rays_and_unknown_modes():
    slabs = _two_slabs()
    with pytest.raises(ValueError):
        render_rays(slabs, np.array([[0, 0, np.nan]]), np.array([[0, 0, 1.0]]))
    with pytest.raises(ValueError):
        render_rays(slabs, np.zeros((1, 3)), np.array([[0, 0, 1.0]]), mode="bicubic")
    with pytest.raises(ValueError):
        render_rays(slabs, np.zeros((1, 3)), np.array([[0, 0, 1.0]]), background=(0, np.inf, 0))


# ---------------------------------------------------------------------------- files


def test_slab_set_round_trip_memory_mapped(tmp_path):
    slabs = _two_slabs()
    slabs[0].depth = np.full(slabs[0].geometry.array_shape[:4], 0.5, np.float32)
    slabs[1].focal_depth = 1.25
    save_slabs(tmp_path, slabs)
    back = load_slabs(tmp_path)
    assert [s.geometry.to_dict() for s in back] == [s.geometry.to_dict() for s in slabs]
    assert isinstance(back[0].radiance, np.memmap) and back[1].depth is None and back[1].focal_depth == 1.25
    np.testing.assert_array_equal(back[0].depth, slabs[0].depth)
    d = np.array([[1.0, 0.0, 1.2], [1.2, 0.0, 1.0]])
    o = -2 * d
    np.testing.assert_array_equal(render_rays(back, o, d), render_rays(slabs, o, d))


def test_slab_arrays_filled_in_place_and_nonfinite_refused(tmp_path):
    g = make_geometry((2, 2, 4, 4), "inplace")
    rad, depth = create_slab_arrays(tmp_path, g)
    rad[:] = 0.5
    depth[:] = 1.0
    write_slab_index(tmp_path, [LightSlab(g, rad, depth)])
    assert float(load_slabs(tmp_path)[0].radiance[1, 1, 3, 3, 2]) == 0.5
    rad[0, 0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        write_slab_index(tmp_path, [LightSlab(g, rad, depth)])
    (tmp_path / "slabs.json").write_text("{not json")
    with pytest.raises(ValueError, match="slabs.json"):
        load_slabs(tmp_path)


def test_compiled_camera_path_matches_general_ray_lookup():
    """render_pinhole's compiled per-pixel kernels (render/lightfield/kernels.py) agree with the numpy
    per-ray path (slab_coordinates + lookup, float64) in every mode, on two slabs seen by a
    camera whose view straddles the quads' edges and both slabs (so selection matters)."""
    g = make_geometry((8, 8, 32, 32))
    slab = analytic_slab(g, 0.7, texture_wavy)
    c, s_ = np.cos(np.radians(25)), np.sin(np.radians(25))
    rot = np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]])  # the second slab faces +z turned 25 degrees about y
    g2 = make_geometry((4, 6, 16, 20), "other", z0=-0.3)
    g2 = SlabGeometry(g2.uv_corners @ rot.T, g2.st_corners @ rot.T, g2.shape, "other")
    other = LightSlab(g2, np.zeros((6, 4, 20, 16, 3), np.float32))
    other.radiance[:] = np.linspace(0, 1, other.radiance.size, dtype=np.float32).reshape(other.radiance.shape)
    other.depth = np.full(other.geometry.array_shape[:4], 0.9, np.float32)
    eye = np.array([0.2, -0.1, -0.4])
    cam = Camera(Intrinsics(40, 30, 30.0, 30.0, 17.0, 16.0), look_at(eye, [0.1, 0.05, 1.0], [0, -1, 0]), "c")
    o, d = cam.pixel_rays()
    ref_hits = slab_coordinates(g, o, d)
    assert 0 < ref_hits.valid.sum() < len(ref_hits.valid)
    best, _ = select_slabs([slab, other], o, d)
    assert {0, 1} <= set(best.tolist())
    for mode in MODES:
        for threads in (1, 3):
            a = render_pinhole([slab, other], cam, mode, background=(0.2, 0.3, 0.4), threads=threads).reshape(-1, 3)
            b = render_rays([slab, other], o, d, mode=mode, background=(0.2, 0.3, 0.4))
            np.testing.assert_allclose(a, b, atol=1e-5)


# ---------------------------------------------------------------------------- vector-quantized slabs


def lossless_vq(radiance: np.ndarray):
    """Codes and codebook with one codeword per tile, built from the documented layout:
    ray (iv, iu, it, is) = codebook[codes[iv // 2, iu // 2, it // 2, is // 2], iv % 2, iu % 2, it % 2, is % 2]
    (odd counts: the missing rays of an edge tile are left at -1, never looked up)."""
    from render.lightfield import VQRadiance

    nv, nu, nt, ns, _ = radiance.shape
    T = [(n + 1) // 2 for n in (nv, nu, nt, ns)]
    codes = np.arange(np.prod(T), dtype=np.uint16).reshape(T)
    book = np.full((codes.size, 2, 2, 2, 2, 3), -1, np.float32)
    for iv, iu, it, is_ in np.ndindex(nv, nu, nt, ns):
        book[codes[iv // 2, iu // 2, it // 2, is_ // 2], iv % 2, iu % 2, it % 2, is_ % 2] = radiance[iv, iu, it, is_]
    return VQRadiance(codes, book, radiance.shape)


def test_vq_slab_decodes_and_renders_like_the_array():
    """Odd sample counts; decoding reproduces the array exactly, and every mode renders the VQ
    slab exactly as the plain one, through the numpy lookup and the compiled camera path."""
    g = make_geometry((5, 3, 21, 18))
    plain = analytic_slab(g, 0.7, texture_wavy)
    vq = LightSlab(g, lossless_vq(plain.radiance), plain.depth)
    np.testing.assert_array_equal(vq.radiance.decode(), plain.radiance)
    assert vq.nbytes < plain.nbytes * 2 and vq.compressed and not plain.compressed
    o, d = random_rays(g, 3000, seed=5, margin=0.0)
    h = slab_coordinates(g, o, d)
    cam = Camera(Intrinsics(40, 30, 30.0, 30.0, 17.0, 16.0), look_at([0.1, 0.0, -0.5], [0.0, 0.05, 1.0], [0, -1, 0]), "c")
    for mode in MODES:
        np.testing.assert_array_equal(lookup(vq, h, mode), lookup(plain, h, mode))
        np.testing.assert_allclose(render_pinhole([vq], cam, mode), render_pinhole([plain], cam, mode), atol=1e-7)


def test_vq_radiance_rejects_bad_codes():
    from render.lightfield import VQRadiance

    book = np.zeros((4, 2, 2, 2, 2, 3), np.float32)
    with pytest.raises(ValueError, match="codes"):
        VQRadiance(np.zeros((2, 2, 2, 2), np.int32), book, (4, 4, 4, 4, 3))
    with pytest.raises(ValueError, match="beyond"):
        VQRadiance(np.full((2, 2, 2, 2), 4, np.uint16), book, (4, 4, 4, 4, 3))
    with pytest.raises(ValueError, match="codes must be"):
        VQRadiance(np.zeros((2, 2, 2, 2), np.uint16), book, (5, 4, 4, 4, 3))


def test_vq_slab_set_round_trip(tmp_path):
    """Codes LZMA-compressed, one float16 codebook shared by two slabs; non-float16 codebooks refused."""
    from render.lightfield import slab_file_bytes

    g1, g2 = make_geometry((2, 2, 8, 6), "a"), make_geometry((4, 2, 4, 4), "b", z0=0.5)
    r1 = np.round(analytic_slab(g1, 0.7, texture_linear).radiance * 64) / 64
    r2 = np.round(analytic_slab(g2, 0.7, texture_linear).radiance * 64) / 64
    v1, v2 = lossless_vq(r1.astype(np.float32)), lossless_vq(r2.astype(np.float32))
    shared = np.concatenate([v1.codebook, v2.codebook])
    v2.codes += len(v1.codebook)
    v1.codebook = v2.codebook = shared
    depth = np.full(g2.array_shape[:4], 0.875, np.float32)  # float16-exact: stored LZMA float16
    slabs = [LightSlab(g1, v1, None, 0.9), LightSlab(g2, v2, depth)]
    save_slabs(tmp_path, slabs)
    sizes = slab_file_bytes(tmp_path)
    assert sizes["radiance"] == 0 and sizes["codes"] > 0 and sizes["codebook"] > 0
    assert (tmp_path / "b.depth.npy.xz").is_file() and not (tmp_path / "b.depth.npy").exists()
    assert sorted(p.name for p in tmp_path.glob("*codebook*")) == ["codebook.npy"]
    back = load_slabs(tmp_path)
    assert back[0].radiance.codebook is back[1].radiance.codebook and back[0].focal_depth == 0.9
    np.testing.assert_array_equal(back[1].radiance.decode(), r2)
    assert back[1].depth.dtype == np.float16 and np.array_equal(back[1].depth.astype(np.float32), depth)  # kept half
    v1.codebook = shared + np.float32(1e-4)  # not representable in float16
    with pytest.raises(ValueError, match="float16"):
        save_slabs(tmp_path / "bad", [LightSlab(g1, v1)])


@pytest.mark.parametrize("mode", MODES)
def test_hard_case_cameras_along_the_planes_and_beyond_st_compiled_path(mode):
    """The compiled camera path on the hard cases: a camera on the uv plane looking along e_s (its
    centre column is exactly parallel to the planes, half its rays point backwards), and a camera
    beyond the st plane looking back at it. Finite; rays that cannot cross get the background; the
    same as the per-ray numpy path."""
    g = make_geometry((8, 8, 32, 32))
    slab = analytic_slab(g, 0.7, texture_wavy)
    bg = (0.1, 0.2, 0.3)
    along = Camera(Intrinsics(33, 9, 3.1, 3.1, 16.5, 4.5), look_at([0, 0, 0], [1, 0, 0], [0, -1, 0]), "along")
    beyond = Camera(Intrinsics(16, 16, 12.0, 12.0, 8.0, 8.0), look_at([0, 0, 1.5], [0, 0, 0], [0, -1, 0]), "beyond")
    for cam in (along, beyond):
        img = render_pinhole([slab], cam, mode, background=bg)
        assert np.all(np.isfinite(img))
        np.testing.assert_allclose(img.reshape(-1, 3), render_rays([slab], *cam.pixel_rays(), mode=mode, background=bg),
                                   atol=1e-5)
    h = slab_coordinates(g, *along.pixel_rays())
    assert 0 < h.valid.sum() and not h.valid.reshape(9, 33)[:, 16].any()  # the parallel column misses
    np.testing.assert_array_equal(render_pinhole([slab], beyond, mode, background=bg), np.broadcast_to(np.float32(bg), (16, 16, 3)))
