"""Distorted cameras downstream (issue 21, part 3): recon.undistort, and the slab and NeRF stages'
view loading on a capture through a strongly distorting lens.

Closed form first: an image whose every pixel holds the ideal-pinhole position of its own ray
must come back from :func:`recon.undistort.undistort_image` as the identity. Then a tiny capture
through a lens (k1 = -0.4: 11 px at the corners of 128x96) against the same capture without
it: the slab stage's ``load_views`` must hand the rebinning the ideal pinhole images, and the
NeRF's training rays must meet the colours the ideal camera sees along them.
"""
from dataclasses import replace

import numpy as np
import pytest

from recon.undistort import pinhole_of, undistort_image, undistort_maps, undistort_view
from render.camera import Camera, Intrinsics, undistort_normalized

REAL_LENS = Intrinsics(1280, 960, 1318.7891613382187, 1318.7891613382187, 646.3, 474.8,
                       (-0.12, 0.03, 0.0008, -0.0005, 0.0))
TINY_LENS = (-0.4, 0.05, 0.001, -0.001, 0.0)


def _pixel_centres(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    return np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)


def _ideal_position_image(k: Intrinsics) -> np.ndarray:
    """(H, W, 3) float32 distorted image whose pixel holds the ideal-pinhole (x, y) of its ray, 0."""
    jj, ii = _pixel_centres(k)
    xy = undistort_normalized(np.stack([(jj.ravel() - k.cx) / k.fx, (ii.ravel() - k.cy) / k.fy], axis=1), k.dist)
    pos = np.stack([k.fx * xy[:, 0] + k.cx, k.fy * xy[:, 1] + k.cy, np.zeros(len(xy))], axis=1)
    return pos.reshape(k.height, k.width, 3).astype(np.float32)


def test_undistorting_the_ray_position_image_gives_the_identity():
    """real_lens at 1/8 size (160x120): every pinhole pixel is covered (barrel lens) and holds its
    own centre within 5e-4 px (measured 3.5e-4: float32 maps, bilinear on a near-linear field);
    the distorted image itself is up to 3.6 px off (measured), so ignoring the lens fails."""
    k = REAL_LENS.scaled(0.125)
    img = _ideal_position_image(k)
    jj, ii = _pixel_centres(k)
    assert np.abs(img[..., 0] - jj).max() > 3.0  # the lens matters at this size
    out = undistort_image(img, k)
    _, _, valid = undistort_maps(k)
    assert valid.all()
    assert np.abs(out[..., 0] - jj).max() < 5e-4 and np.abs(out[..., 1] - ii).max() < 5e-4


def test_undistort_view_keeps_pose_and_K_resamples_depth_and_mask_with_nearest_and_blanks_the_outside():
    """A pincushion lens (k1 > 0) pulls the pinhole corners outside the distorted frame: there rgb
    and depth are 0 and the mask False; depth and mask take only values present in the input."""
    k = Intrinsics(64, 48, 60.0, 60.0, 32.5, 23.7, (0.3, 0.0, 0.0, 0.0, 0.0))
    pose = np.eye(4)
    pose[:3, 3] = (0.1, -0.2, 0.3)
    cam = Camera(k, pose, "train_000")
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0.2, 1.0, (48, 64, 3)).astype(np.float32)
    depth = rng.choice(np.array([0.0, 1.5, 2.5], np.float32), (48, 64))
    mask = depth > 0
    pin, rgb_u, depth_u, mask_u = undistort_view(cam, rgb, depth, mask)
    assert pin.intrinsics == pinhole_of(k) and not pin.intrinsics.has_distortion and pin.name == cam.name
    assert np.array_equal(pin.cam_to_world, pose)
    assert rgb_u.dtype == np.float32 and depth_u.dtype == np.float32 and mask_u.dtype == np.bool_
    _, _, valid = undistort_maps(k)
    assert 0 < (~valid).sum() < valid.size // 4 and not valid[0, 0] and valid[24, 32]
    assert not rgb_u[~valid].any() and not depth_u[~valid].any() and not mask_u[~valid].any()
    assert set(np.unique(depth_u)) <= {0.0, 1.5, 2.5}
    assert np.array_equal(mask_u, depth_u > 0)  # nearest: the same source pixel for both
    assert rgb_u[valid].min() >= 0.2 - 1e-6  # no black mixed in at the border of the valid region
    same = undistort_view(Camera(pinhole_of(k), pose, "v"), rgb, depth, mask)
    assert same[1] is rgb and same[2] is depth and same[3] is mask


# ----------------------------------------------------------------------------- through the stages


@pytest.fixture(scope="module")
def lens_pair(tmp_path_factory):
    """(distorted capture, ideal capture) of the tiny pipeline scene at 128x96 from 0.4 m (the
    board fills the frame), no noise: the ideal capture rendered once, and its copy through
    TINY_LENS made as the rig's capture makes it (rig.sensor.distort_map: radiance bilinear,
    z-depth nearest), its cameras.json carrying the lens."""
    import shutil

    from pipeline.stages.capture import run_capture
    from render.camera_io import read_cameras_json, write_cameras_json
    from render.image_io import read_exr, write_depth_exr, write_exr
    from rig.build import load_scene
    from rig.sensor import distort_map
    from tests.pipeline.conftest import TINY_SCENE, write_scene

    root = tmp_path_factory.mktemp("undistort")
    rings = {split: [{"ring": {**r["ring"], "distance": 0.4}} for r in TINY_SCENE["cameras"][split]]
             for split in ("train", "test")}
    spec = {**TINY_SCENE, "name": "tiny_ideal", "cameras": {**TINY_SCENE["cameras"], **rings, "intrinsics": {
        "width": 128, "height": 96, "fx": 132.0, "fy": 132.0, "cx": 64.6, "cy": 47.4}}}
    scene = write_scene(root / "scenes", spec, "ideal.yaml")
    ideal, lens = root / "ideal" / "capture", root / "lens" / "capture"
    run_capture(load_scene(scene), scene, ideal, quiet=True)
    shutil.copytree(ideal, lens)
    cams, splits = read_cameras_json(ideal / "cameras.json")
    cams = [Camera(replace(c.intrinsics, dist=TINY_LENS), c.cam_to_world, c.name) for c in cams]
    write_cameras_json(lens / "cameras.json", cams, splits)
    for c in cams:
        write_exr(lens / "linear" / f"{c.name}.exr", distort_map(read_exr(ideal / "linear" / f"{c.name}.exr"), c.intrinsics))
        depth = read_exr(ideal / "depth" / f"{c.name}.exr")
        write_depth_exr(lens / "depth" / f"{c.name}.exr", distort_map(depth.reshape(depth.shape[:2]), c.intrinsics, "nearest"))
    return lens, ideal


def test_slab_load_views_hands_rebinning_the_pinhole_images(lens_pair):
    """load_views of the distorted capture (true cameras, with the lens) against the ideal
    capture's images, where both see a surface: mean |difference| <= 0.02 (measured 0.015-0.017:
    two bilinear resamplings of the sharp board, as much as a 0.5 px blur leaves), at least 2.2x
    below the distorted images as they are (measured 2.8x: 0.042-0.048), which the rebinning's
    ideal-pinhole projection would sample at the wrong pixels (up to 11 px at the corners)."""
    from pipeline.stages.capture import read_cameras
    from pipeline.stages.slab import load_views

    lens, ideal = lens_pair
    cams, splits = read_cameras(lens / "cameras.json")
    train = [c for c, s in zip(cams, splits) if s == "train"]
    assert all(c.intrinsics.has_distortion for c in train)
    views = load_views(lens, train)
    truth = load_views(ideal, [Camera(pinhole_of(c.intrinsics), c.cam_to_world, c.name) for c in train])
    raw = [replace(v) for v in load_views(lens, [Camera(pinhole_of(c.intrinsics), c.cam_to_world, c.name) for c in train])]
    errs, raw_errs = [], []
    for v, t, r in zip(views, truth, raw):
        assert not v.camera.intrinsics.has_distortion and v.camera.intrinsics == t.camera.intrinsics
        seen = (v.depth > 0) & (t.depth > 0)
        assert seen.mean() > 0.1
        errs.append(np.abs(v.rgb - t.rgb)[seen].mean())
        raw_errs.append(np.abs(r.rgb - t.rgb)[seen].mean())
        assert np.abs(v.depth - t.depth)[seen].mean() < 0.01 * t.depth[seen].mean()
    assert max(errs) <= 0.02, errs
    assert all(r > 2.2 * e for r, e in zip(raw_errs, errs)), (errs, raw_errs)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, C) samples of (H, W, C) ``img`` at continuous pixel coordinates (centres at +0.5)."""
    h, w = img.shape[:2]
    fx, fy = np.clip(x - 0.5, 0, w - 1.001), np.clip(y - 0.5, 0, h - 1.001)
    x0, y0 = fx.astype(int), fy.astype(int)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    return ((1 - ay) * ((1 - ax) * img[y0, x0] + ax * img[y0, x0 + 1])
            + ay * ((1 - ax) * img[y0 + 1, x0] + ax * img[y0 + 1, x0 + 1]))


def test_nerf_training_rays_meet_the_colours_the_ideal_camera_sees(lens_pair):
    """The NeRF models the lens in ray generation (Camera.pixel_rays inverts the distortion): each
    training ray of the distorted capture, projected into the ideal capture's camera, finds the
    colour it was trained on. Mean |difference| over the interior <= 1e-3 (measured 1e-7: the
    distorted image was sampled bilinearly from the ideal one at these very rays); rays built as
    if the lens were a pinhole miss by 0.034-0.038 (measured)."""
    from recon.nerf.data import camera_rays, load_data

    lens, ideal = lens_pair
    data = load_data(lens, downsample=1)
    ref = {v.name: v for v in load_data(ideal, downsample=1).train}
    errs, pinhole_errs = [], []
    for v in data.train:
        assert v.camera.intrinsics.has_distortion
        t = ref[v.name]
        k = t.camera.intrinsics
        inner = slice(8, k.height - 8), slice(8, k.width - 8)
        colours = v.rgb[inner].reshape(-1, 3)
        for cam, sink in ((v.camera, errs), (Camera(pinhole_of(v.camera.intrinsics), v.camera.cam_to_world), pinhole_errs)):
            o, d = (a.numpy().astype(np.float64) for a in camera_rays(cam))
            d = d.reshape(k.height, k.width, 3)[inner].reshape(-1, 3)
            o = o.reshape(k.height, k.width, 3)[inner].reshape(-1, 3)
            uv, z = t.camera.project(o + d)
            assert (z > 0).all()
            sink.append(np.abs(_bilinear(t.rgb, uv[:, 0], uv[:, 1]) - colours).mean())
    assert max(errs) <= 1e-3, errs
    assert min(pinhole_errs) > 0.02, pinhole_errs
