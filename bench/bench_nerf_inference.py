"""The fast NeRF's held-out render at the capture's resolution, profiled on a trained checkpoint:
occupancy fraction, density lookups and colour evaluations per ray, wall time split between the
compiled march (grid lookups, compositing) and the colour batch (appearance grids + MLP), the
whole 1280x960 view's wall time through ``render_view`` (chunks over both cores), and how far
the default colour threshold moves the image from colouring every sample above
``COLOUR_MIN_WEIGHT`` (display PSNR between the two renders). Run::

    .venv/bin/python -m bench.bench_nerf_inference artifacts/turntable/capture artifacts/turntable/nerf/fast/checkpoint.pt

Writes ``bench/results/bench_nerf_inference.json`` (machine, load average before and after: on
shared cores the absolute times are inflated; the split's ratios hold better).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from bench.common import write_result
from recon.nerf import march_kernels
from recon.nerf.data import camera_rays, load_data
from recon.nerf.models import COLOUR_INFERENCE_WEIGHT, COLOUR_MIN_WEIGHT, make_model
from recon.nerf.train import render_view
from render.metrics import psnr, to_display


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_nerf_inference", description=__doc__.splitlines()[0],
                                 allow_abbrev=False)
    ap.add_argument("capture_dir", nargs="?", default="artifacts/turntable/capture",
                    help="a capture folder (default: the default scene's, as `make demo` writes it)")
    ap.add_argument("checkpoint", nargs="?", default="artifacts/turntable/nerf/fast/checkpoint.pt",
                    help="a fast NeRF checkpoint (default: the demo's)")
    ap.add_argument("--rows-every", type=int, default=16, help="profile every N-th row of the first held-out view")
    a = ap.parse_args(argv)
    if not os.path.isfile(a.checkpoint):
        raise FileNotFoundError(f"checkpoint {a.checkpoint} not found: run `make demo` first or name one")
    torch.set_num_threads(2)
    data = load_data(a.capture_dir)
    state = torch.load(a.checkpoint, weights_only=False)
    model = make_model(state["model_name"], data.lo, data.hi, 0)
    model.load_state_dict(state["state"])
    model.eval()
    v = data.test[0]
    cam = v.full_camera
    h, w = cam.intrinsics.height, cam.intrinsics.width
    o, d = camera_rays(cam)
    rows = torch.arange(0, h, a.rows_every)
    idx = (rows[:, None] * w + torch.arange(w)[None, :]).reshape(-1)
    o, d = o[idx], d[idx]
    load0 = os.getloadavg()[0]
    model.render_inference(o[:512], d[:512])  # compile or load the kernel, build the dense grid
    spent = {"march": 0.0, "colour": 0.0}
    march, colour = march_kernels.march, model.colour

    def timed(name, fn):
        def run(*args, **kw):
            t = time.perf_counter()
            out = fn(*args, **kw)
            spent[name] += time.perf_counter() - t
            return out
        return run

    march_kernels.march, model.colour = timed("march", march), timed("colour", colour)
    torch.set_num_threads(1)  # as render_view runs each chunk
    t0 = time.perf_counter()
    fast = model.render_inference(o, d, threads=1)
    total = time.perf_counter() - t0
    stats = dict(model.last_march)
    march_kernels.march, model.colour = march, colour
    every = model.render_inference(o, d, threads=1, colour_weight=COLOUR_MIN_WEIGHT)
    torch.set_num_threads(2)
    n = int(idx.numel())
    t0 = time.perf_counter()
    render_view(model, cam)
    view_s = time.perf_counter() - t0
    row = {"step": state["step"], "grid_res": model.density_vm.res,
           "occupied_fraction": round(float(model.occupancy.float().mean()), 4),
           "rays_profiled": n, "density_lookups_per_ray": round(stats["density_lookups"] / n, 2),
           "colour_points_per_ray": round(stats["colour_points"] / n, 3),
           "colour_points_per_ray_every_sample": round(every.n_points / n, 3),
           "one_thread_us_per_ray": round(1e6 * total / n, 2),
           "march_us_per_ray": round(1e6 * spent["march"] / n, 2), "colour_us_per_ray": round(1e6 * spent["colour"] / n, 2),
           "other_us_per_ray": round(1e6 * (total - spent["march"] - spent["colour"]) / n, 2),
           "view_wall_s": round(view_s, 2), "view_size": [w, h],
           "colour_weight": COLOUR_INFERENCE_WEIGHT,
           "display_psnr_vs_every_sample": round(psnr(to_display(fast.rgb.numpy()), to_display(every.rgb.numpy())), 2),
           "load_avg_1min_start": load0, "load_avg_1min_end": os.getloadavg()[0]}
    print(row, flush=True)
    write_result("bench_nerf_inference", {"capture": str(a.capture_dir), "checkpoint": str(a.checkpoint), **row})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
