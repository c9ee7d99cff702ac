"""Pose accuracy versus time: method x image scale x feature count, one command.

    .venv/bin/python -m bench.bench_poses [--capture DIR] [--scales 0.5,1] [--features 1024,4096,8192]

Without ``--capture`` the default scene is captured into a temporary folder first. Writes
``bench/results/bench_poses.csv`` (one row per cell) and ``bench/results/bench_poses.json``
(the rows plus each cell's time as a ratio to the ChArUco full-scale baseline of the same run),
and prints the table. Each cell runs once (COLMAP cells take tens of seconds on 2 cores).
"""
from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

from bench.common import RESULTS_DIR, write_result


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=None)
    ap.add_argument("--scales", default="0.5,1")
    ap.add_argument("--features", default="1024,4096,8192")
    ap.add_argument("--methods", default="charuco,colmap")
    a = ap.parse_args(argv)
    from pipeline.stages.poses import load_capture
    from recon.poses.study import STUDY_COLUMNS, pose_study

    with tempfile.TemporaryDirectory(prefix="bench-poses-") as tmp:
        cap_dir = a.capture
        if cap_dir is None:
            from pipeline.cli import main as cli

            cap_dir = Path(tmp) / "capture"
            if cli(["capture", "turntable", "--out", str(cap_dir), "--quiet"]) != 0:
                raise SystemExit("capture failed")
        cap = load_capture(cap_dir)
        rows = pose_study(cap.images, cap.cameras, cap.targets, [float(s) for s in a.scales.split(",")],
                          [int(f) for f in a.features.split(",")], a.methods.split(","))
    base = next((r["wall_time_s"] for r in rows if r["method"] == "charuco" and r["image_scale"] == 1.0), None)
    for r in rows:
        r["time_ratio_to_charuco_full"] = round(r["wall_time_s"] / base, 2) if base else None
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    cols = list(STUDY_COLUMNS) + ["time_ratio_to_charuco_full"]
    with open(RESULTS_DIR / "bench_poses.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    print(f"{'method':8} {'scale':>5} {'size':>9} {'features':>8} {'time s':>7} {'reg':>6} {'rot mean':>9} {'rot max':>8}")
    for r in rows:
        rot = "-" if r["rotation_error_deg_mean"] is None else f"{r['rotation_error_deg_mean']:.4f}"
        rmax = "-" if r["rotation_error_deg_max"] is None else f"{r['rotation_error_deg_max']:.3f}"
        print(f"{r['method']:8} {r['image_scale']:>5} {r['width']:>4}x{r['height']:<4} {str(r['max_features'] or '-'):>8} "
              f"{r['wall_time_s']:>7.1f} {r['registered']:>3}/{r['views']:<2} {rot:>9} {rmax:>8}")
    write_result("bench_poses", {"capture": str(a.capture or "default scene, fresh capture"), "rows": rows,
                                 "note": "one run per cell; times include image I/O; shared 2-core machine"})


if __name__ == "__main__":
    main()
