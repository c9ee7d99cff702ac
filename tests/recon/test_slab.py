"""recon.slab: layouts around content, direct acquisition assembly, rebinning of captures.

The scene is analytic: a finite Lambertian square in the plane z = 0 (|x|, |y| <= HALF) with a
texture linear in x and y, seen from above. A ray-cast "renderer" gives exact radiance and
z-depth for any pinhole camera, so slabs built from it have closed-form samples.
"""
import numpy as np
import pytest

from recon.slab import (SourceView, DirectConfig, LayoutConfig, RebinConfig, acquire_direct, box_normals,
                        content_bounds, fit_slabs, rebin_slabs, ring_normals, slab_layout, uv_subsamples)
from render.camera import Camera, Intrinsics
from render.poses import look_at
from render.lightfield import load_slabs, render_rays, select_slabs, slab_coordinates

HALF = 0.2
UP = np.array([0.0, 0.0, 1.0])


def texture(p):
    """(..., 2) world x, y -> (..., 3) radiance, linear."""
    x, y = p[..., 0], p[..., 1]
    return np.stack([0.5 + x, 0.5 - y, 0.4 + 0.5 * x + 0.5 * y], axis=-1)


def cast(origins, dirs):
    """Exact radiance (N, 3) and hit distance along z-plane: returns (rgb, point, hit)."""
    dz = dirs[:, 2]
    ok = dz < -1e-12
    lam = np.where(ok, -origins[:, 2] / np.where(ok, dz, -1.0), 0.0)
    P = origins + lam[:, None] * dirs
    hit = ok & (lam > 0) & (np.abs(P[:, 0]) <= HALF) & (np.abs(P[:, 1]) <= HALF)
    rgb = np.where(hit[:, None], texture(P[:, :2]), 0.0)
    return rgb, P, hit


class AnalyticRenderer:
    """render(camera) -> (rgb (H, W, 3) float32, z-depth (H, W) float32), counting calls."""

    def __init__(self):
        self.calls = 0

    def __call__(self, cam: Camera):
        self.calls += 1
        k = cam.intrinsics
        o, d = cam.pixel_rays()
        rgb, P, hit = cast(o, d)
        z = np.where(hit, (P - cam.center) @ cam.cam_to_world[:3, 2], 0.0)
        return rgb.reshape(k.height, k.width, 3).astype(np.float32), z.reshape(k.height, k.width).astype(np.float32)


def ring_eyes(n=12, elevation_deg=60.0, distance=1.0):
    az = 2 * np.pi * np.arange(n) / n
    el = np.radians(elevation_deg)
    return np.stack([distance * np.cos(el) * np.cos(az), distance * np.cos(el) * np.sin(az),
                     np.full(n, distance * np.sin(el))], axis=1)


BOUNDS = np.array([[-HALF, -HALF, -0.01], [HALF, HALF, 0.01]])


@pytest.fixture(scope="module")
def layout():
    return slab_layout(LayoutConfig("ring", count=4, uv_res=4, st_res=24), BOUNDS, ring_eyes(), UP)


# ---------------------------------------------------------------------------- layout


def test_ring_and_box_normals():
    n = ring_normals(8, np.radians(30), UP)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1)
    np.testing.assert_allclose(n @ UP, np.sin(np.radians(30)))
    b = box_normals(UP)
    assert b.shape == (5, 3) and np.allclose(b[-1], UP) and np.allclose(b[:4] @ UP, 0)


def test_layout_planes_and_sizes(layout):
    assert len(layout) == 4
    centre = BOUNDS.mean(0)
    eyes = ring_eyes()
    for g in layout:
        # st plane through the content centre, uv plane among the eyes' distances along forward
        assert abs((g.st_corners[0] - centre) @ g.forward) < 1e-9
        along = (centre - eyes) @ g.forward  # the median is over the cameras this slab serves
        assert along[along > 0].min() - 1e-9 <= g.distance <= along.max() + 1e-9
        assert max(g.shape[:2]) == 4 and max(g.shape[2:]) == 24


def test_layout_covers_every_eye_ray_through_the_content(layout):
    """Every ray from a layout camera through a random content point (seed 0) is served by a slab."""
    rng = np.random.default_rng(0)
    eyes = ring_eyes()
    X = rng.uniform(BOUNDS[0], BOUNDS[1], (500, 3))
    o = np.repeat(eyes, len(X), axis=0)
    d = np.tile(X, (len(eyes), 1)) - o
    best, _ = select_slabs([type("S", (), {"geometry": g})() for g in layout], o, d)
    assert np.all(best >= 0)
    # and a ring far outside the camera region is not (the check can fail)
    far = ring_eyes(elevation_deg=-30.0, distance=3.0)
    best, _ = select_slabs([type("S", (), {"geometry": g})() for g in layout], far[:1].repeat(len(X), 0),
                           X - far[:1])
    assert np.all(best < 0)


def test_content_bounds_trims_outliers():
    rng = np.random.default_rng(1)
    p = np.vstack([rng.uniform(-1, 1, (10000, 3)), [[50, 50, 50]]])
    b = content_bounds(p, 0.1)
    assert np.all(b[1] < 1.0) and np.all(b[0] > -1.0)
    with pytest.raises(ValueError):
        content_bounds(p[:3])


# ---------------------------------------------------------------------------- direct acquisition


def _expected(geom, u, v):
    """Exact radiance (Nt, Ns, 3) and z-depth (Nt, Ns) of the sheared camera at (u, v)."""
    nu, nv, ns, nt = geom.shape
    U = geom.uv_point(u, v)
    c = geom.st_corners
    ss, tt = np.meshgrid((np.arange(ns) + 0.5) / ns, (np.arange(nt) + 0.5) / nt)
    S = c[0] + ss[..., None] * (c[1] - c[0]) + tt[..., None] * (c[3] - c[0])
    d = (S - U).reshape(-1, 3)
    rgb, P, hit = cast(np.broadcast_to(U, d.shape), d)
    z = np.where(hit, (P - U) @ geom.forward, 0.0)
    inner = hit & (np.abs(P[:, :2]).max(1) < HALF - 0.03)  # away from the square's border
    return rgb.reshape(nt, ns, 3), z.reshape(nt, ns), inner.reshape(nt, ns)


def test_direct_acquisition_samples_the_sheared_cameras(layout, tmp_path):
    r = AnalyticRenderer()
    slabs = acquire_direct(layout[:2], r, tmp_path)
    assert r.calls == sum(g.shape[0] * g.shape[1] for g in layout[:2])
    for s in slabs:
        g = s.geometry
        nu, nv = g.shape[:2]
        for j, i in ((0, 0), (nv - 1, nu - 1), (nv // 2, 1)):
            rgb, z, _ = _expected(g, (i + 0.5) / nu, (j + 0.5) / nv)
            np.testing.assert_allclose(s.radiance[j, i], rgb, atol=1e-5)
            np.testing.assert_allclose(s.depth[j, i], z, atol=1e-5)
    back = load_slabs(tmp_path)
    assert [b.geometry.name for b in back] == [g.name for g in layout[:2]]


def test_direct_acquisition_aperture_prefilter(layout, tmp_path):
    """uv_supersample=2 averages 4 cameras over the uv cell (and renders the centre once more for
    depth); st_supersample=2 box-filters 2x2 pixels."""
    g = layout[0]
    r = AnalyticRenderer()
    (s,) = acquire_direct([g], r, tmp_path, DirectConfig(uv_supersample=2, st_supersample=2))
    nu, nv = g.shape[:2]
    assert r.calls == nu * nv * 5
    i, j = nu - 1, nv - 1
    fine = g.__class__(g.uv_corners, g.st_corners, (g.shape[0], g.shape[1], 2 * g.shape[2], 2 * g.shape[3]), g.name)
    acc = 0
    for v in uv_subsamples(j, nv, 2):
        for u in uv_subsamples(i, nu, 2):
            rgb, _, _ = _expected(fine, u, v)
            acc = acc + rgb.reshape(g.shape[3], 2, g.shape[2], 2, 3).mean((1, 3))
    np.testing.assert_allclose(s.radiance[j, i], acc / 4, atol=1e-5)
    assert np.all(np.isfinite(s.depth)) and (s.depth > 0).any()


def test_direct_acquisition_rejects_bad_renders(layout, tmp_path):
    def nan_render(cam):
        rgb, z = AnalyticRenderer()(cam)
        rgb[0, 0, 0] = np.nan
        return rgb, z

    with pytest.raises(ValueError, match="non-finite"):
        acquire_direct(layout[:1], nan_render, tmp_path)
    with pytest.raises(ValueError, match="renderer returned"):
        acquire_direct(layout[:1], lambda cam: (np.zeros((2, 2, 3)), np.zeros((2, 2))), tmp_path / "b")


# ---------------------------------------------------------------------------- rebinning


@pytest.fixture(scope="module")
def captures():
    """16 analytic views on two rings (48 x 40 pixels) of the textured square."""
    r = AnalyticRenderer()
    k = Intrinsics.from_fov(48, 40, 40.0)
    views = []
    for el, off in ((45.0, 0.0), (70.0, 0.4)):
        for n, e in enumerate(ring_eyes(8, el, 1.0)):
            Rz = np.array([[np.cos(off), -np.sin(off), 0], [np.sin(off), np.cos(off), 0], [0, 0, 1]])
            cam = Camera(k, look_at(Rz @ e, [0, 0, 0], UP), f"v{el:.0f}_{n}")
            rgb, z = r(cam)
            views.append(SourceView(cam, rgb, z))
    return views


def test_rebinning_fills_surface_rays_with_the_true_radiance(layout, captures, tmp_path):
    slabs, stats = rebin_slabs(layout[:2], captures, tmp_path, RebinConfig(cameras_per_ray=2, candidates=6),
                               background=(0.0, 0.0, 0.0))
    assert stats.coverage > 0.97 and 0.05 < stats.surface_fraction < 0.95
    for s in slabs:
        g = s.geometry
        nu, nv = g.shape[:2]
        for j, i in ((0, 0), (nv - 1, nu - 1), (nv // 2, 1)):
            rgb, z, inner = _expected(g, (i + 0.5) / nu, (j + 0.5) / nv)
            got, zz = np.asarray(s.radiance[j, i]), np.asarray(s.depth[j, i])
            surface = (z > 0) & (zz > 0)
            # the proxy finds the surface where it is (splats quantize to the st sample), and the
            # blended views agree with the closed form up to their bilinear sampling
            assert surface.sum() > 0.9 * (z > 0).sum()
            np.testing.assert_allclose(zz[surface], z[surface], rtol=0.02)
            filled = surface & (got.sum(-1) > 0)
            assert filled.sum() > 0.9 * surface.sum()
            # away from the border (where the views' pixels mix the square with the background)
            sel = filled & inner
            assert sel.sum() > 0.5 * inner.sum() > 0
            assert np.abs(got[sel] - rgb[sel]).max() < 0.02
            # rays beyond the square hit nothing: background, depth 0
            empty = (z == 0) & (zz == 0)
            assert empty.any() and np.all(got[empty] == 0)


def test_rebinning_bad_input(layout, captures, tmp_path):
    bad = [SourceView(captures[0].camera, captures[0].rgb[:10], captures[0].depth)]
    with pytest.raises(ValueError, match="do not match"):
        rebin_slabs(layout[:1], bad, tmp_path)
    empty = [SourceView(c.camera, c.rgb, np.zeros_like(c.depth)) for c in captures[:2]]
    with pytest.raises(ValueError, match="no captured view has depth"):
        rebin_slabs(layout[:1], empty, tmp_path / "e")
    with pytest.raises(ValueError):
        rebin_slabs(layout[:1], [], tmp_path / "n")


def test_rebinned_slab_renders_a_novel_view(captures, tmp_path):
    """A view between the capture rings, rendered from slabs laid out for the capture cameras and
    rebinned from them, with depth correction, matches the ray-cast truth where both see the square."""
    eyes = np.stack([v.camera.center for v in captures])
    layout = slab_layout(LayoutConfig("ring", count=6, uv_res=6, st_res=32), BOUNDS, eyes, UP)
    slabs, _ = rebin_slabs(layout, captures, tmp_path)
    cam = Camera(Intrinsics.from_fov(40, 32, 40.0), look_at(ring_eyes(7, 58.0, 1.0)[2], [0, 0, 0], UP), "novel")
    o, d = cam.pixel_rays()
    truth, _, hit = cast(o, d)
    img = render_rays(slabs, o, d, "depth")
    assert np.all(np.isfinite(img))
    inner = hit & (np.abs(cast(o, d)[1][:, :2]).max(1) < HALF - 0.02)  # away from the square's edges
    assert inner.sum() > 100
    assert np.abs(img[inner] - truth[inner]).mean() < 0.01


# ---------------------------------------------------------------------------- compression (VQ)


def test_tiles_follow_the_vq_code_layout():
    """tiles_of orders tiles as VQRadiance codes and rays within a tile as its codebook entries:
    one codeword per tile decodes to the array exactly (odd counts included)."""
    from recon.slab.compress import tiles_of
    from render.lightfield import VQRadiance

    r = np.random.default_rng(0).random((3, 4, 5, 7, 3)).astype(np.float32)
    t = tiles_of(r)
    T = (2, 2, 3, 4)
    assert t.shape == (np.prod(T), 48)
    vq = VQRadiance(np.arange(len(t), dtype=np.uint16).reshape(T), t.reshape(-1, 2, 2, 2, 2, 3), r.shape)
    np.testing.assert_array_equal(vq.decode(), r)
    np.testing.assert_array_equal(tiles_of(r, slice(1, 2)), t[np.prod(T[1:]):])


def test_kmeans_recovers_separated_clusters():
    """Four well-separated Gaussian blobs (sigma 0.01, centres 1 apart; seed 1): Lloyd's centroids
    are the blobs' sample means, within 5 standard errors sigma / sqrt(n) of the true centres in
    every coordinate (n = 500 per blob)."""
    import torch

    from recon.slab.compress import kmeans

    rng = np.random.default_rng(1)
    centres = np.eye(4, 6) * 1.0
    x = np.concatenate([c + 0.01 * rng.standard_normal((500, 6)) for c in centres]).astype(np.float32)
    c = kmeans(torch.from_numpy(x), 4, 10, torch.Generator().manual_seed(1)).numpy()
    err = np.abs(c[:, None] - centres[None]).max(-1).min(0)  # each true centre's nearest centroid
    assert np.all(err < 5 * 0.01 / np.sqrt(500))


def test_compress_slabs_exact_on_few_distinct_tiles_and_error_accounting():
    """A light field of three distinct float16-exact tiles plus a black background (the most
    frequent tile): a 16-entry codebook codes it exactly, the background by the fixed entry; a
    textured slab's reported RMSE equals the decoded array's, and a larger codebook lowers it."""
    from recon.slab.compress import VQConfig, compress_slabs
    from render.lightfield import LightSlab, SlabGeometry

    uv = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]])
    g = SlabGeometry(uv, uv * [0.6, 0.6, 1] + [0, 0, 1], (6, 4, 16, 12))
    rad = np.zeros(g.array_shape, np.float32)
    rad[:2, :, :4] = [0.25, 0.5, 0.75]
    rad[2:4, :, 4:8] = [0.5, 0.125, 0.0]
    rad[4:, :2, 8:, :6] = 1.0
    out, stats = compress_slabs([LightSlab(g, rad)], VQConfig(codebook_size=16, groups=4, sample=len(rad.reshape(-1)) // 48,
                                                           iterations=6, seed=2))
    np.testing.assert_array_equal(out[0].radiance.decode(), rad)
    assert stats.rmse == 0.0 and stats.codebook_entries <= 16
    rng = np.random.default_rng(3)
    tex = (np.round(rng.random(g.array_shape) * 8) / 8).astype(np.float32)
    rmse = []
    for k in (16, 256):
        (s,), st = compress_slabs([LightSlab(g, tex)], VQConfig(codebook_size=k, groups=4, sample=1024, iterations=6))
        assert st.rmse == pytest.approx(np.sqrt(np.mean((s.radiance.decode() - tex) ** 2.0)), rel=1e-5)
        rmse.append(st.rmse)
    assert rmse[1] < rmse[0]


# ---------------------------------------------------------------------------- st sampling from the pixel footprint


def test_st_density_closed_form():
    """A camera at distance r tilted by a from the plane's normal within the (e_s, normal) plane:
    a pixel covers r / f metres along e_t and r / (f cos a) along e_s."""
    from recon.slab import st_density

    r, f, a = 1.5, 800.0, np.radians(35.0)
    eye = r * np.array([np.sin(a), 0.0, np.cos(a)])
    dens = st_density(np.zeros(3), eye[None], [f], (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])))
    np.testing.assert_allclose(dens, [f * np.cos(a) / r, f / r], rtol=1e-12)
    # the most head-on camera sets the density: a second, straight-on one raises e_s's to f / r
    both = st_density(np.zeros(3), np.stack([eye, [0, 0, r]]), [f, f], (np.array([1.0, 0, 0]),))
    np.testing.assert_allclose(both, [f / r], rtol=1e-12)


@pytest.mark.parametrize("focal", [400.0, 1000.0])
def test_st_resolution_follows_the_capture_pixel_footprint(focal):
    """One slab facing one camera straight on at distance r: st counts are ceil(side x f / r x
    st_per_pixel) per side, so they follow the capture's focal length (fails when st ignores the
    footprint, e.g. a fixed st_res: same counts at both focal lengths); a fixed st_res overrides."""
    r = 1.2
    eyes = np.array([[0.0, 0.0, r]])
    for per_pixel in (1.0, 0.5):
        (g,) = fit_slabs(np.array([[0.0, 0, 1]]), BOUNDS, eyes, [0, 1.0, 0], uv_res=2, st_res=None,
                         focal_px=focal, st_per_pixel=per_pixel)
        ws, ht = g.st_size
        assert g.shape[2:] == (int(np.ceil(per_pixel * ws * focal / r)), int(np.ceil(per_pixel * ht * focal / r)))
    (fixed,) = fit_slabs(np.array([[0.0, 0, 1]]), BOUNDS, eyes, [0, 1.0, 0], uv_res=2, st_res=30, focal_px=focal)
    assert max(fixed.shape[2:]) == 30
    with pytest.raises(ValueError, match="focal"):
        fit_slabs(np.array([[0.0, 0, 1]]), BOUNDS, eyes, [0, 1.0, 0], st_res=None)


@pytest.mark.parametrize("cfg", [RebinConfig(), RebinConfig(cameras_per_ray=2, candidates=6),
                                 RebinConfig(cameras_per_ray=4, candidates=40)])
def test_compiled_blend_matches_the_numpy_reference(captures, cfg):
    """The compiled per-ray blend against its numpy reference on rays towards points near and off
    the square (seen, occluded, outside every view), with more and fewer candidates than views."""
    from recon.slab.rebin import _blend_rays, _blend_rays_numpy, _Views
    rng = np.random.default_rng(3)
    n = 4000
    P = np.concatenate([rng.uniform(-HALF, HALF, (n, 3)) * [1, 1, 0],         # on the square
                        rng.uniform(-0.6, 0.6, (n, 3))])                      # anywhere: mostly unseen
    eye = rng.normal(size=(2 * n, 3))
    eye[:, 2] = np.abs(eye[:, 2]) + 0.3
    r = P - eye
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    views = _Views(captures)
    want, want_ok = _blend_rays_numpy(views, P, r, cfg, 0.01)
    got, got_ok = _blend_rays(views, P, r, cfg, 0.01)
    assert 0.2 < want_ok.mean() < 0.9                       # both kinds of ray are exercised
    np.testing.assert_array_equal(got_ok, want_ok)
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert np.all(got[~got_ok] == 0)


@pytest.mark.parametrize("voxel", [0.004, 0.03])
def test_compiled_splat_matches_the_numpy_reference(layout, captures, voxel, monkeypatch):
    """The compiled depth splat (nearest point per st sample, single holes closed) is the numpy
    reference's, sample for sample, on a dense and a sparse point cloud (where holes are closed)."""
    import recon.slab.rebin as rebin
    cloud = rebin.point_cloud(captures, voxel)
    for geom in layout[:2]:
        want = rebin.splat_depth_numpy(geom, cloud)
        assert 0.05 < (want > 0).mean() < 0.95
        np.testing.assert_array_equal(rebin.splat_depth(geom, cloud), want)
        if voxel > 0.01:
            with monkeypatch.context() as m:
                m.setattr(rebin, "_fill_single_holes", lambda z: z)
                assert (rebin.splat_depth_numpy(geom, cloud) > 0).sum() < (want > 0).sum()  # holes were closed
