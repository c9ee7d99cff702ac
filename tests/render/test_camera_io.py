"""Camera exporters: each format round-trips, and the COLMAP model reads back in pycolmap."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pycolmap
import pytest

from render.camera import Camera, Intrinsics
from render.camera_io import (
    ColmapPoints, read_cameras_json, read_colmap_model, read_colmap_text, read_transforms_json, write_cameras_json,
    write_colmap_model, write_colmap_text, write_transforms_json,
)
from render.poses import invert_rigid, look_at

PINHOLE = Intrinsics(320, 240, 300.0, 302.5, 160.25, 119.75)
OPENCV = Intrinsics(320, 240, 310.0, 309.0, 158.5, 121.0, (-0.12, 0.05, 0.0015, -0.001, 0.0))
FULL = Intrinsics(640, 480, 520.0, 515.0, 318.7, 242.2, (-0.12, 0.05, 0.0015, -0.001, -0.01))


def _ring(intrinsics: list[Intrinsics], seed: int = 0) -> list[Camera]:
    """Cameras on a jittered ring around the origin (+Z up), looking at jittered targets."""
    rng = np.random.default_rng(seed)
    cams = []
    for i, k in enumerate(intrinsics):
        a = 2 * np.pi * i / len(intrinsics)
        eye = np.array([3 * np.cos(a), 3 * np.sin(a), 1.0]) + rng.normal(scale=0.1, size=3)
        cams.append(Camera(k, look_at(eye, rng.normal(scale=0.2, size=3), (0, 0, 1)), f"view_{i:03d}"))
    return cams


@pytest.fixture
def shared_cams() -> list[Camera]:
    return _ring([OPENCV] * 6)


@pytest.fixture
def mixed_cams() -> list[Camera]:
    return _ring([PINHOLE, OPENCV, FULL, PINHOLE, FULL, OPENCV, PINHOLE], seed=1)


def _assert_same_cameras(a: list[Camera], b: list[Camera], atol: float = 1e-9) -> None:
    assert len(a) == len(b)
    for ca, cb in zip(a, b):
        assert ca.name == cb.name
        ka, kb = ca.intrinsics, cb.intrinsics
        assert (ka.width, ka.height) == (kb.width, kb.height)
        np.testing.assert_allclose([ka.fx, ka.fy, ka.cx, ka.cy], [kb.fx, kb.fy, kb.cx, kb.cy], rtol=0, atol=atol)
        np.testing.assert_allclose(ka.dist, kb.dist, rtol=0, atol=atol)
        np.testing.assert_allclose(ca.cam_to_world, cb.cam_to_world, rtol=0, atol=atol)


def _no_partial_files(d: Path) -> None:
    assert not [p.name for p in Path(d).rglob("*") if ".partial" in p.name]


def _names(cams, fmt="images/{}.png"):
    return [fmt.format(c.name) for c in cams]


# --------------------------------------------------------------------------- cameras.json


@pytest.mark.parametrize("which", ["shared_cams", "mixed_cams"])
def test_cameras_json_round_trip_is_lossless(which, request, tmp_path):
    cams = request.getfixturevalue(which)
    splits = ["train" if i % 3 else "test" for i in range(len(cams))]
    write_cameras_json(tmp_path / "cameras.json", cams, splits)
    back, back_splits = read_cameras_json(tmp_path / "cameras.json")
    assert back_splits == splits
    for a, b in zip(cams, back):
        assert a.name == b.name and a.intrinsics == b.intrinsics
        np.testing.assert_array_equal(a.cam_to_world, b.cam_to_world)  # bit-exact
    doc = json.loads((tmp_path / "cameras.json").read_text())
    conv = doc["convention"]
    assert "OpenCV" in conv["camera_frame"] and "j + 0.5" in conv["pixel_centers"]
    _no_partial_files(tmp_path)


def test_cameras_json_rejects_bad_input(shared_cams, tmp_path):
    with pytest.raises(ValueError, match="split"):
        write_cameras_json(tmp_path / "c.json", shared_cams, ["train"] * (len(shared_cams) - 1) + ["val"])
    with pytest.raises(ValueError, match="labels"):
        write_cameras_json(tmp_path / "c.json", shared_cams, ["train"])
    dup = [shared_cams[0], Camera(PINHOLE, shared_cams[1].cam_to_world, shared_cams[0].name)]
    with pytest.raises(ValueError, match="unique"):
        write_cameras_json(tmp_path / "c.json", dup, ["train", "test"])
    scaled = np.diag([2.0, 2.0, 2.0, 1.0])
    with pytest.raises(ValueError, match="rigid"):
        write_cameras_json(tmp_path / "c.json", [Camera(PINHOLE, scaled, "a")], ["train"])
    assert not (tmp_path / "c.json").exists()
    (tmp_path / "other.json").write_text('{"frames": []}')
    with pytest.raises(ValueError, match="format"):
        read_cameras_json(tmp_path / "other.json")
    with pytest.raises(FileNotFoundError):
        read_cameras_json(tmp_path / "missing.json")


# --------------------------------------------------------------------------- COLMAP (through pycolmap)

COLMAP_FILES = ["cameras", "frames", "images", "points3D", "rigs"]  # COLMAP >= 3.12's model


@pytest.mark.parametrize("binary", [False, True], ids=["text", "binary"])
@pytest.mark.parametrize("which", ["shared_cams", "mixed_cams"])
def test_colmap_round_trip(which, binary, request, tmp_path):
    cams = request.getfixturevalue(which)
    write_colmap_model(tmp_path, cams, _names(cams), binary=binary)
    ext = "bin" if binary else "txt"
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{f}.{ext}" for f in COLMAP_FILES]
    _assert_same_cameras(cams, read_colmap_model(tmp_path))


def _points_seen_by(cams, n=30, seed=3) -> ColmapPoints:
    """n points near the origin, each observed where it projects in every camera (a full track)."""
    rng = np.random.default_rng(seed)
    xyz = rng.normal(scale=0.4, size=(n, 3))
    obs = [(i, c, c_cam.project(xyz[i:i + 1])[0][0]) for i in range(n) for c, c_cam in enumerate(cams)]
    return ColmapPoints(xyz=xyz, rgb=rng.integers(0, 256, size=(n, 3), dtype=np.uint8),
                        obs_point=np.array([o[0] for o in obs]), obs_image=np.array([o[1] for o in obs]),
                        obs_xy=np.array([o[2] for o in obs]))


@pytest.mark.parametrize("binary", [False, True], ids=["text", "binary"])
def test_colmap_points_and_tracks_load_in_pycolmap(binary, mixed_cams, tmp_path):
    """COLMAP's own reader gets every point, colour and track, and its own projection of each point
    lands on the observation written for it (1e-7 px): the points, tracks and poses agree."""
    pts = _points_seen_by(mixed_cams)
    write_colmap_model(tmp_path, mixed_cams, _names(mixed_cams), pts, binary=binary)
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert rec.num_points3D() == len(pts.xyz) and rec.num_reg_images() == len(mixed_cams)
    for pid, point in rec.points3D.items():
        i = pid - 1  # ids 1..P in order
        np.testing.assert_array_equal(point.xyz, pts.xyz[i])
        np.testing.assert_array_equal(point.color, pts.rgb[i])
        assert point.track.length() == len(mixed_cams)
        for el in point.track.elements:
            im = rec.images[el.image_id]
            xy = np.asarray(im.points2D[el.point2D_idx].xy)
            assert im.points2D[el.point2D_idx].point3D_id == pid
            np.testing.assert_allclose(np.asarray(im.project_point(point.xyz)).ravel(), xy, atol=1e-7)
    assert rec.compute_mean_reprojection_error() == pytest.approx(0.0, abs=1e-7)


def test_colmap_one_camera_per_distinct_intrinsics_and_model_choice(mixed_cams, tmp_path):
    write_colmap_text(tmp_path, mixed_cams, _names(mixed_cams))
    lines = [ln.split() for ln in (tmp_path / "cameras.txt").read_text().splitlines() if not ln.startswith("#")]
    assert [(ln[0], ln[1], len(ln) - 4) for ln in lines] == [
        ("1", "PINHOLE", 4), ("2", "OPENCV", 8), ("3", "FULL_OPENCV", 12)]
    images = [ln.split() for ln in (tmp_path / "images.txt").read_text().splitlines() if not ln.startswith("#")]
    records = images[0::2]
    assert [r[0] for r in records] == [str(i) for i in range(1, len(mixed_cams) + 1)]
    assert [r[8] for r in records] == ["1", "2", "3", "1", "3", "2", "1"]
    assert [r[9] for r in records] == _names(mixed_cams)
    assert all(ln == [] for ln in images[1::2])  # empty POINTS2D lines


@pytest.mark.parametrize("which", ["shared_cams", "mixed_cams"])
def test_colmap_text_loads_in_pycolmap(which, request, tmp_path):
    cams = request.getfixturevalue(which)
    write_colmap_text(tmp_path, cams, _names(cams))
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert rec.num_images() == len(cams)
    assert rec.num_cameras() == len({c.intrinsics for c in cams})
    assert rec.num_points3D() == 0
    by_name = {im.name: im for im in rec.images.values()}
    pts = np.random.default_rng(2).normal(scale=0.5, size=(20, 3))  # near the origin, in view
    for cam, name in zip(cams, _names(cams)):
        im = by_name[name]
        centre = np.asarray(im.projection_center()).ravel()
        np.testing.assert_allclose(centre, cam.center, rtol=1e-6, atol=1e-12)
        cfw = im.cam_from_world().matrix()  # (3, 4) world-to-camera
        np.testing.assert_allclose(cfw, cam.world_to_cam[:3], atol=1e-9)
        pc = rec.cameras[im.camera_id]
        k = cam.intrinsics
        assert (pc.width, pc.height) == (k.width, k.height)
        assert (pc.focal_length_x, pc.focal_length_y) == pytest.approx((k.fx, k.fy), rel=1e-12)
        assert (pc.principal_point_x, pc.principal_point_y) == pytest.approx((k.cx, k.cy), rel=1e-12)
        expected_model = "PINHOLE" if not k.has_distortion else ("OPENCV" if k.dist[4] == 0 else "FULL_OPENCV")
        assert pc.model.name == expected_model
        if k.has_distortion:
            np.testing.assert_allclose(pc.params[4:8], k.dist[:4], rtol=1e-12)
            if expected_model == "FULL_OPENCV":
                np.testing.assert_allclose(pc.params[8:], [k.dist[4], 0, 0, 0], rtol=1e-12)
        # COLMAP's own projection (its distortion model, its principal point) agrees with ours
        uv, z = cam.project(pts)
        assert np.all(z > 0)
        uv_colmap = np.array([np.asarray(im.project_point(p)).ravel() for p in pts])
        np.testing.assert_allclose(uv_colmap, uv, atol=1e-7)


def test_colmap_reader_accepts_colmap_written_model(mixed_cams, tmp_path):
    # pycolmap re-writes our model (its own formatting, rigs/frames files): still readable
    write_colmap_text(tmp_path / "ours", mixed_cams, _names(mixed_cams))
    rec = pycolmap.Reconstruction(str(tmp_path / "ours"))
    (tmp_path / "theirs").mkdir()
    rec.write_text(str(tmp_path / "theirs"))
    _assert_same_cameras(mixed_cams, read_colmap_text(tmp_path / "theirs"), atol=1e-9)


def test_colmap_reader_models_and_errors(tmp_path):
    (tmp_path / "cameras.txt").write_text(
        "# c\n1 SIMPLE_PINHOLE 100 80 90 50 40\n2 SIMPLE_RADIAL 100 80 90 50 40 0.01\n3 OPENCV_FISHEYE 1 1 1 1 1 1 0 0 0 0\n")
    (tmp_path / "images.txt").write_text("# i\n1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 0 0 1 2 b.png\n\n")
    (tmp_path / "points3D.txt").write_text("")
    with pytest.raises(ValueError, match="OPENCV_FISHEYE"):
        read_colmap_text(tmp_path)
    (tmp_path / "cameras.txt").write_text("1 SIMPLE_PINHOLE 100 80 90 50 40\n2 SIMPLE_RADIAL 100 80 90 50 40 0.01\n")
    a, b = read_colmap_text(tmp_path)
    assert a.name == "a" and a.intrinsics == Intrinsics(100, 80, 90.0, 90.0, 50.0, 40.0)
    assert b.intrinsics.dist == (0.01, 0.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(b.center, [0, 0, -1])  # t = (0, 0, 1), R = I  ->  C = -t
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 7 a.png\n\n")
    with pytest.raises(ValueError, match="unreadable COLMAP model .*ID 7"):
        read_colmap_text(tmp_path)


def test_colmap_writer_rejects_bad_names(shared_cams, tmp_path):
    with pytest.raises(ValueError, match="whitespace"):
        write_colmap_text(tmp_path, shared_cams, ["my image.png"] + _names(shared_cams)[1:])
    with pytest.raises(ValueError, match="unique"):
        write_colmap_text(tmp_path, shared_cams, ["a.png"] * len(shared_cams))
    with pytest.raises(ValueError, match="names for"):
        write_colmap_text(tmp_path, shared_cams, ["a.png"])
    assert not list(tmp_path.iterdir())


# --------------------------------------------------------------------------- transforms.json


@pytest.mark.parametrize("which", ["shared_cams", "mixed_cams"])
def test_transforms_json_round_trip(which, request, tmp_path):
    cams = request.getfixturevalue(which)
    write_transforms_json(tmp_path / "transforms.json", cams, _names(cams))
    _assert_same_cameras(cams, read_transforms_json(tmp_path / "transforms.json"))
    _no_partial_files(tmp_path)


def test_transforms_json_layout_shared(shared_cams, tmp_path):
    write_transforms_json(tmp_path / "t.json", shared_cams, _names(shared_cams))
    doc = json.loads((tmp_path / "t.json").read_text())
    k = OPENCV
    assert doc["camera_model"] == "OPENCV"
    assert {key: doc[key] for key in ("fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2")} == {
        "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height,
        "k1": k.dist[0], "k2": k.dist[1], "p1": k.dist[2], "p2": k.dist[3]}
    assert "k3" not in doc  # zero k3 is left out
    for cam, f in zip(shared_cams, doc["frames"]):
        assert set(f) == {"file_path", "transform_matrix"}
        m = np.array(f["transform_matrix"])
        # OpenGL axes: the camera looks along its -z, its +y is the image's up
        np.testing.assert_allclose(m[:3, 3], cam.center)
        np.testing.assert_allclose(m[:3, 2], -cam.cam_to_world[:3, 2], atol=1e-15)
        np.testing.assert_allclose(m[:3, 1], -cam.cam_to_world[:3, 1], atol=1e-15)
        np.testing.assert_allclose(m[:3, 0], cam.cam_to_world[:3, 0], atol=1e-15)
        target_gl = invert_rigid(m) @ np.array([0, 0, 0, 1.0])  # the ring looks at ~origin
        assert target_gl[2] < 0


def test_transforms_json_layout_mixed(mixed_cams, tmp_path):
    write_transforms_json(tmp_path / "t.json", mixed_cams, _names(mixed_cams))
    doc = json.loads((tmp_path / "t.json").read_text())
    assert doc["camera_model"] == "OPENCV"
    assert not {"fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "p1", "p2"} & set(doc)
    for cam, f in zip(mixed_cams, doc["frames"]):
        assert f["fl_x"] == cam.intrinsics.fx and f["cx"] == cam.intrinsics.cx and f["w"] == cam.intrinsics.width
        assert ("k3" in f) == (cam.intrinsics.dist[4] != 0)


def test_transforms_json_pinhole_model(tmp_path):
    cams = _ring([PINHOLE] * 3)
    write_transforms_json(tmp_path / "t.json", cams, _names(cams))
    assert json.loads((tmp_path / "t.json").read_text())["camera_model"] == "PINHOLE"


def test_transforms_json_reader_follows_nerfstudio_key_rule(tmp_path):
    # top-level keys are defaults; a frame's own key wins (nerfstudio's parser reads per key)
    m = np.eye(4).tolist()
    doc = {"w": 100, "h": 80, "cx": 50.0, "cy": 40.0, "fl_x": 90.0, "fl_y": 91.0, "k1": 0.1,
           "frames": [{"file_path": "images/a.png", "transform_matrix": m},
                      {"file_path": "./images/b.jpg", "transform_matrix": m, "fl_x": 70.0, "fl_y": 71.0}]}
    (tmp_path / "t.json").write_text(json.dumps(doc))
    a, b = read_transforms_json(tmp_path / "t.json")
    assert a.name == "a" and b.name == "b"
    assert (a.intrinsics.fx, b.intrinsics.fx, b.intrinsics.fy, b.intrinsics.cx) == (90.0, 70.0, 71.0, 50.0)
    assert a.intrinsics.dist == (0.1, 0.0, 0.0, 0.0, 0.0)
    np.testing.assert_array_equal(a.cam_to_world, np.diag([1.0, -1.0, -1.0, 1.0]))
    del doc["fl_x"]
    (tmp_path / "t.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="fl_x"):
        read_transforms_json(tmp_path / "t.json")
