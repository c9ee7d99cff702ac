"""Training a radiance field on a wall-clock budget, rendering and evaluating held-out views.

The loop: random rays from all training pixels (a seeded generator), the model's render, MSE
against the sRGB-encoded radiance (``TrainConfig.loss``; plus the coarse network's for NeRF; on the
fast model's pyramid levels its ``fine_loss``, :func:`fit_loss`), Adam with the model's
learning-rate schedule, which follows *progress* = max(training time / budget, step / max_steps).
The clock counts training only: held-out evaluations for the curve and checkpoint writes are
excluded (``wall_s`` in the curve counts everything). Same seed, same data order; the schedule
is deterministic when ``max_steps`` bounds the run before the time budget does.

Checkpoints (``torch.save``): model state, optimizer state, step, training time, curve, sampler
state. ``train(..., checkpoint=path)`` writes one every ``checkpoint_every_s`` seconds of training
and ``resume=True`` continues from it up to the same budget.

A :class:`Deadline` bounds the wall time of training *and of what follows it*: the caller says
when everything must be done (a ``time.perf_counter()`` value), which view its finest render
draws (``probe_camera``: the capture-size view when the held-out views are rendered there) and how
long it needs after training given the measured render cost per ray (held-out renders, writing).
Training then plans its length from the wall clock: the render cost per ray is measured as the final
render spends it, a batch of whole rows of ``probe_camera`` (up to one ``INFERENCE_CHUNK`` per thread)
through :func:`render_view`, at most ``PROBE_SHARE`` of the time left; before the first step, again
after every grid upsampling (larger grids render slower) and after occupancy updates (occupancy
skipping makes a trained model cheaper) once the time since the last probe is ``1 / PROBE_SHARE``
times that probe's (the probes together about ``PROBE_SHARE`` of the time). The held-out curve's own
cost (random pixel subsets, one call per view) is priced from its evaluations. A step is started
only when it, the curve evaluations still due and the caller's share fit before the end (so a
budget too short for one step trains none: the caller still renders and writes the untrained model
in time). The schedule's progress (learning rates, grid upsampling) follows the planned length,
never decreasing; the final held-out curve point is left to the caller (it renders those views
anyway). Why rows of the capture-size view: 128 random working-scale pixels, one call, priced the
default scene's 1280x960 render at 78 us a ray where the render spent 25 (load 5), so a 10-minute
stage reserved a full-resolution render it then judged not to fit, and left ~150 s unused.
"""
from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from render.camera import Camera
from render.image_io import atomic_path
from render.metrics import mse_to_psnr, psnr, ssim, to_display  # one PSNR convention (capped at PSNR_MAX_DB)

from .data import NerfData, PixelSampler, area_downsample, camera_rays, stack_rays
from .models import MODELS, make_model

__all__ = ["TrainConfig", "TrainResult", "Deadline", "probe_pixels", "train", "pixel_schedule", "pixel_samplers",
           "sampler_at", "srgb_slope", "fit_loss", "render_view", "evaluate_view", "evaluate_views",
           "mse_to_psnr", "render_cost_per_ray"]


@dataclass(frozen=True)
class TrainConfig:
    """model: a name in ``MODELS``; minutes: training-time budget; max_steps: optional step cap;
    seed: model init and ray sampling; eval_every_s: training seconds between held-out PSNR
    points of the curve; checkpoint_every_s: training seconds between checkpoints; threads:
    torch CPU threads; clock: "wall" (the issue's wall-clock budget) or "cpu" (process CPU time /
    threads: the wall time the same work takes on an otherwise idle machine, for measuring on
    shared cores)."""

    model: str = "fast"
    minutes: float = 10.0
    max_steps: int | None = None
    seed: int = 0
    eval_every_s: float = 30.0
    checkpoint_every_s: float = 120.0
    threads: int = 2
    clock: str = "wall"
    #: replaces fields of the registry's model config (e.g. smaller grids in tests)
    overrides: tuple[tuple[str, object], ...] = ()
    #: the training loss: "display" (MSE on the sRGB encoding, what display PSNR scores: dark regions
    #: weigh as a viewer sees them) or "linear" (MSE on linear radiance). Fast NeRF on the default
    #: scene, 400 steps, same seed: display 25.79 dB / SSIM 0.927 / linear 27.96 dB against 21.93 /
    #: 0.731 / 27.12 with the linear loss (held-out views at 160x120)
    loss: str = "display"

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"unknown NeRF model {self.model!r}; known: {sorted(MODELS)}")
        if not (self.minutes > 0 and math.isfinite(self.minutes)):
            raise ValueError(f"minutes must be a positive number, got {self.minutes}")
        if self.clock not in ("wall", "cpu"):
            raise ValueError(f"clock must be 'wall' or 'cpu', got {self.clock!r}")
        if self.loss not in ("linear", "display"):
            raise ValueError(f"loss must be 'linear' or 'display', got {self.loss!r}")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")


@dataclass
class TrainResult:
    """model (trained, eval mode); steps; train_s: training seconds; curve: rows of
    {step, train_s, wall_s, display_psnr, linear_psnr} (held-out PSNR in dB at the working scale, of
    the 8-bit sRGB images and of linear radiance); plan: with a
    :class:`Deadline`, the wall-time plan (seconds): ``planned_train_s`` at the first step and at
    the end, ``after_training_s_first`` (the caller's share as first planned), ``train_wall_s`` spent,
    ``render_s_per_ray`` measured last, ``stopped_by``, ``curve_s_per_ray``, ``probes`` and ``probe_s``
    (their number and seconds), ``probe_rays_last``, ``probe_size`` (the probe view's [W, H])."""

    model: nn.Module
    steps: int
    train_s: float
    curve: list[dict] = field(default_factory=list)
    plan: dict = field(default_factory=dict)


#: rays per chunk of a held-out render through ``render_inference`` (one chunk per thread at a time)
INFERENCE_CHUNK = 1 << 15

#: the share of the time left that one render-cost probe may take (:func:`train`'s probe_cost), and
#: of the time between the probes that follow occupancy updates
PROBE_SHARE = 0.02
#: rays of the probe's first estimate (random pixels of the probe view), which sizes the probe
PROBE_CALIBRATION_RAYS = 256
#: a probe's cost per ray less its call's fixed cost is kept at least this share of the raw one
PROBE_MIN_SHARE = 0.25


@dataclass(frozen=True)
class Deadline:
    """end: ``time.perf_counter()`` value by which training and everything after it must be done;
    after_s(s_per_ray): seconds the caller needs after training (held-out renders, writing),
    given the latest measured render cost in seconds per ray (:func:`render_view`); probe_camera:
    the view of the finest render the caller will do (its cost per ray is measured on whole rows of
    it; None: the first held-out view at the working scale)."""

    end: float
    after_s: Callable[[float], float]
    probe_camera: Camera | None = None


def probe_pixels(camera: Camera, n: int) -> torch.Tensor:
    """(min(n, W H),) flat indices of whole rows of ``camera``, evenly spread over its height (the
    last one cut to n): the rays of a render's chunks as :func:`render_view` deals them, coherent
    along each row, with the view's mix of subject and background."""
    k = camera.intrinsics
    total = k.width * k.height
    if n >= total:
        return torch.arange(total)
    rows = torch.linspace(0, k.height - 1, math.ceil(n / k.width)).round().long().unique()
    return (rows[:, None] * k.width + torch.arange(k.width)[None, :]).reshape(-1)[:n]


def render_cost_per_ray(model: nn.Module, camera: Camera, pixels: torch.Tensor, threads: int | None = None) -> float:
    """Wall seconds per ray of :func:`render_view` of ``pixels`` ((P,) flat indices) of ``camera``."""
    t0 = time.perf_counter()
    render_view(model, camera, pixels=pixels, threads=threads)
    return (time.perf_counter() - t0) / max(int(pixels.shape[0]), 1)


@torch.no_grad()
def render_view(model: nn.Module, camera: Camera, chunk: int = 8192,
                pixels: torch.Tensor | None = None, threads: int | None = None) -> dict[str, np.ndarray]:
    """Render a camera: {"rgb": (H, W, 3), "depth": (H, W) z-depth (0 where the opacity is below
    0.5, as the capture's depth), "opacity": (H, W)}, float32. With ``pixels`` ((P,) flat
    row-major indices) only those pixels: (P, 3), (P,), (P,).

    A model with ``render_inference`` (the fast model) renders through it, its rays in chunks of
    ``INFERENCE_CHUNK`` dealt to ``threads`` threads (default torch's count), each running torch
    single-threaded: why, measured on 2 cores shared with other processes (load 7), torch's own
    two threads spent more time waiting for each other than working (a 1280x960 view 55 s against
    30 s with one thread). Other models render ``chunk`` rays at a time through ``render``."""
    model.eval()
    o, d = camera_rays(camera, pixels)
    if hasattr(model, "render_inference"):
        model.prepare_inference()  # the dense density grid, built once before the threads share it
        threads = threads or torch.get_num_threads()
        bounds = list(range(0, o.shape[0], INFERENCE_CHUNK)) + [o.shape[0]]
        jobs = [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        saved = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            draw = lambda ab: model.render_inference(o[ab[0]:ab[1]], d[ab[0]:ab[1]], threads=1)  # noqa: E731
            if threads > 1 and len(jobs) > 1:
                with ThreadPoolExecutor(threads) as pool:
                    outs = list(pool.map(draw, jobs))
            else:
                outs = [draw(ab) for ab in jobs]
        finally:
            torch.set_num_threads(saved)
    else:
        outs = [model.render(o[i:i + chunk], d[i:i + chunk], training=False) for i in range(0, o.shape[0], chunk)]
    if outs:
        rgb, dist, acc = (torch.cat([getattr(x, k) for x in outs]) for k in ("rgb", "distance", "opacity"))
    else:
        rgb, dist, acc = torch.zeros(0, 3), torch.zeros(0), torch.zeros(0)
    forward = torch.from_numpy(camera.cam_to_world[:3, 2].astype(np.float32))
    z = dist * (d @ forward)
    z = torch.where(acc >= 0.5, z, torch.zeros_like(z))
    k = camera.intrinsics
    shape = (k.height, k.width) if pixels is None else (pixels.shape[0],)
    return {"rgb": rgb.reshape(*shape, 3).numpy(), "depth": z.reshape(shape).numpy(),
            "opacity": acc.reshape(shape).numpy()}


def _curve_pixels(data: NerfData, n: int | None, seed: int) -> list[torch.Tensor | None]:
    if n is None:
        return [None] * len(data.test)
    g = torch.Generator().manual_seed(seed + 1)
    out = []
    for v in data.test:
        total = v.camera.intrinsics.width * v.camera.intrinsics.height
        out.append(torch.randperm(total, generator=g)[:min(n, total)])
    return out


def _held_out_psnr(model: nn.Module, data: NerfData, pixels: list) -> tuple[float, float]:
    """Means over held-out views of the display PSNR (8-bit sRGB, :func:`render.metrics.to_display`)
    and the linear PSNR (whole images, or the fixed pixel subsets)."""
    shown, linear = [], []
    for v, px in zip(data.test, pixels):
        pred = render_view(model, v.camera, pixels=px)["rgb"].reshape(-1, 3)
        ref = v.rgb.reshape(-1, 3) if px is None else v.rgb.reshape(-1, 3)[px.numpy()]
        shown.append(psnr(to_display(pred), to_display(ref)))
        linear.append(psnr(pred, ref))
    model.train()
    return float(np.mean(shown)), float(np.mean(linear))


def srgb_encode(linear: torch.Tensor) -> torch.Tensor:
    """The sRGB transfer curve of linear radiance (any shape), differentiable and unclipped above
    1: 12.92 x below 0.0031308, else 1.055 x^(1/2.4) - 0.055. The power's argument is clamped to
    the knee so that its gradient (infinite at 0) is never evaluated where the linear toe applies."""
    x = linear.clamp(min=0.0)
    knee = 0.0031308
    return torch.where(x <= knee, 12.92 * x, 1.055 * x.clamp(min=knee) ** (1.0 / 2.4) - 0.055)


def srgb_slope(linear: torch.Tensor) -> torch.Tensor:
    """The derivative of :func:`srgb_encode` (any shape): 12.92 at and below the knee 0.0031308
    (its largest value), else 1.055 / 2.4 x^(-1.4 / 2.4)."""
    x = linear.clamp(min=0.0)
    knee = 0.0031308
    return torch.where(x <= knee, torch.full_like(x, 12.92), (1.055 / 2.4) * x.clamp(min=knee) ** (-1.4 / 2.4))


def fit_loss(preds: list[torch.Tensor], target: torch.Tensor, kind: str) -> torch.Tensor:
    """The sum over ``preds`` ((R, 3) linear radiance each: the render and the model's auxiliary
    ones) of their mean squared error against ``target`` (R, 3): "display" of the sRGB encodings,
    "linear" of linear radiance, "tangent" of linear radiance times the sRGB curve's slope at the
    prediction held constant (the display error to first order, whose minimiser over targets a ray
    cannot tell apart is their linear mean; the display one's is darker, sRGB being concave)."""
    if kind == "display":
        shown = srgb_encode(target)
        return sum(torch.mean((srgb_encode(p) - shown) ** 2) for p in preds)
    if kind == "linear":
        return sum(torch.mean((p - target) ** 2) for p in preds)
    if kind == "tangent":
        return sum(torch.mean((srgb_slope(p.detach()) * (p - target)) ** 2) for p in preds)
    raise ValueError(f"unknown loss {kind!r}")


def pixel_schedule(model_cfg) -> list[tuple[float, int]]:
    """The model config's training-pixel levels, [(progress, factor)] ascending: its
    ``pixel_schedule``, or ``train_full_res``'s capture pixels from ``full_res_from`` on. Raises
    ValueError naming the field when progress is not ascending in [0, 1] or a factor not >= 1."""
    sched = [tuple(x) for x in getattr(model_cfg, "pixel_schedule", ())]
    if not sched and getattr(model_cfg, "train_full_res", False):
        sched = [(float(getattr(model_cfg, "full_res_from", 0.0)), 1)]
    for i, (p, f) in enumerate(sched):
        if not (0.0 <= p <= 1.0) or (i and p < sched[i - 1][0]):
            raise ValueError(f"pixel_schedule: progress must ascend in [0, 1], got {sched}")
        if int(f) != f or f < 1:
            raise ValueError(f"pixel_schedule: factors must be integers >= 1, got {sched}")
    return [(float(p), int(f)) for p, f in sched]


def pixel_samplers(data: NerfData, model_cfg) -> list[tuple[float, PixelSampler]]:
    """[(progress, PixelSampler)] of :func:`pixel_schedule` (empty when the training views carry no
    full-resolution images: the working scale throughout). A factor equal to the working scale's
    downsampling draws the working scale's pixels (as the sampler's pyramid level)."""
    sched = pixel_schedule(model_cfg)
    if not sched or any(v.full_rgb is None for v in data.train):
        return []
    levels: dict[int, PixelSampler] = {}
    out = []
    for p, f in sched:
        if f not in levels:
            levels[f] = PixelSampler(data.train, f)
        out.append((p, levels[f]))
    return out


def sampler_at(samplers: list[tuple[float, PixelSampler]], progress: float) -> PixelSampler | None:
    """The level of ``samplers`` in force at ``progress`` (the last whose progress it has reached),
    None before the first (the working scale's rays)."""
    level = None
    for p, s in samplers:
        if progress >= p:
            level = s
    return level


def _make_optimizer(model, progress: float) -> torch.optim.Optimizer:
    return torch.optim.Adam(model.param_groups(progress), betas=(0.9, 0.99))


def _save(path: Path, model, opt, step, train_s, curve, gen, cfg: TrainConfig) -> None:
    with atomic_path(path) as tmp:
        torch.save({"model_name": cfg.model, "train_config": asdict(cfg), "state": model.state_dict(),
                    "optimizer": opt.state_dict(), "step": step, "train_s": train_s, "curve": curve,
                    "generator": gen.get_state(), "lo": model.lo.tolist(), "hi": model.hi.tolist()}, tmp)


def train(data: NerfData, cfg: TrainConfig, checkpoint: Path | None = None, resume: bool = False,
          progress: Callable[[dict], None] | None = None, stop_step: int | None = None,
          deadline: Deadline | None = None) -> TrainResult:
    """Train ``cfg.model`` on ``data.train`` for ``cfg.minutes`` of training time.

    checkpoint: where to write checkpoints (None: never); resume: continue from ``checkpoint``
    if it exists; progress: called after every step with {fraction, step, loss, psnr,
    test_psnr (latest held-out display PSNR or None), rays, points}; stop_step: leave after this many
    steps as an interruption would (checkpoint written, schedule unchanged, nothing finalised);
    deadline: also stop so that training and the caller's ``after_s`` fit before ``deadline.end``
    (module docstring); the final held-out curve point is then not computed.
    """
    torch.set_num_threads(cfg.threads)

    def now() -> float:
        return time.perf_counter() if cfg.clock == "wall" else time.process_time() / cfg.threads
    model_cfg = replace(MODELS[cfg.model][1], **dict(cfg.overrides))
    model = make_model(cfg.model, data.lo, data.hi, cfg.seed, model_cfg)
    gen = torch.Generator().manual_seed(cfg.seed)
    o_all, d_all, c_all = stack_rays(data.train)
    samplers = pixel_samplers(data, model_cfg)
    fine_loss = getattr(model_cfg, "fine_loss", "display")  # FastConfig checks its value
    if hasattr(model, "init_colour"):
        model.init_colour(c_all.mean(dim=0))  # a resumed run loads its own state below
    n_rays = o_all.shape[0]
    budget = cfg.minutes * 60.0
    step, train_s, curve = 0, 0.0, []
    state = None
    if resume and checkpoint is not None and Path(checkpoint).is_file():
        state = torch.load(checkpoint, weights_only=False)
        if state["model_name"] != cfg.model:
            raise ValueError(f"{checkpoint}: checkpoint of model {state['model_name']!r}, not {cfg.model!r}")
        model.load_state_dict(state["state"])
        step, train_s, curve = state["step"], state["train_s"], list(state["curve"])
        gen.set_state(state["generator"])

    pixels = _curve_pixels(data, getattr(model_cfg, "curve_pixels", None), cfg.seed)
    curve_rays = sum(v.camera.intrinsics.width * v.camera.intrinsics.height if px is None else int(px.shape[0])
                     for v, px in zip(data.test, pixels))
    plan: dict = {}
    s_per_ray = 0.0        # the caller's render cost per ray (probe_cost)
    curve_s_per_ray = 0.0  # the held-out curve's (random pixel subsets, one call per view)
    probe_log = {"n": 0, "s": 0.0, "last_at": 0.0, "last_s": 0.0, "rays": 0}
    if deadline is not None:
        probe_cam = deadline.probe_camera or data.test[0].camera
        k0 = probe_cam.intrinsics
        g = torch.Generator().manual_seed(cfg.seed + 2)
        calibration = torch.randperm(k0.width * k0.height, generator=g)[:PROBE_CALIBRATION_RAYS + 8]
        probe_rows = probe_pixels(probe_cam, cfg.threads * INFERENCE_CHUNK)

    def probe_cost() -> float:
        """The model's render cost per ray as the caller's render spends it: whole rows of the
        probe view (``probe_pixels``: up to one INFERENCE_CHUNK per thread, dealt to the threads by
        :func:`render_view` as the final render's are), as many as fit PROBE_SHARE of the time left
        before the deadline at the cost of PROBE_CALIBRATION_RAYS random ones (after 8 that take the
        first-call overheads), at least those. Sets the curve's first cost per ray (the calibration's:
        random pixels in one call, as the curve renders them) when none was measured yet."""
        nonlocal curve_s_per_ray
        t_probe = time.perf_counter()
        few = calibration[:8]
        render_view(model, probe_cam, pixels=few, threads=cfg.threads)  # first-call overheads
        # a call's fixed cost (its rays' setup, the threads), which a held-out view pays once
        # (VIEW_OVERHEAD_S), not per ray: subtracted from the probes' costs per ray. Why: on a loaded
        # machine it made a 4793-ray probe price the render at 43 us a ray (the 10-minute stage then
        # planned 420 s for its capture-size render, judged it not to fit and wrote pixel repeats)
        call_s = int(few.shape[0]) * render_cost_per_ray(model, probe_cam, few, threads=cfg.threads)

        def per_ray(raw: float, n: int) -> float:
            return max(raw - call_s / max(n, 1), PROBE_MIN_SHARE * raw)
        cal = calibration[8:] if calibration.shape[0] > 8 else calibration
        cal_raw = render_cost_per_ray(model, probe_cam, cal, threads=cfg.threads)
        if not curve or curve_s_per_ray == 0.0:
            curve_s_per_ray = cal_raw  # the curve's calls pay their fixed cost, one per view
        cal_s_per_ray = per_ray(cal_raw, int(cal.shape[0]))
        left = max(deadline.end - time.perf_counter(), 0.0)
        n = int(min(probe_rows.shape[0], PROBE_SHARE * left / max(cal_s_per_ray, 1e-9)))
        cost, rays = cal_s_per_ray, int(cal.shape[0])
        if n > cal.shape[0]:
            # rows spread over the whole view for this n (the first n of the widest spread are its
            # top rows: on the default scene black background, priced at 2.1 us a ray where the
            # render then spent 11.5, a 3.5-minute stage's render planned at 21 s took 113)
            cost, rays = per_ray(render_cost_per_ray(model, probe_cam, probe_pixels(probe_cam, n), threads=cfg.threads), n), n
        model.train()
        now_ = time.perf_counter()
        probe_log.update(n=probe_log["n"] + 1, s=probe_log["s"] + now_ - t_probe, last_at=now_,
                         last_s=now_ - t_probe, rays=rays)
        return cost

    if deadline is not None:
        s_per_ray = probe_cost()
    occ_seen = int(getattr(model, "occ_updates", 0))
    train_wall = 0.0       # wall seconds spent in steps (with a deadline)
    # a step's wall time, decaying maximum of the recent ones; before the first: its forward pass at
    # the calibration's cost per ray (random rays, one call), backward about twice that
    step_wall = 3.0 * curve_s_per_ray * model.batch_rays()
    hook_wall = 0.0        # the longest schedule hook (grid upsampling, occupancy update) seen
    progress_floor = 0.0   # the schedule never goes back

    def remaining_train_s() -> float:
        """Wall seconds of training that still fit before the deadline (deadline mode only)."""
        eval_s = curve_s_per_ray * curve_rays
        left = deadline.end - time.perf_counter() - deadline.after_s(s_per_ray) - step_wall - hook_wall
        return max(0.0, left) / (1.0 + eval_s / cfg.eval_every_s)  # curve evaluations due meanwhile

    def frac() -> float:
        f = max(progress_floor, train_s / budget)
        if cfg.max_steps is not None:
            f = max(f, step / cfg.max_steps)
        if deadline is not None:
            rest = remaining_train_s()
            f = max(f, 1.0 if rest <= 0.0 else train_wall / (train_wall + rest))
        return f

    if state is None:  # a resumed run's first step applies the schedule after its optimizer state is loaded:
        model.on_progress(frac(), step)  # a growth due then rebuilds the optimizer, as the run not interrupted did
    opt = _make_optimizer(model, frac())  # the first one imports parts of torch: seconds, before the plan
    if state is not None:
        opt.load_state_dict(state["optimizer"])
    if deadline is not None:
        plan["planned_train_s_first"] = round(remaining_train_s(), 3)
        plan["after_training_s_first"] = round(deadline.after_s(s_per_ray), 3)
        plan["render_s_per_ray_untrained"] = s_per_ray
    wall0 = time.perf_counter() - (curve[-1]["wall_s"] if curve else 0.0)
    next_eval = (curve[-1]["train_s"] if curve else 0.0) + cfg.eval_every_s  # no point at step 0
    next_ckpt = train_s + cfg.checkpoint_every_s
    test_psnr = curve[-1]["display_psnr"] if curve else None
    stopped_by = "budget"
    model.train()
    while True:
        if train_s >= next_eval:
            if hasattr(model, "prepare_inference"):
                # the dense density grid is rebuilt once per render pass (the parameters moved), not
                # per ray: inside the per-ray cost it made the plan ~5x the held-out renders' cost
                model.prepare_inference()
            t_eval = time.perf_counter()
            test_psnr, test_linear = _held_out_psnr(model, data, pixels)
            if curve_rays:
                curve_s_per_ray = (time.perf_counter() - t_eval) / curve_rays  # the curve's cost as it is now
            curve.append({"step": step, "train_s": round(train_s, 3), "wall_s": round(time.perf_counter() - wall0, 3),
                          "display_psnr": round(test_psnr, 4), "linear_psnr": round(test_linear, 4)})
            next_eval = train_s + cfg.eval_every_s
        progress_now = frac()
        if progress_now >= 1.0:
            if cfg.max_steps is not None and step >= cfg.max_steps:
                stopped_by = "max_steps"
            elif deadline is not None and train_s < budget:
                stopped_by = "deadline"
            break
        progress_floor = progress_now
        if stop_step is not None and step >= stop_step:
            if checkpoint is not None:
                _save(Path(checkpoint), model, opt, step, train_s, curve, gen, cfg)
            return TrainResult(model, step, train_s, curve, plan)
        t0 = now()
        w0 = time.perf_counter()
        if model.on_progress(progress_now, step):
            opt = _make_optimizer(model, progress_now)
            hook_wall = max(hook_wall, time.perf_counter() - w0)
            if deadline is not None:  # larger grids render slower: measure again
                s_per_ray = probe_cost()
                w0 = time.perf_counter()
        elif deadline is not None and int(getattr(model, "occ_updates", 0)) != occ_seen and \
                time.perf_counter() - probe_log["last_at"] >= probe_log["last_s"] / PROBE_SHARE and \
                probe_log["last_s"] <= PROBE_SHARE * (deadline.end - time.perf_counter()):
            hook_wall = max(hook_wall, time.perf_counter() - w0)
            s_per_ray = probe_cost()  # the occupancy moved: the render cost with it
            occ_seen = int(model.occ_updates)
            w0 = time.perf_counter()
        hook_wall = max(hook_wall, time.perf_counter() - w0)
        for group in opt.param_groups:
            group["lr"] = model.learning_rates(progress_now)[group["name"]]
        level = sampler_at(samplers, progress_now)
        if level is not None:
            o_b, d_b, target = level.sample(model.batch_rays(), gen)
        else:
            idx = torch.randint(n_rays, (model.batch_rays(),), generator=gen)
            o_b, d_b, target = o_all[idx], d_all[idx], c_all[idx]
        out = model.render(o_b, d_b, training=True, generator=gen)
        mse = torch.mean((out.rgb - target) ** 2)
        kind = "tangent" if level is not None and cfg.loss == "display" and fine_loss == "tangent" else cfg.loss
        loss = fit_loss([out.rgb, *out.aux], target, kind)
        if not torch.isfinite(loss):
            raise RuntimeError(f"non-finite loss at step {step} (model {cfg.model})")
        opt.zero_grad(set_to_none=True)
        if loss.requires_grad:  # a batch whose rays all cross empty space has nothing to fit
            loss.backward()
            opt.step()
        step += 1
        train_s += now() - t0
        this_step = time.perf_counter() - w0
        train_wall += this_step
        step_wall = max(this_step, 0.8 * step_wall)
        if progress is not None:
            progress({"fraction": min(frac(), 1.0), "step": step, "loss": loss.item(), "psnr": mse_to_psnr(mse.item()),
                      "test_psnr": test_psnr, "rays": int(target.shape[0]), "points": out.n_points})
        if checkpoint is not None and train_s >= next_ckpt:
            _save(Path(checkpoint), model, opt, step, train_s, curve, gen, cfg)
            next_ckpt = train_s + cfg.checkpoint_every_s
    t_final = time.perf_counter()
    if hasattr(model, "update_occupancy") and step >= getattr(model_cfg, "occ_start", 0):
        model.update_occupancy()  # the final state, so rendering skips all empty space
    if deadline is None and (not curve or curve[-1]["step"] != step):
        test_psnr, test_linear = _held_out_psnr(model, data, pixels)
        curve.append({"step": step, "train_s": round(train_s, 3), "wall_s": round(time.perf_counter() - wall0, 3),
                      "display_psnr": round(test_psnr, 4), "linear_psnr": round(test_linear, 4)})
    if checkpoint is not None:
        _save(Path(checkpoint), model, opt, step, train_s, curve, gen, cfg)
    model.eval()
    if deadline is not None:
        plan.update(planned_train_s_last=round(train_wall + remaining_train_s(), 3), train_wall_s=round(train_wall, 3),
                    render_s_per_ray=s_per_ray, finish_s=round(time.perf_counter() - t_final, 3), stopped_by=stopped_by,
                    curve_rays=curve_rays, curve_s_per_ray=curve_s_per_ray, probes=probe_log["n"],
                    probe_s=round(probe_log["s"], 3), probe_rays_last=probe_log["rays"],
                    probe_size=[k0.width, k0.height])
    return TrainResult(model, step, train_s, curve, plan)


def _scores(pred: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    """display_psnr, display_ssim (8-bit sRGB images) and linear_psnr of a (H, W, 3) render."""
    shown, shown_ref = to_display(pred), to_display(ref)
    return {"display_psnr": psnr(shown, shown_ref), "display_ssim": ssim(shown, shown_ref), "linear_psnr": psnr(pred, ref)}


def evaluate_view(model: nn.Module, v, full_res: bool) -> tuple[dict, dict]:
    """Render one held-out view (:class:`recon.nerf.data.View`) and compare it with its reference:
    (row, render) as one element of :func:`evaluate_views`. A pure function of (model, view), so
    views may be rendered in any process (the pipeline runs one view per unit of work)."""
    f = v.full_camera.intrinsics.width // v.camera.intrinsics.width
    if full_res:
        # the working scale's figure: the capture-size render area-averaged as its reference is (a
        # sensor's larger pixel integrates its footprint); one ray per working pixel aliases a field
        # trained on finer pixels. That point-sampled render is kept as display_psnr_point.
        big = render_view(model, v.full_camera)
        point = render_view(model, v.camera)
        row = {"view": v.name, **_scores(area_downsample(big["rgb"], f), v.rgb),
               "display_psnr_point": psnr(to_display(point["rgb"]), to_display(v.rgb))}
        row.update({f"{k}_full": x for k, x in _scores(big["rgb"], v.full_rgb).items()})
    else:
        small = render_view(model, v.camera)
        row = {"view": v.name, **_scores(small["rgb"], v.rgb)}
        big = {k: np.repeat(np.repeat(a, f, axis=0), f, axis=1) for k, a in small.items()}
    return row, {"rgb": big["rgb"], "depth": big["depth"]}


def evaluate_views(model: nn.Module, data: NerfData, full_res: bool) -> tuple[list[dict], dict[str, dict]]:
    """Render every held-out view and compare it with its reference.

    Returns (rows, renders): rows of {view, display_psnr, display_ssim, linear_psnr} at the working
    scale (against the area-downsampled reference; with ``full_res`` the capture-size render
    area-averaged the same way, and ``display_psnr_point`` the working scale's one ray per pixel),
    plus the same with ``_full`` at the reference's resolution when ``full_res``; renders[view] = {"rgb", "depth"} at the reference's resolution: rendered there
    when ``full_res``, else the working-scale render repeated to that size (nearest).
    """
    rows, renders = [], {}
    for v in data.test:
        row, renders[v.name] = evaluate_view(model, v, full_res)
        rows.append(row)
    return rows, renders
