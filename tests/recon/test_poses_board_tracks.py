"""The calibration board's corners as tracks inside COLMAP's final bundle adjustment
(recon/poses/board_tracks.py, ColmapConfig.board_corners), on the small capture (20 views,
400x300; tests/recon/conftest.py)."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import BadInput
from pipeline.stages.poses import PosesConfig, load_capture, run_poses
from recon.poses import ColmapConfig
from recon.poses.board_tracks import add_corner_tracks, board_definitions, detect_corners
from recon.poses.charuco import make_board


@pytest.fixture(scope="module")
def runs(small_capture, tmp_path_factory):
    """The stage with the corners (the default) and without, on the small capture, one thread."""
    root = tmp_path_factory.mktemp("board_tracks")
    out = {}
    for name, flag in (("on", None), ("off", False)):
        cfg = PosesConfig(colmap=ColmapConfig(board_corners=flag, num_threads=1))
        run_poses(small_capture, "colmap", root / name, cfg, quiet=True)
        out[name] = (root / name, json.loads((root / name / "metrics.json").read_text()))
    return out


def test_corners_are_found_and_added_as_tracks(runs):
    _, on = runs["on"]
    _, off = runs["off"]
    assert on["board_corners"] is True and off["board_corners"] is False
    assert "corner_tracks" not in off and "corners_time_s" not in off
    # the 10 x 10 board has 81 inner corners; 58 ids are seen by two views or more (16 of 20 views
    # see the board at 400x300), 518 observations: measured
    assert on["corner_views"] == on["corner_detect_views"] >= 14
    assert 50 <= on["corner_tracks"] <= 81
    assert on["corner_observations"] >= 2 * on["corner_tracks"] and on["corner_observations"] >= 400
    assert on["points"] == off["points"] + on["corner_tracks"]  # the SIFT tracks kept, the corners beside them
    assert 0 < on["corner_detect_s_per_view"] < 5 and on["corners_cpu_time_s"] > 0


def test_corners_improve_the_rotations_on_the_small_capture(runs):
    """Measured: 0.1134 deg mean without the corners, 0.1067 with them (num_threads 1; the same
    model, the corners added before the 100 final iterations)."""
    _, on = runs["on"]
    _, off = runs["off"]
    assert on["views_registered"] == off["views_registered"] == 20
    assert on["rotation_error_deg_mean"] < off["rotation_error_deg_mean"] - 0.002


def test_without_a_board_definition_the_stage_is_unchanged(runs, small_capture, tmp_path):
    """No targets.json: the same cameras as board_corners False (the path without the corners)."""
    cap = tmp_path / "capture"
    shutil.copytree(small_capture, cap)
    (cap / "targets.json").unlink()
    run_poses(cap, "colmap", tmp_path / "poses", PosesConfig(colmap=ColmapConfig(num_threads=1)), quiet=True)
    m = json.loads((tmp_path / "poses" / "metrics.json").read_text())
    out_off, off = runs["off"]
    assert m["board_corners"] is False and "corner_tracks" not in m
    assert m["rotation_error_deg_mean"] == off["rotation_error_deg_mean"] and m["points"] == off["points"]
    a = json.loads((tmp_path / "poses" / "cameras.json").read_text())
    b = json.loads((out_off / "cameras.json").read_text())
    assert a["cameras"] == b["cameras"] and len(a["cameras"]) == 20


def test_corner_tracks_land_on_the_board_and_fit_their_views(runs, small_capture):
    """The corners triangulated from the stage's own (aligned) model: each corner id lies near the
    true board corner of that id, and reprojects within a fraction of a pixel (measured 0.14 px
    mean; corners half a pixel off, OpenCV's convention left unconverted, give 0.42)."""
    import pycolmap

    out_off, _ = runs["off"]
    cap = load_capture(small_capture)
    rec = pycolmap.Reconstruction(str(out_off / "sparse"))
    found = detect_corners(cap.images, board_definitions(cap.targets), threads=2)
    assert len(found.seconds) == len(cap.images) and len(found.views) >= 14
    new, stats, ids = add_corner_tracks(rec, found.views, lambda xy: xy)
    assert new.num_points3D() == rec.num_points3D() + stats["corner_tracks"] == rec.num_points3D() + len(ids)
    assert new.compute_num_observations() == rec.compute_num_observations() + stats["corner_observations"]
    target = cap.targets["board"]
    T = np.asarray(target["board_to_world"])
    corners = np.asarray(make_board(target["board"]).getChessboardCorners(), dtype=np.float64) @ T[:3, :3].T + T[:3, 3]
    err = [np.linalg.norm(new.points3D[pid].xyz - corners[int(key.split(":")[1])]) for key, pid in ids.items()]
    assert np.median(err) < 2e-3 and max(err) < 4e-3  # scene units (m); the alignment's own error ~1 mm
    assert np.mean([new.points3D[pid].error for pid in ids.values()]) < 0.25
    # every SIFT track carried over: same points, same observations, same poses
    for image_id, img in rec.images.items():
        np.testing.assert_array_equal(new.images[image_id].cam_from_world().matrix(), img.cam_from_world().matrix())
        assert new.images[image_id].num_points3D == img.num_points3D + sum(
            image_id in [e.image_id for e in new.points3D[pid].track.elements] for pid in ids.values())


def test_a_malformed_board_definition_is_one_line_naming_the_file(small_capture, tmp_path):
    cap = tmp_path / "capture"
    shutil.copytree(small_capture, cap)
    doc = json.loads((cap / "targets.json").read_text())
    del doc["board"]["board"]["squares"]
    (cap / "targets.json").write_text(json.dumps(doc))
    with pytest.raises(BadInput, match=r"targets.json: board 'board'.*squares") as exc:
        run_poses(cap, "colmap", tmp_path / "poses", quiet=True)
    assert "\n" not in str(exc.value) and not (tmp_path / "poses").exists()
    with pytest.raises(ValueError, match="field 'board'"):
        board_definitions({"b": {"board_to_world": []}})


def test_corners_detected_beside_a_busy_thread_are_those_of_the_serial_order(small_capture):
    """CornerJob (the stage's detection beside the mapper, threads at nice 19) while this thread
    keeps a core busy: the same views, corner ids and positions, bit for bit, as detect_corners
    on one thread in series, and its threads back at their priority once waited for."""
    import time

    cap = load_capture(small_capture)
    boards = board_definitions(cap.targets)
    serial = detect_corners(cap.images, boards, threads=1)
    from recon.poses.board_tracks import CornerJob

    job = CornerJob(cap.images, boards, threads=2)
    t = time.perf_counter()
    x = 0.0
    while time.perf_counter() - t < 0.5:  # the "mapper": a busy core
        x += 1.0
    found = job.result()
    assert list(found.views) == list(serial.views) and len(found.views) >= 14
    for name, (keys, xy) in serial.views.items():
        assert found.views[name][0] == keys
        np.testing.assert_array_equal(found.views[name][1], xy)
    assert len(found.seconds) == len(cap.images) and found.cpu_s > 0 and found.wall_s > 0


def test_the_stage_with_the_overlapped_corners_gives_the_serial_orders_poses(small_capture, tmp_path, monkeypatch):
    """estimate_colmap with the corners detected beside the mapper (the default) and with a
    CornerJob that detects them in series before the mapper starts (the previous order): the same
    corner figures and the same cameras to 1e-9 deg (one thread everywhere, incremental mapper)."""
    from recon.poses import board_tracks
    from recon.poses.colmap import estimate_colmap
    from render.camera_io import read_cameras_json

    cap = load_capture(small_capture)
    truth, _ = read_cameras_json(small_capture / "cameras.json")
    boards = board_definitions(cap.targets)
    cfg = ColmapConfig(num_threads=1, global_threads=1)
    overlapped = estimate_colmap(cap.images, truth[0].intrinsics, tmp_path / "overlap", cfg, boards=boards)

    class SerialJob:
        def __init__(self, images, boards, threads=1, **_):
            self.found = detect_corners(images, boards, threads)

        def result(self):
            return self.found

        def cancel(self):
            pass

    monkeypatch.setattr(board_tracks, "CornerJob", SerialJob)
    serial = estimate_colmap(cap.images, truth[0].intrinsics, tmp_path / "serial", cfg, boards=boards)
    for key in ("corner_tracks", "corner_observations", "corner_views", "corner_detect_views"):
        assert overlapped.corner_stats[key] == serial.corner_stats[key], key
    assert overlapped.corner_stats["corner_tracks"] >= 50
    assert {"corners_wait", "corners_detect", "corners_tracks"} <= set(overlapped.times_s)
    assert [c.name for c in overlapped.cameras] == [c.name for c in serial.cameras] and len(serial.cameras) == 20
    R0 = np.array([c.cam_to_world[:3, :3] for c in overlapped.cameras])
    R1 = np.array([c.cam_to_world[:3, :3] for c in serial.cameras])
    D = np.einsum("nji,njk->nik", R0, R1)
    w = 0.5 * np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], 1)
    assert np.degrees(np.arcsin(np.linalg.norm(w, axis=1))).max() < 1e-9
