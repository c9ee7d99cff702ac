"""``lumigraph study bias`` through the real process, at the tiny size (``LUMIGRAPH_BIAS_SIZE=tiny``).

Checked: every file, the manifest and the summary's lecture contract; a figure that can fail
(each sensor's unbiased curve estimate, seed s, against the independent reference, seed s + 1:
|difference| < 4 combined standard errors, two-sided alpha 6.3e-5 per sensor); the rows of the
estimates table; a bad size variable is exit 2 with one stderr line naming it, and no folder.
"""
import csv
import json
import math
import os
import subprocess
import sys

import pytest

from pipeline.stages.bias_study import HALL_SENSORS, Z95, first_inside

FILES = ("sensors.csv", "estimates.csv", "bias_error.svg", "summary.json", "manifest.json",
         *(f"bias_{s.name}.svg" for s in HALL_SENSORS))


def _lumigraph(*args, env=None):
    return subprocess.run([sys.executable, "-m", "pipeline", *args], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYOPENGL_PLATFORM": "egl", **(env or {})})


def _csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_study_bias_cli(tmp_path):
    out = tmp_path / "bias"
    run = _lumigraph("study", "bias", "--out", str(out), "--seed", "3", "-q", env={"LUMIGRAPH_BIAS_SIZE": "tiny"})
    assert run.returncode == 0, run.stderr
    for name in FILES:
        assert (out / name).is_file(), name
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["stage"] == "lecture_bias" and manifest["params"]["seed"] == 3
    summary = json.loads((out / "summary.json").read_text())
    assert summary["title"] and summary["claim"] and summary["size"] == "tiny" and summary["cache"] == "run"
    assert all({"figure", "value", "unit", "note"} <= set(r) for r in summary["headline"])
    # two overall rows, then one per (biased estimator, sensor)
    assert len(summary["headline"]) == 2 + 2 * len(HALL_SENSORS)
    assert summary["figures"] and all((out / f).is_file() for f in summary["figures"])

    sensors = {r["sensor"]: r for r in _csv(out / "sensors.csv")}
    assert list(sensors) == [s.name for s in HALL_SENSORS]
    rows = _csv(out / "estimates.csv")
    assert {r["estimator"] for r in rows} == {"unbiased", "photon", "cache"}
    for r in rows:
        assert all(math.isfinite(float(r[k])) for k in ("time_s", "E_r", "E_g", "E_b", "Y", "rel_error_pct"))
    # the figure that can fail: the curve's last unbiased estimate against the independent reference
    last = {}
    for r in rows:
        if r["estimator"] == "unbiased":
            last[r["sensor"]] = r  # rows are in budget order
    for name, ref in sensors.items():
        y_ref, se_ref = float(ref["Y"]), float(ref["Y_se"])
        assert y_ref > 0 and 0 < se_ref < 0.02 * y_ref, (name, y_ref, se_ref)
        r = last[name]
        se = (float(r["Y_hi"]) - float(r["Y_lo"])) / (2 * Z95)
        z = abs(float(r["Y"]) - y_ref) / math.hypot(se, se_ref)
        assert z < 4.0, f"{name}: unbiased curve {r['Y']} vs reference {y_ref} (|z| = {z:.2f})"

    bad = _lumigraph("study", "bias", "--out", str(tmp_path / "bad"), "-q", env={"LUMIGRAPH_BIAS_SIZE": "huge"})
    assert bad.returncode == 2 and not (tmp_path / "bad").exists()
    assert bad.stderr.strip().count("\n") == 0 and "LUMIGRAPH_BIAS_SIZE" in bad.stderr


@pytest.mark.parametrize("inside,expected", [([False, True, True], 1), ([True, False, True], 2), ([True, True], 0),
                                             ([True, False], None), ([], None)])
def test_first_inside(inside, expected):
    """The budget from which every later estimate stays inside (the headline's 'inside from')."""
    assert first_inside(inside) == expected
