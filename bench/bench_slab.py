"""Slab benchmark: render frames/s at 256x256 on 2 cores (goal >= 30) and slab build time.

Set-up (not timed): the default turntable scene is captured at its own size into a temporary
folder. Timed:

* ``build_direct_s``: the stage's default slab set (8 ring slabs, uv_res 8, st at the capture's pixel
  footprint, float16 samples: ~235M rays, 1.75 GiB on the default scene) acquired
  directly with the rig's rasterizer (sheared cameras), assembled into memory-mapped arrays.
* ``build_rebin_s``: the same layout rebinned from the 48 captured train views and their depth.
* ``compress_s``: vector quantization of the direct slab set (recon.slab.compress_slabs, defaults).
* ``fps``: one 256x256 frame (a held-out pose, 40 degree field) rendered from the memory-mapped
  direct slabs, per interpolation mode, with 1 and 2 threads: median wall time of REPEATS runs,
  and the minimum CPU time of one frame (process time, all threads) beside it: on a shared
  machine the wall figure depends on the load (``loadavg`` before and after is recorded), the
  CPU figure much less. ``fps_vq``: the same from the compressed slabs (through the codebook).
* baseline (same run): the general per-ray numpy path ``render_rays(slabs, *camera.pixel_rays())``
  (float64 plane intersections and gathers per ray, one thread); ``speedup`` = baseline / ours.

Run: ``.venv/bin/python -m bench.bench_slab``; writes bench/results/slab.json.

At the capture's resolution (issue 15): ``.venv/bin/python -m bench.bench_slab --capture-resolution
CAPTURE_DIR [--poses POSES_DIR]`` runs the slab stage as a process (``python -m pipeline slab``,
under ``/usr/bin/time`` for its wall time and peak resident memory) for each configuration of
:data:`CONFIGS` (``before``: st 384 float32, the former default; ``after``: st from the pixel
footprint, float16), direct and, given COLMAP's poses, rebinned (slab-colmap), and scores its
depth-corrected renders against the capture's own held-out views at the capture's size (display
PSNR / SSIM, LDR- and HDR-ꟻLIP, linear PSNR; whole image and the subject's mask), beside the
all-black image's scores, with the slab set's bytes, the VQ figures the stage wrote, and frames/s of
one held-out view at the capture's size from the memory-mapped set. Writes
bench/results/slab_capture_resolution.json (machine, load averages) and a side-by-side crop of the
board (reference | each configuration) as slab_capture_resolution_crop.png. ``--built LABEL=DIR``
scores stage folders already built instead; ``--merge`` keeps the rows already in the JSON.

Partial slabs (issue 15's ablations at a fraction of the cost): ``.venv/bin/python -m bench.bench_slab
--partial CAPTURE_DIR [--st-per-pixel 0.5,1.0] [--uv-res 8]`` builds, per held-out view, only the
uv cells that view's pixels read (every slab it looks through, restricted to a sub-quad of whole
uv cells: the same sample positions, so the same render as from the whole set), direct with the
rig's rasterizer (or, with ``--poses``, rebinned from the train views on those cameras, as
``lumigraph slab --method rebin``), float16 like the stage, and scores the depth-mode render against the capture's
view at the capture's size (display PSNR / SSIM, linear PSNR; whole image and subject; no ꟻLIP),
with the CPU time of one frame (1 thread). A view reads ~2 x 2 uv cells of one or two slabs: 8
renders instead of the whole set's 288. Writes bench/results/slab_partial.json.
"""
from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench.common import RESULTS_DIR, median_time, write_result
from render.camera import Camera, Intrinsics
from render.camera_io import read_cameras_json
from render.lightfield import MODES, load_slabs, render_pinhole, render_rays

SIZE = 256
REPEATS = 10


def _frame_times(fn, repeats: int) -> tuple[float, float]:
    """(median wall s, minimum CPU s) of ``fn()`` after one warm-up call."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), min(cpu)


def _fps_rows(slabs, cam, modes, baseline: bool) -> dict:
    rows = {}
    for mode in modes:
        row = {}
        for threads in (1, 2):
            wall, cpu = _frame_times(lambda: render_pinhole(slabs, cam, mode, threads=threads), REPEATS)
            row[f"threads_{threads}_ms"] = round(wall * 1e3, 2)
            row[f"threads_{threads}_fps"] = round(1.0 / wall, 1)
            row[f"threads_{threads}_cpu_ms"] = round(cpu * 1e3, 2)
        if baseline:
            o, d = cam.pixel_rays()
            base, _ = median_time(lambda: render_rays(slabs, o, d, mode), max(3, REPEATS // 3))
            row["baseline_per_ray_ms"] = round(base * 1e3, 2)
            row["speedup_2_threads"] = round(base / (row["threads_2_ms"] / 1e3), 2)
        rows[mode] = row
    return rows


def default_run() -> None:
    """The default study (no options): CONFIGS built and scored."""
    from pipeline.stages.capture import run_capture
    from pipeline.stages.slab import SlabStageConfig, build_slabs
    from recon.slab import compress_slabs
    from rig.build import load_scene
    from rig.spec import resolve_scene_path

    with tempfile.TemporaryDirectory(prefix="bench_slab_") as tmp:
        tmp = Path(tmp)
        run_capture(load_scene("turntable"), resolve_scene_path("turntable"), tmp / "capture", quiet=True)
        load0 = os.getloadavg()
        t0 = time.perf_counter()
        _, info = build_slabs(tmp / "capture", tmp / "direct", SlabStageConfig(method="direct"), quiet=True)
        build_direct = time.perf_counter() - t0
        t0 = time.perf_counter()
        _, rinfo = build_slabs(tmp / "capture", tmp / "rebin", SlabStageConfig(method="rebin"), quiet=True)
        build_rebin = time.perf_counter() - t0

        slabs = load_slabs(tmp / "direct")
        t0 = time.perf_counter()
        vq, vq_stats = compress_slabs(slabs)
        compress_s = time.perf_counter() - t0
        cams, splits = read_cameras_json(tmp / "capture" / "cameras.json")
        pose = [c for c, s in zip(cams, splits) if s == "test"][0].cam_to_world
        cam = Camera(Intrinsics.from_fov(SIZE, SIZE, 40.0), pose, "bench")
        load1 = os.getloadavg()
        fps = _fps_rows(slabs, cam, MODES, baseline=True)
        fps_vq = _fps_rows(vq, cam, ("quadrilinear", "depth"), baseline=False)
        load2 = os.getloadavg()
        write_result("slab", {
            "size": [SIZE, SIZE], "repeats": REPEATS, "goal_fps": 30,
            "loadavg_1_5_15": {"before_build": [round(x, 2) for x in load0], "before_fps": [round(x, 2) for x in load1],
                               "after_fps": [round(x, 2) for x in load2]},
            "slab_mb": round(info["bytes"] / 2**20, 1), "slab_radiance_mb": round(info["radiance_bytes"] / 2**20, 1),
            "slabs": len(slabs), "renders": info["renders"],
            "build_direct_s": round(build_direct, 2), "build_rebin_s": round(build_rebin, 2),
            "rebin_coverage": round(rinfo["coverage"], 4), "compress_s": round(compress_s, 2),
            "vq": vq_stats.to_dict(),
            "fps": fps, "fps_vq": fps_vq,
        })


#: configurations of the capture-resolution row: label -> extra ``lumigraph slab`` options
CONFIGS = {"before_st384_float32": ["--st-res", "384", "--precision", "single"],
           "after_footprint_float16": []}
#: the board crop of the side-by-side (rows, cols of a 1280x960 held-out view; scaled to others)
CROP = (slice(560, 800), slice(300, 620))


def _time_log(path: Path) -> dict:
    """Wall time and peak RSS from GNU time's log: ``-f "%e %M"`` or ``-v``."""
    text = path.read_text()
    if "Maximum resident set size" not in text:
        wall, rss_kb = text.split()[-2:]
        return {"stage_wall_s": float(wall), "peak_rss_mb": round(int(rss_kb) / 1024, 1)}
    out = {}
    for line in text.splitlines():
        key, _, value = line.strip().rpartition(": ")
        if key.startswith("Elapsed (wall clock)"):
            parts = [float(x) for x in value.split(":")]
            out["stage_wall_s"] = round(sum(x * 60 ** i for i, x in enumerate(reversed(parts))), 2)
        elif key.startswith("Maximum resident set size"):
            out["peak_rss_mb"] = round(int(value) / 1024, 1)
    return out


def _stage(capture: Path, out: Path, args: list[str], poses: Path | None) -> dict:
    """Run the slab stage as a process; its wall time and peak RSS (GNU time's %e, %M)."""
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "pipeline", "slab", str(capture), "--out", str(out), "--reference", str(capture),
           "--quiet", "--overwrite", *args, *(["--method", "rebin", "--poses", str(poses)] if poses else [])]
    timing = out.parent / f"{out.name}.time"
    run = subprocess.run(["/usr/bin/time", "-f", "%e %M", "-o", str(timing), *cmd], capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {run.stderr.strip().splitlines()[-1:]}")
    return _time_log(timing)


def _scores(capture: Path, folder: Path, views: list[str]) -> tuple[dict, dict]:
    """(mean scores of ``folder``'s renders, of the all-black image) against the capture's views."""
    import numpy as np

    from pipeline.stages.validate import subject_mask
    from render.image_io import read_exr
    from render.metrics import black_image_scores, score_images

    rows, black = [], []
    for v in views:
        ref = read_exr(capture / "linear" / f"{v}.exr")
        mask = subject_mask(capture, v, ref.shape)
        rows.append(score_images(read_exr(folder / "renders" / f"{v}.exr"), ref, mask))
        black.append(black_image_scores(ref, mask))
    mean = lambda rs: {k: round(float(np.mean([r[k] for r in rs])), 4) for k in rs[0]}  # noqa: E731
    return mean(rows), mean(black)


def capture_resolution(capture: Path, poses: Path | None, work: Path, built: dict[str, Path] | None = None,
                       merge: bool = False) -> None:
    """The capture-resolution rows (module docstring). ``built``: row label -> a slab stage folder
    already built by the same command (its GNU time log, ``-v`` or ``-f "%e %M"``, at
    ``<folder>.time`` when there is one; else the manifest's wall time and no peak memory), scored
    instead of running :data:`CONFIGS` (rows cost tens of minutes each on a loaded machine)."""
    import json

    import numpy as np

    from render.image_io import read_exr, write_preview

    cams, splits = read_cameras_json(capture / "cameras.json")
    test = [c for c, s in zip(cams, splits) if s == "test"]
    views = [c.name for c in test]
    rows, crops, black = {}, [], None
    first = read_exr(capture / "linear" / f"{views[0]}.exr")
    h, w = first.shape[:2]
    crop = (slice(CROP[0].start * h // 960, CROP[0].stop * h // 960),
            slice(CROP[1].start * w // 1280, CROP[1].stop * w // 1280))
    crops.append(first[crop])
    loads = {"start": [round(x, 2) for x in os.getloadavg()]}
    if built is None:
        plan = [(f"{label}_{method}", work / f"{label}_{method}", args, pose_dir) for label, args in CONFIGS.items()
                for method, pose_dir in (("direct", None), ("rebin_colmap", poses))
                if method == "direct" or pose_dir is not None]
    else:
        plan = [(label, Path(folder), None, None) for label, folder in built.items()]
    for name, out, args, pose_dir in plan:
        if args is not None:
            row = _stage(capture, out, args, pose_dir)
        elif out.with_name(out.name + ".time").is_file():
            row = _time_log(out.with_name(out.name + ".time"))
        else:
            row = {"stage_wall_s": json.loads((out / "manifest.json").read_text())["wall_time_s"],
                   "peak_rss_mb": None}
        metrics = json.loads((out / "metrics.json").read_text())
        row["scores"], black = _scores(capture, out, views)
        build = metrics["build"]
        row.update(rays=build.get("rays"), slab_bytes=build["bytes"], precision=build.get("precision", "single"),
                   shapes={k: v["shape"] for k, v in build["slabs"].items()}, build_s=build["build_s"],
                   stage_display_psnr=metrics.get("display_psnr_mean"))
        if "compression" in metrics:
            c = metrics["compression"]
            row["vq"] = {"ratio_vs_float32": round(c["ratio_vs_float32"], 1), "display_psnr": c.get("display_psnr"),
                         "compress_s": c["compress_s"]}
        slabs = load_slabs(out / "slabs")
        wall, cpu = _frame_times(lambda: render_pinhole(slabs, test[0], "depth", threads=2), 3)
        row["fps_capture_size_2_threads"] = round(1.0 / wall, 2)
        row["frame_cpu_ms"] = round(cpu * 1e3, 1)
        rows[name] = row
        loads[f"after_{name}"] = [round(x, 2) for x in os.getloadavg()]
        crops.append(read_exr(out / "renders" / f"{views[0]}.exr")[crop])
    previous = RESULTS_DIR / "slab_capture_resolution.json"
    if merge and previous.is_file():  # earlier rows kept (their own load averages beside them)
        before = json.loads(previous.read_text())
        rows = {**{k: v for k, v in before.get("rows", {}).items() if k not in rows}, **rows}
        loads = {**{k: v for k, v in before.get("loadavg_1_5_15", {}).items() if k not in loads}, **loads}
    write_preview(RESULTS_DIR / "slab_capture_resolution_crop.png", np.concatenate(crops, axis=1))
    write_result("slab_capture_resolution", {
        "capture": str(capture), "size": [w, h], "views": views, "reference": "the capture's held-out views",
        "mode": "depth", "loadavg_1_5_15": loads, "black_image": black, "rows": rows,
        "crop": {"view": views[0], "rows": [crop[0].start, crop[0].stop], "cols": [crop[1].start, crop[1].stop],
                 "panels": ["reference", *rows]}})



def _sub_slab_geometry(g, iu0: int, iu1: int, iv0: int, iv1: int):
    """Slab ``g`` restricted to uv cells [iu0, iu1] x [iv0, iv1] (whole cells: the samples sit
    where they sit in ``g``)."""
    from render.lightfield import SlabGeometry

    nu, nv, ns, nt = g.shape
    c = g.uv_corners
    eu, ev = c[1] - c[0], c[3] - c[0]
    a0, a1, b0, b1 = iu0 / nu, (iu1 + 1) / nu, iv0 / nv, (iv1 + 1) / nv
    uv = [c[0] + a0 * eu + b0 * ev, c[0] + a1 * eu + b0 * ev, c[0] + a1 * eu + b1 * ev, c[0] + a0 * eu + b1 * ev]
    return SlabGeometry(uv, g.st_corners, (iu1 - iu0 + 1, iv1 - iv0 + 1, ns, nt), g.name)


def partial_geometries(geoms, cam) -> list:
    """The slabs ``cam``'s pixels read, each restricted to the sub-quad of the uv cells its pixels'
    bilinear uv taps touch (:func:`_sub_slab_geometry`)."""
    import numpy as np

    from render.lightfield import slab_coordinates

    o, d = cam.pixel_rays()
    hits = [slab_coordinates(g, o, d) for g in geoms]
    best = np.full(len(o), -1)
    score = np.zeros(len(o))
    for k, h in enumerate(hits):
        better = h.valid & (h.cos > score)
        best[better], score[better] = k, h.cos[better]
    subs = []
    for k, g in enumerate(geoms):
        sel = best == k
        if not sel.any():
            continue
        nu, nv = g.shape[:2]
        cu = np.clip(hits[k].coords[sel, 0] * nu - 0.5, 0, nu - 1)
        cv = np.clip(hits[k].coords[sel, 1] * nv - 0.5, 0, nv - 1)
        subs.append(_sub_slab_geometry(g, int(cu.min()), min(nu - 1, int(cu.max()) + 1),
                                       int(cv.min()), min(nv - 1, int(cv.max()) + 1)))
    return subs


def _direct_partial(subs, render) -> list:
    """float16 slabs of geometries ``subs`` acquired with ``render(camera) -> frame`` (the rig's rasterizer)."""
    import numpy as np

    from render.lightfield import LightSlab, sheared_camera

    slabs = []
    for sub in subs:
        rad = np.zeros(sub.array_shape, np.float16)
        depth = np.zeros(sub.array_shape[:4], np.float16)
        for j in range(sub.shape[1]):
            for i in range(sub.shape[0]):
                frame = render(sheared_camera(sub, (i + 0.5) / sub.shape[0], (j + 0.5) / sub.shape[1]))
                rad[j, i], depth[j, i] = frame.rgb, frame.depth
        slabs.append(LightSlab(sub, rad, depth))
    return slabs


def partial(capture: Path, st_per_pixel: list[float], uv_res: int, poses: Path | None = None) -> None:
    """The ``--partial`` rows (module docstring); rebinned from the train views on ``poses``'
    cameras (as ``lumigraph slab --method rebin --poses``) when given, else direct."""
    import numpy as np

    from pipeline.renderers import RasterPool
    from pipeline.stages.slab import (SlabStageConfig, _background, _cameras, _content_points, _layout, _scene_file,
                                      load_views)
    from pipeline.stages.validate import subject_mask
    from recon.slab import LayoutConfig, RebinConfig, content_bounds, rebin_slabs
    from render.image_io import read_exr
    from render.metrics import score_images
    from rig.build import load_scene
    from rig.capture import plan_capture

    cams, splits = _cameras(poses or capture)
    train = [c for c, s in zip(cams, splits) if s == "train"]
    test = [c for c, s in zip(cams, splits) if s == "test"]
    config = SlabStageConfig()
    views = load_views(capture, train)
    bounds = content_bounds(_content_points(views, config.min_radiance))
    rig = load_scene(_scene_file(capture) or json.loads((capture / "manifest.json").read_text())["params"]["scene"])
    if poses is None and plan_capture(rig).renderer != "raster":
        raise SystemExit("--partial acquires with the rasterizer: this capture's scene needs the path tracer")
    pool = RasterPool(rig.scene)
    background = _background(views)
    method = "rebin" if poses else "direct"
    loads = {"start": [round(x, 2) for x in os.getloadavg()]}
    rows = {}
    for spp in st_per_pixel:
        layout = LayoutConfig(uv_res=uv_res, st_per_pixel=spp)
        geoms = _layout(SlabStageConfig(layout=layout), bounds, train, np.asarray(rig.scene.up, np.float64))
        per_view = {}
        for cam in test:
            ref = read_exr(capture / "linear" / f"{cam.name}.exr")
            subs = partial_geometries(geoms, cam)
            t0 = time.perf_counter()
            if poses is None:
                slabs = _direct_partial(subs, pool.render)
            else:
                with tempfile.TemporaryDirectory(prefix="bench_slab_rebin_") as tmp:
                    built, _ = rebin_slabs(subs, views, tmp, RebinConfig(), background, dtype=np.float16)
                    slabs = [type(s)(s.geometry, np.array(s.radiance), np.array(s.depth)) for s in built]
            build_s = time.perf_counter() - t0
            render_pinhole(slabs, cam, "depth", threads=1)  # compiled on first use
            c0 = time.process_time()
            img = render_pinhole(slabs, cam, "depth", background=background, threads=1)
            cpu = time.process_time() - c0
            per_view[cam.name] = {**score_images(img, ref, subject_mask(capture, cam.name, ref.shape), with_flip=False),
                                  "uv_cells": int(sum(g.shape[0] * g.shape[1] for g in subs)),
                                  "build_s": round(build_s, 2), "frame_cpu_ms_1_thread": round(cpu * 1e3, 1)}
        keys = next(iter(per_view.values())).keys()
        rows[f"{method}_st_per_pixel_{spp:g}_uv_{uv_res}"] = {
            "mean": {k: round(float(np.mean([v[k] for v in per_view.values()])), 4) for k in keys},
            "st_counts": {g.name: list(g.shape[2:]) for g in geoms}, "per_view": per_view}
        loads[f"after_{method}_st_per_pixel_{spp:g}"] = [round(x, 2) for x in os.getloadavg()]
    out = RESULTS_DIR / "slab_partial.json"
    if out.is_file():  # rows of other settings kept
        before = json.loads(out.read_text())
        rows = {**{k: v for k, v in before.get("rows", {}).items() if k not in rows}, **rows}
        loads = {**{k: v for k, v in before.get("loadavg_1_5_15", {}).items() if k not in loads}, **loads}
    write_result("slab_partial", {"capture": str(capture), "mode": "depth", "precision": "half",
                                  "reference": "the capture's held-out views", "loadavg_1_5_15": loads, "rows": rows})


def main(argv: list[str] | None = None) -> None:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m bench.bench_slab", description=__doc__.splitlines()[0],
                                     allow_abbrev=False)
    parser.add_argument("--capture-resolution", type=Path, default=None, metavar="CAPTURE_DIR")
    parser.add_argument("--poses", type=Path, default=None, help="COLMAP's poses folder (adds slab-colmap rows)")
    parser.add_argument("--built", nargs="*", default=None, metavar="LABEL=DIR",
                        help="score slab stage folders already built instead of building CONFIGS")
    parser.add_argument("--merge", action="store_true", help="keep the rows already in slab_capture_resolution.json")
    parser.add_argument("--partial", type=Path, default=None, metavar="CAPTURE_DIR",
                        help="per-view partial slabs (module docstring): ablations at a fraction of the cost")
    parser.add_argument("--st-per-pixel", default="0.5,1.0", help="--partial: comma-separated st_per_pixel values")
    parser.add_argument("--uv-res", type=int, default=8, help="--partial: uv samples along a uv quad's longer side")
    ns = parser.parse_args(list(argv or []))  # bench.run_all calls main() with no arguments
    if ns.partial is not None:
        partial(ns.partial.resolve(), [float(x) for x in ns.st_per_pixel.split(",")], ns.uv_res,
                ns.poses.resolve() if ns.poses else None)
    elif ns.capture_resolution is None:
        default_run()
    else:
        built = None if ns.built is None else {k: Path(v) for k, v in (b.split("=", 1) for b in ns.built)}
        with tempfile.TemporaryDirectory(prefix="bench_slab_cr_") as tmp:
            capture_resolution(ns.capture_resolution.resolve(), ns.poses.resolve() if ns.poses else None, Path(tmp), built,
                               ns.merge)


if __name__ == "__main__":
    main(sys.argv[1:])
