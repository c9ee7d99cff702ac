"""Posing at scale without COLMAP runs: what ``auto`` resolves to at the benchmark's view counts,
the benchmark's growth exponents (closed form), and the stoppable child process's error
protocol (the child's exception re-raised in the parent, a bug's with the child's traceback)."""
import math
from pathlib import Path

import pytest

from bench.bench_poses import LAYOUTS, colmap_config, growth
from recon.poses import ColmapConfig, ReconstructionError
from recon.poses.colmap import (LARGE_IMAGE_SCALE, resolve_board_corners, resolve_extractor,
                                resolve_final_ba_iterations, resolve_first_octave,
                                resolve_image_scale, resolve_mapper, resolve_matcher)
from recon.poses.colmap_process import estimate_colmap_stoppable


def test_auto_resolves_by_view_count():
    """56 views: every pair, the incremental mapper; from 150 views on: the capture's order
    (sequential by name without it), the global mapper; SIFT on the doubled image at every count
    (octave 0 doubled the rotation error at 224 views). A given option is kept whatever the count."""
    cfg = ColmapConfig()
    assert [sum(n for _, n in LAYOUTS[v][0]) + LAYOUTS[v][1][1] for v in LAYOUTS] == [56, 224, 1000]
    table = {v: (resolve_matcher(cfg, v, True), resolve_mapper(cfg, v), resolve_first_octave(cfg, v)) for v in LAYOUTS}
    assert table == {56: ("exhaustive", "incremental", -1), 224: ("capture_order", "global", -1),
                     1000: ("capture_order", "global", -1)}
    assert resolve_matcher(cfg, 224, False) == "sequential"
    # COLMAP's SIFT where the 56-view figures were measured, OpenCV's (4x fewer CPU seconds) at scale
    assert [resolve_extractor(cfg, v) for v in LAYOUTS] == ["colmap", "opencv", "opencv"]
    assert resolve_extractor(ColmapConfig(extractor="colmap"), 1000) == "colmap"
    assert resolve_extractor(ColmapConfig(extractor="opencv"), 56) == "opencv"
    with pytest.raises(ValueError, match="extractor"):
        ColmapConfig(extractor="orb")
    assert colmap_config("auto+cvsift+link0+w4").extractor == "opencv"
    assert (colmap_config("auto+link0+w4").link_window, colmap_config("auto+w4").sequential_overlap) == (0, 4)
    # the global mapper skips its retriangulation and gets 10 final iterations; the incremental 100
    assert [resolve_final_ba_iterations(cfg, resolve_mapper(cfg, v)) for v in LAYOUTS] == [100, 10, 10]
    assert not cfg.global_retriangulate and cfg.crop_to_subject is None and cfg.pair_offsets == "doubling"
    assert resolve_final_ba_iterations(ColmapConfig(final_ba_iterations=0), "global") == 0
    assert resolve_first_octave(ColmapConfig(first_octave=-1), 1000) == -1
    assert resolve_first_octave(ColmapConfig(first_octave=0), 56) == 0
    with pytest.raises(ValueError, match="first_octave"):
        ColmapConfig(first_octave=2)
    assert colmap_config("capture_order+global+o-1").first_octave == -1
    assert colmap_config("exhaustive+incremental").first_octave is None
    c = colmap_config("auto+nocrop+consecutive+t300+noretri+ba0")
    assert (c.matcher, c.crop_to_subject, c.pair_offsets, c.global_tracks_per_view, c.global_retriangulate,
            c.final_ba_iterations) == ("auto", False, "consecutive", 300, False, 0)
    with pytest.raises(ValueError, match="modifier"):
        colmap_config("auto+fast")
    assert colmap_config("auto+nocorners").board_corners is False and colmap_config("auto+feat4096").max_features == 4096
    assert colmap_config("auto+scale0.5+feat1024").image_scale == 0.5
    # the board's corners: never without a board; by default with known intrinsics and a final bundle adjustment
    assert resolve_board_corners(cfg, True, "global") and resolve_board_corners(cfg, True, "incremental")
    assert not resolve_board_corners(cfg, False, "global")
    assert not resolve_board_corners(ColmapConfig(board_corners=False), True, "global")
    assert not resolve_board_corners(ColmapConfig(final_ba_iterations=0), True, "global")
    assert not resolve_board_corners(ColmapConfig(known_intrinsics=False), True, "incremental")
    assert resolve_board_corners(ColmapConfig(known_intrinsics=False, board_corners=True), True, "incremental")


def test_auto_image_scale_by_view_count():
    """``image_scale`` None: full scale up to 499 views, 0.75 from 500 on (1000 views: 615.9 s at
    0.0286 deg against 711.6 s at 0.0249 at full scale, session 34); a given scale is kept."""
    cfg = ColmapConfig()
    assert cfg.image_scale is None and LARGE_IMAGE_SCALE == 0.75
    assert [resolve_image_scale(cfg, v) for v in (56, 224, 499, 500, 1000)] == [1.0, 1.0, 1.0, 0.75, 0.75]
    assert resolve_image_scale(ColmapConfig(image_scale=1.0), 1000) == 1.0
    assert resolve_image_scale(ColmapConfig(image_scale=0.5), 56) == 0.5
    assert resolve_image_scale(ColmapConfig(large_min_images=100), 224) == 0.75
    with pytest.raises(ValueError, match="large_min_images"):
        ColmapConfig(large_min_images=1)
    with pytest.raises(ValueError, match="image_scale"):
        ColmapConfig(image_scale=0.0)


def test_global_ba_rounds_reach_the_global_mapper():
    """``global_ba_rounds`` is COLMAP's ``ba_num_iterations`` (3 by default; 1 measured at 224
    views: the same 0.0166 deg, the mapper ~5% faster, not adopted); the bench's ``barN``."""
    from recon.poses.colmap import _global_options

    assert _global_options(ColmapConfig(), 224).mapper.ba_num_iterations == 3
    assert _global_options(colmap_config("auto+bar1"), 224).mapper.ba_num_iterations == 1
    assert colmap_config("auto+ba5+bar2").final_ba_iterations == 5
    with pytest.raises(ValueError, match="global_ba_rounds"):
        ColmapConfig(global_ba_rounds=0)


def test_the_auto_scale_reaches_the_images_and_comes_back_in_the_intrinsics(small_capture, tmp_path):
    """With ``large_min_images`` at the view count the stage's images are resized by 0.75 (on
    threads) and the cameras still come back at the input resolution."""
    from PIL import Image

    from recon.poses.colmap import estimate_colmap
    from render.camera_io import read_cameras_json

    truth, _ = read_cameras_json(small_capture / "cameras.json")
    train = [c for c in truth if c.name.startswith("train")]
    images = {c.name: small_capture / "images" / f"{c.name}.png" for c in train}
    cfg = ColmapConfig(matcher="exhaustive", mapper="global", large_min_images=len(images), num_threads=2)
    res = estimate_colmap(images, train[0].intrinsics, tmp_path / "work", cfg)
    assert res.image_scale == 0.75 and len(res.cameras) == 16
    w, h = train[0].intrinsics.width, train[0].intrinsics.height
    sizes = {Image.open(p).size for p in (tmp_path / "work" / "images").glob("*.png")}
    assert sizes == {(round(w * 0.75), round(h * 0.75))}
    k = train[0].intrinsics
    for c in res.cameras:
        got = c.intrinsics
        assert (got.width, got.height) == (w, h)
        assert max(abs(got.fx - k.fx), abs(got.fy - k.fy), abs(got.cx - k.cx), abs(got.cy - k.cy)) < 1e-9


def test_growth_exponents_are_the_log_log_slopes():
    """Times proportional to views give exponent 1, to views squared 2; per-view seconds as given."""
    rows = [{"config": "c", "views": v, "failure": None, "pairs": 21 * v, "extract_s": 0.5 * v,
             "match_s": 0.01 * v * v, "map_s": 3.0 * v ** 1.5, "poses_wall_s": 0.5 * v + 0.01 * v * v + 3.0 * v ** 1.5,
             "extract_cpu_s": 0.2 * v, "match_cpu_s": 0.02 * v * v, "map_cpu_s": 2.0 * v ** 1.5}
            for v in (56, 224, 1000)]
    rows.append({"config": "c", "views": 2000, "failure": "did not finish"})  # failed runs are left out
    rows.insert(0, {**rows[0], "extract_s": 99.0})  # an earlier run at 56 views: the later one counts
    g = growth(rows)
    assert [e["views"] for e in g] == [[56, 224], [224, 1000]]
    for e in g:
        assert e["pairs_exponent"] == e["extract_s_exponent"] == 1.0
        assert e["match_s_exponent"] == 2.0 and e["map_s_exponent"] == 1.5
        assert (e["extract_cpu_s_exponent"], e["match_cpu_s_exponent"], e["map_cpu_s_exponent"]) == (1.0, 2.0, 1.5)
        assert 1.0 < e["poses_wall_s_exponent"] < 2.0
    assert g[0]["extract_s_per_view"] == [0.5, 0.5]
    assert g[1]["match_s_per_view"] == [2.24, 10.0]
    assert math.isclose(g[0]["map_s_per_view"][0], round(3.0 * 56 ** 0.5, 3))


def test_the_child_process_hands_back_its_errors(tmp_path):
    """A ReconstructionError raised in the child (one image: nothing to reconstruct) reaches the
    caller as itself, its one-line message intact; a bug (a missing image file) as its own type
    with the child's traceback attached as a note."""
    img = tmp_path / "a.png"
    img.write_bytes(b"not an image")
    with pytest.raises(ReconstructionError, match="at least 2 images, got 1") as info:
        estimate_colmap_stoppable({"a": img}, None, tmp_path / "work1", ColmapConfig(known_intrinsics=False))
    assert str(info.value) == "structure from motion needs at least 2 images, got 1"
    with pytest.raises(FileNotFoundError) as info:
        estimate_colmap_stoppable({"a": img, "b": tmp_path / "missing.png"}, None, tmp_path / "work2",
                                  ColmapConfig(known_intrinsics=False))
    assert any("in the COLMAP child process" in n and "Traceback" in n for n in info.value.__notes__)
    assert not (tmp_path / "work2" / "result").exists()


def _views(tmp_path, boxes, size=(320, 240), noise=0.0, seed=0):
    """PNG views: black frames (plus Gaussian noise of ``noise`` 8-bit levels) with a bright
    textured rectangle at each ``(x0, y0, x1, y1)``."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    paths = []
    for i, (x0, y0, x1, y1) in enumerate(boxes):
        img = rng.normal(0.0, noise, (size[1], size[0], 3)) if noise else np.zeros((size[1], size[0], 3))
        img[y0:y1, x0:x1] = rng.uniform(60, 255, (y1 - y0, x1 - x0, 3))
        paths.append(tmp_path / f"v{i}.png")
        cv2.imwrite(str(paths[-1]), np.clip(img, 0, 255).astype(np.uint8))
    return paths


def test_subject_box_is_the_union_of_the_views_subjects_from_the_images_alone(tmp_path):
    """Two views with the subject at (96..160, 64..120) and (128..200, 80..144): the box is their
    union (96..200, 64..144) grown by SUBJECT_MARGIN, to within one averaging cell; centred, it is
    symmetric about the frame's centre; read noise (sigma 4 levels) on the background does not
    grow it; a subject filling the frame gives no crop."""
    from recon.poses.colmap import SUBJECT_CELL, SUBJECT_MARGIN, subject_box

    m, cell = SUBJECT_MARGIN, SUBJECT_CELL
    paths = _views(tmp_path, [(96, 64, 160, 120), (128, 80, 200, 144)])
    box = subject_box(paths)
    want = (96 - m, 64 - m, 200 + m, 144 + m)
    assert all(abs(a - b) <= cell for a, b in zip(box, want)), box
    assert box[0] <= want[0] and box[1] <= want[1] and box[2] >= want[2] and box[3] >= want[3]  # never cuts in
    x0, y0, x1, y1 = subject_box(paths, centred=True)
    assert (x0 + x1, y0 + y1) == (320, 240) and x0 <= box[0] and y0 <= box[1] and x1 >= box[2]
    (tmp_path / "noisy").mkdir()
    assert subject_box(_views(tmp_path / "noisy", [(96, 64, 160, 120)], noise=4.0)) == subject_box(paths[:1])
    assert subject_box(_views(tmp_path, [(4, 4, 316, 236)])) is None


def test_cropped_intrinsics_map_back_to_the_input_frame():
    """A COLMAP camera in the cropped, half-scale working frame comes back at the input
    resolution: focal times the scale, principal point times the scale plus the crop's corner."""
    import pycolmap

    from recon.poses.colmap import _camera_from_colmap

    cam = pycolmap.Camera(model="PINHOLE", width=200, height=150, params=[500.0, 510.0, 90.5, 60.25])
    k = _camera_from_colmap(cam, (2.0, 2.0), 1280, 960, offset=(224.0, 250.0))
    assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (1280, 960, 1000.0, 1020.0, 2 * 90.5 + 224, 2 * 60.25 + 250)


def test_colmap_on_the_subjects_box_gives_the_true_camera_back(small_capture, tmp_path, monkeypatch):
    """The small capture's 16 train views posed from a tight crop around the subject (no margin,
    any box accepted): the box is off the frame's centre, the cameras come back with the true
    intrinsics of the whole frame and the poses of the whole-frame run (measured: 0.17 deg mean
    both). A crop whose corner is not added back (or not taken off the working camera's
    principal point) misplaces every view by the box's offset."""
    import json

    import numpy as np

    from recon.poses import score_cameras
    from recon.poses.colmap import estimate_colmap
    from render.camera_io import read_cameras_json

    monkeypatch.setattr("recon.poses.colmap.CROP_MAX_AREA", 1.0)
    monkeypatch.setattr("recon.poses.colmap.SUBJECT_MARGIN", 0)
    truth, _ = read_cameras_json(small_capture / "cameras.json")
    train = [c for c in truth if c.name.startswith("train")]
    images = {c.name: small_capture / "images" / f"{c.name}.png" for c in train}
    cfg = ColmapConfig(matcher="exhaustive", mapper="incremental", final_ba_iterations=10, num_threads=1)
    res = estimate_colmap(images, train[0].intrinsics, tmp_path / "work", cfg)
    x0, y0, x1, y1 = res.crop_box
    k = train[0].intrinsics
    assert (x1 - x0) * (y1 - y0) < 0.9 * k.width * k.height and (x0 + x1, y0 + y1) != (k.width, k.height)
    assert len(res.cameras) == 16 and all(c.intrinsics == k for c in res.cameras)
    _, m, _ = score_cameras(res.cameras, {c.name: c for c in truth}, align=True)
    assert m["rotation_error_deg_mean"] < 0.4, m["rotation_error_deg_mean"]


def test_opencv_sift_on_each_views_own_box_gives_the_true_camera_back(small_capture, tmp_path, monkeypatch):
    """The same 16 views through OpenCV's SIFT (the extractor ``auto`` picks at scale), each view
    cropped to its own tight box (no margin) as it is read: the keypoints shifted back to the whole
    frame, the true intrinsics, every view registered and the rotation error of the COLMAP SIFT
    run above (bound as there). A per-view box whose corner is not added back misplaces each view
    by its own offset."""
    from recon.poses import score_cameras
    from recon.poses.colmap import estimate_colmap
    from render.camera_io import read_cameras_json

    monkeypatch.setattr("recon.poses.colmap.SUBJECT_MARGIN", 0)
    truth, _ = read_cameras_json(small_capture / "cameras.json")
    train = [c for c in truth if c.name.startswith("train")]
    images = {c.name: small_capture / "images" / f"{c.name}.png" for c in train}
    cfg = ColmapConfig(matcher="exhaustive", mapper="incremental", final_ba_iterations=10, num_threads=1,
                       extractor="opencv")
    res = estimate_colmap(images, train[0].intrinsics, tmp_path / "work", cfg)
    assert res.extractor == "opencv" and res.crop_box is None
    assert len(res.cameras) == 16 and all(c.intrinsics == train[0].intrinsics for c in res.cameras)
    _, m, _ = score_cameras(res.cameras, {c.name: c for c in truth}, align=True)
    assert m["rotation_error_deg_mean"] < 0.4, m["rotation_error_deg_mean"]


def test_the_global_mapper_runs_on_two_threads_and_they_change_the_poses_by_rounding_only(small_capture, tmp_path):
    """The global mapper's three thread counts (pipeline, mapper: rotation averaging and global
    positioning, its bundle adjustment's Ceres) follow ``global_threads`` (default 2: 0.60x the
    mapper's wall time at 224 views); one thread and two map the same 16 views to the same poses
    within 1e-6 deg (measured at 224 views: 3.2e-13)."""
    import numpy as np

    from recon.poses.colmap import _global_options, estimate_colmap
    from render.camera_io import read_cameras_json

    for threads in (2, 1):
        opts = _global_options(ColmapConfig(global_threads=threads), 224)
        assert (opts.num_threads, opts.mapper.num_threads,
                opts.mapper.bundle_adjustment.ceres.solver_options.num_threads) == (threads,) * 3
    assert ColmapConfig().global_threads == 2
    with pytest.raises(ValueError, match="global_threads"):
        ColmapConfig(global_threads=0)
    truth, _ = read_cameras_json(small_capture / "cameras.json")
    train = [c for c in truth if c.name.startswith("train")]
    images = {c.name: small_capture / "images" / f"{c.name}.png" for c in train}
    rotations = []
    for threads in (1, 2):
        cfg = ColmapConfig(matcher="exhaustive", mapper="global", num_threads=1, global_threads=threads)
        res = estimate_colmap(images, train[0].intrinsics, tmp_path / f"work{threads}", cfg)
        assert res.mapper == "global" and len(res.cameras) == 16
        rotations.append(np.array([c.cam_to_world[:3, :3] for c in res.cameras]))
    D = np.einsum("nji,njk->nik", rotations[0], rotations[1])
    w = 0.5 * np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], 1)
    assert np.degrees(np.arcsin(np.linalg.norm(w, axis=1))).max() < 1e-6
