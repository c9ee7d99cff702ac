"""NeRF throughput per model: training samples/s (field evaluations per second of a full training
step: render, loss, backward, Adam) and rendering rays/s (no grad), medians over repeats, with
ratios against the vanilla NeRF measured in the same run.

Rays come from cameras on a ring at the default scene's distance (1.1) looking at the box centre,
so every ray crosses the box. The fast model is measured twice: untrained with occupancy off
(worst case: every step inside the box is evaluated) and with an occupancy grid holding only a
0.16-wide cube (the box of the default scene), where empty-space skipping works as after
training. Run: ``.venv/bin/python -m bench.bench_nerf`` (about 2 minutes on an idle machine).
"""
from __future__ import annotations

import sys

import numpy as np
import torch

from bench.common import median_time, parse_flags, write_result
from recon.nerf.data import scene_box
from recon.nerf.models import make_model
from render.camera import Camera, Intrinsics
from render.poses import look_at


def _rays(n: int, seed: int = 0):
    k = Intrinsics.from_fov(160, 120, 40.0)
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(16):
        az, el = 2 * np.pi * i / 16, np.radians(25 + 25 * (i % 2))
        eye = 1.1 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]) + [0, 0, 0.05]
        cams.append(Camera(k, look_at(eye, np.array([0, 0, 0.05]), np.array([0.0, 0, 1])), f"v{i}"))
    o, d = zip(*(c.pixel_rays() for c in cams))
    o, d = np.concatenate(o), np.concatenate(d)
    idx = rng.choice(len(o), n, replace=False)
    lo, hi = scene_box(cams)
    return torch.from_numpy(o[idx].astype(np.float32)), torch.from_numpy(d[idx].astype(np.float32)), lo, hi


def _measure(model, o, d, n_train: int, n_render: int, repeats: int) -> dict:
    opt = torch.optim.Adam(model.param_groups(0.0))
    g = torch.Generator().manual_seed(0)
    target = torch.zeros(n_train, 3)
    points = []

    def step():
        out = model.render(o[:n_train], d[:n_train], training=True, generator=g)
        loss = ((out.rgb - target) ** 2).mean() + sum(((a - target) ** 2).mean() for a in out.aux)
        opt.zero_grad()
        loss.backward()
        opt.step()
        points.append(out.n_points)

    t_train, _ = median_time(step, repeats=repeats)

    def render():
        with torch.no_grad():
            model.render(o[:n_render], d[:n_render], training=False)

    t_render, _ = median_time(render, repeats=repeats)
    pts = float(np.median(points))
    return {"train_step_s": t_train, "train_rays": n_train, "train_points_per_step": pts,
            "train_samples_per_s": pts / t_train, "render_rays_per_s": n_render / t_render}


def main(argv: list[str] | None = None) -> None:
    parse_flags("bench_nerf", "NeRF ray marching and training throughput.", argv, {})
    torch.set_num_threads(2)
    o, d, lo, hi = _rays(8192)
    figures = {}
    figures["vanilla"] = _measure(make_model("vanilla", lo, hi), o, d, 256, 1024, 3)
    for name in ("vanilla_noview", "vanilla_nope"):
        figures[name] = _measure(make_model(name, lo, hi), o, d, 256, 1024, 3)
    fast = make_model("fast", lo, hi)
    figures["fast_no_occupancy"] = _measure(fast, o, d, 256, 1024, 3)
    fast = make_model("fast", lo, hi)
    g = fast.cfg.occ_res
    u = (torch.arange(g) + 0.5) / g * (fast.hi - fast.lo)[0] + fast.lo[0]
    inside = (u.abs() <= 0.09)
    zin = ((u - 0.05).abs() <= 0.09)
    fast.occupancy.copy_(inside[:, None, None] & inside[None, :, None] & zin[None, None, :])
    fast.occ_active.fill_(True)
    figures["fast_occupancy_box"] = _measure(fast, o, d, 4096, 8192, 5)
    base = figures["vanilla"]
    ratios = {k: {"train_samples_per_s": v["train_samples_per_s"] / base["train_samples_per_s"],
                  "render_rays_per_s": v["render_rays_per_s"] / base["render_rays_per_s"]}
              for k, v in figures.items() if k != "vanilla"}
    write_result("nerf", {"models": figures, "ratio_to_vanilla": ratios,
                          "notes": "medians; fast_occupancy_box: occupancy limited to a 0.18 m cube (as after training)"})


if __name__ == "__main__":
    main(sys.argv[1:])
