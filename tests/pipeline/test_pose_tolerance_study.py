"""``lumigraph study pose_tolerance`` (issue 21, part 4): the perturbations in closed form, and the
study through the real CLI process at the tests' size (LUMIGRAPH_POSE_STUDY_SIZE=tiny)."""
import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.report_poses import pose_tolerance_section
from pipeline.stages.pose_tolerance_study import loss_headline, perturb_cameras, random_rotations
from render.camera import Camera, Intrinsics

from .conftest import TINY_SCENE, write_scene

REPO = Path(__file__).resolve().parents[2]


def lumigraph(*args, env=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=REPO, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "PYOPENGL_PLATFORM": "egl", **(env or {})})


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1)))


def test_perturbations_in_closed_form():
    """Rotations turn each camera by exactly the level about its own centre (angle of R^T R' from
    its trace), a different axis per camera; focal errors scale fx and fy by 1 + level / 100;
    no_distortion zeroes the lens and nothing else."""
    k = Intrinsics(64, 48, 60.0, 61.0, 32.5, 23.7, (-0.1, 0.02, 0.001, 0.0, 0.0))
    rng = np.random.default_rng(1)
    cams = []
    for i in range(5):
        m = np.eye(4)
        m[:3, :3] = random_rotations(1, 40.0 * i, rng)[0]
        m[:3, 3] = rng.normal(size=3)
        cams.append(Camera(k, m, f"train_{i:03d}"))
    for level in (0.01, 1.0):
        turned = perturb_cameras(cams, "rotation_deg", level, seed=3)
        for c, t in zip(cams, turned):
            assert _angle_deg(c.cam_to_world[:3, :3], t.cam_to_world[:3, :3]) == pytest.approx(level, rel=1e-6)
            assert np.array_equal(c.center, t.center) and t.intrinsics == c.intrinsics
            assert np.allclose(t.cam_to_world[:3, :3].T @ t.cam_to_world[:3, :3], np.eye(3), atol=1e-12)
        axes = [Rotation_axis(c.cam_to_world[:3, :3].T @ t.cam_to_world[:3, :3]) for c, t in zip(cams, turned)]
        assert min(np.linalg.norm(a - b) for a, b in zip(axes, axes[1:])) > 1e-3
    focal = perturb_cameras(cams, "focal_pct", 2.0, seed=0)
    assert all(f.intrinsics.fx == pytest.approx(60.0 * 1.02) and f.intrinsics.fy == pytest.approx(61.0 * 1.02)
               and f.intrinsics.cx == 32.5 and np.array_equal(f.cam_to_world, c.cam_to_world) for f, c in zip(focal, cams))
    flat = perturb_cameras(cams, "no_distortion", 1.0, seed=0)
    assert all(not f.intrinsics.has_distortion and f.intrinsics.fx == 60.0 for f in flat)
    with pytest.raises(ValueError, match="unknown perturbation"):
        perturb_cameras(cams, "shear", 1.0, seed=0)


def Rotation_axis(r: np.ndarray) -> np.ndarray:
    """Unit axis of rotation matrix ``r`` (from its skew part; angle well inside (0, pi))."""
    a = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return a / np.linalg.norm(a)


@pytest.fixture(scope="module")
def lens_capture(tmp_path_factory) -> Path:
    """The tiny scene through a lens (k1 -0.3) with two train rings of 6 (30 and 50 deg) around the
    held-out ring (40 deg), so the rebinned slab's uv planes span the held-out cameras."""
    root = tmp_path_factory.mktemp("pose_tolerance")
    ring = {"distance": 0.8}
    spec = {**TINY_SCENE, "name": "tiny_lens", "sensor": {"distortion": True},
            "cameras": {"intrinsics": {"width": 128, "height": 96, "fx": 132.0, "fy": 132.0, "cx": 64.6, "cy": 47.4,
                                       "dist": [-0.3, 0.05, 0.0, 0.0, 0.0]},
                        "train": [{"ring": {**ring, "elevation_deg": 30, "count": 6}},
                                  {"ring": {**ring, "elevation_deg": 50, "count": 6, "azimuth_offset_deg": 30}}],
                        "test": [{"ring": {**ring, "elevation_deg": 40, "count": 2, "azimuth_offset_deg": 45}}]}}
    scene = write_scene(root / "scenes", spec)
    proc = lumigraph("capture", scene, "--out", root / "capture", "--quiet")
    assert proc.returncode == 0, proc.stderr
    return root / "capture"


def test_a_nerf_that_stopped_short_gives_no_loss_figure():
    """Session 35's real_lens study: one point's NeRF hit the minutes cap at 17 of 150 steps and its
    'loss' read as the focal error's. A point (or the truth) whose NeRF stopped short now has no NeRF
    loss, only the reason; the slab's loss stays, and complete points keep theirs."""
    rows = [{"kind": "truth", "name": "truth", "nerf_steps": 150, "nerf_display_psnr": 21.0, "slab_display_psnr": 26.0},
            {"kind": "rotation_deg", "name": "rotation_deg_1", "nerf_steps": 150, "nerf_display_psnr": 20.3,
             "slab_display_psnr": 18.3},
            {"kind": "focal_pct", "name": "focal_pct_0.1", "nerf_steps": 17, "nerf_display_psnr": 12.0,
             "slab_display_psnr": 25.5}]
    got = {h["figure"]: h for h in loss_headline(rows, 150)}
    assert got["nerf loss, rotation_deg_1"]["value"] == 0.7 and got["slab loss, rotation_deg_1"]["value"] == 7.7
    assert got["nerf loss, focal_pct_0.1"]["value"] is None
    assert "stopped at 17 of 150 steps" in got["nerf loss, focal_pct_0.1"]["note"]
    assert got["slab loss, focal_pct_0.1"]["value"] == 0.5
    rows[0]["nerf_steps"] = 40  # the truth stopped short: no NeRF loss is comparable
    assert all(h["value"] is None for h in loss_headline(rows, 150) if h["figure"].startswith("nerf"))


def test_pose_tolerance_study_through_the_cli(lens_capture, tmp_path):
    """At the tests' size (one rotation, one focal error, the lens dropped; 3 NeRF steps, uv 4):
    the folder holds the table, both plots and summary.json, every figure finite, and the report's
    pose section shows them; a 1 degree
    rotation costs the slab >= 1 dB (measured 3.2 dB at 128x96: 26.1 -> 23.0 dB, 2.3 px of misregistration)."""
    out = tmp_path / "study_pose_tolerance"  # where the report looks, beside the scene's stages
    proc = lumigraph("study", "pose_tolerance", "--capture", lens_capture, "--out", out, "--quiet",
                     env={"LUMIGRAPH_POSE_STUDY_SIZE": "tiny"})
    assert proc.returncode == 0, proc.stderr
    assert "study pose_tolerance: 4 points" in proc.stdout
    rows = list(csv.DictReader((out / "points.csv").open()))
    assert [r["name"] for r in rows] == ["truth", "rotation_deg_1", "focal_pct_2", "no_distortion"]
    assert all(math.isfinite(float(r[k])) for r in rows for k in ("nerf_display_psnr", "slab_display_psnr"))
    psnr = {r["name"]: float(r["slab_display_psnr"]) for r in rows}
    print("slab display PSNR", psnr)
    assert psnr["truth"] - psnr["rotation_deg_1"] >= 1.0, psnr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["figures"] == ["rotation.svg", "focal.svg"] and summary["settings"]["nerf_steps"] == 3
    for f in summary["figures"]:
        assert (out / f).read_text().startswith("<svg")
    assert not (out / "points").exists()  # the models are deleted, only the figures stay
    assert json.loads((out / "manifest.json").read_text())["stage"] == "pose_tolerance_study"
    section = pose_tolerance_section(tmp_path)  # the report's pose section
    assert section.count("<svg") == 2 and "rotation_deg_1" in section and "no_distortion" in section
    assert "no study_pose_tolerance/" in pose_tolerance_section(tmp_path / "elsewhere")


@pytest.mark.parametrize("args, word", [((), "--capture"), (("--capture", "{capture}", "--poses", "/nonexistent"), "--poses"),
                                        (("--capture", "/nonexistent"), "--capture")])
def test_pose_tolerance_bad_input_is_one_line_exit_2(lens_capture, tmp_path, args, word):
    args = [a.replace("{capture}", str(lens_capture)) for a in args]
    proc = lumigraph("study", "pose_tolerance", *args, "--out", tmp_path / "s", "--quiet")
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and word in proc.stderr, proc.stderr
    assert not (tmp_path / "s").exists()
