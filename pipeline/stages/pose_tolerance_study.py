"""``lumigraph study pose_tolerance --capture DIR``: what pose accuracy costs the models (issue 21, part 4).

The capture's train cameras are perturbed, one kind of error at a time, and a NeRF and a rebinned
light slab are built from the perturbed cameras and scored on the capture's held-out views (true
cameras, display PSNR of the 8-bit sRGB images, :mod:`render.metrics`):

* ``rotation_deg``: every train camera turned by exactly that angle about a uniformly random
  axis through its centre (a fixed seed; the angle is what the poses stage reports as
  ``rotation_error_deg_mean``, so the two read on one axis);
* ``focal_pct``: fx and fy of every train camera scaled by (1 + level / 100): a calibration error
  is shared by all views of one lens (the poses stage's ``focal_rel``, in percent);
* ``no_distortion``: the lens's Brown coefficients dropped (level 1: a camera model that ignores
  the lens; only when the capture has distortion);
* ``truth`` (level 0) and ``estimated`` (``--poses``: the poses stage's own cameras), the
  baselines the curves are read against.

Each point writes a poses-like folder (``points/<name>/cameras.json`` and a ``poses`` manifest
naming the capture's cameras.json, so the stages accept it as ``--poses``), trains the NeRF for
a fixed, small number of steps (the same for every point, so shared cores do not tilt the
comparison) and rebins the slab at a coarse st (``st_per_pixel``), then deletes the models and
keeps the figures::

    <out>/points.csv        kind, level, name, nerf_display_psnr, slab_display_psnr, nerf_steps, slab_build_s
    <out>/rotation.svg      display PSNR against rotation error (log x), the estimate's error marked
    <out>/focal.svg         display PSNR against focal error (log x), the estimate's error marked
    <out>/summary.json      title, claim, headline, figures, rows, the estimate's accuracy, settings
    <out>/manifest.json

Profiles (``--profile``): ``quick`` (the default: rotation 0.01 / 0.1 / 1 deg, focal 0.1 / 2 %,
NeRF 150 steps, st_per_pixel 0.25), ``full`` (5 rotations, 4 focal errors, 600 steps,
st_per_pixel 0.5); the environment variable ``LUMIGRAPH_POSE_STUDY_SIZE=tiny`` shrinks either
to the tests' size (one point per kind, a few NeRF steps on a small grid).
"""
from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from render.camera import Camera
from render.camera_io import write_cameras_json

from ..artifacts import BadInput, Manifest, atomic_stage, read_json, write_json
from ..io import write_csv
from ..plot import Series, svg_plot, write_svg
from .lecture import size_name

__all__ = ["ToleranceProfile", "PROFILES", "SIZE_ENV", "perturb_cameras", "random_rotations",
           "run_pose_tolerance", "default_out"]

SIZE_ENV = "LUMIGRAPH_POSE_STUDY_SIZE"
KINDS = ("truth", "estimated", "rotation_deg", "focal_pct", "no_distortion")


@dataclass(frozen=True)
class ToleranceProfile:
    """rotation_deg / focal_pct: the sweep's levels; nerf_steps: training steps of every point's
    NeRF (a step count, not a time budget: every point trains alike whatever the load on shared
    cores, as long as the cap allows them); nerf_minutes: the NeRF stage's wall budget, a cap that
    also sizes its held-out renders; nerf_downsample: its working scale (None: ~160 px wide);
    nerf_overrides: fields of the model's config replaced (the tests' toy grid); st_per_pixel,
    uv_res: the rebinned slab's sampling (coarse, so a point costs seconds)."""

    rotation_deg: tuple[float, ...]
    focal_pct: tuple[float, ...]
    nerf_steps: int
    st_per_pixel: float
    uv_res: int = 8
    nerf_minutes: float = 3.0
    nerf_downsample: int | None = None
    nerf_overrides: tuple = ()


PROFILES: dict[str, ToleranceProfile] = {
    "quick": ToleranceProfile((0.01, 0.1, 1.0), (0.1, 2.0), nerf_steps=150, st_per_pixel=0.25),
    "full": ToleranceProfile((0.01, 0.03, 0.1, 0.3, 1.0), (0.1, 0.3, 1.0, 2.0), nerf_steps=600, st_per_pixel=0.5,
                             nerf_minutes=10.0),
    "tiny": ToleranceProfile((1.0,), (2.0,), nerf_steps=3, st_per_pixel=0.5, uv_res=4, nerf_minutes=0.5, nerf_downsample=8,
                             nerf_overrides=(("res_init", 16), ("res_final", 24), ("occ_res", 16), ("steps_per_side", 48),
                                             ("n_comp_app", 8), ("points_per_batch", 4096), ("max_rays", 512))),
}


def default_out(capture_dir: Path) -> Path:
    """``<capture>/../study_pose_tolerance`` (beside the scene's other stages; the report reads it)."""
    return Path(capture_dir).parent / "study_pose_tolerance"


def random_rotations(n: int, angle_deg: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3, 3) float64 rotations by exactly ``angle_deg`` about uniformly random axes (Rodrigues)."""
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    a = math.radians(angle_deg)
    K = np.zeros((n, 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K -= K.transpose(0, 2, 1)
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def perturb_cameras(cameras: list[Camera], kind: str, level: float, seed: int) -> list[Camera]:
    """``cameras`` with one kind of error (module docstring): ``rotation_deg`` (each camera turned
    by ``level`` degrees about a random axis through its centre, camera frame), ``focal_pct``
    (fx, fy scaled by 1 + level / 100), ``no_distortion`` (dist zeroed), ``truth`` (unchanged)."""
    if kind == "truth":
        return list(cameras)
    if kind == "rotation_deg":
        rots = random_rotations(len(cameras), level, np.random.default_rng(seed))
        out = []
        for c, d in zip(cameras, rots):
            m = c.cam_to_world.copy()
            m[:3, :3] = m[:3, :3] @ d
            out.append(Camera(c.intrinsics, m, c.name))
        return out
    if kind == "focal_pct":
        s = 1.0 + level / 100.0
        return [Camera(replace(c.intrinsics, fx=c.intrinsics.fx * s, fy=c.intrinsics.fy * s), c.cam_to_world, c.name)
                for c in cameras]
    if kind == "no_distortion":
        return [Camera(replace(c.intrinsics, dist=(0.0,) * 5), c.cam_to_world, c.name) for c in cameras]
    raise ValueError(f"unknown perturbation {kind!r}; known: {', '.join(KINDS)}")


def _estimate_accuracy(poses_dir: Path | None) -> dict:
    """The poses stage's reached accuracy (rotation_error_deg_mean, focal_rel in %) or {}."""
    if poses_dir is None or not (Path(poses_dir) / "metrics.json").is_file():
        return {}
    m = read_json(Path(poses_dir) / "metrics.json")
    out = {"poses": str(poses_dir)}
    if isinstance(m.get("rotation_error_deg_mean"), (int, float)):
        out["rotation_deg"] = float(m["rotation_error_deg_mean"])
    if isinstance(m.get("focal_rel"), (int, float)):
        out["focal_pct"] = 100.0 * float(m["focal_rel"])
    return out


def _write_point(folder: Path, capture_dir: Path, cams: list[Camera], splits: list[str], what: str) -> None:
    """A poses-like folder the stages accept as ``--poses``: cameras.json + a poses manifest."""
    folder.mkdir(parents=True)
    write_cameras_json(folder / "cameras.json", cams, splits)
    m = Manifest("poses", params={"method": "pose_tolerance_study", "perturbation": what})
    m.add_input(capture_dir / "cameras.json")
    m.write(folder)


def _score_point(capture_dir: Path, point: Path, prof: ToleranceProfile, seed: int) -> dict:
    from .nerf import NerfStageConfig, run_nerf
    from .slab import SlabStageConfig, build_slabs, held_out_references, score_slab_views
    from .capture import read_cameras
    from recon.slab import LayoutConfig
    from render.lightfield import load_slabs

    nerf = run_nerf(capture_dir, point, point / "nerf",
                    NerfStageConfig(minutes=prof.nerf_minutes, seed=seed, max_steps=prof.nerf_steps, downsample=prof.nerf_downsample,
                                    overrides=dict(prof.nerf_overrides)), quiet=True)
    cfg = SlabStageConfig(method="rebin", compress=False,
                          layout=replace(LayoutConfig(), uv_res=prof.uv_res, st_per_pixel=prof.st_per_pixel))
    cams, splits = read_cameras(capture_dir / "cameras.json")
    test, refs, _, _ = held_out_references(capture_dir, cams, splits, None)
    _, info = build_slabs(capture_dir, point / "slabs", cfg, point, quiet=True)
    slabs = load_slabs(point / "slabs")
    metrics, _ = score_slab_views(slabs, test, refs, (cfg.mode,), info.get("background", (0.0, 0.0, 0.0)), ssim_modes=())
    del slabs
    row = {"nerf_display_psnr": round(nerf["metrics"]["display_psnr_mean"], 4),
           "slab_display_psnr": round(metrics[cfg.mode]["display_psnr_mean"], 4),
           "nerf_steps": nerf["metrics"]["steps"], "slab_build_s": round(info["build_s"], 2)}
    shutil.rmtree(point / "nerf")
    shutil.rmtree(point / "slabs")
    return row


def loss_headline(rows: list[dict], nerf_steps: int) -> list[dict]:
    """Each point's loss against the true cameras, NeRF and slab (dB, display PSNR). A NeRF that
    stopped before ``nerf_steps`` (the profile's minutes cap, hit on a busy machine) trained less
    than the others: its loss is None with the reason, not a figure read as the cameras' doing."""
    truth = next(r for r in rows if r["kind"] == "truth")
    headline = []
    for r in rows:
        if r["kind"] == "truth":
            continue
        for model in ("nerf", "slab"):
            entry = {"figure": f"{model} loss, {r['name']}", "unit": "dB",
                     "note": "display PSNR of true cameras minus this point's"}
            short = [x for x in (truth, r) if x["nerf_steps"] < nerf_steps]
            if model == "nerf" and short:
                entry["value"] = None
                entry["note"] = "not comparable: " + "; ".join(
                    f"{x['name']}'s NeRF stopped at {x['nerf_steps']} of {nerf_steps} steps (minutes cap)" for x in short)
            else:
                entry["value"] = round(truth[f"{model}_display_psnr"] - r[f"{model}_display_psnr"], 2)
            headline.append(entry)
    return headline


def _plot(rows: list[dict], kind: str, xlabel: str, marked: float | None, title: str) -> str:
    """Display PSNR against ``kind``'s level (log x), NeRF and slab; dashed: their truth figures."""
    pts = sorted((r for r in rows if r["kind"] == kind), key=lambda r: r["level"])
    base = {r["kind"]: r for r in rows}
    series, hlines = [], []
    for model, colour in (("nerf", "#1f77b4"), ("slab", "#2ca02c")):
        key = f"{model}_display_psnr"
        series.append(Series(model, [r["level"] for r in pts], [r[key] for r in pts], colour=colour, line=True))
        if "truth" in base:
            hlines.append((base["truth"][key], f"{model}, true cameras"))
        if "estimated" in base and marked is not None and marked > 0:
            series.append(Series(f"{model}, poses stage", [marked], [base["estimated"][key]], colour=colour,
                                 labels=[f"estimate {marked:.3g}"], annotate=True))
    return svg_plot(series, xlabel, "held-out display PSNR (dB)", title, logx=True, hlines=hlines)


def run_pose_tolerance(capture_dir: Path, out: Path, poses_dir: Path | None = None, profile: str = "quick",
                       seed: int = 0, quiet: bool = False, overwrite: bool = False) -> dict:
    """Run the study (module docstring) into ``out`` atomically; returns the manifest's content.
    BadInput (one line naming the file or option) for a missing capture, bad ``--poses`` or profile."""
    from .capture import check_capture_folder
    from .poses import check_poses

    capture_dir = Path(capture_dir)
    if profile not in ("quick", "full"):
        raise BadInput(f"--profile: {profile!r} is not one of quick, full")
    if not capture_dir.is_dir():
        raise BadInput(f"--capture {capture_dir}: no such folder")
    prof = PROFILES[size_name(profile, SIZE_ENV)]
    cams, splits = check_capture_folder(capture_dir, need=("linear", "depth"))
    if poses_dir is not None:
        est = {c.name: c for c in check_poses(poses_dir, capture_dir, cams, splits)}
    train_idx = [i for i, s in enumerate(splits) if s == "train"]
    points: list[tuple[str, float]] = [("truth", 0.0)]
    if poses_dir is not None:
        points.append(("estimated", 0.0))
    points += [("rotation_deg", x) for x in prof.rotation_deg] + [("focal_pct", x) for x in prof.focal_pct]
    if any(cams[i].intrinsics.has_distortion for i in train_idx):
        points.append(("no_distortion", 1.0))
    accuracy = _estimate_accuracy(poses_dir)
    manifest = Manifest("pose_tolerance_study", params={"profile": profile, "size": size_name(profile, SIZE_ENV),
                                                        "seed": seed, "settings": {**prof.__dict__}})
    manifest.add_input(capture_dir / "cameras.json")
    if poses_dir is not None:
        manifest.add_input(Path(poses_dir) / "cameras.json")
    rows = []
    t0 = time.perf_counter()
    with atomic_stage(Path(out), "pose_tolerance_study", overwrite) as tmp:
        for n, (kind, level) in enumerate(points):
            name = kind if kind in ("truth", "estimated", "no_distortion") else f"{kind}_{level:g}"
            if kind == "estimated":
                train = [est[cams[i].name] for i in train_idx if cams[i].name in est]
            else:
                train = perturb_cameras([cams[i] for i in train_idx], kind, level, seed + n)
            point = tmp / "points" / name
            _write_point(point, capture_dir, train, ["train"] * len(train), name)
            t_point = time.perf_counter()
            row = {"kind": kind, "level": level, "name": name, **_score_point(capture_dir, point, prof, seed)}
            rows.append(row)
            if not quiet:
                short = "" if row["nerf_steps"] >= prof.nerf_steps else f" of {prof.nerf_steps}: stopped short, not comparable"
                print(f"pose tolerance {name}: NeRF {row['nerf_display_psnr']:.2f} dB ({row['nerf_steps']} steps{short}), "
                      f"slab {row['slab_display_psnr']:.2f} dB ({time.perf_counter() - t_point:.0f} s)", flush=True)
        shutil.rmtree(tmp / "points")
        write_csv(tmp / "points.csv", rows, list(rows[0]))
        write_svg(tmp / "rotation.svg", _plot(rows, "rotation_deg", "rotation error of every train camera (deg)",
                                              accuracy.get("rotation_deg"), "display PSNR against rotation error"))
        write_svg(tmp / "focal.svg", _plot(rows, "focal_pct", "focal length error (%)",
                                           accuracy.get("focal_pct"), "display PSNR against focal error"))
        by_kind = {r["kind"]: r for r in rows}
        headline = loss_headline(rows, prof.nerf_steps)
        summary = {"title": "What pose accuracy costs",
                   "claim": "Display PSNR of a NeRF and a rebinned light slab trained on cameras with one kind of "
                            "error (rotation, focal length, ignored lens distortion), read against the accuracy "
                            "the poses stage reached.",
                   "headline": headline, "figures": ["rotation.svg", "focal.svg"], "rows": rows,
                   "estimate": accuracy, "settings": {**prof.__dict__, "slab_method": "rebin"}}
        write_json(tmp / "summary.json", summary)
        manifest.metrics = {"points": len(rows), "wall_time_s": round(time.perf_counter() - t0, 1),
                            "nerf_stopped_short": [r["name"] for r in rows if r["nerf_steps"] < prof.nerf_steps],
                            "truth": {k: by_kind["truth"][k] for k in ("nerf_display_psnr", "slab_display_psnr")}}
        return manifest.write(tmp)
