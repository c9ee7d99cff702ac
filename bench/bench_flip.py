"""ꟻLIP maps: render.metrics' torch port against NVIDIA's flip_evaluator on one held-out view.

Both implementations score the same pair (a model's render of a view against the reference),
LDR and HDR, interleaved (flip_evaluator, torch, flip_evaluator, ...) so a change in the shared
machine's load hits both alike; the figures are medians, their ratio, and how far the maps
differ (per-pixel max, mean). Writes bench/results/bench_flip.json with the load average before
and after.

    python -m bench.bench_flip [--artifacts artifacts/turntable] [--model slab] [--view test_000] [--repeats 3]

Without the artifacts folder it scores a synthetic 1280x960 pair (a lit disc on black, noise).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from bench.common import write_result


def _pair(artifacts: Path, model: str, view: str) -> tuple[np.ndarray, np.ndarray, str]:
    """(render, reference) linear (H, W, 3) and where they came from."""
    ref_path, pred_path = artifacts / "reference" / "linear" / f"{view}.exr", artifacts / model / "renders" / f"{view}.exr"
    if ref_path.is_file() and pred_path.is_file():
        from pipeline.io import read_image
        return read_image(pred_path), read_image(ref_path), f"{pred_path} vs {ref_path}"
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:960, 0:1280]
    ref = np.where(((yy - 480) ** 2 + (xx - 640) ** 2 < 300 ** 2)[..., None], rng.uniform(0.02, 0.3, 3), 0.0)
    pred = np.abs(ref + rng.normal(0.0, 0.01, ref.shape) * (ref > 0))
    return pred, ref, "synthetic 1280x960 disc"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_flip", description=__doc__.splitlines()[0],
                                 allow_abbrev=False)
    ap.add_argument("--artifacts", type=Path, default=Path("artifacts/turntable"))
    ap.add_argument("--model", default="slab")
    ap.add_argument("--view", default="test_000")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    from render.metrics import flip_map
    pred, ref, source = _pair(args.artifacts, args.model, args.view)
    load_before = os.getloadavg()
    times: dict[str, list[float]] = {}
    maps: dict[str, np.ndarray] = {}
    flip_map(pred[:64, :64], ref[:64, :64], True)  # warm-up: torch's first call, filter tables
    for _ in range(args.repeats):
        for kind, hdr in (("ldr", False), ("hdr", True)):
            for impl in ("flip_evaluator", "torch"):
                t0 = time.perf_counter()
                maps[f"{impl}_{kind}"] = flip_map(pred, ref, hdr, implementation=impl)
                times.setdefault(f"{impl}_{kind}", []).append(time.perf_counter() - t0)
    figures = {"source": source, "shape": list(ref.shape), "repeats": args.repeats,
               "load_average_before": load_before, "load_average_after": os.getloadavg()}
    for kind in ("ldr", "hdr"):
        c, t = maps[f"flip_evaluator_{kind}"], maps[f"torch_{kind}"]
        med_c, med_t = statistics.median(times[f"flip_evaluator_{kind}"]), statistics.median(times[f"torch_{kind}"])
        figures[kind] = {"flip_evaluator_s": times[f"flip_evaluator_{kind}"], "torch_s": times[f"torch_{kind}"],
                         "flip_evaluator_median_s": med_c, "torch_median_s": med_t, "speedup": med_c / med_t,
                         "mean_flip_evaluator": float(c.mean(dtype=np.float64)), "mean_torch": float(t.mean(dtype=np.float64)),
                         "max_abs_diff": float(np.abs(c - t).max()),
                         "fraction_over_1e-4": float((np.abs(c - t) > 1e-4).mean())}
    write_result("bench_flip", figures)


if __name__ == "__main__":
    main()
