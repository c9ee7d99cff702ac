"""The nerf stage's wall time against its budget (issue 15: ``--minutes M`` bounds the whole stage,
training, held-out renders and writing, to at most 1.1 M of wall time on a quiet machine).

Runs the stage (``pipeline.stages.nerf.run_nerf``, the fast model with ``render_full_res``) and
reads what it recorded in ``metrics.json``: ``time.budget_s`` and ``time.actual.stage_s`` (from the
stage's start to its last file). Every run must end within ``BOUND`` x the budget; the 1-minute load
average before and after each run is recorded beside it (the bound is for a quiet machine: read an
overrun under load with that figure). Without arguments (``make bench``) the tiny fog-cube capture
of tests/recon/nerf_fixtures.py with the shrunk fast model on a 24 s budget (the check the unit test
tests/pipeline/test_nerf_plan.py made before timed bounds moved here); on the default scene::

    .venv/bin/python -m bench.bench_nerf_budget --capture artifacts/turntable/capture \\
        --reference artifacts/turntable/reference --minutes 3.5 --repeats 1

Writes ``bench/results/bench_nerf_budget.json``; raises ``BudgetOverrun`` (after writing) when a run
ended past the bound.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

from bench.common import write_result

#: the stage's wall time may exceed its budget by 10% (issue 15: "wall time at most 1.1 M")
BOUND = 1.1


class BudgetOverrun(RuntimeError):
    """A nerf stage ended past ``BOUND`` x its budget."""


def run_stage(capture: Path, reference: Path | None, minutes: float, out: Path, downsample: int | None,
              overrides: dict) -> dict:
    """One stage run; its budget, wall time, ratio and what stopped training, with the load."""
    from pipeline.stages.nerf import NerfStageConfig, run_nerf

    load0 = os.getloadavg()[0]
    run_nerf(capture, None, out, NerfStageConfig("fast", minutes, downsample=downsample, overrides=overrides),
             reference, quiet=True, overwrite=True)
    m = json.loads((out / "metrics.json").read_text())
    t = m["time"]
    stage_s, budget_s = t["actual"]["stage_s"], t["budget_s"]
    return {"budget_s": budget_s, "stage_s": stage_s, "ratio": round(stage_s / budget_s, 4),
            "within_bound": stage_s <= BOUND * budget_s, "stopped_by": t["actual"]["stopped_by"],
            "render_full_res": t["planned"]["render_full_res"], "render_s": t["actual"]["render_s"],
            "render_s_planned": t["planned"]["render_s"], "steps": m["steps"],
            "display_psnr_full_mean": m.get("display_psnr_full_mean"),
            "load_avg_1min_start": round(load0, 2), "load_avg_1min_end": round(os.getloadavg()[0], 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_nerf_budget", description=__doc__.splitlines()[0],
                                 allow_abbrev=False)
    ap.add_argument("--capture", type=Path, default=None,
                    help="a capture folder (default: the tests' tiny fog cube, shrunk fast model)")
    ap.add_argument("--reference", type=Path, default=None)
    ap.add_argument("--minutes", type=float, default=None, help="the stage's budget (default: 0.4 on the tiny capture, 3.5 else)")
    ap.add_argument("--downsample", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv or [])
    tmp = Path(tempfile.mkdtemp(prefix="bench_nerf_budget_"))
    try:
        if a.capture is None:
            from tests.recon.nerf_fixtures import FAST_SMALL, make_tiny_capture

            capture, overrides = make_tiny_capture(tmp / "capture"), dict(FAST_SMALL, render_full_res=True)
            minutes, downsample, name = a.minutes or 0.4, a.downsample or 2, "tiny fog cube (tests/recon/nerf_fixtures.py)"
        else:
            capture, overrides, minutes, downsample, name = a.capture, {}, a.minutes or 3.5, a.downsample, str(a.capture)
        runs = []
        for i in range(a.repeats):
            runs.append(run_stage(capture, a.reference, minutes, tmp / "nerf" / "fast", downsample, overrides))
            print(f"run {i}: {runs[-1]}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ratios = [r["ratio"] for r in runs]
    over = [i for i, r in enumerate(runs) if not r["within_bound"]]
    write_result("bench_nerf_budget", {"capture": name, "minutes": minutes, "bound": BOUND,
                                       "ratio_median": statistics.median(ratios), "ratio_max": max(ratios),
                                       "all_within_bound": not over, "runs": runs})
    if over:
        raise BudgetOverrun(f"nerf stage past {BOUND} x its {minutes} min budget in runs {over}: ratios "
                            f"{[ratios[i] for i in over]} (1-min load at their start "
                            f"{[runs[i]['load_avg_1min_start'] for i in over]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
