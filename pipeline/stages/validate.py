"""The ``validate`` stage: every model's held-out renders judged against the reference path tracer.

Layout (DESIGN.md)::

    validate/metrics.json                  summary per model + per view (see below), poses, best
    validate/details.json                  the same with every per-view figure (mse, rmse, noise_mse, ...)
    validate/errors/<model>/<view>.png     |render - reference|, mean over RGB, x ``error_gain``, grey sRGB
    validate/zmaps/<model>/<view>.png      per-pixel Z-score against the reference noise: grey
                                           (darker = smaller) where within noise, red beyond
    validate/plots/models.csv              one row per model: accuracy and time (DVC plots)
    validate/plots/per_view.csv            one row per (model, view): PSNR, SSIM (DVC plots)
    validate/manifest.json
    validate/report.html                   written afterwards by :mod:`pipeline.report`

Models are discovered, not listed: any finished stage folder under the scene's artifacts
(``slab``, ``nerf/<model>``, ``nerf/<model>-colmap``, ...) that holds ``renders/<view>.exr`` is a
model, named by its path relative to the artifacts folder (``nerf/fast``). Its renders pair with
``reference/linear/<view>.exr`` by view name; the views judged are the reference's held-out
(``test``) views. A model rendering at an integer fraction 1/k of the reference's size (a NeRF
evaluated at its working scale) is judged against the reference area-averaged by k (``scale``
per view), its variance divided by k^2 accordingly. A folder with renders but no ``manifest.json`` is unfinished and is skipped
(listed under ``skipped``), never judged.

How much of a difference is reference noise. The reference is a Monte Carlo mean whose
``variance/<view>.exr`` is the variance of that mean, var_ref. If the reference is unbiased and
independent of the model, E[(model - ref)^2] = (model - truth)^2 + var_ref, so per view:

* ``noise_mse`` = mean var_ref; ``psnr_noise_ceiling`` = 10 log10(1 / noise_mse): the PSNR a
  perfect model (the true image) would be expected to score against this reference;
* ``noise_share`` = noise_mse / mse: the fraction of the measured squared error the reference's
  noise explains (near 1: the model is as good as this reference can tell);
* ``psnr_truth_est`` = 10 log10(1 / (mse - noise_mse)): the PSNR against the noise-free truth,
  estimated (null when mse <= noise_mse, flagged ``within_noise``);
* ``reference.psnr_black_mean``: what an all-black image scores (mostly dark scenes score well
  doing nothing: a model's PSNR means something only above this);
* ``z_within_fraction``: the fraction of pixel channels with z = |model - ref| / sigma_ref at most
  z_crit = Phi^-1(1 - alpha / 2) (two-sided, per-pixel alpha, sigma_ref = sqrt(var_ref) clamped
  below at ``sigma_floor``; the Z-test of REFERENCES.md). A model equal to the truth scores about
  1 - alpha.

These noise figures use unclipped linear radiance; ``psnr`` and ``ssim`` are
:mod:`render.metrics`' (images clipped to [0, 1]), as every stage reports them. Every PSNR here
follows render.metrics' convention: an MSE of 0 (identical images, an exact reference) gives
the finite cap PSNR_MAX_DB = 100 dB, never infinity or null.

Time. ``time_s`` is the model stage's own wall time (its manifest); ``upstream_s`` adds what it
needed before: the capture's wall time, and the poses stage's when the model read estimated
poses (an input path under ``poses/<method>/``); ``end_to_end_s`` = ``time_s + upstream_s``.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.stats import norm

from render.image_io import write_png
from render.metrics import mse_to_psnr, psnr, ssim

from ..artifacts import (MANIFEST, BadInput, Manifest, atomic_stage, check_file_stem, check_out, read_json,
                         read_manifest, read_stage_manifest, write_json)
from ..io import error_image, read_image, write_csv
from ..progress import progress_bar
from .capture import read_cameras

__all__ = ["ValidateConfig", "ModelDir", "discover_models", "reference_views", "compare_view", "z_scores",
           "model_subfolder", "zmap_png", "run_validate", "NOT_MODELS", "reference_at", "area_average", "pose_summary"]

#: top-level stage folders that are not models (inputs, ground truth, or this stage)
NOT_MODELS = ("capture", "reference", "validate", "poses", "study")
_SAFE = re.compile(r"[^A-Za-z0-9_.-]")


@dataclass(frozen=True)
class ValidateConfig:
    """alpha: per-pixel two-sided level of the Z-test; sigma_floor: lower clamp of the reference's
    standard deviation (linear radiance; pixels whose samples all agreed, e.g. black background,
    have zero variance); error_gain: multiplier of the error PNGs."""

    alpha: float = 0.01
    sigma_floor: float = 1e-3
    error_gain: float = 8.0

    def __post_init__(self):
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")
        if not self.sigma_floor > 0.0:
            raise ValueError(f"sigma_floor must be positive, got {self.sigma_floor}")


@dataclass(frozen=True)
class ModelDir:
    """A model's stage folder: ``name`` (path relative to the artifacts folder, '/'-separated),
    ``folder``, and whether it is ``finished`` (has a manifest)."""

    name: str
    folder: Path
    finished: bool


# ------------------------------------------------------------------------------------- discovery


def discover_models(artifacts_dir: Path, max_depth: int = 3) -> list[ModelDir]:
    """Every folder under ``artifacts_dir`` (at most ``max_depth`` levels down) holding
    ``renders/*.exr``, except hidden (partial) folders and :data:`NOT_MODELS`; sorted by name."""
    root = Path(artifacts_dir)
    found = []
    for dirpath, dirnames, _ in os.walk(root):
        here = Path(dirpath)
        rel = here.relative_to(root)
        depth = len(rel.parts)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".") and d != "renders"
                             and not (depth == 0 and d in NOT_MODELS))
        if depth >= max_depth:
            dirnames[:] = []
        if depth and (here / "renders").is_dir() and any((here / "renders").glob("*.exr")):
            found.append(ModelDir(rel.as_posix(), here, (here / MANIFEST).is_file()))
    return sorted(found, key=lambda m: m.name)


def reference_views(reference_dir: Path) -> list[str]:
    """Names of the reference's held-out views: its cameras.json ``test`` split (all its views
    when none is marked test), else the stems of ``linear/*.exr``. BadInput when there are none."""
    reference_dir = Path(reference_dir)
    cam_file = reference_dir / "cameras.json"
    if cam_file.is_file():
        cams, splits = read_cameras(cam_file)  # view names are plain file stems: they name our files
        names = [c.name for c, s in zip(cams, splits) if s == "test"] or [c.name for c in cams]
    else:
        names = [check_file_stem(p.stem, str(p)) for p in sorted((reference_dir / "linear").glob("*.exr"))]
    if not names:
        raise BadInput(f"{reference_dir}: no reference views (linear/<view>.exr)")
    return names


# ------------------------------------------------------------------------------------- metrics


def z_scores(render: np.ndarray, ref: np.ndarray, var: np.ndarray, sigma_floor: float) -> np.ndarray:
    """(H, W, 3) float64 |render - ref| / max(sqrt(var), sigma_floor); var is the variance of the
    reference's mean (H, W, 3)."""
    sigma = np.maximum(np.sqrt(np.maximum(var.astype(np.float64), 0.0)), sigma_floor)
    return np.abs(render.astype(np.float64) - ref) / sigma


def compare_view(render: np.ndarray, ref: np.ndarray, var: np.ndarray, config: ValidateConfig = ValidateConfig()
                 ) -> dict:
    """Scores of one (H, W, 3) float32 linear render against the reference mean and its variance
    (module docstring): psnr, ssim, rmse, mse, noise_mse, noise_share, psnr_noise_ceiling,
    psnr_truth_est, within_noise, z_within_fraction. Finite numbers or null, never NaN/Inf."""
    d = render.astype(np.float64) - ref
    mse = float(np.mean(d * d))
    noise = float(np.mean(np.maximum(var, 0.0), dtype=np.float64))
    z_crit = float(norm.ppf(1.0 - config.alpha / 2.0))
    z = z_scores(render, ref, var, config.sigma_floor)
    excess = mse - noise
    return {
        "psnr": psnr(render, ref),  # identical images: render.metrics.PSNR_MAX_DB
        "ssim": ssim(render, ref),
        "rmse": math.sqrt(mse),
        "mse": mse,
        "noise_mse": noise,
        "noise_share": min(1.0, noise / mse) if mse > 0 else 1.0,
        "psnr_noise_ceiling": mse_to_psnr(noise),
        "psnr_truth_est": mse_to_psnr(excess) if excess > 0 else None,  # None: the error is within noise
        "within_noise": bool(excess <= 0),
        "z_within_fraction": float(np.mean(z <= z_crit)),
    }


def zmap_png(z: np.ndarray, z_crit: float) -> np.ndarray:
    """(H, W, 3) uint8 map of the largest per-channel Z-score: grey ramp up to z_crit (within the
    reference's noise), then red saturating at 4 z_crit (a real difference)."""
    zmax = z.max(axis=2)
    within = np.clip(zmax / z_crit, 0.0, 1.0) * 160.0
    beyond = np.clip((zmax - z_crit) / (3.0 * z_crit), 0.0, 1.0)
    out = np.empty(z.shape[:2] + (3,), np.float64)
    out[...] = within[..., None]
    red = zmax > z_crit
    out[red, 0] = 180.0 + 75.0 * beyond[red]
    out[red, 1] = 40.0 * (1.0 - beyond[red])
    out[red, 2] = 40.0 * (1.0 - beyond[red])
    return np.round(out).astype(np.uint8)


def area_average(img: np.ndarray, factor: int) -> np.ndarray:
    """(H, W, C) -> (H / factor, W / factor, C) mean over factor x factor blocks (float64)."""
    h, w = img.shape[0] // factor, img.shape[1] // factor
    return img.astype(np.float64).reshape(h, factor, w, factor, -1).mean(axis=(1, 3))


def reference_at(ref: np.ndarray, var: np.ndarray, shape: tuple[int, ...], where: Path
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """The reference mean and variance at a model's render size: as is when equal, area-averaged
    by an integer factor k when the render is k times smaller on both axes (the variance of a
    mean of k^2 independent pixels is their mean variance / k^2). Returns (ref, var, k); BadInput
    naming ``where`` for any other size."""
    if shape == ref.shape:
        return ref, var, 1
    k = ref.shape[0] // shape[0] if len(shape) == 3 and shape[0] else 0
    if (len(shape) != 3 or shape[2] != ref.shape[2] or k < 2 or ref.shape[0] != k * shape[0]
            or ref.shape[1] != k * shape[1]):
        raise BadInput(f"{where}: shape {shape}, expected {ref.shape} (the reference's) or an integer fraction of it")
    return (area_average(ref, k).astype(np.float32), (area_average(var, k) / (k * k)).astype(np.float32), k)


def _mean(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def _summary(per_view: dict) -> dict:
    keys = ("psnr", "ssim", "rmse", "noise_share", "psnr_noise_ceiling", "psnr_truth_est", "z_within_fraction")
    out = {f"{k}_mean": _mean([m[k] for m in per_view.values()]) for k in keys}
    out["views_within_noise"] = int(sum(m["within_noise"] for m in per_view.values()))
    return out


# ------------------------------------------------------------------------------------- time


_POSES_IN = re.compile(r"(?:^|/)poses/([^/]+)/")


def _poses_method(manifest: dict) -> str | None:
    """The poses method a model read (an input under ``poses/<method>/``), None for the capture's."""
    for path in list(manifest.get("inputs", {})) + [str(v) for v in manifest.get("params", {}).values()
                                                     if isinstance(v, str)]:
        m = _POSES_IN.search(path.replace(os.sep, "/"))
        if m:
            return m.group(1)
    return None


def _wall(folder: Path) -> float | None:
    f = Path(folder) / MANIFEST
    if not f.is_file():
        return None
    t = read_manifest(folder).get("wall_time_s")
    return float(t) if isinstance(t, (int, float)) else None


def pose_summary(artifacts_dir: Path) -> dict:
    """{method: flat pose accuracy figures} from every ``poses/<method>/metrics.json`` (failed
    estimates included, with status and reason)."""
    keys = ("status", "reason", "views_registered", "views_total", "registered_fraction",
            "rotation_error_deg_mean", "rotation_error_deg_max", "center_error_rel_mean", "center_error_rel_max",
            "reprojection_error_px", "focal_rel", "estimate_time_s", "wall_time_s")
    out = {}
    for f in sorted(Path(artifacts_dir).glob("poses/*/metrics.json")):
        if f.parent.name.startswith("."):
            continue
        m = read_json(f)
        if not isinstance(m, dict):
            raise BadInput(f"{f}: expected a JSON object of pose metrics")
        out[f.parent.name] = {k: m[k] for k in keys if k in m and (m[k] is None or isinstance(m[k], (int, float, str)))}
    return out


# ------------------------------------------------------------------------------------- stage


#: per-view figures kept in metrics.json (``dvc metrics show`` stays readable); details.json has all
COMPACT_VIEW_KEYS = ("psnr", "ssim", "psnr_truth_est", "noise_share", "z_within_fraction", "scale")


def _compact(metrics: dict) -> dict:
    out = {**metrics, "models": {}}
    for n, r in metrics["models"].items():
        out["models"][n] = {**r, "per_view": {v: {k: m[k] for k in COMPACT_VIEW_KEYS} for v, m in r["per_view"].items()}}
    out["reference"] = {**metrics["reference"], "per_view": {
        v: {"psnr_noise_ceiling": m["psnr_noise_ceiling"]} for v, m in metrics["reference"]["per_view"].items()}}
    return out


def model_subfolder(name: str) -> Path:
    """The relative folder of model ``name``'s images under ``errors/`` and ``zmaps/``: its
    '/'-separated parts with every character outside [A-Za-z0-9_.-] replaced by '_'."""
    return Path(*[_SAFE.sub("_", p) for p in name.split("/")])


def run_validate(artifacts_dir: Path, out: Path | None = None, config: ValidateConfig = ValidateConfig(),
                 quiet: bool = False, overwrite: bool = False) -> dict:
    """Judge every model under ``artifacts_dir`` (``artifacts/<scene>``) against its finished
    ``reference`` stage; writes ``out`` (default ``artifacts_dir/validate``) atomically and returns
    the manifest. BadInput (one line naming the file) when the reference is missing or unfinished,
    no finished model exists, or a model lacks a held-out view or has it at the wrong size.
    ``out`` may be absent, empty or a finished validate folder (its report.html goes with it),
    anything else is refused before any work unless ``overwrite``."""
    artifacts_dir = Path(artifacts_dir)
    if not artifacts_dir.is_dir():
        raise BadInput(f"{artifacts_dir}: no such artifacts folder")
    out = Path(out) if out is not None else artifacts_dir / "validate"
    check_out(out, "validate", overwrite)
    ref_dir = artifacts_dir / "reference"
    ref_manifest = read_stage_manifest(ref_dir, "reference")
    views = reference_views(ref_dir)
    found = discover_models(artifacts_dir)
    models = [m for m in found if m.finished]
    skipped = {m.name: f"no {MANIFEST} (unfinished stage)" for m in found if not m.finished}
    if not models:
        raise BadInput(f"{artifacts_dir}: no finished model stage with renders/<view>.exr to validate")
    for m in models:  # check every input before any work
        for v in views:
            if not (m.folder / "renders" / f"{v}.exr").is_file():
                raise BadInput(f"{m.folder / 'renders' / (v + '.exr')}: missing held-out view {v!r} of model {m.name!r}")
    capture_s = _wall(artifacts_dir / "capture") or 0.0
    manifest = Manifest("validate", params={**asdict(config), "views": views, "models": [m.name for m in models]})
    z_crit = float(norm.ppf(1.0 - config.alpha / 2.0))
    refs = {}
    for v in views:
        ref = read_image(ref_dir / "linear" / f"{v}.exr")
        if ref.ndim != 3 or ref.shape[2] != 3:
            raise BadInput(f"{ref_dir / 'linear' / (v + '.exr')}: expected an RGB image, got shape {ref.shape}")
        var = read_image(ref_dir / "variance" / f"{v}.exr", ref.shape, grey_to_rgb=True, shape_of="the reference's")
        refs[v] = (ref, var)
        manifest.add_input(ref_dir / "linear" / f"{v}.exr")
        manifest.add_input(ref_dir / "variance" / f"{v}.exr")
    rp = ref_manifest.get("params", {})
    ref_noise = {v: float(np.mean(var, dtype=np.float64)) for v, (_, var) in refs.items()}
    reference = {"spp": rp.get("spp"), "integrator": rp.get("integrator"), "views": len(views),
                 "wall_time_s": ref_manifest.get("wall_time_s"),
                 "per_view": {v: {"noise_mse": n, "psnr_noise_ceiling": mse_to_psnr(n)}
                              for v, n in ref_noise.items()}}
    reference["psnr_noise_ceiling_mean"] = _mean([p["psnr_noise_ceiling"] for p in reference["per_view"].values()])
    # what an empty (black) image scores: a model must beat this to have rendered anything
    reference["psnr_black_mean"] = _mean([psnr(np.zeros_like(r), r) for r, _ in refs.values()])
    results, view_rows = {}, []
    with atomic_stage(out, "validate", overwrite) as tmp, progress_bar(quiet) as bar:
        task = bar.add_task("validate", total=len(models) * len(views), info=f"{len(models)} models")
        for m in models:
            mm = read_manifest(m.folder)
            per_view = {}
            for v in views:
                ref, var = refs[v]
                path = m.folder / "renders" / f"{v}.exr"
                img = read_image(path)
                if img.ndim == 2:
                    img = np.repeat(img[..., None], 3, axis=2)
                ref, var, k = reference_at(ref, var, img.shape, path)
                manifest.add_input(path)
                per_view[v] = {**compare_view(img, ref, var, config), "scale": k}
                write_png(tmp / "errors" / model_subfolder(m.name) / f"{v}.png", error_image(img, ref, config.error_gain))
                write_png(tmp / "zmaps" / model_subfolder(m.name) / f"{v}.png",
                          zmap_png(z_scores(img, ref, var, config.sigma_floor), z_crit))
                view_rows.append({"model": m.name, "view": v, "model_view": f"{m.name}:{v}", **per_view[v]})
                bar.advance(task)
            method = _poses_method(mm)
            poses_s = _wall(artifacts_dir / "poses" / method) if method else None
            t = mm.get("wall_time_s")
            t = float(t) if isinstance(t, (int, float)) else 0.0
            upstream = capture_s + (poses_s or 0.0)
            results[m.name] = {**_summary(per_view), "stage": mm.get("stage", m.name.split("/")[0]),
                               "poses": method or "capture", "time_s": t, "upstream_s": round(upstream, 3),
                               "end_to_end_s": round(t + upstream, 3), "per_view": per_view}
        scored = [n for n in results if results[n]["psnr_mean"] is not None]
        best = max(scored, key=lambda n: (results[n]["psnr_mean"], -results[n]["end_to_end_s"])) if scored else None
        metrics = {"reference": reference, "models": results, "poses": pose_summary(artifacts_dir),
                   "skipped": skipped, "z_crit": z_crit,
                   "best": {"model": best, "psnr_mean": results[best]["psnr_mean"],
                            "ssim_mean": results[best]["ssim_mean"], "end_to_end_s": results[best]["end_to_end_s"]}
                   if best else None}
        write_json(tmp / "details.json", metrics)
        write_json(tmp / "metrics.json", _compact(metrics))
        model_rows = [{"model": n, **{k: v for k, v in r.items() if k != "per_view"}} for n, r in results.items()]
        write_csv(tmp / "plots" / "models.csv", model_rows,
                   ["model", "stage", "poses", "psnr_mean", "ssim_mean", "psnr_truth_est_mean", "noise_share_mean",
                    "z_within_fraction_mean", "psnr_noise_ceiling_mean", "time_s", "upstream_s", "end_to_end_s"])
        write_csv(tmp / "plots" / "per_view.csv", view_rows,
                   ["model_view", "model", "view", "psnr", "ssim", "psnr_noise_ceiling", "noise_share",
                    "z_within_fraction"])
        manifest.metrics = {"models": len(results), "views": len(views), "best": best,
                            **{f"psnr_mean.{n}": r["psnr_mean"] for n, r in results.items()},
                            "psnr_noise_ceiling_mean": reference["psnr_noise_ceiling_mean"]}
        result = manifest.write(tmp)
    return result

