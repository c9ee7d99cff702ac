"""Hard cases of COLMAP pose estimation (recon/poses/colmap.py): duplicate images. Each states the
case and asserts a bounded outcome: a one-line ReconstructionError naming the problem, or finite
poses that obey the closed form (a duplicate sits exactly where its original does). The catalogue
of every hard case is docs/hard_cases.md."""
from __future__ import annotations

import numpy as np
import pytest

from recon.poses import ColmapConfig
from recon.poses.colmap import ReconstructionError, estimate_colmap
from render.camera_io import read_cameras_json


def test_hard_case_only_duplicate_images(small_capture, tmp_path):
    """Hard case: three copies of one image (zero baseline, nothing to triangulate). A one-line
    ReconstructionError that says the images are identical (formerly COLMAP's matcher verdict
    blamed a static background), before COLMAP runs."""
    image = small_capture / "images" / "train_000.png"
    with pytest.raises(ReconstructionError, match="identical") as exc:
        estimate_colmap({f"copy_{k}": image for k in range(3)}, None, tmp_path, ColmapConfig(known_intrinsics=False))
    assert len(str(exc.value).splitlines()) == 1


def test_hard_case_duplicates_among_distinct_views(small_capture, tmp_path):
    """Hard case: one view given twice under two names among the 16 train views (fewer do not
    register at 400x300: one ring of 8 finds no initial pair, with or without the duplicate).
    Every view registers, all poses are finite, and the duplicate's pose equals its original's
    (camera centres within 1e-6 of the orbit's size, rotations within 1e-6; measured 1e-15)."""
    cams, _ = read_cameras_json(small_capture / "cameras.json")
    ring = [c for c in cams if c.name.startswith("train_")]
    images = {c.name: small_capture / "images" / f"{c.name}.png" for c in ring}
    images["duplicate_of_train_002"] = images["train_002"]
    res = estimate_colmap(images, ring[0].intrinsics, tmp_path, ColmapConfig(max_features=2048))
    got = {c.name: c for c in res.cameras}
    assert set(got) == set(images)
    assert all(np.all(np.isfinite(c.cam_to_world)) for c in got.values())
    a, b = got["duplicate_of_train_002"], got["train_002"]
    size = np.ptp(np.array([c.center for c in got.values()]), axis=0).max()
    assert np.linalg.norm(a.center - b.center) < 1e-6 * size
    assert np.abs(a.cam_to_world[:3, :3] - b.cam_to_world[:3, :3]).max() < 1e-6
