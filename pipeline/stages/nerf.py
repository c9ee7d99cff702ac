"""The ``nerf`` stage: train a radiance field from a capture and render its held-out views.

Layout (DESIGN.md)::

    nerf/<model>/checkpoint.pt          model + optimizer state (resumable)
    nerf/<model>/renders/<view>.exr     linear RGB at the capture's resolution; <view>.png preview
    nerf/<model>/depth/<view>.exr       z-depth (0 where the opacity is below 0.5), same size
    nerf/<model>/metrics.json           display PSNR / SSIM (8-bit sRGB) and linear PSNR per held-out
                                        view, means, training figures, how the budget was spent
    nerf/<model>/curve.csv              held-out display and linear PSNR against training time
    nerf/<model>/manifest.json

Metrics are computed at the working scale (the capture area-averaged by ``downsample``, by default
the factor giving a width of about 160 pixels: 160x120 for the 1280x960 default scene) and, with
the fast model's ``render_full_res`` (the default; the vanilla models repeat working-scale pixels),
at the capture's resolution: every capture pixel is
rendered (``FastNeRF.render_inference``: a compiled march with empty-space jumps, the dense density
grid and early termination; colour batched in torch; chunks of rays over both cores) and
scored as ``display_psnr_full`` / ``display_ssim_full`` / ``linear_psnr_full``, and the working
scale's figures are then that render area-averaged as the reference is (``display_psnr_point``: one
ray per working pixel). The fast model trains coarse to fine (``FastConfig.pixel_schedule``: the
working scale, then the capture area-averaged by 4 and 2, then its own pixels), the working scale
serving the held-out curve (docs/architecture.md). The full-resolution render is planned when its measured
cost (:func:`plan_renders`) fits ``FULL_RES_SHARE`` of the budget, and done when it fits the time left
after training; otherwise the time is planned for the working scale's render alone and the renders
are its pixels repeated (nearest), ``render_full_res`` false under ``time.planned``. ꟻLIP and the
subject's figures are the validate stage's (ꟻLIP costs seconds per view). The reference is
``--reference DIR`` (``linear/<view>.exr``, the path tracer's stage) when given, else the
capture's own held-out images (exact for direct-only scenes rendered by the rasterizer).

Training runs in this process (one optimizer, one model: it does not split into independent units);
the held-out views are then rendered and scored one view per unit of work (pipeline.distributed,
``cluster``), the trained model shared once.

While training, checkpoints go to a hidden ``.<model>.resume.pt`` beside the stage folder, so an
interrupted run resumes with ``resume=True`` and a finished folder never looks half-written.

Time: ``minutes`` bounds the whole stage's wall time from the call (loading, training, held-out
renders, writing; the interpreter's start and imports before it are not counted). Training runs
against a deadline (:class:`recon.nerf.train.Deadline`): it stops when the time left covers only
the held-out renders, planned from the render cost per ray measured on the model as the final render
spends it (whole rows of the capture-size view with ``render_full_res``, else of the working-scale
view, through the same chunks and threads; untrained first, then after grid growth and occupancy
updates) by :func:`plan_renders`: at the capture's resolution when that fits ``FULL_RES_SHARE`` of the
budget, else at the finest evaluation scale whose cost fits ``RENDER_SHARE`` of it, plus writing
(``WRITE_S_PER_MPIX``, the checkpoint at ``CHECKPOINT_BYTES_PER_S``).
After training the held-out views are evaluated at the working scale when their measured cost
fits the time left, else at the finest coarser scale that fits (working size / k, the reference
area-averaged by k; ``eval_factor`` in metrics, renders still written at the capture's size).
``metrics.json`` records the plan and what happened under ``time``: ``budget_s``; ``planned``
(load_s, train_s at the first step and at the end, render_s, write_s, eval_factor, render_full_res,
the last probe's view size and rays, the probes' number and seconds) and
``actual`` (load_s, train_wall_s, render_s, write_s, stage_s, stopped_by). A budget that leaves
no time for one training step trains none (``steps`` 0): the untrained model is still rendered,
at the coarsest scale if need be. ``clock="cpu"`` (measuring on shared cores) keeps
the old meaning: ``minutes`` of training time, no deadline.
"""
from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from recon.nerf.omp import passive_omp_wait

# before torch loads OpenMP: idle intra-op threads sleep rather than spin (recon/nerf/omp.py: ~6x
# the training steps on 2 loaded cores)
OMP_WAIT_POLICY = passive_omp_wait()
# torch.optim's first optimizer imports torch._dynamo (3 s on idle cores, 25 s on loaded ones):
# imported with the stage, so it is start-up, not time taken out of the --minutes budget's work
import torch._dynamo  # noqa: F401

from recon.nerf.data import NerfInputError, View, area_downsample, load_data
from recon.nerf.models import MODELS, make_model
from recon.nerf.train import Deadline, TrainConfig, evaluate_view, train
from render.camera import Camera
from render.image_io import write_depth_exr, write_exr, write_preview

from ..artifacts import BadInput, Manifest, atomic_stage, check_out, write_json
from ..distributed import ClusterConfig, DaskEngine, LocalEngine, engine, map_units
from ..io import write_csv
from ..progress import console, progress_bar
from .capture import check_capture_folder
from .poses import check_poses

__all__ = ["NerfStageConfig", "run_nerf", "nerf_view", "write_curve_csv", "CURVE_FIELDS", "CURVE_TIME", "CURVE_PSNR", "eval_factors", "eval_factor",
           "plan_renders", "render_reserve_s", "RenderReserve", "RENDER_SHARE", "RENDER_PLAN_FACTOR", "RENDER_MARGIN", "FULL_RES_SHARE", "WRITE_S_PER_MPIX"]

#: curve.csv's columns: training step, training seconds, wall seconds since training began, held-out
#: display PSNR (8-bit sRGB) and linear PSNR (dB)
CURVE_FIELDS = ("step", "train_s", "wall_s", "display_psnr", "linear_psnr")
#: the columns plotted (the report; dvc.yaml's ``plots`` x and y)
CURVE_TIME, CURVE_PSNR = "train_s", "display_psnr"
#: the share of the budget held-out renders are planned to take before their cost is known: the
#: untrained model's cost (every sample evaluated) bounds the trained one from above and would
#: leave short runs no training; what does not fit at the end is evaluated at a coarser scale
RENDER_SHARE = 0.25
#: the share of the budget the held-out renders may take at the capture's resolution (``render_full_res``;
#: every capture pixel instead of the working scale's, so a larger share than RENDER_SHARE)
FULL_RES_SHARE = 0.5
#: writing one held-out view (linear EXR, PNG preview, depth EXR) per megapixel of the capture,
#: seconds (measured 0.6 on 2 cores shared by 7 processes, 0.22 on idle ones)
WRITE_S_PER_MPIX = 0.6
#: the render's cost per ray reserved during training: the probe's (whole rows of a capture-size
#: view, recon.nerf.train) times this. Why 1.0 (was 1.25): the probe over-prices the final render
#: (quiet stages of session 32: 10 minutes probed 9.0 us a ray, rendered at 6.1; 5 minutes 7.7 and
#: 7.0; the demo's 3.5 7.2 and 6.0), so the 1.25 left 38 s of the demo's 210 and 59 of 600 unused
RENDER_PLAN_FACTOR = 1.0
#: after training, the capture-size render is done when its planned cost fits this times the time
#: left (the slack spent: a last step's overrun does not discard the render planned; the stage
#: then ends at most (RENDER_MARGIN - 1) x the render's cost late)
RENDER_MARGIN = 1.25
#: a held-out view's fixed cost besides its rays (scoring, upsampling to the capture's size), seconds
VIEW_OVERHEAD_S = 0.3
#: checkpoint writing and copying speed assumed by the plan (a local disk, conservatively)
CHECKPOINT_BYTES_PER_S = 100e6


def write_curve_csv(path: Path, curve: list[dict]) -> None:
    """curve.csv: one row per held-out evaluation, columns ``CURVE_FIELDS`` (seconds, dB), every digit kept."""
    write_csv(path, curve, CURVE_FIELDS, float_format=None)


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


def eval_factors(width: int, height: int) -> list[int]:
    """Factors k (ascending, 1 first) by which held-out views of ``width`` x ``height`` working
    pixels can be evaluated coarser: k divides both sides, so the reference area-averages exactly."""
    return [k for k in range(1, min(width, height) + 1) if width % k == 0 and height % k == 0]


def eval_factor(s_per_ray: float, rays_at_1: int, available_s: float, factors: list[int]) -> int:
    """The smallest factor k of ``factors`` whose render cost s_per_ray * rays_at_1 / k^2 fits in
    ``available_s`` seconds; the largest factor when none fits."""
    for k in factors:
        if s_per_ray * rays_at_1 / (k * k) <= available_s:
            return k
    return factors[-1]


def plan_renders(s_per_ray: float, rays_at_1: int, rays_full: int, room_s: float, full_room_s: float,
                 factors: list[int]) -> tuple[int, bool]:
    """What the held-out renders will be, (k, full_res), at ``s_per_ray`` seconds a ray: at the
    capture's resolution (``rays_full`` rays, 0 when not asked for, besides the working scale's
    ``rays_at_1``) when that costs at most ``full_room_s`` seconds, k = 1; else the working scale
    alone, at the smallest factor k whose cost fits ``room_s`` (:func:`eval_factor`). One rule
    for both the time reserved before training and the choice after it, so time is never
    reserved for a render that is then not done."""
    if rays_full and s_per_ray * (rays_at_1 + rays_full) <= full_room_s:
        return 1, True
    return eval_factor(s_per_ray, rays_at_1, room_s, factors), False


def render_reserve_s(s_per_ray: float, rays_at_1: int, rays_full: int, budget_s: float, view_s: float,
                     factors: list[int], left_s: float = math.inf) -> float:
    """Seconds reserved during training for the held-out renders at ``s_per_ray`` (the margin
    included), ``view_s`` the views' fixed cost: the render :func:`plan_renders` plans with
    ``FULL_RES_SHARE`` (capture resolution; only while it also fits ``left_s``, the seconds still
    left for renders: a cost that falls late in training does not reserve more than is left) and
    ``RENDER_SHARE`` (working scale) of ``budget_s``, the working scale's capped at its share (the
    coarsest scale when none fits)."""
    k, full = plan_renders(s_per_ray, rays_at_1, rays_full, RENDER_SHARE * budget_s - view_s,
                           min(FULL_RES_SHARE * budget_s, left_s) - view_s, factors)
    render = s_per_ray * (rays_at_1 / (k * k) + (rays_full if full else 0)) + view_s
    return render if full else min(render, RENDER_SHARE * budget_s)


class RenderReserve:
    """:func:`render_reserve_s` for one stage, called with each new cost per ray (margin included)
    and the seconds left: once the capture-resolution render has been reserved it stays reserved
    while it fits ``FULL_RES_SHARE``, even when a later probe prices it above what is left (training
    then stops at once and the stage decides after training, the margin spent). Why: training runs
    until the time left is the reserve, so any later probe that measures a little more (a loaded
    machine) used to drop the capture-resolution render for the working scale's pixels and give its
    time to training (measured: a 3.5-minute stage, load 4-5, trained to 2 s before its deadline
    and wrote pixel repeats)."""

    def __init__(self, rays_at_1: int, rays_full: int, budget_s: float, view_s: float, factors: list[int]):
        self.args = (rays_at_1, rays_full, budget_s, view_s, factors)
        self.full_held = False

    def __call__(self, s_per_ray: float, left_s: float = math.inf) -> float:
        rays_at_1, rays_full, budget_s, view_s, factors = self.args
        render = render_reserve_s(s_per_ray, rays_at_1, rays_full, budget_s, view_s, factors, left_s)
        if rays_full:
            by_share = render_reserve_s(s_per_ray, rays_at_1, rays_full, budget_s, view_s, factors)
            full_fits_share = plan_renders(s_per_ray, rays_at_1, rays_full, RENDER_SHARE * budget_s - view_s,
                                           FULL_RES_SHARE * budget_s - view_s, factors)[1]
            if full_fits_share and (self.full_held or render == by_share):
                self.full_held = True
                return by_share
            self.full_held = False
        return render


def _at_scale(view: View, k: int) -> View:
    """``view`` evaluated k times coarser: camera scaled by 1/k, reference area-averaged by k."""
    if k == 1:
        return view
    cam = Camera(view.camera.intrinsics.scaled(1.0 / k), view.camera.cam_to_world, view.name)
    return View(view.name, cam, area_downsample(view.rgb, k), view.full_camera, view.full_rgb)


@dataclass(frozen=True)
class NerfStageConfig:
    """model: a name of :data:`recon.nerf.models.MODELS`; minutes: the budget (``clock`` "wall": the
    whole stage's wall time, module docstring; "cpu": training time counted as process CPU time /
    threads, for measuring on shared cores, no wall deadline); downsample: train at capture size / N
    (None: about 160 pixels wide); seed: training seed; max_steps: stop after this many steps (None:
    the budget decides); overrides: fields of the model's config to replace (tests use small grids)."""

    model: str = "fast"
    minutes: float = 10.0
    downsample: int | None = None
    seed: int = 0
    max_steps: int | None = None
    clock: str = "wall"
    overrides: dict = field(default_factory=dict)


def run_nerf(capture_dir: Path, poses_dir: Path | None, out: Path, config: NerfStageConfig = NerfStageConfig(),
             reference_dir: Path | None = None, resume: bool = False, quiet: bool = False,
             cluster: ClusterConfig | LocalEngine | DaskEngine | None = None, overwrite: bool = False) -> dict:
    """Train ``config.model`` on ``capture_dir`` (poses from ``poses_dir``/cameras.json when given)
    and write ``out`` atomically, all within ``config.minutes`` of wall time; returns the manifest.
    resume: continue an interrupted run's checkpoint. cluster: where the held-out renders run, one
    view per unit (pipeline.distributed): None (default) in this process; training always runs here.

    Bad input (missing or damaged capture, ``--poses`` of another capture, unknown model,
    ``out`` holding something else than a finished NeRF folder
    without ``overwrite``) raises BadInput before anything is written.
    """
    model, minutes, downsample, seed = config.model, config.minutes, config.downsample, config.seed
    max_steps, clock, overrides = config.max_steps, config.clock, config.overrides
    t_start = time.perf_counter()
    capture_dir = Path(capture_dir)
    out = Path(out)
    if model not in MODELS:
        raise BadInput(f"--model: unknown NeRF model {model!r}; known: {', '.join(sorted(MODELS))}")
    if not (minutes > 0 and math.isfinite(minutes)):
        raise BadInput(f"--minutes must be a positive number, got {minutes}")
    check_out(out, "nerf", overwrite)
    if not capture_dir.is_dir():
        raise BadInput(f"{capture_dir}: no such folder")
    cams, splits = check_capture_folder(capture_dir, need=("linear",))
    if poses_dir is not None:
        check_poses(poses_dir, capture_dir, cams, splits)
    if reference_dir is not None and not Path(reference_dir).is_dir():
        raise BadInput(f"--reference {reference_dir}: no such folder")
    cfg_now = replace(MODELS[model][1], **dict(overrides or {}))
    train_full = bool(cfg_now.needs_full_images()) if hasattr(cfg_now, "needs_full_images") else False
    try:
        data = load_data(capture_dir, poses_dir, reference_dir, downsample, train_full=train_full)
    except NerfInputError as exc:
        raise BadInput(str(exc).splitlines()[0]) from None
    load_s = time.perf_counter() - t_start
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
    full_res = bool(model_cfg.render_full_res)
    budget_s = minutes * 60.0
    deadline_end = t_start + budget_s
    factors = eval_factors(small.width, small.height)
    rays_at_1 = len(data.test) * small.width * small.height
    rays_full = len(data.test) * full.width * full.height if full_res else 0
    write_s = WRITE_S_PER_MPIX * len(data.test) * full.width * full.height / 1e6

    def checkpoint_s(m, param_bytes: int | None = None) -> float:
        """Seconds to save ``m`` (or parameters of ``param_bytes``) with Adam's two moments, then copy
        it into the stage."""
        if param_bytes is None:
            param_bytes = sum(p.numel() * p.element_size() for p in m.parameters())
        return 2.0 * 3.0 * param_bytes / CHECKPOINT_BYTES_PER_S

    ckpt_s_est = 0.0

    view_s = VIEW_OVERHEAD_S * len(data.test)

    reserve = RenderReserve(rays_at_1, rays_full, budget_s, view_s, factors)

    def after_training_s(s_per_ray: float) -> float:
        """Held-out renders as :func:`plan_renders` plans them (at the capture's resolution when
        that fits FULL_RES_SHARE of the budget, else at the finest evaluation scale whose cost fits
        RENDER_SHARE of it, the coarsest when none does; :class:`RenderReserve`), writing the views
        and the checkpoint."""
        left = deadline_end - time.perf_counter() - write_s - ckpt_s_est
        return reserve(RENDER_PLAN_FACTOR * s_per_ray, left) + write_s + ckpt_s_est

    manifest = Manifest("nerf", params={
        "model": model, "minutes": minutes, "clock": clock, "max_steps": max_steps, "seed": seed,
        "downsample": downsample,
        "working_size": [small.width, small.height], "render_size": [full.width, full.height],
        "render_full_res": full_res, "poses": data.poses, "reference": data.reference,
        "background": "black (the scene's); masks unused", "box_lo": data.lo.tolist(), "box_hi": data.hi.tolist(),
        "overrides": {k: str(v) for k, v in overrides.items()}})
    manifest.add_input(capture_dir / "cameras.json")
    manifest.add_input(capture_dir / "linear")
    if poses_dir is not None:
        manifest.add_input(Path(poses_dir) / "cameras.json")
    if reference_dir is not None:
        manifest.add_input(Path(reference_dir) / "linear")

    with progress_bar(quiet) as bar, engine(cluster, quiet) as eng:
        task = bar.add_task(f"nerf {model}", total=100, info="")

        def on_step(p: dict) -> None:
            held = "-" if p["test_psnr"] is None else f"{p['test_psnr']:.2f}"
            bar.update(task, completed=round(100 * p["fraction"], 1),
                       info=f"step {p['step']} loss {p['loss']:.2e} linear psnr {p['psnr']:.2f} held-out display {held} dB")

        t_train = time.perf_counter()
        if clock == "wall":  # the grids grow from res_init to res_final (fast model): the saved state with them
            m0 = make_model(model, data.lo, data.hi, seed, model_cfg)
            ckpt_s_est = checkpoint_s(m0, m0.param_bytes_final() if hasattr(m0, "param_bytes_final") else None)
        deadline = (Deadline(deadline_end, after_training_s, data.test[0].full_camera if full_res else None)
                    if clock == "wall" else None)
        result = train(data, cfg, checkpoint=ckpt, resume=resume, progress=on_step, deadline=deadline)
        if result.steps == 0 and not quiet:
            console.print(f"nerf: --minutes {minutes:g} left no time for a training step; the untrained model is "
                          "rendered (steps 0 in metrics.json)")
        train_end = time.perf_counter()
        plan = dict(result.plan)
        s_per_ray = RENDER_PLAN_FACTOR * plan.get("render_s_per_ray", 0.0)
        available = math.inf
        if deadline is not None:
            # the checkpoint is saved (training wrote it): what is left is copying it into the stage
            available = deadline_end - train_end - write_s - checkpoint_s(result.model) / 2 - view_s
            # the margin is spent now: the capture-resolution render is done when its measured cost
            # fits (a step's overrun at the end of training does not discard the render planned)
            k, full_res = plan_renders(s_per_ray, rays_at_1, rays_full, available, RENDER_MARGIN * available, factors)
        else:
            k = 1
        views = [_at_scale(v, k) for v in data.test]
        bar.update(task, completed=100, info=f"rendering {len(views)} held-out views")
        done: list = [None] * len(views)
        t_render = time.perf_counter()
        model_h = eng.share(result.model)
        map_units(eng, nerf_view, [(v, full_res, cfg.threads) for v in views],
                  shared=[model_h], on_result=done.__setitem__, name="nerf-view")
        del model_h
        render_s = time.perf_counter() - t_render
        rows = [row for row, _ in done]
        renders = {v.name: r for v, (_, r) in zip(views, done)}

    t_write = time.perf_counter()
    eval_w, eval_h = views[0].camera.intrinsics.width, views[0].camera.intrinsics.height
    with atomic_stage(out, "nerf", overwrite) as tmp:
        shutil.copyfile(ckpt, tmp / "checkpoint.pt")
        for name, r in renders.items():
            write_exr(tmp / "renders" / f"{name}.exr", r["rgb"])
            write_preview(tmp / "renders" / f"{name}.png", r["rgb"])
            write_depth_exr(tmp / "depth" / f"{name}.exr", r["depth"])
        means = {f"{k}_mean": float(np.mean([r[k] for r in rows])) for k in ("display_psnr", "display_ssim", "linear_psnr")}
        curve = list(result.curve)
        if deadline is not None and (not curve or curve[-1]["step"] != result.steps):
            # the last point is the held-out evaluation itself (whole views at the evaluation scale)
            curve.append({"step": result.steps, "train_s": round(result.train_s, 3),
                          "wall_s": round(time.perf_counter() - t_train, 3),
                          "display_psnr": round(means["display_psnr_mean"], 4),
                          "linear_psnr": round(means["linear_psnr_mean"], 4)})
        write_curve_csv(tmp / "curve.csv", curve)
        metrics = {
            **means, "model": model,
            "scale": f"{eval_w}x{eval_h} (capture {full.width}x{full.height} / {downsample * k}, area-averaged)",
            "reference": data.reference, "poses": data.poses, "views": rows, "steps": result.steps, "train_s": round(result.train_s, 3),
            "curve_final_display_psnr": curve[-1]["display_psnr"] if curve else None,
            "torch_threads": cfg.threads, "omp_wait_policy": OMP_WAIT_POLICY,
        }
        if full_res:
            for k_ in ("display_psnr", "display_ssim", "linear_psnr"):
                metrics[f"{k_}_full_mean"] = float(np.mean([r[f"{k_}_full"] for r in rows]))
            # the working scale's figures above are the capture-size render area-averaged as the
            # reference is; one ray per working pixel (the former figure, aliased) beside them
            metrics["display_psnr_point_mean"] = float(np.mean([r["display_psnr_point"] for r in rows]))
            metrics["scale"] += "; the render: capture-size, area-averaged"
        if deadline is not None:
            metrics["time"] = {
                "budget_s": round(budget_s, 3),
                "planned": {"load_s": round(load_s, 3),
                            "train_s_first": plan["planned_train_s_first"],
                            "after_training_s_first": plan["after_training_s_first"],
                            "train_s": plan["planned_train_s_last"],
                            "render_s": round(s_per_ray * (rays_at_1 / (k * k) + (rays_full if full_res else 0)), 3),
                            "render_s_per_ray": s_per_ray, "render_budget_s": round(available, 3),
                            "render_s_per_ray_first": RENDER_PLAN_FACTOR * plan["render_s_per_ray_untrained"],
                            "render_s_per_view": VIEW_OVERHEAD_S,
                            "write_s": round(write_s + checkpoint_s(result.model), 3),
                            "eval_factor": k, "eval_size": [eval_w, eval_h],
                            "render_full_res": full_res, "probe_size": plan.get("probe_size"),
                            "probe_rays": plan.get("probe_rays_last"), "probes": plan.get("probes"),
                            "probe_s": plan.get("probe_s")},
                "actual": {"load_s": round(load_s, 3), "train_wall_s": plan["train_wall_s"],
                           "train_total_s": round(train_end - t_train, 3), "render_s": round(render_s, 3),
                           "stopped_by": plan["stopped_by"]},
            }
            metrics["time"]["actual"]["write_s"] = round(time.perf_counter() - t_write, 3)  # all but this file
            metrics["time"]["actual"]["stage_s"] = round(time.perf_counter() - t_start, 3)
        write_json(tmp / "metrics.json", metrics)
        manifest.metrics = {k_: metrics[k_] for k_ in ("display_psnr_mean", "display_ssim_mean", "linear_psnr_mean",
                                                       "steps", "train_s")}
        if deadline is not None:
            done_t = metrics["time"]["actual"]
            manifest.metrics.update(budget_s=round(budget_s, 3), eval_factor=k, load_s=done_t["load_s"],
                                    train_total_s=done_t["train_total_s"], render_s=done_t["render_s"],
                                    write_s=done_t["write_s"], stage_s=done_t["stage_s"])
        m = manifest.write(tmp)
    ckpt.unlink(missing_ok=True)
    return m
