"""The fast NeRF at the capture's resolution: training on the working scale's averages (160x120,
the former default) against training on rays through the capture's own pixels (``train_full_res``)
and the coarse-to-fine schedule (``pixel_schedule`` with ``app_res_final``), at equal step counts,
scored where the issue asks: display PSNR (8-bit sRGB) of the held-out views at the capture's
resolution and at 1/8 scale (the working scale, ground truth area-averaged in linear light), and
the held-out render's cost per capture pixel (``FastNeRF.render_inference``).

Capture-resolution PSNR is estimated on ``--pixels`` random pixels per held-out view (the mean of
squared errors over a uniform pixel sample is unbiased for the whole view's MSE; the same pixels for
every variant). Steps are fixed (``--steps``), so variants compare at equal work whatever the load;
the training CPU time and the load average are recorded beside them. Run::

    .venv/bin/python -m bench.bench_nerf_fullres artifacts/turntable/capture --steps 300

Writes ``bench/results/bench_nerf_fullres.json``.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from bench.common import write_result
from recon.nerf.data import load_data
from recon.nerf.train import TrainConfig, render_view, train
from render.metrics import psnr, to_display


def _full_res_psnr(model, data, pixels: int, seed: int) -> float:
    g = torch.Generator().manual_seed(seed)
    shown, ref = [], []
    for v in data.test:
        k = v.full_camera.intrinsics
        px = torch.randperm(k.width * k.height, generator=g)[:pixels]
        shown.append(render_view(model, v.full_camera, pixels=px)["rgb"])
        ref.append(v.full_rgb.reshape(-1, 3)[px.numpy()])
    return psnr(to_display(np.concatenate(shown)), to_display(np.concatenate(ref)))


def _working_psnr(model, data) -> float:
    return float(np.mean([psnr(to_display(render_view(model, v.camera)["rgb"]), to_display(v.rgb)) for v in data.test]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_nerf_fullres", description=__doc__.splitlines()[0],
                                 allow_abbrev=False)
    ap.add_argument("capture_dir", nargs="?", default="artifacts/turntable/capture",
                    help="a capture folder (default: the default scene's, as `make demo` writes it)")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--pixels", type=int, default=20000, help="random capture pixels per held-out view")
    ap.add_argument("--variants", default="working,pixels,c2f")
    a = ap.parse_args(argv)
    data = load_data(a.capture_dir, train_full=True)
    former = (("pixel_schedule", ()), ("app_res_final", 0), ("app_upsample_at", ()))
    variants = {"working": former + (("train_full_res", False),), "pixels": former + (("train_full_res", True),),
                # coarse-to-fine pixels with appearance planes grown past the density's (session 32's default)
                "c2f": (("pixel_schedule", ((0.4, 4), (0.6, 2), (0.8, 1))), ("app_res_final", 400),
                        ("app_upsample_at", (0.5,)))}
    rows = {}
    for name in a.variants.split(","):
        load0 = os.getloadavg()[0]
        cpu0 = time.process_time()
        res = train(data, TrainConfig(model="fast", minutes=1e4, max_steps=a.steps, eval_every_s=1e9, clock="cpu",
                                      overrides=variants[name]))
        train_cpu = time.process_time() - cpu0
        v = data.test[0]
        t0 = time.perf_counter()
        c0 = time.process_time()
        render_view(res.model, v.full_camera)
        render_wall, render_cpu = time.perf_counter() - t0, time.process_time() - c0
        n_full = v.full_camera.intrinsics.width * v.full_camera.intrinsics.height
        rows[name] = {"steps": res.steps, "train_cpu_s": round(train_cpu, 1),
                      "display_psnr_capture_res": round(_full_res_psnr(res.model, data, a.pixels, 7), 3),
                      "display_psnr_working_scale": round(_working_psnr(res.model, data), 3),
                      "render_view_wall_s": round(render_wall, 2), "render_view_cpu_s": round(render_cpu, 2),
                      "render_cpu_us_per_capture_pixel": round(1e6 * render_cpu / n_full, 2),
                      "occupied_fraction": round(float(res.model.occupancy.float().mean()), 4),
                      "load_avg_1min_start": load0, "load_avg_1min_end": os.getloadavg()[0]}
        print(name, rows[name], flush=True)
    write_result("bench_nerf_fullres", {"capture": str(a.capture_dir), "steps": a.steps, "pixels_per_view": a.pixels,
                                        "held_out_views": len(data.test), "variants": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
