"""``lumigraph study SCENE``: what accuracy costs in time, per stage and end to end.

One command sweeps each stage's accuracy knob on a scene, measures the wall time of every setting
and its error against a high-sample reference of the same held-out views, and draws the Pareto
fronts (the settings no other setting beats in both time and accuracy)::

    study/study.csv            one row per setting: stage, family, setting, time_s, display_psnr,
                               display_ssim (8-bit sRGB), linear_psnr, display_psnr_truth_est,
                               psnr_truth_est (linear), rotation_error_deg (poses), end_to_end_s, pareto
    study/study.json           the rows, the fronts, the profile, the machine
    study/pareto.csv           the Pareto-optimal rows of each stage and end to end
    study/pareto_<stage>.svg   accuracy against time per stage; pareto_end_to_end.svg
    study/manifest.json

Knobs (``profile``: ``quick`` at half the scene's image size, 2 held-out views, no NeRF — the NeRF
stage's fixed costs alone exceed a couple of minutes on 2 cores today; ``full`` at the scene's size,
every held-out view, the fast NeRF for 2, 5 and 10 minutes and the vanilla one for 10):

* reference (path tracer): samples per pixel x integrator (``direct``, ``path``; an integrator the
  scene's effects rule out is recorded as skipped);
* poses: method (gt, charuco, colmap) x COLMAP's image scale; accuracy = mean rotation error;
* slab: (uv_res, st_res) x interpolation mode (time = build + rendering the views in that mode);
* nerf (when the NeRF stage exists): model x training minutes;
* end to end: every way to a model of the held-out views — slab direct (each grid point and
  mode), slab rebinned on each pose estimate, NeRF — with time = capture + poses (when
  estimated) + the model stage, and display PSNR against the study's reference.

Accuracy is display PSNR (the 8-bit sRGB images', as the field reports it: the fronts' y axis),
at the reference's resolution (the NeRF's held-out renders as written, at the capture's size);
linear PSNR is kept as a column. ꟻLIP is the validate stage's (seconds per view and model).

The study's scene is the given one with its image size scaled (``size_scale``) and its held-out
rings cut to ``test_views`` cameras (quick profile): a derived YAML in the work folder (relative
file paths made absolute). The study's reference renders the held-out views at ``truth_spp`` with
the scene's own integrator and a seed different from every swept render (independent noise);
every accuracy is :func:`pipeline.stages.validate.compare_view` against it, so the reference's
noise ceiling is reported too. All stages run in a scratch folder inside the study folder that is
deleted before the manifest is written; only the figures are kept.

Points run one after another in this process, each stage in process (no Dask engine): timings
of points run concurrently on shared cores would not be comparable (docs/scaling.md, "Stages").
"""
from __future__ import annotations

import copy
import re
import shutil
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from render.metrics import display_noise_mse, mse_to_psnr

from ..artifacts import BadInput, Manifest, atomic_stage, check_out, read_json, write_json
from ..io import read_image, write_csv
from ..plot import Series, pareto_mask, svg_plot, write_svg
from ..progress import progress_bar
from .validate import ValidateConfig, compare_view, reference_at

__all__ = ["StudyConfig", "PROFILES", "STUDY_STAGES", "derived_scene", "run_study", "pareto_rows"]

_TRUTH_SEED_OFFSET = 1000

#: the sweeps a study can run (``lumigraph study --only``); rebinning runs when both poses and slab do
STUDY_STAGES = ("reference", "poses", "slab", "nerf")


@dataclass(frozen=True)
class StudyConfig:
    """size_scale: image size factor applied to the scene's intrinsics (1 = as specified);
    test_views: held-out cameras kept per test ring (0 = all); truth_spp: samples of the study's
    reference; spp / integrators: path tracer sweep; poses: (method, COLMAP image scale) pairs;
    slab_grid: (uv_res, st_res) pairs (every interpolation mode is scored); rebin_grid: the
    (uv_res, st_res) of slabs rebinned on each pose estimate; nerf: (model, minutes) pairs; stages: the
    sweeps run (a subset of STUDY_STAGES; the capture and the study's reference always run)."""

    size_scale: float = 0.5
    test_views: int = 2
    truth_spp: int = 64
    spp: tuple[int, ...] = (1, 4, 16)
    integrators: tuple[str, ...] = ("direct", "path")
    poses: tuple[tuple[str, float], ...] = (("gt", 1.0), ("charuco", 1.0), ("colmap", 1.0))
    slab_grid: tuple[tuple[int, int], ...] = ((4, 48), (8, 96))
    rebin_grid: tuple[int, int] = (4, 48)
    nerf: tuple[tuple[str, float], ...] = (("fast", 0.5), ("fast", 1.5))
    stages: tuple[str, ...] = STUDY_STAGES

    def __post_init__(self):
        unknown = [s for s in self.stages if s not in STUDY_STAGES]
        if unknown or not self.stages:
            raise ValueError(f"stages must be a non-empty subset of {', '.join(STUDY_STAGES)}, got {list(self.stages)}")
        if not 0 < self.size_scale <= 4:
            raise ValueError(f"size_scale must be in (0, 4], got {self.size_scale}")
        if self.truth_spp < 2 or any(s < 1 for s in self.spp):
            raise ValueError("truth_spp must be at least 2 and every spp at least 1")


PROFILES = {
    "quick": StudyConfig(),
    "full": StudyConfig(size_scale=1.0, test_views=0, truth_spp=256, spp=(1, 2, 4, 8, 16, 32, 64),
                        poses=(("gt", 1.0), ("charuco", 1.0), ("colmap", 0.25), ("colmap", 0.5), ("colmap", 1.0)),
                        slab_grid=((4, 48), (8, 96), (16, 192), (24, 256)), rebin_grid=(16, 192),
                        nerf=(("fast", 2.0), ("fast", 5.0), ("fast", 10.0), ("vanilla", 10.0))),
}


# ------------------------------------------------------------------------------------- scene


def _absolute_paths(node, base: Path):
    """Copy of a spec tree with relative ``image`` / ``file`` paths made absolute against ``base``."""
    if isinstance(node, dict):
        out = {}
        for k, v in node.items():
            if k in ("image", "file") and isinstance(v, str) and not v.startswith("skimage:") and not Path(v).is_absolute():
                out[k] = str((base / v).resolve())
            else:
                out[k] = _absolute_paths(v, base)
        return out
    if isinstance(node, list):
        return [_absolute_paths(v, base) for v in node]
    return node


def derived_scene(scene: str | Path, folder: Path, size_scale: float, test_views: int) -> Path:
    """Write the study's variant of ``scene`` to ``folder/<name>.yaml``: intrinsics scaled by
    ``size_scale`` (width, height and any explicit fx, fy, cx, cy), each held-out ring cut to
    ``test_views`` cameras (0 keeps all). Returns its path; SpecError/BadInput on a bad scene."""
    from rig.spec import resolve_scene_path

    src = resolve_scene_path(scene)
    data = yaml.safe_load(src.read_text())
    if not isinstance(data, dict) or "cameras" not in data:
        raise BadInput(f"{src}: not a scene spec with cameras")
    data = _absolute_paths(copy.deepcopy(data), src.parent)
    k = data["cameras"].get("intrinsics", {})
    for key in ("width", "height"):
        if key in k:
            k[key] = max(8, int(round(k[key] * size_scale)))
    for key in ("fx", "fy", "cx", "cy"):
        if k.get(key) is not None:
            k[key] = k[key] * size_scale
    if test_views > 0:
        for layout in data["cameras"].get("test", []) or []:
            if isinstance(layout, dict) and "ring" in layout:
                layout["ring"]["count"] = min(layout["ring"]["count"], test_views)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{data.get('name', src.stem)}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


# ------------------------------------------------------------------------------------- scoring


def _score(images: dict[str, np.ndarray], truth: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    """Mean display_psnr, display_ssim, linear_psnr, display_psnr_truth_est, psnr_truth_est of
    renders (view -> (H, W, 3)) against the study reference (validate's compare_view, no ꟻLIP)."""
    rows = []
    for v, (ref, var) in truth.items():
        img = images[v]
        r, s, _ = reference_at(ref, var, img.shape, Path(v))
        rows.append(compare_view(img, r, s, ValidateConfig(flip=False)))

    def mean(key):
        vals = [m[key] for m in rows if m[key] is not None]
        return float(np.mean(vals)) if vals else None

    return {k: mean(k) for k in ("display_psnr", "display_ssim", "linear_psnr", "display_psnr_truth_est",
                                 "psnr_truth_est")}


def _read_views(folder: Path, views: list[str]) -> dict[str, np.ndarray]:
    return {v: read_image(folder / f"{v}.exr") for v in views}


def pareto_rows(rows: list[dict], accuracy: str = "display_psnr", lower_is_better: bool = False,
                cost: str = "time_s") -> list[bool]:
    """Pareto flags of ``rows`` (lower ``cost``, better ``accuracy``); rows lacking either: False."""
    c = [r.get(cost) if r.get(cost) is not None else np.nan for r in rows]
    a = [r.get(accuracy) if r.get(accuracy) is not None else np.nan for r in rows]
    a = [-x for x in a] if lower_is_better else a
    return [bool(x) for x in pareto_mask(c, a)] if rows else []


# ------------------------------------------------------------------------------------- sweeps


class _Sweep:
    """Runs sweep points in scratch folders, times them, collects rows; a failed point (BadInput:
    a pose estimate that fails, an integrator the scene rules out) is a row with its reason."""

    def __init__(self, work: Path, bar, task):
        self.work, self.bar, self.task, self.rows = work, bar, task, []

    def point(self, stage: str, family: str, setting: str, fn, **extra) -> dict | None:
        t0 = time.perf_counter()
        try:
            result = fn()
        except BadInput as exc:
            reason = re.sub(r" \(see [^)]*\)$", "", str(exc).splitlines()[0])  # scratch paths are deleted
            self.rows.append({"stage": stage, "family": family, "setting": setting, "status": "failed",
                              "reason": reason[:200], "time_s": round(time.perf_counter() - t0, 3),
                              **extra})
            result = None
        finally:
            self.bar.advance(self.task)
        return result

    def add(self, **row) -> dict:
        row.setdefault("status", "ok")
        self.rows.append(row)
        return row


def _sweep_reference(sw: _Sweep, rig, scene_file: Path, views: list[str], truth, cfg: StudyConfig, seed: int) -> None:
    from .reference import ReferenceConfig, run_reference

    # untimed warm-up: the first render in a process pays one-off costs (compilation, caches)
    run_reference(rig, scene_file, sw.work / "pt" / "warmup", ReferenceConfig(spp=1, seed=seed), quiet=True)
    shutil.rmtree(sw.work / "pt" / "warmup", ignore_errors=True)
    for integ in cfg.integrators:
        for spp in cfg.spp:
            out = sw.work / "pt" / f"{integ}_{spp}"

            def go():
                return run_reference(rig, scene_file, out, ReferenceConfig(spp=spp, integrator=integ, seed=seed),
                                     quiet=True)

            m = sw.point("reference", integ, f"{integ} {spp} spp", go, spp=spp)
            if m is None:
                continue
            sw.add(stage="reference", family=integ, setting=f"{integ} {spp} spp", spp=m["params"]["spp"],
                   time_s=m["wall_time_s"], **_score(_read_views(out / "linear", views), truth))
            shutil.rmtree(out, ignore_errors=True)


def _sweep_poses(sw: _Sweep, capture: Path, cfg: StudyConfig) -> dict[str, tuple[Path, float]]:
    """Runs every pose setting; returns {label: (poses folder, wall time)} of those that worked."""
    from recon.poses import ColmapConfig

    from .poses import PosesConfig, run_poses

    done = {}
    for method, scale in cfg.poses:
        label = method if method != "colmap" else f"colmap x{scale:g}"
        out = sw.work / "poses" / label.replace(" ", "_")
        pc = PosesConfig(colmap=ColmapConfig(image_scale=scale))
        m = sw.point("poses", method, label, lambda: run_poses(capture, method, out, pc, quiet=True),
                     image_scale=scale)
        if m is None:
            continue
        mt = m["metrics"]
        sw.add(stage="poses", family=method, setting=label, image_scale=scale, time_s=m["wall_time_s"],
               rotation_error_deg=mt.get("rotation_error_deg_mean"), center_error_rel=mt.get("center_error_rel_mean"),
               registered_fraction=mt.get("registered_fraction"))
        done[label] = (out, m["wall_time_s"])
    return done


def _slab_rows(sw: _Sweep, m: dict, out: Path, family: str, setting: str, n_views: int, upstream_s: float,
               extra: dict, modes=None) -> None:
    met = read_json(out / "metrics.json")
    build_s = met["build"]["build_s"]
    for mode, mm in met["modes"].items():
        if modes is not None and mode not in modes:
            continue
        t = build_s + mm["render_s_per_view"] * n_views
        sw.add(stage="slab", family=family if modes is not None else mode, setting=f"{setting} {mode}", mode=mode,
               time_s=round(t, 3), end_to_end_s=round(t + upstream_s, 3), display_psnr=mm["display_psnr_mean"],
               display_ssim=mm["display_ssim_mean"], linear_psnr=mm["linear_psnr_mean"],
               **extra)


def _sweep_slab(sw: _Sweep, capture: Path, truth_dir: Path, capture_s: float, n_views: int, cfg: StudyConfig) -> None:
    from recon.slab import LayoutConfig

    from .slab import SlabStageConfig, run_slab

    for uv, st in cfg.slab_grid:
        out = sw.work / "slab" / f"uv{uv}_st{st}"
        sc = SlabStageConfig(layout=LayoutConfig(uv_res=uv, st_res=st))
        m = sw.point("slab", "direct", f"uv{uv} st{st}",
                     lambda: run_slab(capture, None, out, sc, reference_dir=truth_dir, quiet=True), uv_res=uv, st_res=st)
        if m is not None:
            _slab_rows(sw, m, out, "direct", f"direct uv{uv} st{st}", n_views, capture_s, {"uv_res": uv, "st_res": st})
            shutil.rmtree(out, ignore_errors=True)


def _sweep_rebin(sw: _Sweep, capture: Path, truth_dir: Path, capture_s: float, n_views: int, poses: dict,
                 cfg: StudyConfig) -> None:
    from recon.slab import LayoutConfig

    from .slab import SlabStageConfig, run_slab

    uv, st = cfg.rebin_grid
    for label, (pdir, pose_s) in poses.items():
        out = sw.work / "rebin" / label.replace(" ", "_")
        sc = SlabStageConfig(method="rebin", layout=LayoutConfig(uv_res=uv, st_res=st))
        m = sw.point("slab", f"rebin on {label}", f"rebin uv{uv} st{st} on {label}",
                     lambda: run_slab(capture, pdir, out, sc, reference_dir=truth_dir, quiet=True))
        if m is not None:
            _slab_rows(sw, m, out, f"rebin on {label}", f"rebin uv{uv} st{st} on {label}", n_views,
                       capture_s + pose_s, {"uv_res": uv, "st_res": st, "poses": label, "poses_s": pose_s},
                       modes=("depth",))
            shutil.rmtree(out, ignore_errors=True)


def _sweep_nerf(sw: _Sweep, capture: Path, truth_dir: Path, capture_s: float, views: list[str], truth,
                cfg: StudyConfig, seed: int) -> None:
    try:
        from .nerf import NerfStageConfig, run_nerf
    except ImportError:
        return
    for model, minutes in cfg.nerf:
        out = sw.work / "nerf" / f"{model}_{minutes:g}"
        m = sw.point("nerf", model, f"{model} {minutes:g} min",
                     lambda: run_nerf(capture, None, out, NerfStageConfig(model, minutes, seed=seed), truth_dir,
                                      quiet=True),
                     minutes=minutes)
        if m is None:
            continue
        t = m["wall_time_s"]
        sw.add(stage="nerf", family=model, setting=f"{model} {minutes:g} min", minutes=minutes, time_s=t,
               end_to_end_s=round(t + capture_s, 3), **_score(_read_views(out / "renders", views), truth))
        shutil.rmtree(out, ignore_errors=True)


# ------------------------------------------------------------------------------------- output


def _machine() -> dict:
    import os
    import platform

    return {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "load_average": list(os.getloadavg())}


COLUMNS = ["stage", "family", "setting", "status", "time_s", "end_to_end_s", "display_psnr", "display_ssim",
           "linear_psnr", "display_psnr_truth_est", "psnr_truth_est",
           "rotation_error_deg", "center_error_rel", "registered_fraction", "spp", "image_scale", "uv_res", "st_res",
           "mode", "poses", "minutes", "pareto", "reason"]


def _front_svg(rows: list[dict], title: str, ylabel: str, accuracy: str, cost: str, lower_is_better: bool,
               hlines) -> str:
    """One series per family, plus the Pareto front as a dashed black line."""
    families = sorted({r["family"] for r in rows})
    series = [Series(f, [r[cost] for r in rows if r["family"] == f], [r[accuracy] for r in rows if r["family"] == f],
                     [r["setting"] for r in rows if r["family"] == f], line=len(families) < 8) for f in families]
    front = sorted((r for r in rows if r.get("pareto")), key=lambda r: r[cost])
    if front:
        series.append(Series("Pareto front", [r[cost] for r in front], [r[accuracy] for r in front],
                             [r["setting"] for r in front], colour="#000000", line=True, dashed=True, annotate=True))
    return svg_plot(series, "wall time (s)" if cost == "time_s" else "end-to-end time (s)", ylabel, title, logx=True,
                    hlines=hlines)


def run_study(scene: str | Path, out: Path | None = None, profile: str = "quick", config: StudyConfig | None = None,
              seed: int = 0, root: Path = Path("artifacts"), quiet: bool = False, overwrite: bool = False,
              only: tuple[str, ...] | None = None) -> dict:
    """Sweep every stage's accuracy knob on ``scene`` (a built-in name or YAML path) with
    ``profile``'s settings (or ``config``); ``only`` restricts the sweeps to those stages
    (STUDY_STAGES); writes ``out`` (default ``root/<scene>/study``) atomically and returns the
    manifest. BadInput on an unknown profile or stage or a bad scene, or when ``out`` holds
    something else than a finished study (unless ``overwrite``)."""
    from rig.build import load_scene

    from .capture import run_capture
    from .reference import ReferenceConfig, run_reference

    if config is None:
        if profile not in PROFILES:
            raise BadInput(f"--profile must be one of {', '.join(PROFILES)}, got {profile!r}")
        config = PROFILES[profile]
    if only:
        bad = [s for s in only if s not in STUDY_STAGES]
        if bad:
            raise BadInput(f"--only must name stages among {', '.join(STUDY_STAGES)}, got {bad[0]!r}")
        config = replace(config, stages=tuple(dict.fromkeys(only)))
    from rig.spec import load_spec, resolve_scene_path

    spec, _ = load_spec(scene)  # SpecError (exit 2) on a bad scene, before anything is written
    out = Path(out) if out is not None else Path(root) / spec.name / "study"
    check_out(out, "study", overwrite)
    manifest = Manifest("study", params={"scene": str(scene), "profile": profile, "seed": seed, **asdict(config)})
    t_start = time.perf_counter()
    with atomic_stage(out, "study", overwrite) as tmp:
        work = tmp / ".work"
        scene_file = derived_scene(scene, work, config.size_scale, config.test_views)
        rig = load_scene(scene_file)
        art = work / "art" / rig.scene.name
        run = set(config.stages)
        n_points = (("reference" in run) * len(config.integrators) * len(config.spp)
                    + ("poses" in run) * len(config.poses) * (1 + ("slab" in run))
                    + ("slab" in run) * len(config.slab_grid) + ("nerf" in run) * len(config.nerf) + 2)
        with progress_bar(quiet) as bar:
            task = bar.add_task(f"study {rig.scene.name}", total=n_points, info=profile)
            sw = _Sweep(work, bar, task)
            cap = sw.point("capture", "capture", "capture", lambda: run_capture(rig, scene_file, art / "capture", seed,
                                                                                 quiet=True))
            if cap is None:
                raise BadInput(f"study: the capture of {scene} failed")
            capture_s = cap["wall_time_s"]
            truth_dir = art / "reference"
            tm = sw.point("reference", "truth", "study reference",
                          lambda: run_reference(rig, scene_file, truth_dir,
                                                ReferenceConfig(spp=config.truth_spp, seed=seed + _TRUTH_SEED_OFFSET),
                                                quiet=True))
            views = [c.name for c in rig.cameras.get("test", [])]
            truth = {v: (read_image(truth_dir / "linear" / f"{v}.exr"), read_image(truth_dir / "variance" / f"{v}.exr"))
                     for v in views}
            ceiling = float(np.mean([mse_to_psnr(display_noise_mse(r, var)) for r, var in truth.values()]))
            linear_ceiling = float(np.mean([mse_to_psnr(float(np.mean(var))) for _, var in truth.values()]))
            black = float(np.mean([_score({v: np.zeros_like(r)}, {v: (r, s)})["display_psnr"]
                                   for v, (r, s) in truth.items()]))
            if "reference" in run:
                _sweep_reference(sw, rig, scene_file, views, truth, config, seed)
            poses = _sweep_poses(sw, art / "capture", config) if "poses" in run else {}
            if "slab" in run:
                _sweep_slab(sw, art / "capture", truth_dir, capture_s, len(views), config)
                _sweep_rebin(sw, art / "capture", truth_dir, capture_s, len(views), poses, config)
            if "nerf" in run:
                _sweep_nerf(sw, art / "capture", truth_dir, capture_s, views, truth, config, seed)
        rows = [r for r in sw.rows]
        ok = [r for r in rows if r["status"] == "ok"]
        fronts = {}
        for stage in ("reference", "poses", "slab", "nerf"):
            sr = [r for r in ok if r["stage"] == stage]
            acc, low = ("rotation_error_deg", True) if stage == "poses" else ("display_psnr", False)
            for r, p in zip(sr, pareto_rows(sr, acc, low)):
                r["pareto"] = p
            fronts[stage] = [r["setting"] for r in sr if r["pareto"]]
        e2e = [dict(r, stage="end_to_end", family=r["stage"] if r["stage"] == "nerf" else r["family"].split(" on ")[0]
                    if r["family"].startswith("rebin") else "slab direct")
               for r in ok if r["stage"] in ("slab", "nerf") and r.get("end_to_end_s") is not None]
        for r, p in zip(e2e, pareto_rows(e2e, "display_psnr", False, "end_to_end_s")):
            r["pareto"] = p
        fronts["end_to_end"] = [r["setting"] for r in e2e if r["pareto"]]
        shutil.rmtree(work)
        hl = [(ceiling, "study reference noise ceiling"), (black, "empty (black) image")]
        plots = {"reference": ("path tracer: samples per pixel x integrator", "display PSNR (dB)", "display_psnr", False),
                 "poses": ("poses: method x image scale", "mean rotation error (deg)", "rotation_error_deg", True),
                 "slab": ("light slab: resolution x interpolation", "display PSNR (dB)", "display_psnr", False),
                 "nerf": ("NeRF: model x minutes (stage wall time)", "display PSNR at capture resolution (dB)",
                          "display_psnr", False)}
        for stage, (title, ylabel, acc, low) in plots.items():
            sr = [r for r in ok if r["stage"] == stage]
            if sr:
                svg = _front_svg(sr, f"study {title}", ylabel, acc, "time_s", low, [] if stage == "poses" else hl)
                write_svg(tmp / f"pareto_{stage}.svg", svg)
        if e2e:
            svg = _front_svg(e2e, "study end to end: capture + poses + model", "display PSNR (dB)", "display_psnr",
                             "end_to_end_s",
                             False, hl)
            write_svg(tmp / "pareto_end_to_end.svg", svg)
        all_rows = rows + e2e
        write_csv(tmp / "study.csv", all_rows, COLUMNS)
        write_csv(tmp / "pareto.csv", [r for r in all_rows if r.get("pareto")],
             ["stage", "setting", "time_s", "end_to_end_s", "display_psnr", "linear_psnr", "rotation_error_deg"])
        write_json(tmp / "study.json", {"profile": profile, "config": asdict(config), "scene": rig.scene.name,
                                        "views": views, "truth_spp": config.truth_spp,
                                        "truth_time_s": tm["wall_time_s"] if tm else None,
                                        "capture_s": capture_s, "display_psnr_noise_ceiling": ceiling,
                                        "psnr_noise_ceiling": linear_ceiling, "display_psnr_black": black,
                                        "rows": all_rows, "fronts": fronts, "machine": _machine(),
                                        "study_s": round(time.perf_counter() - t_start, 3)})
        manifest.add_input(resolve_scene_path(scene))
        manifest.metrics = {"points": len(rows), "failed": sum(r["status"] != "ok" for r in rows),
                            "display_psnr_noise_ceiling": ceiling, **{f"front.{k}": v for k, v in fronts.items()}}
        result = manifest.write(tmp)
    return result

