"""The irradiance cache through the real CLI process: ``lumigraph reference ... --integrator
irradiance_cache`` (renders on the Cornell box, refuses cleanly where it cannot reach an effect)
and ``lumigraph study caching`` at its tests' size (``LUMIGRAPH_CACHING_SIZE=tiny``: the quick
profile takes over a minute on 2 cores; tiny checks the files and the lecture contract)."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from render.image_io import read_exr

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYOPENGL_PLATFORM": "egl"}


def _lumigraph(*args, env=ENV, timeout=600):
    return subprocess.run([sys.executable, "-m", "pipeline", *args], cwd=ROOT, capture_output=True, text=True,
                          env=env, timeout=timeout)


def test_reference_with_the_cache_on_the_cornell_box_and_refusals(tmp_path):
    """Exit 0 and a finite, lit EXR on the Cornell box at toy size; exit 2 with one stderr line
    naming the integrator and the effect on a scene with glass and mirrors, nothing written."""
    out = tmp_path / "ref"
    r = _lumigraph("reference", "cornell", "--integrator", "irradiance_cache", "--size", "12", "12", "--spp", "4",
                   "--out", str(out), "-q")
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["params"]["integrator"] == "irradiance_cache"
    exrs = sorted((out / "linear").glob("*.exr"))
    assert len(exrs) == 1
    img = read_exr(exrs[0])
    assert img.shape == (12, 12, 3) and np.all(np.isfinite(img)) and img.mean() > 0.01
    bad = tmp_path / "bad"
    r = _lumigraph("reference", "cornell_spheres", "--integrator", "irradiance_cache", "--size", "8", "8",
                   "--spp", "4", "--out", str(bad), "-q")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "irradiance_cache" in lines[0] and "cannot reach effect" in lines[0], r.stderr
    assert not bad.exists()


def test_study_caching_writes_its_files_and_the_lecture_contract(tmp_path):
    """``lumigraph study caching`` (tiny size): every CSV, SVG and PNG the summary names, one
    equal-time row per scene and error bound with finite RMSEs, the contract's fields."""
    out = tmp_path / "caching"
    r = _lumigraph("study", "caching", "--out", str(out), "-q", env={**ENV, "LUMIGRAPH_CACHING_SIZE": "tiny"})
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["size"] == "tiny" and summary["title"] and summary["claim"]
    for fig in summary["figures"]:
        assert (out / fig).stat().st_size > 0, fig
    assert all({"figure", "value", "unit", "note"} <= set(h) for h in summary["headline"])
    with open(out / "caching_equal_time.csv") as f:
        rows = list(csv.DictReader(f))
    assert {(row["scene"], float(row["error_bound"])) for row in rows} == {
        (s, a) for s in ("cornell", "turntable") for a in (0.3, 0.8)}
    for row in rows:
        assert all(np.isfinite(float(row[k])) and float(row[k]) > 0 for k in ("cache_rmse", "path_rmse", "cache_s"))
        assert int(row["records"]) > 0
    with open(out / "caching_bias.csv") as f:
        assert len(list(csv.DictReader(f))) == 4
    assert json.loads((out / "manifest.json").read_text())["stage"] == "lecture_caching"
    r = _lumigraph("study", "caching", "--out", str(tmp_path / "x"), "-q", env={**ENV, "LUMIGRAPH_CACHING_SIZE": "huge"})
    assert r.returncode == 2 and "LUMIGRAPH_CACHING_SIZE" in r.stderr and not (tmp_path / "x").exists()
