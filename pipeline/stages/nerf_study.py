"""NeRF models against training time on one plot: the command around :mod:`recon.nerf.study`::

    python -m pipeline.stages.nerf_study CAPTURE_DIR --out DIR --minutes 10 \
        --run fast --run vanilla --run vanilla_noview --run vanilla_nope \
        [--run colmap=fast@artifacts/turntable/poses/colmap] [--reference DIR]

Each ``--run`` is ``[label=]model[@poses_dir]``. Writes ``DIR/curves.csv`` (label, model, poses,
step, train_s, wall_s, display_psnr, linear_psnr), ``DIR/curves.svg`` (held-out display PSNR, 8-bit
sRGB as the public figures are, against training minutes, one line per run, plus the public
factored-grid CPU reference points as a separate series; drawn by :mod:`pipeline.plot`) and
``DIR/summary.json`` (final held-out display PSNR per run, the settings).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from recon.nerf.omp import passive_omp_wait

passive_omp_wait()  # before torch loads OpenMP (recon/nerf/omp.py)

from recon.nerf.study import CURVES_COLUMNS, PUBLIC_REFERENCE, NerfStudy, parse_run, parse_settings, run_study

from ..artifacts import write_json
from ..io import write_csv
from ..plot import Series, svg_plot, write_svg

__all__ = ["curves_plot", "write_nerf_study", "main"]


def curves_plot(curves: dict[str, list[dict]], title: str) -> str:
    """SVG: held-out display PSNR (dB, 8-bit sRGB) against training minutes, one line per label, and
    :data:`recon.nerf.study.PUBLIC_REFERENCE` as unjoined points."""
    series = [Series(label, [r["train_s"] / 60.0 for r in c], [r["display_psnr"] for r in c], line=True)
              for label, c in curves.items()]
    series.append(Series("public factored-grid CPU reference", [m for m, _ in PUBLIC_REFERENCE],
                         [p for _, p in PUBLIC_REFERENCE], colour="#000000"))
    return svg_plot(series, "training minutes (2 CPU cores)", "held-out display PSNR (dB)", title)


def write_nerf_study(out: Path, study: NerfStudy) -> None:
    """curves.csv, curves.svg and summary.json of ``study`` into ``out`` (each file atomically)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "curves.csv", study.rows, CURVES_COLUMNS, float_format=None)
    w, h = study.working_size
    write_svg(out / "curves.svg", curves_plot(study.curves, f"NeRF held-out display PSNR vs time, {w}x{h}"))
    write_json(out / "summary.json", {"minutes": study.minutes, "clock": study.clock, "downsample": study.downsample,
                                      "runs": study.summary})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="NeRF models: held-out PSNR against training time")
    ap.add_argument("capture_dir", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--run", action="append", default=None, help="[label=]model[@poses_dir], repeatable")
    ap.add_argument("--reference", type=Path)
    ap.add_argument("--downsample", type=int, default=None, help="default: working width about 160 px")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--clock", default="wall", choices=["wall", "cpu"])
    ap.add_argument("--eval-every", type=float, default=30.0, help="training seconds between curve points")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a model config field for every run whose model has it, e.g. batch_rays=256")
    a = ap.parse_args(argv)
    try:
        runs = [parse_run(r) for r in (a.run or ["fast", "vanilla", "vanilla_noview", "vanilla_nope"])]
        settings = parse_settings(a.set, runs)
    except ValueError as exc:  # bad input: one line naming the field, exit 2
        print(f"error: {exc}", file=sys.stderr)
        return 2
    study = run_study(a.capture_dir, runs, a.minutes, a.reference, a.downsample, a.seed, a.eval_every,
                      clock=a.clock, settings=settings)
    write_nerf_study(a.out, study)
    print(json.dumps(study.summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
