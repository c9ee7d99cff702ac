"""What accuracy costs in time: held-out PSNR against training minutes for several models (and
pose sources) on one capture. This module trains the runs and returns their curves;
:mod:`pipeline.stages.nerf_study` is the command that writes them (``curves.csv``, the plot
``curves.svg``, ``summary.json``)::

    python -m pipeline.stages.nerf_study CAPTURE_DIR --out DIR --minutes 10 \
        --run fast --run vanilla --run vanilla_noview --run vanilla_nope \
        [--run colmap=fast@artifacts/turntable/poses/colmap] [--reference DIR]

Each ``--run`` is ``[label=]model[@poses_dir]``. PSNR is at the working scale (see
:mod:`recon.nerf.data`), the mean over held-out views of whole images or of the model's fixed
pixel subsets (``curve_pixels``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from .data import load_data
from .models import MODELS
from .train import TrainConfig, train

__all__ = ["Run", "NerfStudy", "CURVES_COLUMNS", "parse_run", "parse_settings", "run_study", "PUBLIC_REFERENCE"]

#: (training minutes, held-out PSNR dB) of a public pure-PyTorch factored-grid NeRF on these 2
#: cores, 200x200 object: the scale the curves are compared with
PUBLIC_REFERENCE = [(2.0, 28.0), (5.0, 35.0), (10.0, 38.0)]


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


_MISSING = object()


def parse_settings(items: list[str], runs: list[Run]) -> dict[str, tuple]:
    """``FIELD=VALUE`` strings -> {model: overrides} for :class:`recon.nerf.train.TrainConfig`.
    A field applies to every run whose model config has it (values are parsed as that field's
    type, a text field as given); a field no run's model has, or a value its config refuses, is a
    ValueError naming the field."""
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
            elif isinstance(default, str):
                value = text  # a choice (e.g. FastConfig.fine_loss): the config checks it below
            else:
                raise ValueError(f"--set {item!r}: field {name!r} of model {model!r} cannot be set from the command line")
            per_model[model].append((name, value))
            used = True
        if not used:
            raise ValueError(f"--set {item!r}: no run's model config has a field {name!r}")
    for model, items_m in per_model.items():
        try:
            replace(MODELS[model][1], **dict(items_m))
        except ValueError as exc:
            raise ValueError(f"--set: {exc}") from None
    return {m: tuple(v) for m, v in per_model.items()}


@dataclass(frozen=True)
class NerfStudy:
    """What :func:`run_study` measured. curves: {label: held-out curve rows (step, train_s,
    wall_s, display_psnr, linear_psnr)}; rows: the curve rows of every run with ``label``, ``model``, ``poses`` first
    (:data:`CURVES_COLUMNS`); summary: {label: {model, poses, final_display_psnr, steps, train_s,
    settings}}; minutes, clock, downsample: the study's settings; working_size: (width, height) of
    the held-out views as trained."""

    curves: dict[str, list[dict]]
    rows: list[dict]
    summary: dict[str, dict]
    minutes: float
    clock: str
    downsample: int
    working_size: tuple[int, int]


#: columns of the study's table (one row per curve point of every run)
CURVES_COLUMNS = ("label", "model", "poses", "step", "train_s", "wall_s", "display_psnr", "linear_psnr")


def run_study(capture_dir, runs: list[Run], minutes: float, reference_dir=None, downsample: int | None = None,
              seed: int = 0, eval_every_s: float = 30.0, log=print, clock: str = "wall",
              settings: dict[str, tuple] | None = None) -> NerfStudy:
    """Train every run for ``minutes`` of training time and return the curves (nothing is
    written). clock: "wall" or "cpu" (see :class:`recon.nerf.train.TrainConfig`); settings:
    {model: overrides of its config} (:func:`parse_settings`), recorded in the summary."""
    settings = settings or {}
    curves, summary = {}, {}
    rows = []
    for run in runs:
        model_cfg = replace(MODELS[run.model][1], **dict(settings.get(run.model, ())))
        data = load_data(capture_dir, run.poses, reference_dir, downsample,
                         train_full=bool(getattr(model_cfg, "needs_full_images", lambda: False)()))
        log(f"study: {run.label} ({run.model}, poses {data.poses}) for {minutes} min")
        res = train(data, TrainConfig(model=run.model, minutes=minutes, seed=seed, eval_every_s=eval_every_s,
                                      clock=clock, overrides=settings.get(run.model, ())))
        curves[run.label] = res.curve
        summary[run.label] = {"model": run.model, "poses": data.poses, "final_display_psnr": res.curve[-1]["display_psnr"],
                              "steps": res.steps, "train_s": round(res.train_s, 1),
                              "settings": dict(settings.get(run.model, ()))}
        rows += [{"label": run.label, "model": run.model, "poses": str(run.poses or "gt"), **r} for r in res.curve]
        log(f"study: {run.label}: display PSNR {res.curve[-1]['display_psnr']:.2f} dB after {res.steps} steps")
    k = data.test[0].camera.intrinsics
    return NerfStudy(curves, rows, summary, minutes, clock, data.downsample, (k.width, k.height))
