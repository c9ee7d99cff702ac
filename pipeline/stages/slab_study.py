"""What accuracy costs: slab resolution x interpolation mode -> display PSNR, SSIM, memory, render time.

One command builds the slab set of a capture at every (uv_res, st_res) of a grid (direct
acquisition by default, or rebinning), renders the held-out views in every interpolation mode,
and writes::

    <out>/study.csv      one row per (uv_res, st_res, mode): display_psnr (8-bit sRGB), display_ssim
                         (the stage's primary mode only: SSIM costs ~10x a render at 1280x960),
                         linear_psnr, slab MB, render ms at the
                         capture size and at 256x256 (wall, and CPU over both threads), build s
    <out>/study.svg      display PSNR against slab memory, one line per interpolation mode
    <out>/study.json     the same rows plus the machine and the grid
    <out>/manifest.json

Slabs are built in a scratch folder inside the stage folder and deleted after each grid point
(the study keeps only the figures). Run it as
``.venv/bin/python -m pipeline.stages.slab_study artifacts/turntable/capture --out artifacts/turntable/slab_study``.
"""
from __future__ import annotations

import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from render.camera import Camera, Intrinsics
from render.lightfield import MODES, load_slabs, render_pinhole

from ..artifacts import Manifest, atomic_stage, write_json
from ..io import write_csv
from ..plot import Series, svg_plot, write_svg
from .capture import read_cameras
from .slab import SlabStageConfig, build_slabs, held_out_references, score_slab_views

__all__ = ["run_slab_study", "memory_plot", "DEFAULT_UV", "DEFAULT_ST"]

DEFAULT_UV = (4, 8, 16)
DEFAULT_ST = (96, 192, 384)
MODE_COLOURS = {"nearest": "#d62728", "uv": "#ff7f0e", "st": "#9467bd", "quadrilinear": "#1f77b4", "depth": "#2ca02c"}


def _ms_256(slabs, cam: Camera, mode: str, repeats: int = 3) -> tuple[float, float]:
    """(median wall ms, minimum CPU ms over both threads) of one 256x256 frame of ``cam``'s pose
    (40 degree vertical field), two threads."""
    c = Camera(Intrinsics.from_fov(256, 256, 40.0), cam.cam_to_world, cam.name)
    render_pinhole(slabs, c, mode)
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        render_pinhole(slabs, c, mode)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall) * 1e3), float(np.min(cpu) * 1e3)


def memory_plot(rows: list[dict]) -> str:
    """SVG (:func:`pipeline.plot.svg_plot`): mean held-out display PSNR (dB) against slab memory (MB, log
    scale), one line per (interpolation mode, uv resolution) along which st grows; one colour per mode."""
    series = []
    for mode in MODES:
        for uv in sorted({r["uv_res"] for r in rows if r["mode"] == mode}):
            pts = sorted((r["slab_mb"], r["display_psnr"], r["st_res"]) for r in rows if r["mode"] == mode and r["uv_res"] == uv)
            series.append(Series(f"{mode} uv{uv}", [p[0] for p in pts], [p[1] for p in pts], [f"st{p[2]}" for p in pts],
                                 colour=MODE_COLOURS.get(mode, "#000000"), line=True))
    return svg_plot(series, "slab memory (MB)", "mean display PSNR of held-out views (dB)",
                    "light slab: display PSNR against memory per interpolation mode", logx=True)


def run_slab_study(capture_dir: Path, out: Path, uv_res=DEFAULT_UV, st_res=DEFAULT_ST,
                   config: SlabStageConfig = SlabStageConfig(), reference_dir: Path | None = None,
                   quiet: bool = False) -> dict:
    """Build and score every grid point; returns the manifest (see the module docstring)."""
    capture_dir = Path(capture_dir)
    cams, splits = read_cameras(capture_dir / "cameras.json")
    test, refs, _, ref_kind = held_out_references(capture_dir, cams, splits, reference_dir)
    manifest = Manifest("slab_study", params={"uv_res": list(uv_res), "st_res": list(st_res), "method": config.method,
                                              "reference": ref_kind})
    manifest.add_input(capture_dir / "cameras.json")
    rows = []
    with atomic_stage(out) as tmp:
        for uv in uv_res:
            for st in st_res:
                cfg = replace(config, layout=replace(config.layout, uv_res=int(uv), st_res=int(st)))
                scratch = tmp / "scratch"
                _, info = build_slabs(capture_dir, scratch, cfg, None, quiet)
                slabs = load_slabs(scratch)
                metrics, _ = score_slab_views(slabs, test, refs, MODES, info.get("background", (0.0, 0.0, 0.0)),
                                            ssim_modes=(config.mode,))
                for mode in MODES:
                    wall_ms, cpu_ms = _ms_256(slabs, test[0], mode)
                    rows.append({"uv_res": int(uv), "st_res": int(st), "mode": mode,
                                 "display_psnr": round(metrics[mode]["display_psnr_mean"], 4),
                                 "display_ssim": "" if metrics[mode]["display_ssim_mean"] is None
                                 else round(metrics[mode]["display_ssim_mean"], 5),
                                 "linear_psnr": round(metrics[mode]["linear_psnr_mean"], 4),
                                 "slab_mb": round(info["bytes"] / 2**20, 2),
                                 "radiance_mb": round(info["radiance_bytes"] / 2**20, 2),
                                 "render_ms_view": round(metrics[mode]["render_s_per_view"] * 1e3, 1),
                                 "render_ms_256": round(wall_ms, 1), "render_cpu_ms_256": round(cpu_ms, 1),
                                 "build_s": info["build_s"]})
                del slabs
                shutil.rmtree(scratch)
                if not quiet:
                    best = max((r for r in rows if r["uv_res"] == uv and r["st_res"] == st), key=lambda r: r["display_psnr"])
                    print(f"slab study uv{uv} st{st}: {rows[-1]['slab_mb']:.0f} MB, best {best['mode']} "
                          f"display PSNR {best['display_psnr']:.2f} dB, build {info['build_s']:.1f} s", flush=True)
        write_csv(tmp / "study.csv", rows, list(rows[0]))
        write_svg(tmp / "study.svg", memory_plot(rows))
        write_json(tmp / "study.json", {"rows": rows, "uv_res": list(uv_res), "st_res": list(st_res),
                                        "reference": ref_kind, "views": [c.name for c in test]})
        manifest.metrics = {"grid_points": len(uv_res) * len(st_res),
                            "best": max(rows, key=lambda r: r["display_psnr"])}
        result = manifest.write(tmp)
    return result


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="slab resolution x interpolation mode study")
    ap.add_argument("capture_dir", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--uv", type=int, nargs="+", default=list(DEFAULT_UV))
    ap.add_argument("--st", type=int, nargs="+", default=list(DEFAULT_ST))
    ap.add_argument("--method", default="direct", choices=["direct", "rebin"])
    ap.add_argument("--reference", type=Path)
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args()
    m = run_slab_study(a.capture_dir, a.out, a.uv, a.st, SlabStageConfig(method=a.method), a.reference, a.quiet)
    print(m["metrics"])
