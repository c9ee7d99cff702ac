"""Slab benchmark: render frames/s at 256x256 on 2 cores (goal >= 30) and slab build time.

Set-up (not timed): the default turntable scene is captured at its own size into a temporary
folder. Timed:

* ``build_direct_s``: the stage's default slab set (8 ring slabs, uv_res 16, st_res 192) acquired
  directly with the rig's rasterizer (sheared cameras), assembled into memory-mapped arrays.
* ``build_rebin_s``: the same layout rebinned from the 48 captured train views and their depth.
* ``fps``: one 256x256 frame (a held-out pose, 40 degree field) rendered from the memory-mapped
  direct slabs, per interpolation mode, with 1 and 2 threads: median of REPEATS runs.
* baseline (same run): the general per-ray path ``render_rays(slabs, *camera.pixel_rays())``
  (float64 plane intersections per ray, one thread); ``speedup`` = baseline / ours.

Run: ``.venv/bin/python -m bench.bench_slab``; writes bench/results/slab.json.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from bench.common import median_time, write_result
from render.camera import Camera, Intrinsics
from render.camera_io import read_cameras_json
from render.slab import MODES, render_rays, render_view
from render.slab_io import load_slabs

SIZE = 256
REPEATS = 10


def main() -> None:
    from pipeline.stages.capture import run_capture
    from pipeline.stages.slab import SlabStageConfig, build_slabs
    from rig.build import load_scene
    from rig.spec import resolve_scene_path

    with tempfile.TemporaryDirectory(prefix="bench_slab_") as tmp:
        tmp = Path(tmp)
        run_capture(load_scene("turntable"), resolve_scene_path("turntable"), tmp / "capture", quiet=True)
        t0 = time.perf_counter()
        _, info = build_slabs(tmp / "capture", tmp / "direct", SlabStageConfig(method="direct"), quiet=True)
        build_direct = time.perf_counter() - t0
        t0 = time.perf_counter()
        _, rinfo = build_slabs(tmp / "capture", tmp / "rebin", SlabStageConfig(method="rebin"), quiet=True)
        build_rebin = time.perf_counter() - t0

        slabs = load_slabs(tmp / "direct")
        cams, splits = read_cameras_json(tmp / "capture" / "cameras.json")
        pose = [c for c, s in zip(cams, splits) if s == "test"][0].cam_to_world
        cam = Camera(Intrinsics.from_fov(SIZE, SIZE, 40.0), pose, "bench")
        fps = {}
        for mode in MODES:
            row = {}
            for threads in (1, 2):
                med, _ = median_time(lambda: render_view(slabs, cam, mode, threads=threads), REPEATS)
                row[f"threads_{threads}_ms"] = round(med * 1e3, 2)
                row[f"threads_{threads}_fps"] = round(1.0 / med, 1)
            o, d = cam.pixel_rays()
            base, _ = median_time(lambda: render_rays(slabs, o, d, mode), max(3, REPEATS // 3))
            row["baseline_per_ray_ms"] = round(base * 1e3, 2)
            row["speedup_2_threads"] = round(base / (row["threads_2_ms"] / 1e3), 2)
            fps[mode] = row
        write_result("slab", {
            "size": [SIZE, SIZE], "repeats": REPEATS, "goal_fps": 30,
            "slab_mb": round(info["bytes"] / 2**20, 1), "slab_radiance_mb": round(info["radiance_bytes"] / 2**20, 1),
            "slabs": len(slabs), "renders": info["renders"],
            "build_direct_s": round(build_direct, 2), "build_rebin_s": round(build_rebin, 2),
            "rebin_coverage": round(rinfo["coverage"], 4),
            "fps": fps,
        })


if __name__ == "__main__":
    main()
