"""The ``nerf`` stage: train a radiance field from a capture and render its held-out views.

Layout (DESIGN.md)::

    nerf/<model>/checkpoint.pt          model + optimizer state (resumable)
    nerf/<model>/renders/<view>.exr     linear RGB at the capture's resolution; <view>.png preview
    nerf/<model>/depth/<view>.exr       z-depth (0 where the opacity is below 0.5), same size
    nerf/<model>/metrics.json           PSNR / SSIM per held-out view, means, training figures
    nerf/<model>/curve.csv              held-out PSNR against training time
    nerf/<model>/manifest.json

Metrics are computed at the working scale (the capture area-averaged by ``downsample``, by default
the factor giving a width of about 160 pixels: 160x120 for the 1280x960 default scene), where the
model is trained. Renders are written at the capture's resolution as DESIGN.md asks, by repeating
each working-scale pixel (nearest); a model config with ``render_full_res=True`` renders every
pixel instead and also reports ``psnr_full`` / ``ssim_full`` (costly: 9.8M rays for 8 views at
1280x960). The reference is
``--reference DIR`` (``linear/<view>.exr``, the path tracer's stage) when given, else the
capture's own held-out images (exact for direct-only scenes rendered by the rasterizer).

Training runs in this process (one optimizer, one model: it does not split into independent units);
the held-out views are then rendered and scored one view per unit of work (pipeline.distributed,
``cluster``), the trained model shared once.

While training, checkpoints go to a hidden ``.<model>.resume.pt`` beside the stage folder, so an
interrupted run resumes with ``resume=True`` and a finished folder never looks half-written.
"""
from __future__ import annotations

import csv
import io
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from recon.nerf.data import NerfInputError, load_data
from recon.nerf.models import MODELS
from recon.nerf.train import TrainConfig, evaluate_view, train
from render.image_io import atomic_path, write_exr, write_preview

from ..artifacts import BadInput, Manifest, atomic_stage, read_manifest, write_json
from ..distributed import ClusterConfig, DaskEngine, LocalEngine, engine, map_units
from ..progress import progress_bar

__all__ = ["run_nerf", "nerf_view", "write_curve_csv", "CURVE_FIELDS"]

CURVE_FIELDS = ("step", "train_s", "wall_s", "psnr")


def write_curve_csv(path: Path, curve: list[dict]) -> None:
    """curve.csv: one row per held-out evaluation, columns ``CURVE_FIELDS`` (seconds, dB)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CURVE_FIELDS, lineterminator="\n")
    w.writeheader()
    for row in curve:
        w.writerow({k: row[k] for k in CURVE_FIELDS})
    with atomic_path(path) as tmp:
        Path(tmp).write_text(buf.getvalue())


def nerf_view(model, view, full_res: bool, threads: int) -> tuple[dict, dict]:
    """One unit of work: a held-out view rendered by the shared trained model and scored
    (:func:`recon.nerf.train.evaluate_view`) with ``threads`` torch threads (training's own count,
    so a view's reductions split as they do in the training process)."""
    import torch

    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    return evaluate_view(model, view, full_res)


def _resume_file(out: Path) -> Path:
    return out.parent / f".{out.name}.resume.pt"


def run_nerf(capture_dir: Path, poses_dir: Path | None, model: str, minutes: float, out: Path,
             reference_dir: Path | None = None, downsample: int | None = None, seed: int = 0,
             max_steps: int | None = None,
             resume: bool = False, quiet: bool = False, clock: str = "wall", overrides: dict | None = None,
             cluster: ClusterConfig | LocalEngine | DaskEngine | None = None) -> dict:
    """Train ``model`` for ``minutes`` of training time on ``capture_dir`` (poses from
    ``poses_dir``/cameras.json when given) and write ``out`` atomically; returns the manifest.
    clock: "wall" budget, or "cpu" (process CPU time / threads, for measuring on shared cores);
    overrides: fields of the model's config to replace (tests use small grids).
    cluster: where the held-out renders run, one view per unit (pipeline.distributed): None
    (default) in this process; training always runs here.

    Bad input (missing capture, images or cameras, unknown model) raises BadInput.
    """
    capture_dir = Path(capture_dir)
    out = Path(out)
    read_manifest(capture_dir)  # a finished capture stage, else BadInput
    if model not in MODELS:
        raise BadInput(f"--model: unknown NeRF model {model!r}; known: {', '.join(sorted(MODELS))}")
    if not (minutes > 0):
        raise BadInput(f"--minutes must be positive, got {minutes}")
    for what, folder in (("--poses", poses_dir), ("--reference", reference_dir)):
        if folder is not None and not Path(folder).is_dir():
            raise BadInput(f"{what} {folder}: no such folder")
    try:
        data = load_data(capture_dir, poses_dir, reference_dir, downsample)
    except NerfInputError as exc:
        raise BadInput(str(exc)) from None
    overrides = dict(overrides or {})
    downsample = data.downsample
    cfg = TrainConfig(model=model, minutes=minutes, max_steps=max_steps, seed=seed, clock=clock,
                      overrides=tuple(sorted(overrides.items())))
    model_cfg = replace(MODELS[model][1], **overrides)
    ckpt = _resume_file(out)
    if resume and not ckpt.exists() and (out / "checkpoint.pt").is_file():
        shutil.copyfile(out / "checkpoint.pt", ckpt)
    elif not resume and ckpt.exists():
        ckpt.unlink()
    small = data.test[0].camera.intrinsics
    full = data.test[0].full_camera.intrinsics
    manifest = Manifest("nerf", params={
        "model": model, "minutes": minutes, "clock": clock, "max_steps": max_steps, "seed": seed,
        "downsample": downsample,
        "working_size": [small.width, small.height], "render_size": [full.width, full.height],
        "render_full_res": bool(model_cfg.render_full_res), "poses": data.poses, "reference": data.reference,
        "background": "black (the scene's); masks unused", "box_lo": data.lo.tolist(), "box_hi": data.hi.tolist(),
        "overrides": {k: str(v) for k, v in overrides.items()}})
    manifest.add_input(capture_dir / "cameras.json")
    manifest.add_input(capture_dir / "linear")
    if poses_dir is not None:
        manifest.add_input(Path(poses_dir) / "cameras.json")
    if reference_dir is not None:
        manifest.add_input(Path(reference_dir) / "linear")

    with progress_bar(quiet) as bar:
        task = bar.add_task(f"nerf {model}", total=100, info="")

        def on_step(p: dict) -> None:
            held = "-" if p["test_psnr"] is None else f"{p['test_psnr']:.2f}"
            bar.update(task, completed=round(100 * p["fraction"], 1),
                       info=f"step {p['step']} loss {p['loss']:.2e} psnr {p['psnr']:.2f} held-out {held} dB")

        result = train(data, cfg, checkpoint=ckpt, resume=resume, progress=on_step)
        bar.update(task, completed=100, info=f"rendering {len(data.test)} held-out views")
        done: list = [None] * len(data.test)
        with engine(cluster, quiet) as eng:
            model_h = eng.share(result.model)
            map_units(eng, nerf_view, [(v, bool(model_cfg.render_full_res), cfg.threads) for v in data.test],
                      shared=[model_h], on_result=done.__setitem__, name="nerf-view")
            del model_h
        rows = [row for row, _ in done]
        renders = {v.name: r for v, (_, r) in zip(data.test, done)}

    with atomic_stage(out) as tmp:
        shutil.copyfile(ckpt, tmp / "checkpoint.pt")
        for name, r in renders.items():
            write_exr(tmp / "renders" / f"{name}.exr", r["rgb"])
            write_preview(tmp / "renders" / f"{name}.png", r["rgb"])
            write_exr(tmp / "depth" / f"{name}.exr", r["depth"])
        write_curve_csv(tmp / "curve.csv", result.curve)
        metrics = {
            "model": model, "scale": f"{small.width}x{small.height} (capture {full.width}x{full.height} / {downsample}, "
                                     "area-averaged)",
            "reference": data.reference, "poses": data.poses,
            "psnr_mean": float(np.mean([r["psnr"] for r in rows])), "ssim_mean": float(np.mean([r["ssim"] for r in rows])),
            "views": rows, "steps": result.steps, "train_s": round(result.train_s, 3),
            "curve_final_psnr": result.curve[-1]["psnr"] if result.curve else None,
        }
        if model_cfg.render_full_res:
            metrics["psnr_full_mean"] = float(np.mean([r["psnr_full"] for r in rows]))
            metrics["ssim_full_mean"] = float(np.mean([r["ssim_full"] for r in rows]))
        write_json(tmp / "metrics.json", metrics)
        manifest.metrics = {k: metrics[k] for k in ("psnr_mean", "ssim_mean", "steps", "train_s")}
        m = manifest.write(tmp)
    ckpt.unlink(missing_ok=True)
    return m

