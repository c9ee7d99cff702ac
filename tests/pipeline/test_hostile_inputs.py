"""Hostile and careless input through the real ``lumigraph`` process (issue 14).

* ``--out`` never deletes a user's files: a folder of the user's files, a plain file or another
  stage's folder is refused (exit 2, one line naming the path, nothing touched) unless
  ``--overwrite``; a stage's own finished folder is replaced as before.
* Names read from input files never become paths outside the output folder: a view named
  ``../../x`` or ``/abs`` in a cameras.json is exit 2 naming the file and field.
* Corrupted stage inputs (missing or damaged cameras.json, truncated EXR, random-byte PNG, mixed
  image sizes, a missing manifest, ``--poses`` of another scene): exit 2, one stderr line naming
  the file (and field), no traceback, nothing written.
* ``nerf --minutes`` bounds the stage: the plan recorded in metrics.json is consistent (not a
  timing assertion: the figures are checked against each other and the budget).

One tiny capture (TINY_SCENE at 64x48) is made once per module; every case works on a copy.
"""
from __future__ import annotations

import copy
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import MANIFEST, Manifest
from render.camera_io import write_cameras_json
from render.image_io import read_exr, write_exr, write_png

from ..recon.nerf_fixtures import tiny_cameras
from .conftest import TINY_SCENE, write_scene

SIZE = (64, 48)


def lumigraph(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    """The real command (``--quiet`` added for the verbs that have it)."""
    quiet = ["--quiet"] if args[0] not in ("inspect", "report") else []
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args), *quiet],
                          capture_output=True, text=True, timeout=timeout)


def one_error_line(proc: subprocess.CompletedProcess) -> str:
    """Exit 2 with exactly one stderr line and no traceback; returns the line."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    return lines[0]


def leftovers(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".partial" in p.name or ".old-" in p.name] if folder.exists() else []


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    """``art/`` laid out as artifacts/<scene>: a real capture of the tiny scene, a reference made
    of the capture's held-out images (zero variance), a finished model folder rendering them, and
    ``other_poses/``: a finished poses folder of another scene (10 views named view_000..)."""
    root = tmp_path_factory.mktemp("hostile")
    spec = copy.deepcopy(TINY_SCENE)
    spec["cameras"]["intrinsics"].update(width=SIZE[0], height=SIZE[1])
    scene = write_scene(root / "scenes", spec)
    art = root / "art"
    proc = lumigraph("capture", scene, "--out", art / "capture", "--workers", "0")
    assert proc.returncode == 0, proc.stderr
    cameras = json.loads((art / "capture" / "cameras.json").read_text())["cameras"]
    tests = [c["name"] for c in cameras if c["split"] == "test"]
    for v in tests:
        rgb = read_exr(art / "capture" / "linear" / f"{v}.exr")
        write_exr(art / "reference" / "linear" / f"{v}.exr", rgb)
        write_exr(art / "reference" / "variance" / f"{v}.exr", np.zeros_like(rgb))
        write_exr(art / "model" / "renders" / f"{v}.exr", 0.9 * rgb)
    ref_cams = {"format": "lumigraph.cameras/1", "cameras": [c for c in cameras if c["split"] == "test"]}
    (art / "reference" / "cameras.json").write_text(json.dumps(ref_cams))
    Manifest("reference", params={"spp": 1}).write(art / "reference")
    Manifest("slab").write(art / "model")
    other, splits = tiny_cameras()
    write_cameras_json(root / "other_poses" / "cameras.json", other, splits)
    Manifest("poses", params={"method": "gt"}).write(root / "other_poses")
    return root


@pytest.fixture
def work(pristine, tmp_path) -> Path:
    """A private copy of the pristine tree."""
    shutil.copytree(pristine / "art", tmp_path / "art")
    shutil.copytree(pristine / "other_poses", tmp_path / "other_poses")
    return tmp_path


# ------------------------------------------------------------------------------ corruptions


def _cameras(folder: Path) -> tuple[Path, dict]:
    path = folder / "cameras.json"
    return path, json.loads(path.read_text())


def _first_train(folder: Path) -> str:
    return next(c["name"] for c in _cameras(folder)[1]["cameras"] if c["split"] == "train")


def no_cameras(art: Path, where: str) -> None:
    (art / where / "cameras.json").unlink()


def nan_pose(art: Path, where: str) -> None:
    path, doc = _cameras(art / where)
    doc["cameras"][0]["cam_to_world"][0][3] = math.nan
    path.write_text(json.dumps(doc))  # Python's json writes NaN, and reads it back


def inf_intrinsics(art: Path, where: str) -> None:
    path, doc = _cameras(art / where)
    doc["cameras"][0]["intrinsics"]["fx"] = math.inf
    path.write_text(json.dumps(doc))


def _rename_view(art: Path, where: str, new: str) -> None:
    """Rename camera 0 in cameras.json (its files keep their names: the reader must refuse first)."""
    path, doc = _cameras(art / where)
    doc["cameras"][0]["name"] = new
    path.write_text(json.dumps(doc))


def view_traversal(art: Path, where: str) -> None:
    _rename_view(art, where, "../../escaped_view")


def absolute_view(art: Path, where: str) -> None:
    _rename_view(art, where, str(art.parent / "escaped_abs"))


def truncated_exr(art: Path, where: str) -> None:
    folder = art / where
    name = _first_train(folder) if where == "capture" else _cameras(folder)[1]["cameras"][0]["name"]
    path = folder / "linear" / f"{name}.exr"
    path.write_bytes(path.read_bytes()[:600])


def random_png(art: Path, where: str) -> None:
    path = art / where / "images" / f"{_first_train(art / where)}.png"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes())


def mixed_sizes(art: Path, where: str) -> None:
    """A later view's files at half the size (a resized image dropped into the capture)."""
    name = [c["name"] for c in _cameras(art / where)[1]["cameras"] if c["split"] == "train"][1]
    write_png(art / where / "images" / f"{name}.png", np.zeros((SIZE[1] // 2, SIZE[0] // 2, 3), np.uint8))
    write_exr(art / where / "linear" / f"{name}.exr", np.zeros((SIZE[1] // 2, SIZE[0] // 2, 3), np.float32))


def no_manifest(art: Path, where: str) -> None:
    (art / where / MANIFEST).unlink()


def poses_of_another_scene(art: Path, where: str) -> None:
    pass  # the verb is given --poses other_poses (a finished poses folder of a 10-view scene)


# (verb, extra args, corruption, folder corrupted, words the one stderr line must hold)
CASES = [
    ("inspect", (), random_png, "capture", ("train_000.png", "unreadable")),
    ("poses", ("--method", "gt"), no_cameras, "capture", ("cameras.json",)),
    ("poses", ("--method", "gt"), nan_pose, "capture", ("cameras.json", "cam_to_world")),
    ("poses", ("--method", "gt"), view_traversal, "capture", ("cameras.json", "'name'", "path separator")),
    ("poses", ("--method", "gt"), random_png, "capture", ("train_000.png", "unreadable")),
    ("poses", ("--method", "gt"), mixed_sizes, "capture", ("train_001.png", "mixed image sizes")),
    ("poses", ("--method", "gt"), no_manifest, "capture", ("capture", "manifest.json")),
    ("poses", ("--method", "charuco"), inf_intrinsics, "capture", ("cameras.json", "intrinsics.fx")),
    ("poses", ("--method", "charuco"), absolute_view, "capture", ("cameras.json", "'name'", "path separator")),
    ("slab", (), truncated_exr, "capture", ("train_000.exr",)),
    ("slab", ("--poses", "{other_poses}"), poses_of_another_scene, "capture", ("other_poses", "cameras.json", "name")),
    ("slab", (), mixed_sizes, "capture", ("train_001", "mixed image sizes")),
    ("nerf", ("--minutes", "0.5"), truncated_exr, "capture", ("train_000.exr",)),
    ("nerf", ("--minutes", "0.5"), view_traversal, "capture", ("cameras.json", "'name'", "path separator")),
    ("nerf", ("--minutes", "0.5", "--poses", "{other_poses}"), poses_of_another_scene, "capture",
     ("other_poses", "cameras.json", "name")),
    ("validate", (), truncated_exr, "reference", ("reference", "test_000.exr", "unreadable")),
    ("validate", (), view_traversal, "reference", ("reference", "cameras.json", "'name'", "path separator")),
    ("validate", (), nan_pose, "reference", ("reference", "cameras.json", "cam_to_world")),
]


@pytest.mark.parametrize("verb, args, corrupt, where, words", CASES,
                         ids=[f"{c[0]}{'-' + c[1][1] if c[0] == 'poses' else ''}-{c[2].__name__}" for c in CASES])
def test_corrupted_input_exits_2_with_one_line_and_writes_nothing(work, verb, args, corrupt, where, words):
    """Each damage, through the verb that reads it: exit 2, one stderr line naming the file (and
    field), no traceback, no output folder, no partial folder, nothing outside the output."""
    art = work / "art"
    corrupt(art, where)
    before = sorted(p.relative_to(work) for p in work.rglob("*"))
    out = work / "out" / verb
    args = [a.format(other_poses=work / "other_poses") for a in args]
    if verb == "inspect":
        argv = ["inspect", art / "capture"]
    elif verb == "validate":
        argv = ["validate", art, "--out", out]
    else:
        argv = [verb, art / "capture", *args, "--out", out]
    line = one_error_line(lumigraph(*argv))
    for w in words:
        assert w in line, line
    assert not out.exists() and not leftovers(work)
    assert sorted(p.relative_to(work) for p in work.rglob("*")) == before  # nothing written anywhere


# ------------------------------------------------------------------------------ --out


def test_out_refuses_a_folder_of_user_files_then_overwrite_replaces_it(work):
    """`capture --out DIR` on a folder holding the user's files used to delete them and exit 0."""
    scene = write_scene(work / "scenes", {**copy.deepcopy(TINY_SCENE), "cameras": {
        **TINY_SCENE["cameras"], "intrinsics": {"width": SIZE[0], "height": SIZE[1], "fov_y_deg": 40}}})
    mine = work / "mine"
    (mine / "sub").mkdir(parents=True)
    (mine / "thesis.tex").write_text("years of work")
    (mine / "sub" / "data.csv").write_text("1,2,3")
    line = one_error_line(lumigraph("capture", scene, "--out", mine, "--workers", "0"))
    assert str(mine) in line and "--overwrite" in line
    assert (mine / "thesis.tex").read_text() == "years of work" and (mine / "sub" / "data.csv").is_file()
    assert not leftovers(work)
    assert lumigraph("capture", scene, "--out", mine, "--workers", "0", "--overwrite").returncode == 0
    assert json.loads((mine / MANIFEST).read_text())["stage"] == "capture" and not (mine / "thesis.tex").exists()


def test_out_refuses_a_file_and_another_stages_folder(work):
    """`--out` on an existing file used to replace it with a folder; a capture folder is not a
    poses folder; a stage's own finished folder is still replaced (re-runs work)."""
    art = work / "art"
    notes = work / "notes.txt"
    notes.write_text("keep me")
    line = one_error_line(lumigraph("poses", art / "capture", "--method", "gt", "--out", notes))
    assert str(notes) in line and notes.read_text() == "keep me"
    capture_files = sorted(p.relative_to(art) for p in (art / "capture").rglob("*"))
    line = one_error_line(lumigraph("poses", art / "capture", "--method", "gt", "--out", art / "capture"))
    assert "'capture'" in line and "'poses'" in line
    assert sorted(p.relative_to(art) for p in (art / "capture").rglob("*")) == capture_files
    out = art / "poses" / "gt"
    for _ in range(2):  # the second run replaces the first's finished folder
        assert lumigraph("poses", art / "capture", "--method", "gt", "--out", out).returncode == 0
        assert json.loads((out / MANIFEST).read_text())["stage"] == "poses" and not leftovers(art)


def test_failed_charuco_leaves_only_its_failure_record_and_reruns_over_it(work):
    """The tiny capture is too small for the board detector: a finding, not bad input. The folder
    holds only metrics.json (status failed, no manifest: never looks finished), written
    atomically, and the next run replaces it (pipeline_run records failed estimates this way)."""
    art = work / "art"
    out = art / "poses" / "charuco"
    for _ in range(2):
        line = one_error_line(lumigraph("poses", art / "capture", "--method", "charuco", "--out", out))
        assert "no calibration board" in line and str(out / "metrics.json") in line
        assert sorted(p.name for p in out.iterdir()) == ["metrics.json"] and not leftovers(art)
        assert json.loads((out / "metrics.json").read_text())["status"] == "failed"


def test_report_out_does_not_clobber_an_unrelated_file(work):
    """`report --out FILE` used to replace any file silently: now only a report, or --overwrite."""
    art = work / "art"
    assert lumigraph("validate", art).returncode == 0
    page = work / "page.html"
    page.write_text("<html>my homepage</html>")
    line = one_error_line(lumigraph("report", art, "--out", page))
    assert str(page) in line and page.read_text() == "<html>my homepage</html>"
    for extra in (["--overwrite"], []):  # the user insists; then a report replaces a report
        proc = lumigraph("report", art, "--out", page, *extra)
        assert proc.returncode == 0 and "lumigraph report" in page.read_text(), proc.stderr


# ------------------------------------------------------------------------------ nerf time bound


def test_eval_factor_takes_the_finest_scale_that_fits():
    """Closed form: cost(k) = s_per_ray * rays / k^2; the smallest k with cost <= available."""
    from pipeline.stages.nerf import eval_factor, eval_factors

    assert eval_factors(64, 48) == [1, 2, 4, 8, 16]
    assert eval_factor(1e-3, 10_000, 10.0, [1, 2, 4]) == 1           # 10 s fits 10 s
    assert eval_factor(1e-3, 10_000, 2.5, [1, 2, 4]) == 2            # 10 / 4 = 2.5
    assert eval_factor(1e-3, 10_000, 2.49, [1, 2, 4]) == 4
    assert eval_factor(1e-3, 10_000, 0.1, [1, 2, 4]) == 4            # nothing fits: the coarsest


def test_nerf_minutes_bounds_the_stage_and_records_a_consistent_plan(work):
    """`nerf --minutes 1` on the tiny capture: the plan in metrics.json fits the budget. (A step
    of the untrained fast model costs seconds, 256 rays x 400 samples, so the budget is not made
    smaller: the plan's figures are checked against each other, not the clock.)"""
    from pipeline.stages.nerf import (FULL_RES_SHARE, RENDER_MARGIN, RENDER_SHARE, WRITE_S_PER_MPIX, eval_factor,
                                      eval_factors)

    art = work / "art"
    out = art / "nerf" / "fast"
    proc = lumigraph("nerf", art / "capture", "--minutes", "1", "--out", out, "--workers", "0")
    assert proc.returncode == 0, proc.stderr
    m = json.loads((out / "metrics.json").read_text())
    t, plan, done = m["time"], m["time"]["planned"], m["time"]["actual"]
    assert t["budget_s"] == 60.0 and done["stopped_by"] in ("deadline", "budget")
    assert done["train_wall_s"] <= plan["train_s"] <= t["budget_s"]
    # the evaluation scale: the finest whose cost fits what was left after training, else the coarsest
    w, h = json.loads((out / MANIFEST).read_text())["params"]["working_size"]
    k = plan["eval_factor"]
    assert plan["eval_size"] == [w // k, h // k] and w % k == 0 and h % k == 0
    # the fast model renders at the capture's size too (render_full_res, the default) when it fits
    rays_full = len(m["views"]) * SIZE[0] * SIZE[1]
    rays_done = len(m["views"]) * w * h / k ** 2 + (rays_full if plan["render_full_res"] else 0)
    assert plan["render_s_per_ray"] * rays_done == pytest.approx(plan["render_s"], abs=2e-3)
    if plan["render_full_res"]:  # done when its cost, the margin spent, fits what was left
        assert k == 1 and plan["render_s"] <= RENDER_MARGIN * plan["render_budget_s"]
    else:
        assert plan["render_s"] <= plan["render_budget_s"] or k == max(eval_factors(w, h))
    if k > 1:  # a finer scale would not have fitted
        assert plan["render_s"] * k ** 2 / eval_factors(w, h)[eval_factors(w, h).index(k) - 1] ** 2 > plan["render_budget_s"]
    # training was first planned around the renders' reserve (their first measured cost: at the
    # capture's size when that fits FULL_RES_SHARE of the budget, else at the finest scale fitting
    # RENDER_SHARE of it) and the writes
    rays, views_s, s = len(m["views"]) * w * h, plan["render_s_per_view"] * len(m["views"]), plan["render_s_per_ray_first"]
    if s * (rays + rays_full) <= FULL_RES_SHARE * t["budget_s"] - views_s:
        reserve = s * (rays + rays_full) + views_s
    else:
        k_first = eval_factor(s, rays, RENDER_SHARE * t["budget_s"] - views_s, eval_factors(w, h))
        reserve = min(s * rays / k_first ** 2 + views_s, RENDER_SHARE * t["budget_s"])
    writes = WRITE_S_PER_MPIX * len(m["views"]) * SIZE[0] * SIZE[1] / 1e6
    assert plan["after_training_s_first"] >= reserve + writes - 2e-3  # (rounded to ms)
    assert plan["train_s_first"] <= t["budget_s"] - plan["load_s"] - plan["after_training_s_first"]
    assert all(math.isfinite(v) for v in (m["display_psnr_mean"], m["display_ssim_mean"], m["linear_psnr_mean"]))
    for r in m["views"]:  # written at the capture's size whatever the evaluation scale
        assert read_exr(out / "renders" / f"{r['view']}.exr").shape == (SIZE[1], SIZE[0], 3)
    assert (out / "curve.csv").read_text().splitlines()[-1].startswith(f"{m['steps']},")


#: the stage's own phases may overrun its budget by 10% (issue 15: "wall time at most 1.1 M")
BUDGET_SLACK = 1.1
#: the process's start-up beside the stage (interpreter, torch, torch._dynamo, the CLI): measured in
#: the test by importing the same modules in a fresh interpreter just before (5.8 s CPU; 6 s of
#: wall on idle cores, 45 s at a load average of 11 on 2 cores), allowed x START_UP_FACTOR + START_UP_PAD_S
START_UP_FACTOR, START_UP_PAD_S = 1.5, 5.0


def test_nerf_minutes_bounds_the_whole_stage_through_the_cli(work):
    """`nerf --minutes 0.2` (12 s) on the tiny capture: the stage's own clock, from the call to the
    last file written before metrics.json, stays within 1.1 x 12 s; its recorded phases (load,
    training, held-out renders, writing) account for that time; and the whole process, start-up
    included, ends within 1.1 x 12 s plus the start-up allowance measured here (module constants).
    Before the render-cost probe was sized to the time left and torch._dynamo imported with the
    stage, the same command ran 38 s of stage time (the probe alone 10 s, the first optimizer's
    import 25 s) on loaded cores."""
    t0 = time.perf_counter()
    probe = subprocess.run([sys.executable, "-c", "import pipeline.cli, pipeline.stages.nerf, kornia.metrics"],
                           capture_output=True, text=True, timeout=600)
    start_up_s = time.perf_counter() - t0
    assert probe.returncode == 0, probe.stderr
    out = work / "art" / "nerf" / "bounded"
    t0 = time.perf_counter()
    proc = lumigraph("nerf", work / "art" / "capture", "--minutes", "0.2", "--out", out, "--workers", "0")
    wall_s = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    t = json.loads((out / "metrics.json").read_text())["time"]
    done = t["actual"]
    assert t["budget_s"] == 12.0
    assert done["stage_s"] <= BUDGET_SLACK * t["budget_s"], done
    phases = done["load_s"] + done["train_total_s"] + done["render_s"] + done["write_s"]
    assert phases <= done["stage_s"] + 0.01 and done["stage_s"] - phases < 1.0, (phases, done)
    assert wall_s <= BUDGET_SLACK * t["budget_s"] + START_UP_FACTOR * start_up_s + START_UP_PAD_S, (wall_s, start_up_s)
    manifest = json.loads((out / MANIFEST).read_text())["metrics"]
    assert manifest["stage_s"] == done["stage_s"] and manifest["budget_s"] == 12.0
