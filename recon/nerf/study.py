"""What accuracy costs in time: held-out PSNR against training minutes for several models (and
pose sources) on one capture, on one plot, by one command::

    python -m recon.nerf.study CAPTURE_DIR --out DIR --minutes 10 \
        --run fast --run vanilla --run vanilla_noview --run vanilla_nope \
        [--run colmap=fast@artifacts/turntable/poses/colmap] [--reference DIR]

Each ``--run`` is ``[label=]model[@poses_dir]``. Writes ``DIR/curves.csv`` (label, model, poses,
step, train_s, wall_s, psnr), ``DIR/curves.png`` (PSNR vs training minutes, one line per run,
plus the public factored-grid CPU reference points of the issue as crosses) and
``DIR/summary.json`` (final held-out PSNR per run). PSNR is at the working scale (see
:mod:`recon.nerf.data`), the mean over held-out views of whole images or of the model's fixed
pixel subsets (``curve_pixels``).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from render.image_io import atomic_path

from .data import load_data
from .models import MODELS
from .train import TrainConfig, train

__all__ = ["Run", "parse_run", "parse_settings", "run_study", "plot_curves", "PUBLIC_REFERENCE"]

#: the issue's scale: a public pure-PyTorch factored-grid NeRF on these 2 cores, 200x200 object
PUBLIC_REFERENCE = [(2.0, 28.0), (5.0, 35.0), (10.0, 38.0)]
_COLOURS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (255, 127, 14), (148, 103, 189), (140, 86, 75),
            (227, 119, 194), (127, 127, 127)]


@dataclass(frozen=True)
class Run:
    label: str
    model: str
    poses: Path | None = None


def parse_run(text: str) -> Run:
    """``[label=]model[@poses_dir]`` -> :class:`Run` (ValueError naming the known models)."""
    label, _, rest = text.rpartition("=") if "=" in text else ("", "", text)
    model, _, poses = rest.partition("@")
    if model not in MODELS:
        raise ValueError(f"--run {text!r}: unknown model {model!r}; known: {sorted(MODELS)}")
    return Run(label or (f"{model}@{Path(poses).name}" if poses else model), model, Path(poses) if poses else None)


def plot_curves(path: Path, curves: dict[str, list[dict]], title: str, size=(900, 560)) -> None:
    """PSNR (dB) against training minutes, one polyline per label; PNG written atomically."""
    W, H = size
    left, right, top, bottom = 70, 200, 40, 60
    img = Image.new("RGB", size, "white")
    dr = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    pts = [(r["train_s"] / 60.0, r["psnr"]) for c in curves.values() for r in c] + PUBLIC_REFERENCE
    xmax = max([p[0] for p in pts] + [1.0])
    ys = [p[1] for p in pts]
    ymin, ymax = np.floor(min(ys) / 5) * 5, np.ceil(max(ys) / 5) * 5
    ymax = max(ymax, ymin + 5)

    def xy(x, y):
        return (left + (W - left - right) * x / xmax, H - bottom - (H - top - bottom) * (y - ymin) / (ymax - ymin))

    dr.rectangle([left, top, W - right, H - bottom], outline="black")
    for y in np.arange(ymin, ymax + 1e-9, 5):
        px, py = xy(0, y)
        dr.line([(left, py), (W - right, py)], fill=(225, 225, 225))
        dr.text((left - 40, py - 6), f"{y:.0f}", fill="black", font=font)
    step = max(1, int(np.ceil(xmax / 10)))
    for x in range(0, int(np.floor(xmax)) + 1, step):
        px, _ = xy(x, ymin)
        dr.text((px - 4, H - bottom + 6), str(x), fill="black", font=font)
    dr.text(((W - right + left) / 2 - 60, H - bottom + 26), "training minutes (2 CPU cores)", fill="black", font=font)
    dr.text((8, top - 25), "held-out PSNR (dB)", fill="black", font=font)
    dr.text((left + 150, 10), title, fill="black", font=font)
    for i, (label, c) in enumerate(curves.items()):
        col = _COLOURS[i % len(_COLOURS)]
        line = [xy(r["train_s"] / 60.0, r["psnr"]) for r in c]
        if len(line) > 1:
            dr.line(line, fill=col, width=2)
        for p in line:
            dr.ellipse([p[0] - 2, p[1] - 2, p[0] + 2, p[1] + 2], fill=col)
        dr.line([(W - right + 10, top + 10 + 18 * i), (W - right + 35, top + 10 + 18 * i)], fill=col, width=3)
        dr.text((W - right + 40, top + 4 + 18 * i), label, fill="black", font=font)
    n = len(curves)
    for x, y in PUBLIC_REFERENCE:
        px, py = xy(x, y)
        dr.line([(px - 5, py - 5), (px + 5, py + 5)], fill="black", width=2)
        dr.line([(px - 5, py + 5), (px + 5, py - 5)], fill="black", width=2)
    dr.text((W - right + 10, top + 4 + 18 * n), "x public factored-grid\n  CPU reference (issue)", fill="black", font=font)
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")


_MISSING = object()


def parse_settings(items: list[str], runs: list[Run]) -> dict[str, tuple]:
    """``FIELD=VALUE`` strings -> {model: overrides} for :class:`recon.nerf.train.TrainConfig`.
    A field applies to every run whose model config has it (values are parsed as that field's
    type); a field no run's model has is a ValueError naming it."""
    per_model: dict[str, list] = {r.model: [] for r in runs}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep:
            raise ValueError(f"--set {item!r}: expected FIELD=VALUE")
        used = False
        for model in per_model:
            default = getattr(MODELS[model][1], name, _MISSING)
            if default is _MISSING:
                continue
            if default is None or isinstance(default, int) and not isinstance(default, bool):
                value = None if text.lower() == "none" else int(text)
            elif isinstance(default, bool):
                value = text.lower() in ("1", "true", "yes")
            elif isinstance(default, float):
                value = float(text)
            else:
                raise ValueError(f"--set {item!r}: field {name!r} of model {model!r} cannot be set from the command line")
            per_model[model].append((name, value))
            used = True
        if not used:
            raise ValueError(f"--set {item!r}: no run's model config has a field {name!r}")
    return {m: tuple(v) for m, v in per_model.items()}


def run_study(capture_dir, runs: list[Run], minutes: float, out, reference_dir=None, downsample: int | None = None,
              seed: int = 0, eval_every_s: float = 30.0, log=print, clock: str = "wall",
              settings: dict[str, tuple] | None = None) -> dict:
    """Train every run for ``minutes`` of training time; write curves.csv, curves.png,
    summary.json into ``out``; return the summary {label: {model, poses, final_psnr, steps}}.
    clock: "wall" or "cpu" (see :class:`recon.nerf.train.TrainConfig`); settings: {model:
    overrides of its config} (:func:`parse_settings`), recorded in summary.json."""
    settings = settings or {}
    out = Path(out)
    curves, summary = {}, {}
    rows = []
    for run in runs:
        data = load_data(capture_dir, run.poses, reference_dir, downsample)
        log(f"study: {run.label} ({run.model}, poses {data.poses}) for {minutes} min")
        res = train(data, TrainConfig(model=run.model, minutes=minutes, seed=seed, eval_every_s=eval_every_s,
                                      clock=clock, overrides=settings.get(run.model, ())))
        curves[run.label] = res.curve
        summary[run.label] = {"model": run.model, "poses": data.poses, "final_psnr": res.curve[-1]["psnr"],
                              "steps": res.steps, "train_s": round(res.train_s, 1),
                              "settings": dict(settings.get(run.model, ()))}
        rows += [{"label": run.label, "model": run.model, "poses": str(run.poses or "gt"), **r} for r in res.curve]
        log(f"study: {run.label}: {res.curve[-1]['psnr']:.2f} dB after {res.steps} steps")
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=["label", "model", "poses", "step", "train_s", "wall_s", "psnr"],
                       lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    with atomic_path(out / "curves.csv") as tmp:
        Path(tmp).write_text(buf.getvalue())
    scale = data.test[0].camera.intrinsics
    plot_curves(out / "curves.png", curves, f"NeRF held-out PSNR vs time, {scale.width}x{scale.height}")
    with atomic_path(out / "summary.json") as tmp:
        Path(tmp).write_text(json.dumps({"minutes": minutes, "clock": clock, "downsample": data.downsample,
                                         "runs": summary}, indent=2))
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
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
    runs = [parse_run(r) for r in (a.run or ["fast", "vanilla", "vanilla_noview", "vanilla_nope"])]
    summary = run_study(a.capture_dir, runs, a.minutes, a.out, a.reference, a.downsample, a.seed,
                        a.eval_every, clock=a.clock, settings=parse_settings(a.set, runs))
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
