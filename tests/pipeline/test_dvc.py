"""`dvc repro` runs the project's dvc.yaml for real (local cache only, no remote)."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from pipeline.artifacts import read_manifest

from .conftest import TINY_SCENE, write_scene

REPO = Path(__file__).resolve().parents[2]


def test_dvc_repro_runs_every_stage_and_is_then_up_to_date(tmp_path):
    work = tmp_path / "proj"
    work.mkdir()
    shutil.copy(REPO / "dvc.yaml", work)
    for pkg in ("render", "rig", "recon", "pipeline"):  # the stages' code dependencies
        shutil.copytree(REPO / pkg, work / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    write_scene(work / "scenes", TINY_SCENE)
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params.update(scene="tiny")
    params["reference"]["spp"] = 4
    params["poses"]["method"] = "gt"  # six 128x96 views are too few for SfM; the stage wiring is what is tested
    params["slab"].update(uv_res=4, st_per_pixel=0.5)
    params["nerf"].update(minutes=0.05)  # a few seconds of training: the wiring is what is tested
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    bin_dir = Path(sys.executable).parent
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "DVC_NO_ANALYTICS": "1"}
    dvc = [str(bin_dir / "dvc")]
    run = lambda *a: subprocess.run(dvc + list(a), cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert run("init", "--no-scm", "-q").returncode == 0
    first = run("repro")
    assert first.returncode == 0, first.stderr + first.stdout
    m = read_manifest(work / "artifacts" / "tiny" / "capture")
    assert m["stage"] == "capture" and m["metrics"]["views"] == 6
    ref = read_manifest(work / "artifacts" / "tiny" / "reference")
    assert ref["params"]["spp"] == 4 and ref["metrics"]["views"] == 2
    assert read_manifest(work / "artifacts" / "tiny" / "poses" / "gt")["stage"] == "poses"
    assert read_manifest(work / "artifacts" / "tiny" / "slab")["stage"] == "slab"
    assert read_manifest(work / "artifacts" / "tiny" / "nerf" / "fast")["stage"] == "nerf"
    assert read_manifest(work / "artifacts" / "tiny" / "validate")["stage"] == "validate"
    assert (work / "artifacts" / "tiny" / "validate" / "report.html").is_file()
    assert (work / "dvc.lock").is_file()

    second = run("repro")  # unchanged: nothing is redone
    assert second.returncode == 0 and "Running stage" not in second.stdout, second.stdout
    assert second.stdout.count("didn't change") == 6

    shown = run("metrics", "show", "--json")
    assert shown.returncode == 0, shown.stderr
    metrics = json.loads(shown.stdout)
    files = next(iter(metrics.values()))["data"]
    assert "display_psnr_mean" in files["artifacts/tiny/nerf/fast/metrics.json"]["data"]
    assert "models" in files["artifacts/tiny/validate/metrics.json"]["data"]
    plots = run("plots", "show", "--json")
    assert plots.returncode == 0 and "curve.csv" in plots.stdout and "models.csv" in plots.stdout, plots.stderr

    # one parameter changed: only the stages downstream of it run again
    params["slab"].update(st_per_pixel=0.4)
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    third = run("repro")
    assert third.returncode == 0, third.stderr + third.stdout
    ran = {s for s in ("capture", "reference", "poses", "slab", "nerf", "validate")
           if f"Running stage '{s}'" in third.stdout}
    assert ran == {"slab", "validate"}, third.stdout


def test_params_yaml_holds_run_defaults_and_every_dependency_exists():
    """params.yaml's values are `lumigraph run`'s (pipeline.params.RunParams, stated once), and every
    code dependency dvc.yaml names exists in the tree (a moved module must move its dvc dep too)."""
    from pipeline.params import RunParams

    assert yaml.safe_load((REPO / "params.yaml").read_text()) == RunParams().as_params_yaml()
    stages = yaml.safe_load((REPO / "dvc.yaml").read_text())["stages"]
    deps = [d for s in stages.values() for d in s.get("deps", []) if "${" not in d]
    assert deps and all((REPO / d).exists() for d in deps), [d for d in deps if not (REPO / d).exists()]
