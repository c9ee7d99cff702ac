"""The calibration sequence (rig.calibration): its poses and the spec's ``calibration`` section."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from render.camera import Camera, Intrinsics
from rig.calibration import board_overfill_distance, calibration_poses

REPO = Path(__file__).resolve().parents[2]
#: scenes/real_lens.yaml's lens and board (0.45 m, OpenCV board frame on the ground, facing +z)
LENS = Intrinsics(1280, 960, 1318.79, 1318.79, 646.3, 474.8, (-0.12, 0.03, 0.0008, -0.0005, 0.0))
BOARD_TO_WORLD = np.array([[1.0, 0, 0, -0.225], [0, -1, 0, 0.225], [0, 0, -1, 0], [0, 0, 0, 1]])


def _board_hits(cam: Camera, pixels: np.ndarray) -> np.ndarray:
    """(N, 2) board-frame points where the rays of ``pixels`` meet the board's plane (z = 0)."""
    origins, dirs = cam.pixel_rays(pixels)
    w2b = np.linalg.inv(BOARD_TO_WORLD)
    o = origins @ w2b[:3, :3].T + w2b[:3, 3]
    d = dirs @ w2b[:3, :3].T
    t = -o[:, 2] / d[:, 2]
    assert np.all(t > 0)  # in front of the camera
    return (o + t[:, None] * d)[:, :2]


def test_sequence_poses_see_the_board_from_the_front_and_the_first_fills_the_frame():
    """5 + 3 x 12 views; every camera is above the board (on its front side) and sees the board's
    centre; the first, frontal, sees board in the four corners of its (distorted) image, and the
    four quadrant views put the board into each corner of the frame."""
    poses = calibration_poses(BOARD_TO_WORLD, (0.45, 0.45), LENS)
    assert len(poses) == 5 + 3 * 12
    corners = np.array([[0.5, 0.5], [LENS.width - 0.5, 0.5], [LENS.width - 0.5, LENS.height - 0.5],
                        [0.5, LENS.height - 0.5]])
    for i, pose in enumerate(poses):
        cam = Camera(LENS, pose, f"c{i}")
        assert cam.center[2] > 0.1  # board on the ground (z = 0), facing up
        uv, z = cam.project(np.array([[0.0, 0.0, 0.0]]))
        assert z[0] > 0 and 0 <= uv[0, 0] <= LENS.width and 0 <= uv[0, 1] <= LENS.height
    inside = lambda p: np.all((p > 0) & (p < 0.45), axis=1)  # noqa: E731
    assert inside(_board_hits(Camera(LENS, poses[0], "f"), corners)).all()
    for i, corner in enumerate(corners):  # quadrant views 1..4: top-left, top-right, bottom-right, bottom-left
        assert inside(_board_hits(Camera(LENS, poses[1 + i], "q"), corner[None])).all()
    assert 0.3 < board_overfill_distance((0.45, 0.45), LENS) < 0.45


def test_a_calibration_board_that_is_not_a_board_is_refused_with_one_line(tmp_path):
    spec = yaml.safe_load((REPO / "scenes" / "real_lens.yaml").read_text())
    spec["calibration"] = {"board": "box"}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(spec))
    proc = subprocess.run([sys.executable, "-m", "pipeline", "capture", str(path), "--out", str(tmp_path / "c"),
                           "--quiet"], cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYOPENGL_PLATFORM": "egl"})
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "calibration.board" in lines[0] and "bad.yaml" in lines[0]
    assert not (tmp_path / "c").exists()
