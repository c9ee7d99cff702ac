"""The study on the tiny scene with a minimal sweep (2 spp values x 2 integrators, gt and ChArUco
poses — the latter fails at 128x96 and must be recorded, not fatal — one slab grid point in every
mode, rebinning on the gt poses): its files, the Pareto flags, what the sweep must show (more
samples, less error), and that the report embeds its fronts."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.artifacts import BadInput, read_manifest, sha256_file
from pipeline.report import write_report
from pipeline.stages.study import PROFILES, StudyConfig, derived_scene, pareto_rows, run_study

from .conftest import write_scene
from .test_validate import TINY_E2E, tiny_artifacts  # noqa: F401  (the shared session fixture)

MINI = StudyConfig(size_scale=1.0, test_views=0, truth_spp=16, spp=(1, 8), integrators=("direct", "path"),
                   poses=(("gt", 1.0), ("charuco", 1.0)), slab_grid=((4, 24),), rebin_grid=(4, 24), nerf=())


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("study")
    scene = write_scene(root / "scenes", TINY_E2E)
    out = root / "study"
    run_study(scene, out, profile="mini", config=MINI, quiet=True)
    return out


def _rows(study, stage):
    return [r for r in json.loads((study / "study.json").read_text())["rows"] if r["stage"] == stage]


def test_study_writes_its_files_and_nothing_else(study):
    m = read_manifest(study)
    for rel, digest in m["outputs"].items():
        assert sha256_file(study / rel) == digest
    names = set(m["outputs"])
    assert {"study.csv", "study.json", "pareto.csv", "pareto_reference.svg", "pareto_poses.svg", "pareto_slab.svg",
            "pareto_end_to_end.svg"} <= names
    assert not any(n.startswith(".work") for n in names) and not (study / ".work").exists()
    rows = list(csv.DictReader((study / "study.csv").open()))
    assert rows and {"stage", "setting", "time_s", "display_psnr", "display_ssim", "linear_psnr", "pareto"} <= set(rows[0])
    assert list(rows[0])[6:9] == ["display_psnr", "display_ssim", "linear_psnr"]  # the field's figures first
    for f in study.glob("*.svg"):
        text = f.read_text()
        assert text.startswith("<svg") and "nan" not in text.lower().replace("nano", "")


def test_more_samples_less_error(study):
    """Path tracer: 8 spp has 1/8 the variance of 1 spp, ideally +9 dB; the 16 spp study reference's
    own noise (ceiling 43.6 dB) takes some of it. Measured 2026-11-22 (linear PSNR): direct 31.19 ->
    38.80 dB (+7.6), path 30.99 -> 38.59 dB (+7.6); the test asks for +3 dB of linear PSNR, and a
    higher display PSNR (the sRGB curve reweights the same noise)."""
    pt = {(r["family"], r["spp"]): r for r in _rows(study, "reference") if r["status"] == "ok" and r["family"] != "truth"}
    for integ in ("direct", "path"):
        assert pt[(integ, 8)]["linear_psnr"] > pt[(integ, 1)]["linear_psnr"] + 3.0, (integ, pt[(integ, 8)], pt[(integ, 1)])
        assert pt[(integ, 8)]["display_psnr"] > pt[(integ, 1)]["display_psnr"], (integ, pt[(integ, 8)], pt[(integ, 1)])


def test_failed_points_are_recorded_not_fatal(study):
    poses = {r["setting"]: r for r in _rows(study, "poses")}
    assert poses["gt"]["status"] == "ok" and poses["gt"]["rotation_error_deg"] == 0.0
    assert poses["charuco"]["status"] == "failed" and "charuco" in poses["charuco"]["reason"]
    assert [r for r in _rows(study, "slab") if r.get("poses") == "gt"], "slab rebinned on the gt poses is missing"


def test_pareto_flags_are_the_fronts(study):
    doc = json.loads((study / "study.json").read_text())
    for stage in ("reference", "poses", "slab", "end_to_end"):
        rows = [r for r in doc["rows"] if r["stage"] == stage and r["status"] == "ok"]
        front = [r for r in rows if r["pareto"]]
        assert front and {r["setting"] for r in front} == set(doc["fronts"][stage])
        acc = "rotation_error_deg" if stage == "poses" else "display_psnr"
        cost = "end_to_end_s" if stage == "end_to_end" else "time_s"
        sign = -1 if stage == "poses" else 1
        best = max(rows, key=lambda r: (sign * r[acc], -r[cost]))
        assert best["pareto"]  # the most accurate (cheapest among ties) is always on the front
    for r in (r for r in doc["rows"] if r["stage"] == "end_to_end"):
        assert r["end_to_end_s"] >= r["time_s"]


def test_pareto_rows_handles_missing_values():
    rows = [{"time_s": 1.0, "display_psnr": 20.0}, {"time_s": 2.0, "display_psnr": None},
            {"time_s": 3.0, "display_psnr": 25.0}, {"time_s": 4.0, "display_psnr": 24.0}]
    assert pareto_rows(rows) == [True, False, True, False]
    assert pareto_rows(rows, lower_is_better=True) == [True, False, False, False]


def test_derived_scene_scales_the_images_and_cuts_the_test_rings(tmp_path):
    data = json.loads(json.dumps(TINY_E2E))
    data["textures"]["photo"] = {"image": "photo.png"}
    data["cameras"]["test"][0]["ring"]["count"] = 5
    src = write_scene(tmp_path / "src", data)
    path = derived_scene(src, tmp_path / "work", 0.5, 2)
    d = yaml.safe_load(path.read_text())
    assert (d["cameras"]["intrinsics"]["width"], d["cameras"]["intrinsics"]["height"]) == (64, 48)
    assert d["cameras"]["test"][0]["ring"]["count"] == 2
    assert d["cameras"]["train"] == TINY_E2E["cameras"]["train"]
    assert d["textures"]["photo"]["image"] == str((tmp_path / "src" / "photo.png").resolve())


def test_bad_profile_and_scene_are_bad_input(tmp_path):
    from rig.spec import SpecError

    with pytest.raises(BadInput, match="profile"):
        run_study("turntable", tmp_path / "o", profile="slow")
    with pytest.raises(SpecError):
        run_study(tmp_path / "none.yaml", tmp_path / "o")
    assert not (tmp_path / "o").exists()
    assert set(PROFILES) == {"quick", "full"}


def test_report_embeds_the_study(study, tiny_artifacts, tmp_path):  # noqa: F811
    art = tmp_path / "tiny"
    shutil.copytree(tiny_artifacts, art)
    shutil.copytree(study, art / "study")
    text = write_report(art).read_text()
    assert text.count("<svg") >= 1 + len(list(study.glob("*.svg")))
    assert "Study: Pareto-optimal settings" in text and "light slab: resolution x interpolation" in text
    assert np.isfinite(json.loads((study / "study.json").read_text())["psnr_noise_ceiling"])


def test_nerf_study_writes_its_table_plot_and_summary(tmp_path):
    """The NeRF study's files from given curves (no training): the table keeps every digit, the
    SVG (pipeline.plot) holds a line per run plus the public reference points, the summary is JSON."""
    from recon.nerf.study import CURVES_COLUMNS, NerfStudy

    from pipeline.stages.nerf_study import write_nerf_study

    curves = {"a": [{"step": i, "train_s": 30.0 * i, "wall_s": 31.0 * i, "display_psnr": 20.0 + i / 3,
                     "linear_psnr": 25.0 + i / 3} for i in range(1, 5)],
              "b": [{"step": 7, "train_s": 60.0, "wall_s": 61.0, "display_psnr": 18.0, "linear_psnr": 23.0}]}
    rows = [{"label": k, "model": "fast", "poses": "gt", **r} for k, c in curves.items() for r in c]
    write_nerf_study(tmp_path, NerfStudy(curves, rows, {"a": {"final_display_psnr": 21.3}}, 2.0, "wall", 8, (160, 120)))
    table = list(csv.DictReader((tmp_path / "curves.csv").open()))
    assert list(table[0]) == list(CURVES_COLUMNS) and len(table) == 5
    assert float(table[0]["display_psnr"]) == 20.0 + 1 / 3  # repr: every digit kept
    assert float(table[0]["linear_psnr"]) == 25.0 + 1 / 3
    svg = (tmp_path / "curves.svg").read_text()
    assert svg.startswith("<svg") and svg.count("<polyline") == 1  # "b" has one point: nothing to join
    assert ">a</text>" in svg and "public factored-grid CPU reference" in svg and "160x120" in svg
    assert json.loads((tmp_path / "summary.json").read_text())["runs"]["a"]["final_display_psnr"] == 21.3


def test_full_profile_sweeps_the_fast_nerf_at_2_5_and_10_minutes():
    """Issue 15: the study's NeRF front is display PSNR at capture resolution against 2, 5 and 10
    minutes of the stage (its wall time on the x axis)."""
    from pipeline.stages.study import PROFILES
    assert [m for model, m in PROFILES["full"].nerf if model == "fast"] == [2.0, 5.0, 10.0]


def _study_cli(*args):
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYOPENGL_PLATFORM="egl")
    return subprocess.run([sys.executable, "-m", "pipeline", "study", *map(str, args)],
                          cwd=Path(__file__).resolve().parents[2], env=env, capture_output=True, text=True,
                          timeout=600)


def test_study_only_runs_the_named_sweeps_through_the_cli(tmp_path):
    """`lumigraph study SCENE --only reference`: the path tracer's sweep and nothing of poses, slab or
    NeRF (the quick profile would train two NeRFs); its front drawn, the others absent."""
    scene = write_scene(tmp_path / "scenes", TINY_E2E)
    out = tmp_path / "study"
    proc = _study_cli(scene, "--only", "reference", "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    rows = json.loads((out / "study.json").read_text())["rows"]
    stages = {r["stage"] for r in rows}
    assert stages == {"reference"}, stages
    quick = PROFILES["quick"]
    assert sum(r["family"] != "truth" for r in rows if r["stage"] == "reference") == len(quick.spp) * len(quick.integrators)
    assert (out / "pareto_reference.svg").is_file() and not (out / "pareto_nerf.svg").exists()
    assert json.loads((out / "study.json").read_text())["config"]["stages"] == ["reference"]


@pytest.mark.parametrize("args, field", [(("--only", "render"), "--only"),
                                         (("pose_tolerance", "--only", "nerf"), "--only")])
def test_study_only_refuses_what_it_cannot_select(tmp_path, args, field):
    scene_args = args if args[0] == "pose_tolerance" else (write_scene(tmp_path / "scenes", TINY_E2E), *args)
    out = tmp_path / "study"
    proc = _study_cli(*scene_args, "--out", out, "--quiet")
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and field in lines[0], proc.stderr
    assert not out.exists()
