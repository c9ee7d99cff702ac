"""The end-to-end matrix (issue 14): every advertised path through the ``lumigraph`` process.

Everything runs as a user would run it: ``python -m pipeline ...`` in a subprocess, judged by its
real exit code, stderr and files. Tiny sizes keep the whole file within a few minutes:

* every built-in scene (``scenes/*.yaml``) through ``capture`` (on a copy of its spec shrunk to
  32x24 pixels and at most 2 views per split, everything else identical: capture has no size
  option) and through ``reference`` with its default (``auto``) integrator and default views
  (``--spp 1 --size 16 12``);
* every integrator ``--integrator`` accepts through ``reference`` on the Cornell box's own
  camera at 16x16 with SPP = 9 (above the stage's SAMPLE_BATCH = 8, so units really split: two
  sample batches, or eight sppm / nine pssmlt groups); ``direct`` cannot reach interreflection
  and must be refused with exit 2 and one line; sppm and pssmlt (whose units are groups) once more with
  ``--workers 2`` (a Dask local cluster), byte for byte the same files;
* ``lumigraph run`` on the tiny scene (tests/pipeline/conftest.py) through validate and report,
  unstubbed, then ``lumigraph inspect`` on every stage folder it wrote;
* what cannot fit is refused before any allocation: ``--spp 99999999999`` and ``--size 100000
  100000`` exit 2 with one line naming the option and the bound, within seconds.

Shared work (the shrunken specs, the renders, the run) lives in module-scoped fixtures; the
independent single-process commands run two at a time (:func:`lumigraph_all`: most of a tiny
command's time is the interpreter importing, on one core), the Dask runs and ``run`` alone.
"""
from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.stages.reference import MAX_SPP, SAMPLE_BATCH
from render.image_io import read_exr
from render.metrics import PSNR_MAX_DB

from .conftest import TINY_SCENE, write_scene

REPO = Path(__file__).resolve().parents[2]
SCENES = sorted(p.stem for p in (REPO / "scenes").glob("*.yaml"))
INTEGRATORS = ("direct", "path", "volpath", "bdpt", "pssmlt", "sppm", "auto")
#: refused combinations on the Cornell box (exit 2, one line naming the reason)
REFUSED = {"direct": "interreflection"}
SPP = SAMPLE_BATCH + 1
TWO_WORKERS = ("sppm", "pssmlt")


def lumigraph(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m pipeline args`` from the repository root, output captured."""
    env = dict(os.environ, PYOPENGL_PLATFORM="egl")
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=timeout)


def lumigraph_all(commands: dict, parallel: int = 2) -> dict:
    """{key: lumigraph(*args)} for {key: args}, ``parallel`` processes at a time."""
    with ThreadPoolExecutor(parallel) as pool:
        futures = {k: pool.submit(lumigraph, *args) for k, args in commands.items()}
        return {k: f.result() for k, f in futures.items()}


def assert_ok(r: subprocess.CompletedProcess) -> None:
    assert r.returncode == 0, f"exit {r.returncode}\n{r.stderr[-3000:]}"
    assert "Traceback" not in r.stderr


def assert_refused(r: subprocess.CompletedProcess, *words: str) -> None:
    """Exit 2 with exactly one stderr line naming every word, no traceback."""
    lines = [l for l in r.stderr.splitlines() if l.strip()]
    assert r.returncode == 2 and len(lines) == 1, f"exit {r.returncode}\n{r.stderr[-3000:]}"
    for w in words:
        assert w in lines[0], (w, lines[0])


def finite_images(folder: Path) -> list[Path]:
    """Every EXR under ``folder``: read, finite; returns their paths (at least one)."""
    files = sorted(folder.rglob("*.exr"))
    assert files, f"no EXR under {folder}"
    for f in files:
        assert np.all(np.isfinite(read_exr(f))), f
    return files


def shrunk(spec: dict) -> dict:
    """A built-in spec with 32x24 images and at most 2 views per split (the first layout of each
    split; rings of at most 2 cameras); everything else identical."""
    out = copy.deepcopy(spec)
    cams = out["cameras"]
    intr = cams["intrinsics"]
    intr["width"], intr["height"] = 32, 24
    for split, layouts in cams.items():
        if split == "intrinsics":
            continue
        first = copy.deepcopy(layouts[0])
        if "ring" in first:
            first["ring"]["count"] = min(first["ring"]["count"], 2)
        cams[split] = [first]
    return out


# ---------------------------------------------------------------- every built-in scene
@pytest.fixture(scope="module")
def scene_runs(tmp_path_factory) -> dict[tuple[str, str], tuple[subprocess.CompletedProcess, Path]]:
    """For every built-in scene: capture of its shrunk copy, and its default reference."""
    root = tmp_path_factory.mktemp("scenes")
    commands, outs = {}, {}
    for name in SCENES:
        spec = yaml.safe_load((REPO / "scenes" / f"{name}.yaml").read_text())
        copy_path = write_scene(root / "specs", shrunk(spec), f"{name}.yaml")
        outs[name, "capture"] = root / name / "capture"
        commands[name, "capture"] = ("capture", copy_path, "--out", outs[name, "capture"], "--quiet")
        outs[name, "reference"] = root / name / "reference"
        commands[name, "reference"] = ("reference", name, "--spp", 1, "--size", 16, 12, "--out",
                                       outs[name, "reference"], "--quiet")
    results = lumigraph_all(commands)
    return {k: (results[k], outs[k]) for k in commands}


@pytest.mark.parametrize("name", SCENES)
def test_every_scene_captures(name, scene_runs):
    """capture of each built-in scene (shrunk copy): exit 0, finite linear images, a manifest."""
    r, out = scene_runs[name, "capture"]
    assert_ok(r)
    assert (out / "manifest.json").is_file()
    finite_images(out / "linear")


@pytest.mark.parametrize("name", SCENES)
def test_every_scene_renders_its_default_reference(name, scene_runs):
    """reference of each built-in scene with its defaults (auto integrator; auto views: the test
    views, else the scene camera): exit 0, finite mean and variance images at 16x12, integrator
    recorded. Media (cornell_fog, glowing_smoke) and glossy (veach_mis) scenes crashed here
    (KeyError 'rays'); cornell's scene-only views exited 2."""
    r, out = scene_runs[name, "reference"]
    assert_ok(r)
    m = json.loads((out / "manifest.json").read_text())
    assert m["params"]["integrator"] in INTEGRATORS and m["metrics"]["views"] >= 1
    for f in finite_images(out):
        assert read_exr(f).shape[:2] == (12, 16)


# ---------------------------------------------------------------- every integrator
@pytest.fixture(scope="module")
def integrator_renders(tmp_path_factory) -> dict[tuple[str, int], subprocess.CompletedProcess]:
    root = tmp_path_factory.mktemp("integrators")
    commands = {(integ, workers): ("reference", "cornell", "--views", "scene", "--spp", SPP, "--size", 16, 16,
                                   "--integrator", integ, "--workers", workers, "--out", root / f"{integ}-w{workers}",
                                   "--quiet")
                for integ in INTEGRATORS for workers in ((0, 2) if integ in TWO_WORKERS else (0,))}
    results = lumigraph_all({k: a for k, a in commands.items() if k[1] == 0})
    results.update({k: lumigraph(*a) for k, a in commands.items() if k[1] == 2})  # a cluster uses both cores
    return {k: (results[k], root / f"{k[0]}-w{k[1]}") for k in commands}


@pytest.mark.parametrize("integ", INTEGRATORS)
def test_every_integrator_through_the_reference_verb(integ, integrator_renders):
    """Each --integrator on the Cornell box at 16x16, 9 spp (split into units): exit 0 with finite
    mean and variance (variance > 0 somewhere: sppm's is the spread of its groups, no longer
    all zeros), or a refusal with exit 2 and one line. sppm and pssmlt exited 1 here (their
    sample ranges could not be split)."""
    r, out = integrator_renders[integ, 0]
    if integ in REFUSED:
        assert_refused(r, "--integrator", REFUSED[integ])
        assert not out.exists()
        return
    assert_ok(r)
    m = json.loads((out / "manifest.json").read_text())
    assert m["params"]["spp"] == SPP and m["params"]["units_per_view"] >= 2
    assert integ == "auto" or m["params"]["integrator"] == integ
    (mean,) = finite_images(out / "linear")
    (var,) = finite_images(out / "variance")
    assert read_exr(mean).max() > 0 and read_exr(var).max() > 0
    assert m["metrics"]["paths_per_s"] > 0


@pytest.mark.parametrize("integ", TWO_WORKERS)
def test_two_workers_give_the_same_bytes(integ, integrator_renders):
    """The same render in process and on a 2-worker Dask local cluster: every output file
    (mean, variance, preview, cameras) byte for byte equal (the fold in unit order)."""
    (r0, out0), (r2, out2) = integrator_renders[integ, 0], integrator_renders[integ, 2]
    assert_ok(r0)
    assert_ok(r2)
    m0, m2 = (json.loads((o / "manifest.json").read_text()) for o in (out0, out2))
    assert m2["metrics"]["workers"] == 2 and m0["metrics"]["workers"] != 2
    assert m0["outputs"] == m2["outputs"] and len(m0["outputs"]) >= 4
    for f in sorted((out0 / "linear").glob("*.exr")) + sorted((out0 / "variance").glob("*.exr")):
        assert f.read_bytes() == (out2 / f.relative_to(out0)).read_bytes(), f


# ---------------------------------------------------------------- what cannot fit
@pytest.mark.parametrize("args, words", [
    (["--spp", "99999999999"], ["--spp", str(MAX_SPP)]),
    (["--size", "100000", "100000"], ["--size 100000 100000", "available"]),
])
def test_what_cannot_fit_is_refused_before_allocating(args, words, tmp_path):
    """Refused with exit 2 and one line naming the option and its bound, nothing written, in
    seconds (it took 37 s and 10 GB to fail, or tried to allocate 224 GiB)."""
    t0 = time.perf_counter()
    r = lumigraph("reference", "cornell", *args, "--out", tmp_path / "ref", "--quiet", timeout=60)
    assert_refused(r, *words)
    assert not (tmp_path / "ref").exists() and time.perf_counter() - t0 < 30


# ---------------------------------------------------------------- lumigraph run, then inspect
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    root = tmp_path_factory.mktemp("run")
    scene = write_scene(root / "scenes", TINY_SCENE)
    r = lumigraph("run", scene, "--root", root / "artifacts", "--spp", 2, "--nerf-minutes", 0.5, "--quiet",
                  timeout=900)
    return r, root / "artifacts" / "tiny"


def test_run_goes_through_validate_and_report(tiny_run):
    """`lumigraph run` on the tiny scene, unstubbed: exit 0, the report exists, validate judged
    at least one model and its metrics are finite numbers (PSNRs at most PSNR_MAX_DB)."""
    r, art = tiny_run
    assert_ok(r)
    report = art / "validate" / "report.html"
    assert report.is_file() and report.stat().st_size > 0 and str(report) in r.stdout
    metrics = json.loads((art / "validate" / "metrics.json").read_text())
    assert metrics["models"] and metrics["best"]["model"]

    def numbers(x):
        if isinstance(x, dict):
            for v in x.values():
                yield from numbers(v)
        elif isinstance(x, list):
            for v in x:
                yield from numbers(v)
        elif isinstance(x, (int, float)) and not isinstance(x, bool):
            yield float(x)

    values = list(numbers(metrics))
    assert values and all(math.isfinite(v) for v in values)
    for model in metrics["models"].values():
        assert 0 < model["display_psnr_mean"] <= PSNR_MAX_DB and 0 < model["linear_psnr_mean"] <= PSNR_MAX_DB


def test_inspect_every_stage_folder_run_wrote(tiny_run):
    """`lumigraph inspect` on every finished stage folder of the run (every manifest.json):
    exit 0, and its table names the folder's stage."""
    r, art = tiny_run
    assert_ok(r)
    folders = sorted(m.parent for m in art.rglob("manifest.json") if not any(p.startswith(".") for p in m.parts))
    stages = {json.loads((f / "manifest.json").read_text())["stage"] for f in folders}
    assert {"capture", "reference", "poses", "slab", "nerf", "validate"} <= stages
    for f, res in lumigraph_all({f: ("inspect", f, "--no-sheet") for f in folders}).items():
        assert_ok(res)
        stage = json.loads((f / "manifest.json").read_text())["stage"]
        assert f"'{stage}'" in res.stdout, res.stdout  # the title "<folder> - stage '<stage>'" (may wrap)


def test_exact_match_metrics_are_written_as_finite_json(tiny_run, tmp_path):
    """Hard case: a model that reproduces its reference exactly. The slab stage's scoring
    (pipeline.stages.slab.score_slab_views, on the run's slab set, against its own render of a
    captured view) and the NeRF stage's (recon.nerf.train.evaluate_view, an untrained model
    against its own render) give PSNR_MAX_DB and SSIM 1, and their metrics write as strict JSON
    (pipeline.artifacts.write_json, allow_nan=False), where +inf used to crash both stages."""
    from pipeline.artifacts import write_json
    from pipeline.stages.capture import read_cameras
    from pipeline.stages.slab import score_slab_views
    from recon.nerf.data import View
    from recon.nerf.models import make_model
    from recon.nerf.train import evaluate_view, render_view as nerf_render
    from render.camera import Camera, Intrinsics
    from render.lightfield import load_slabs, render_pinhole as slab_render

    r, art = tiny_run
    assert_ok(r)
    slabs = load_slabs(art / "slab" / "slabs")
    cams, splits = read_cameras(art / "capture" / "cameras.json")
    cam = [c for c, s in zip(cams, splits) if s == "train"][0]  # the tiny scene's test views miss the slabs
    own = slab_render(slabs, cam, "depth", (0.0, 0.0, 0.0))
    assert own.max() > 0
    metrics, _ = score_slab_views(slabs, [cam], [own], modes=("depth",))
    assert metrics["depth"]["display_psnr_mean"] == metrics["depth"]["linear_psnr_mean"] == PSNR_MAX_DB
    assert metrics["depth"]["display_ssim_mean"] == 1.0
    write_json(tmp_path / "slab_metrics.json", metrics)

    model = make_model("fast", -np.ones(3), np.ones(3)).eval()
    small = Camera(Intrinsics.from_fov(8, 6, 50.0), cam.cam_to_world, "exact")
    view = View("exact", small, nerf_render(model, small)["rgb"], small)
    row, _ = evaluate_view(model, view, False)
    assert row["display_psnr"] == row["linear_psnr"] == PSNR_MAX_DB and row["display_ssim"] == 1.0
    write_json(tmp_path / "nerf_metrics.json", {"display_psnr_mean": float(np.mean([row["display_psnr"]])),
                                                "views": [row]})
    for name in ("slab_metrics.json", "nerf_metrics.json"):
        json.loads((tmp_path / name).read_text())
