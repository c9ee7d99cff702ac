"""Slab benchmark: render frames/s at 256x256 on 2 cores (goal >= 30) and slab build time.

Set-up (not timed): the default turntable scene is captured at its own size into a temporary
folder. Timed:

* ``build_direct_s``: the stage's default slab set (8 ring slabs, uv_res 8, st_res 384) acquired
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
"""
from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

from bench.common import median_time, write_result
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


def main() -> None:
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


if __name__ == "__main__":
    main()
