"""The ``validate`` stage: every model's held-out renders judged against the reference path tracer.

Layout (DESIGN.md)::

    validate/metrics.json                  summary per model + per view (see below), poses, best
    validate/details.json                  the same with every per-view figure (mse, rmse, noise_mse, ...)
    validate/errors/<model>/<view>.png     |render - reference|, mean over RGB, x ``error_gain``, grey sRGB
    validate/zmaps/<model>/<view>.png      per-pixel Z-score against the reference noise: grey
                                           (darker = smaller) where within noise, red beyond
    validate/flip_ldr/<model>/<view>.png   LDR-ꟻLIP error map (magma: black 0 .. pale yellow 1)
    validate/flip_hdr/<model>/<view>.png   HDR-ꟻLIP error map, same colours
    validate/plots/models.csv              one row per model: accuracy and time (DVC plots)
    validate/plots/per_view.csv            one row per (model, view): display PSNR, SSIM, ꟻLIP (DVC plots)

The figures, headline first (:func:`render.metrics.score_images`): ``display_psnr`` and
``display_ssim`` (8-bit sRGB images, as NeRF, TensoRF and Instant-NGP report), ``flip_ldr`` (LDR-ꟻLIP
on the display images) and ``flip_hdr`` (HDR-ꟻLIP on linear radiance), ``linear_psnr`` (PSNR of
linear radiance clipped to [0, 1]); each also on the subject's pixels (``<name>_subject``: the
capture's ``masks/<view>.png``, area-averaged to a smaller render; null when the capture has no
mask or the view shows no subject pixel). ``reference.black`` holds the all-black image's scores
(means over views, same names), so an empty background cannot carry a figure.
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
* ``reference.black``: what an all-black image scores (mostly dark scenes score well doing
  nothing: a model's figure means something only above this);
* ``display_psnr_noise_ceiling`` / ``display_psnr_truth_est``: the same accounting in display
  space, the noise's display MSE by the delta method (:func:`render.metrics.display_noise_mse`:
  mean of the sRGB curve's slope^2 x var_ref) and the truth estimate from the display MSE minus it;
* ``z_within_fraction``: the fraction of pixel channels with z = |model - ref| / sigma_ref at most
  z_crit = Phi^-1(1 - alpha / 2), or Student's t quantile with R - 1 degrees of freedom against a
  Sobol reference of R replicates (its manifest's ``replicates``) (two-sided, per-pixel alpha, sigma_ref = sqrt(var_ref) clamped
  below at ``sigma_floor``; the Z-test of REFERENCES.md). A model equal to the truth scores about
  1 - alpha.

The linear noise figures use unclipped linear radiance; the scores are :mod:`render.metrics`'
(images clipped to [0, 1]), as every stage reports them. Every PSNR here
follows render.metrics' convention: an MSE of 0 (identical images, an exact reference) gives
the finite cap PSNR_MAX_DB = 100 dB, never infinity or null.

Time. ``time_s`` is the model stage's own wall time (its manifest); ``upstream_s`` adds what it
needed before: the capture's wall time, and the poses stage's when the model read estimated
poses (an input path under ``poses/<method>/``); ``end_to_end_s`` = ``time_s + upstream_s``.
"""
from __future__ import annotations

import math
import multiprocessing
import os
import re
from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from scipy.stats import norm
from scipy.stats import t as student_t

from render.image_io import write_png
from render.image_io import read_png
from render.metrics import (FLIP_IMPLEMENTATIONS, FLIP_NAMES, SCORE_NAMES, black_image_scores, display_noise_mse,
                            flip_map, flip_means, mse_to_psnr, score_images, score_order, to_display)

from ..artifacts import (MANIFEST, BadInput, Manifest, atomic_stage, check_file_stem, check_out, read_json,
                         read_manifest, read_stage_manifest, write_json)
from ..io import error_image, read_image, write_csv
from ..progress import progress_bar
from .capture import read_cameras

__all__ = ["ValidateConfig", "ModelDir", "discover_models", "reference_views", "compare_view", "z_scores",
           "model_subfolder", "zmap_png", "run_validate", "NOT_MODELS", "reference_at", "area_average", "pose_summary",
           "flip_implementation"]

#: top-level stage folders that are not models (inputs, ground truth, or this stage)
NOT_MODELS = ("capture", "reference", "validate", "poses", "study")
_SAFE = re.compile(r"[^A-Za-z0-9_.-]")


@dataclass(frozen=True)
class ValidateConfig:
    """alpha: per-pixel two-sided level of the Z-test; sigma_floor: lower clamp of the reference's
    standard deviation (linear radiance; pixels whose samples all agreed, e.g. black background,
    have zero variance); error_gain: multiplier of the error PNGs; flip: score ꟻLIP and write its
    maps (about 5 s per 1280x960 view and model, LDR and HDR)."""

    alpha: float = 0.01
    sigma_floor: float = 1e-3
    error_gain: float = 8.0
    flip: bool = True

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


def z_critical(alpha: float, var_dof: float | None = None) -> float:
    """The per-pixel two-sided threshold of z_within_fraction: Phi^-1(1 - alpha / 2), or Student's
    t quantile with ``var_dof`` degrees of freedom when the reference's variance image is an
    estimate with that many (the Sobol sampler's R replicates: R - 1, the reference manifest's
    ``replicates``), so that a model equal to the truth still scores about 1 - alpha (with R = 16
    and normal thresholds it scored 0.979 at alpha 0.01)."""
    if var_dof is None:
        return float(norm.ppf(1.0 - alpha / 2.0))
    return float(student_t.ppf(1.0 - alpha / 2.0, var_dof))


def compare_view(render: np.ndarray, ref: np.ndarray, var: np.ndarray, config: ValidateConfig = ValidateConfig(),
                 mask: np.ndarray | None = None, maps: dict | None = None, var_dof: float | None = None) -> dict:
    """Scores of one (H, W, 3) float32 linear render against the reference mean and its variance
    (module docstring): the field's figures of :func:`render.metrics.score_images` (display_psnr,
    display_ssim, flip_ldr, flip_hdr, linear_psnr; ``_subject`` variants on the (H, W) ``mask``'s
    pixels when given and not empty, else null), and the noise accounting: rmse, mse, noise_mse,
    noise_share, psnr_noise_ceiling, psnr_truth_est, within_noise, z_within_fraction (linear), and
    display_psnr_noise_ceiling / display_psnr_truth_est (display, delta method). ``maps`` receives
    the ꟻLIP error maps. Finite numbers or null, never NaN/Inf. var_dof: degrees of freedom of
    var (:func:`z_critical`)."""
    d = render.astype(np.float64) - ref
    mse = float(np.mean(d * d))
    noise = float(np.mean(np.maximum(var, 0.0), dtype=np.float64))
    z_crit = z_critical(config.alpha, var_dof)
    z = z_scores(render, ref, var, config.sigma_floor)
    excess = mse - noise
    subject = mask if mask is not None and np.any(mask) else None
    scores = score_images(render, ref, subject, with_flip=config.flip, maps=maps)
    if subject is None:  # no subject pixel in view (or no mask): the subject's figures are absent
        scores.update({f"{k}_subject": None for k in list(scores)})
    display_mse = mse_to_display_mse(render, ref)
    display_noise = display_noise_mse(ref, var)
    display_excess = display_mse - display_noise
    return {
        **scores,  # identical images: render.metrics.PSNR_MAX_DB
        "rmse": math.sqrt(mse),
        "mse": mse,
        "noise_mse": noise,
        "noise_share": min(1.0, noise / mse) if mse > 0 else 1.0,
        "psnr_noise_ceiling": mse_to_psnr(noise),
        "psnr_truth_est": mse_to_psnr(excess) if excess > 0 else None,  # None: the error is within noise
        "within_noise": bool(excess <= 0),
        "display_psnr_noise_ceiling": mse_to_psnr(display_noise),
        "display_psnr_truth_est": mse_to_psnr(display_excess) if display_excess > 0 else None,
        "z_within_fraction": float(np.mean(z <= z_crit)),
    }


def mse_to_display_mse(render: np.ndarray, ref: np.ndarray) -> float:
    """MSE of the two images' display (8-bit sRGB) encodings, the one display_psnr scores."""
    return float(np.mean((to_display(render) - to_display(ref)) ** 2))


#: ꟻLIP's magma colour map (its error maps' convention), sampled at 0, 1/8, ..., 1 (sRGB 0..255)
_MAGMA = np.array([[0, 0, 4], [28, 16, 68], [79, 18, 123], [129, 37, 129], [181, 54, 122], [229, 80, 100],
                   [251, 135, 97], [254, 194, 135], [252, 253, 191]], np.float64)


def flip_png(err: np.ndarray) -> np.ndarray:
    """(H, W) ꟻLIP error in [0, 1] -> (H, W, 3) uint8 magma image (black 0, pale yellow 1), as
    ꟻLIP's own tool draws its maps."""
    t = np.clip(np.asarray(err, np.float64), 0.0, 1.0) * (len(_MAGMA) - 1)
    i = np.minimum(t.astype(int), len(_MAGMA) - 2)
    f = (t - i)[..., None]
    return np.round(_MAGMA[i] * (1.0 - f) + _MAGMA[i + 1] * f).astype(np.uint8)


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


#: the per-view figures averaged into a model's summary (``<key>_mean``), headline first
SUMMARY_KEYS = (*[n + s for n in SCORE_NAMES for s in ("", "_subject")], "display_psnr_noise_ceiling",
                "display_psnr_truth_est", "psnr_noise_ceiling", "psnr_truth_est", "noise_share", "z_within_fraction",
                "rmse")


def _summary(per_view: dict) -> dict:
    out = {f"{k}_mean": _mean([m.get(k) for m in per_view.values()]) for k in SUMMARY_KEYS}
    out["views_within_noise"] = int(sum(m["within_noise"] for m in per_view.values()))
    return out


def subject_mask(capture_dir: Path, view: str, shape: tuple[int, ...]) -> np.ndarray | None:
    """The capture's subject mask of ``view`` (``masks/<view>.png``, nonzero = subject) at an image
    ``shape`` (H, W[, C]): as is, or area-averaged by the integer factor k of a smaller render (a
    block is subject when at least half its pixels are); None when the capture has no such mask.
    BadInput naming the file when it is unreadable or of a size no integer factor maps."""
    path = Path(capture_dir) / "masks" / f"{view}.png"
    if not path.is_file():
        return None
    try:
        m = read_png(path)
    except Exception as exc:  # a damaged PNG: one line naming it
        raise BadInput(f"{path}: unreadable PNG ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    m = (m.max(axis=2) if m.ndim == 3 else m) > 0
    h, w = shape[:2]
    if m.shape == (h, w):
        return m
    k = m.shape[0] // h if h else 0
    if k < 2 or m.shape != (k * h, k * w):
        raise BadInput(f"{path}: shape {m.shape}, expected {(h, w)} or an integer multiple of it")
    return area_average(m[..., None].astype(np.float64), k)[..., 0] >= 0.5


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


# ------------------------------------------------------------------------------------- ꟻLIP pool


def flip_implementation() -> str:
    """The ꟻLIP implementation validate uses: render.metrics' torch port, or
    ``LUMIGRAPH_FLIP_IMPLEMENTATION=flip_evaluator`` for NVIDIA's C++ package (same maps to float32
    rounding, ~2-3x slower). BadInput naming the variable for any other value."""
    name = os.environ.get("LUMIGRAPH_FLIP_IMPLEMENTATION") or "torch"
    if name not in FLIP_IMPLEMENTATIONS:
        raise BadInput(f"LUMIGRAPH_FLIP_IMPLEMENTATION: {name!r} is not one of {', '.join(FLIP_IMPLEMENTATIONS)}")
    return name


class FlipPool:
    """ꟻLIP error maps computed in worker processes, in step with the stage's loop.

    Each map already spreads over the cores (torch's intra-op threads; flip_evaluator's OpenMP),
    so the pool does not make the maps faster; it lets this process read, score (SSIM, PSNR,
    noise accounting) and write the next units meanwhile. ``workers`` <= 1 computes each map in
    this process when asked for. Workers are spawned (not forked: torch's thread pools do not
    survive a fork) on the first submit and import only render.metrics."""

    def __init__(self, workers: int, implementation: str = "torch"):
        self.workers = max(1, int(workers))
        self.implementation = implementation
        self._pool: ProcessPoolExecutor | None = None

    def __enter__(self) -> "FlipPool":
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def submit(self, pred: np.ndarray, ref: np.ndarray) -> dict[str, Future]:
        """{"flip_ldr", "flip_hdr"}: futures of :func:`render.metrics.flip_map` of the linear
        (H, W, 3) ``pred`` against ``ref``, each an (H, W) float32 map in [0, 1]."""
        out = {}
        for name, hdr in FLIP_NAMES:
            if self.workers > 1:
                if self._pool is None:
                    self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"))
                out[name] = self._pool.submit(flip_map, pred, ref, hdr, self.implementation)
            else:
                f: Future = Future()
                f.set_result(flip_map(pred, ref, hdr, self.implementation))
                out[name] = f
        return out


#: below this many pixels of ꟻLIP maps in a stage (~10 s of maps), spawning workers (each imports
#: torch, 2-3 s) costs more than it saves
FLIP_POOL_MIN_PIXELS = 4_000_000


def flip_workers(total_pixels: int) -> int:
    """Worker processes for ``total_pixels`` of ꟻLIP maps (LDR and HDR counted once): the cores
    this process may use, at most 2, or 1 (in-process) for a small stage.
    ``LUMIGRAPH_FLIP_WORKERS`` overrides."""
    env = os.environ.get("LUMIGRAPH_FLIP_WORKERS")
    if env:
        return max(1, int(env))
    if total_pixels < FLIP_POOL_MIN_PIXELS:
        return 1
    from ..distributed import machine_cores
    return min(2, machine_cores())


# ------------------------------------------------------------------------------------- stage


#: per-view figures kept in metrics.json (``dvc metrics show`` stays readable); details.json has all
COMPACT_VIEW_KEYS = ("display_psnr", "display_psnr_subject", "display_ssim", "flip_ldr", "flip_hdr", "linear_psnr",
                     "display_psnr_truth_est", "psnr_truth_est", "noise_share", "z_within_fraction", "scale")


def _compact(metrics: dict) -> dict:
    out = {**metrics, "models": {}}
    for n, r in metrics["models"].items():
        out["models"][n] = {**r, "per_view": {v: {k: m.get(k) for k in COMPACT_VIEW_KEYS}
                                              for v, m in r["per_view"].items()}}
    out["reference"] = {**metrics["reference"], "per_view": {
        v: {k: m[k] for k in ("display_psnr_noise_ceiling", "psnr_noise_ceiling")}
        for v, m in metrics["reference"]["per_view"].items()}}
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
    implementation = flip_implementation() if config.flip else "torch"
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
    replicates = ref_manifest.get("params", {}).get("replicates")
    # the Sobol sampler's replicate variance (a manifest without a sensible count: normal thresholds)
    var_dof = float(replicates - 1) if isinstance(replicates, int) and replicates >= 2 else None
    z_crit = z_critical(config.alpha, var_dof)
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
    capture_dir = artifacts_dir / "capture"
    masks = {v: subject_mask(capture_dir, v, refs[v][0].shape) for v in views}
    per_ref = {}
    black_views = {}
    for v, (r, var) in refs.items():
        n, dn = float(np.mean(var, dtype=np.float64)), display_noise_mse(r, var)
        per_ref[v] = {"noise_mse": n, "psnr_noise_ceiling": mse_to_psnr(n),
                      "display_noise_mse": dn, "display_psnr_noise_ceiling": mse_to_psnr(dn)}
        # what an empty (black) image scores: a model must beat this to have rendered anything
        m = masks[v] if masks[v] is not None and masks[v].any() else None
        black_views[v] = (black_image_scores(r, m, with_flip=False), m)
    reference = {"spp": rp.get("spp"), "integrator": rp.get("integrator"), "views": len(views),
                 "wall_time_s": ref_manifest.get("wall_time_s"), "per_view": per_ref,
                 "subject_masks": sum(m is not None for m in masks.values())}
    for key in ("psnr_noise_ceiling", "display_psnr_noise_ceiling"):
        reference[f"{key}_mean"] = _mean([p[key] for p in per_ref.values()])
    results, view_rows = {}, []
    no_flip = replace(config, flip=False)
    flip_pixels = (len(models) + 1) * sum(r.shape[0] * r.shape[1] for r, _ in refs.values())  # + the black row
    with atomic_stage(out, "validate", overwrite) as tmp, progress_bar(quiet) as bar, \
            FlipPool(flip_workers(flip_pixels) if config.flip else 1, implementation) as flips:
        task = bar.add_task("validate", total=len(models) * len(views), info=f"{len(models)} models")
        black_maps = {v: flips.submit(np.zeros_like(r), r) for v, (r, _) in refs.items()} if config.flip else {}
        per_model_view: dict = {m.name: {} for m in models}
        # (model, view, scores, subject mask, ꟻLIP futures): at most a few units' images wait on the pool
        pending: deque = deque()

        def finish_unit() -> None:
            name, v, scores, mask, futures = pending.popleft()
            maps = {n: f.result() for n, f in futures.items()}
            subject = mask if mask is not None and mask.any() else None
            scores.update(flip_means(maps, subject))
            if subject is None:  # as compare_view: no subject pixel, no subject figure
                scores.update({f"{n}_subject": None for n in maps})
            for n, err in maps.items():
                write_png(tmp / n / model_subfolder(name) / f"{v}.png", flip_png(err))
            per_model_view[name][v] = row = score_order(scores)
            view_rows.append({"model": name, "view": v, "model_view": f"{name}:{v}", **row})
            bar.advance(task)

        for m in models:
            for v in views:
                ref, var = refs[v]
                path = m.folder / "renders" / f"{v}.exr"
                img = read_image(path)
                if img.ndim == 2:
                    img = np.repeat(img[..., None], 3, axis=2)
                ref, var, k = reference_at(ref, var, img.shape, path)
                mask = subject_mask(capture_dir, v, img.shape) if masks[v] is not None else None
                manifest.add_input(path)
                futures = flips.submit(img, ref) if config.flip else {}
                scores = {**compare_view(img, ref, var, no_flip, mask, None, var_dof), "scale": k}
                sub = model_subfolder(m.name)
                write_png(tmp / "errors" / sub / f"{v}.png", error_image(img, ref, config.error_gain))
                write_png(tmp / "zmaps" / sub / f"{v}.png", zmap_png(z_scores(img, ref, var, config.sigma_floor), z_crit))
                pending.append((m.name, v, scores, mask, futures))
                if len(pending) > 2 * flips.workers:
                    finish_unit()
        while pending:
            finish_unit()
        for v, (scores, m) in black_views.items():
            if v in black_maps:
                scores.update(flip_means({n: f.result() for n, f in black_maps[v].items()}, m))
            black_views[v] = score_order(scores)
        reference["black"] = {f"{k}_mean": _mean([b.get(k) for b in black_views.values()])
                              for k in SUMMARY_KEYS if any(k in b for b in black_views.values())}
        reference["black_per_view"] = black_views
        for m in models:
            mm = read_manifest(m.folder)
            per_view = {v: per_model_view[m.name][v] for v in views}
            method = _poses_method(mm)
            poses_s = _wall(artifacts_dir / "poses" / method) if method else None
            t = mm.get("wall_time_s")
            t = float(t) if isinstance(t, (int, float)) else 0.0
            upstream = capture_s + (poses_s or 0.0)
            results[m.name] = {**_summary(per_view), "stage": mm.get("stage", m.name.split("/")[0]),
                               "poses": method or "capture", "time_s": t, "upstream_s": round(upstream, 3),
                               "end_to_end_s": round(t + upstream, 3), "per_view": per_view}
        scored = [n for n in results if results[n]["display_psnr_mean"] is not None]
        best = max(scored, key=lambda n: (results[n]["display_psnr_mean"], -results[n]["end_to_end_s"])) if scored else None
        metrics = {"best": {"model": best, **{k: results[best][k] for k in (
                       "display_psnr_mean", "display_ssim_mean", "flip_ldr_mean", "linear_psnr_mean", "end_to_end_s")}}
                   if best else None,
                   "models": results, "reference": reference, "poses": pose_summary(artifacts_dir),
                   "skipped": skipped, "z_crit": z_crit}
        write_json(tmp / "details.json", metrics)
        write_json(tmp / "metrics.json", _compact(metrics))
        model_rows = [{"model": n, **{k: v for k, v in r.items() if k != "per_view"}} for n, r in results.items()]
        write_csv(tmp / "plots" / "models.csv", model_rows,
                   ["model", "stage", "poses", "display_psnr_mean", "display_psnr_subject_mean", "display_ssim_mean",
                    "flip_ldr_mean", "flip_hdr_mean", "linear_psnr_mean", "display_psnr_truth_est_mean",
                    "psnr_truth_est_mean", "noise_share_mean", "z_within_fraction_mean",
                    "display_psnr_noise_ceiling_mean", "psnr_noise_ceiling_mean", "time_s", "upstream_s",
                    "end_to_end_s"])
        write_csv(tmp / "plots" / "per_view.csv", view_rows,
                   ["model_view", "model", "view", "display_psnr", "display_psnr_subject", "display_ssim", "flip_ldr",
                    "flip_hdr", "linear_psnr", "display_psnr_noise_ceiling", "psnr_noise_ceiling", "noise_share",
                    "z_within_fraction"])
        manifest.metrics = {"models": len(results), "views": len(views), "best": best,
                            **{f"display_psnr_mean.{n}": r["display_psnr_mean"] for n, r in results.items()},
                            **{f"flip_ldr_mean.{n}": r["flip_ldr_mean"] for n, r in results.items()},
                            **{f"linear_psnr_mean.{n}": r["linear_psnr_mean"] for n, r in results.items()},
                            "black.display_psnr_mean": reference["black"]["display_psnr_mean"],
                            "display_psnr_noise_ceiling_mean": reference["display_psnr_noise_ceiling_mean"],
                            "psnr_noise_ceiling_mean": reference["psnr_noise_ceiling_mean"]}
        result = manifest.write(tmp)
    return result

