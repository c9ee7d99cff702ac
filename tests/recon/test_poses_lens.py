"""The lens recovered (issue 21, goal 2) through the real CLI process, on a small distorted capture.

The capture is ``scenes/real_lens.yaml`` shrunk to 400x300 (its lens scaled with it, the principal
point kept 6.3 / -5.2 px off centre, its noise and vignetting kept) with 16 + 4 views from 0.6 m,
so the board fills the frame and the features reach 77% of the half-diagonal (the default
distance, 1.1 m, leaves the lens outside the subject unmeasured). ``poses --method colmap
--self-calibrate`` must give back the true camera; the figures of one run are in each assert.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from render.camera_io import read_cameras_json

REPO = Path(__file__).resolve().parents[2]
OFFSET = (6.3, -5.2)  # principal point from the image centre, px


def lumigraph(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=1800, env={**os.environ, "PYOPENGL_PLATFORM": "egl"})


def small_real_lens() -> dict:
    """scenes/real_lens.yaml at 400x300 (focal scaled, principal point OFFSET from the centre),
    rings of 8 + 8 train views at 30 / 50 deg and 4 held out at 40 deg, 0.6 m from the target."""
    spec = yaml.safe_load((REPO / "scenes" / "real_lens.yaml").read_text())
    spec["name"] = "real_lens_small"
    k = spec["cameras"]["intrinsics"]
    s = 400 / k["width"]
    k.update(width=400, height=300, fx=k["fx"] * s, fy=k["fy"] * s, cx=200 + OFFSET[0], cy=150 + OFFSET[1])
    ring = {"distance": 0.6, "target": [0, 0, 0.05]}
    spec["cameras"]["train"] = [{"ring": {**ring, "elevation_deg": 30, "count": 8}},
                                {"ring": {**ring, "elevation_deg": 50, "count": 8, "azimuth_offset_deg": 22.5}}]
    spec["cameras"]["test"] = [{"ring": {**ring, "elevation_deg": 40, "count": 4, "azimuth_offset_deg": 45}}]
    return spec


@pytest.fixture(scope="module")
def self_calibrated(tmp_path_factory):
    """(capture folder, poses folder, CLI stdout) of one ``poses --self-calibrate`` run."""
    root = tmp_path_factory.mktemp("lens")
    scene = root / "real_lens_small.yaml"
    scene.write_text(yaml.safe_dump(small_real_lens(), sort_keys=False))
    proc = lumigraph("capture", scene, "--out", root / "capture", "--quiet")
    assert proc.returncode == 0, proc.stderr
    proc = lumigraph("poses", root / "capture", "--method", "colmap", "--self-calibrate", "--out", root / "poses",
                     "--quiet")
    assert proc.returncode == 0, proc.stderr
    return root / "capture", root / "poses", proc.stdout


def test_self_calibration_recovers_the_lens_through_the_cli(self_calibrated):
    """Measured (one run, load ~20): 20/20 views; ``auto`` kept SIMPLE_RADIAL with its principal
    point freed (RADIAL and OPENCV lower the residuals insignificantly and predict the outermost
    10% of the features worse when fitted without them; RADIAL, forced, puts the outer corners
    1.6 px off); focal 0.29% off, principal point 0.70 px off, the whole camera within 0.47 px of
    the truth where the features reach and 0.75 px at the image's outer corners, rotation
    0.106 deg mean. With the principal point pinned to the centre (the earlier behaviour) it is
    8.2 px off; without the lens (PINHOLE) the corners are ~10 px off."""
    capture, poses, stdout = self_calibrated
    m = json.loads((poses / "metrics.json").read_text())
    assert m["status"] == "ok" and m["registered_fraction"] == 1.0 and m["calibration"] == "self"
    assert [s["model"] for s in m["lens_steps"]] == ["SIMPLE_RADIAL", "RADIAL", "OPENCV"]
    assert [s["model"] for s in m["lens_steps"] if s["chosen"]] == [m["camera_model"]]
    assert m["focal_rel"] < 0.004
    assert m["principal_point_px"] < 2.0
    assert m["observed_radius_rel"] > 0.6
    assert m["projection_error_px_max_covered"] < 1.0 and m["projection_error_px_max"] < 1.5
    assert m["rotation_error_deg_mean"] < 0.25
    assert "principal point" in stdout and m["camera_model"] in stdout


def test_the_estimated_lens_is_written_to_cameras_json_and_reads_back(self_calibrated):
    """cameras.json carries the estimated focal, principal point and distortion (not the truth's:
    they differ), in every registered view, and the downstream readers load it: the stage's own
    ``check_poses`` (what slab and nerf call for ``--poses``) and transforms.json's OPENCV model."""
    from pipeline.stages.capture import read_cameras
    from pipeline.stages.poses import check_poses

    capture, poses, _ = self_calibrated
    est, _ = read_cameras_json(poses / "cameras.json")
    truth, splits = read_cameras_json(capture / "cameras.json")
    k, kt = est[0].intrinsics, truth[0].intrinsics
    assert all(c.intrinsics == k for c in est) and k != kt
    assert k.dist[0] == pytest.approx(kt.dist[0], abs=0.02) and k.has_distortion
    assert (k.cx - kt.cx, k.cy - kt.cy) != (0.0, 0.0) and abs(k.cx - 200 - OFFSET[0]) < 2 and abs(k.cy - 150 - OFFSET[1]) < 2
    cams, _ = read_cameras(capture / "cameras.json")
    loaded = check_poses(poses, capture, cams, splits)
    assert [c.intrinsics for c in loaded] == [c.intrinsics for c in est]
    doc = json.loads((poses / "transforms.json").read_text())
    assert doc["camera_model"] == "OPENCV" and np.isclose(doc.get("k1", doc["frames"][0].get("k1")), k.dist[0])


def test_charuco_calibration_through_the_cli(self_calibrated, tmp_path):
    """``--calibration charuco``: cv2.calibrateCamera on the board corners of every view, held fixed
    in COLMAP; the intrinsics in cameras.json are the calibration's (not the truth's), its figures
    in metrics.json."""
    capture, _, _ = self_calibrated
    proc = lumigraph("poses", capture, "--method", "colmap", "--calibration", "charuco", "--out", tmp_path / "p",
                     "--quiet")
    assert proc.returncode == 0, proc.stderr
    m = json.loads((tmp_path / "p" / "metrics.json").read_text())
    assert m["status"] == "ok" and m["calibration"] == "charuco" and m["camera_model"] == "OPENCV"
    assert 0 < m["charuco_calibration_rms_px"] < 1 and m["charuco_calibration_views"] >= 16
    est, _ = read_cameras_json(tmp_path / "p" / "cameras.json")
    truth, _ = read_cameras_json(capture / "cameras.json")
    assert est[0].intrinsics.has_distortion and est[0].intrinsics != truth[0].intrinsics
    assert m["focal_rel"] < 0.02 and "lens (charuco" in proc.stdout


@pytest.mark.parametrize("args, word", [(["--self-calibrate", "--camera-model", "FISHEYE"], "camera_model"),
                                        (["--calibration", "lab"], "--calibration"),
                                        (["--self-calibrate", "--calibration", "known"], "--calibration")])
def test_lens_flags_are_checked_with_one_line(tmp_path, args, word):
    proc = lumigraph("poses", tmp_path, "--method", "colmap", *args)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and word in lines[0], proc.stderr


# --------------------------------------------------------------------------- closed forms (no capture)

def _orbit(k, n=6):
    """``n`` cameras of intrinsics ``k`` 1 m from the origin, looking at it (OpenCV axes)."""
    from render.camera import Camera

    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        c = np.array([np.cos(a), np.sin(a), 0.5])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        m = np.eye(4)
        m[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        m[:3, 3] = c
        cams.append(Camera(k, m, f"v{i}"))
    return cams


def test_projection_error_is_zero_for_the_truth_and_the_shift_of_a_moved_principal_point():
    """The whole-camera and lens-only errors: 0 for the true cameras; a principal point moved by
    (0.6, 0.8) px moves every projection by exactly 1 px, at any depth."""
    from dataclasses import replace

    from recon.poses import projection_error
    from render.camera import Intrinsics

    k = Intrinsics(320, 240, 300.0, 300.0, 163.0, 118.0, (-0.12, 0.03, 0.0008, -0.0005, 0.0))
    truth = _orbit(k)
    by_name = {c.name: c for c in truth}
    same = projection_error(truth, by_name, radius_rel=0.5)
    assert max(same.values()) < 1e-9
    moved = [replace(c, intrinsics=replace(k, cx=k.cx + 0.6, cy=k.cy + 0.8)) for c in truth]
    shifted = projection_error(moved, by_name)
    for key in ("projection_error_px_max", "projection_error_px_mean", "lens_projection_error_px_max"):
        assert shifted[key] == pytest.approx(1.0, abs=1e-9)


def test_promoting_a_camera_model_keeps_its_projection_and_rational_refit_is_exact_without_k4():
    """calibrate_lens starts each model from the previous solution: SIMPLE_RADIAL -> RADIAL ->
    OPENCV -> FULL_OPENCV with the new terms at 0 projects every point where it did; a
    FULL_OPENCV camera with k4 = k5 = k6 = 0 is written as its own Brown lens (0 px)."""
    import pycolmap

    from recon.poses.colmap import CAMERA_MODELS, _camera_from_colmap, _promote, rational_refit_px

    cam = pycolmap.Camera.create_from_model_name(1, "SIMPLE_RADIAL", 300.0, 320, 240)
    cam.params = [300.0, 163.0, 118.0, -0.12]
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), np.ones(200)])
    before = np.asarray(cam.img_from_cam(points))
    for model in CAMERA_MODELS[1:]:
        _promote(cam, model)
        assert cam.model_name == model
        np.testing.assert_allclose(np.asarray(cam.img_from_cam(points)), before, atol=1e-9)
    assert rational_refit_px(cam) == 0.0
    assert _camera_from_colmap(cam, 1.0, 320, 240).dist == (-0.12, 0.0, 0.0, 0.0, 0.0)
