"""The fast NeRF's training step under OpenMP's wait policies, on 2 shared cores.

torch's intra-op threads are libgomp's; with its default policy a thread waiting at a barrier
spins, and on cores shared with other busy processes each parallel operation can wait for a
descheduled partner (recon/nerf/omp.py). This measures a training step (render, display loss,
backward, Adam) of the untrained fast model with the occupancy grid off (every sample inside the
box evaluated: the stage's first ``occ_start`` steps, ~300 samples a ray), in a fresh process per
variant (the policy is read when OpenMP loads), in interleaved rounds:

- ``default``: 2 torch threads, OMP_WAIT_POLICY unset (what the stage had);
- ``passive``: 2 torch threads, OMP_WAIT_POLICY=PASSIVE (what the NeRF stage sets now);
- ``one_thread``: 1 torch thread.

Per variant: median wall and CPU seconds per step (steps after the first two), the ratios of the
default's median wall per step to each variant's (same round), the load average at each round.
Run: ``.venv/bin/python -m bench.bench_nerf_threads [--rounds 3 --steps 12]``; writes
``bench/results/bench_nerf_threads.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

VARIANTS = {"default": (2, None), "passive": (2, "PASSIVE"), "one_thread": (1, None)}


def _child(threads: int, steps: int, rays: int) -> dict:
    import torch

    from bench.bench_nerf import _rays
    from recon.nerf.models import make_model
    from recon.nerf.train import srgb_encode

    torch.set_num_threads(threads)
    o, d, lo, hi = _rays(4096)
    model = make_model("fast", lo, hi, 0)
    model.train()
    target = torch.rand(o.shape[0], 3, generator=torch.Generator().manual_seed(1))
    opt = torch.optim.Adam(model.param_groups(0.0), betas=(0.9, 0.99))
    g = torch.Generator().manual_seed(0)
    walls, cpus, points = [], [], []
    for _ in range(steps):
        idx = torch.randint(o.shape[0], (rays,), generator=g)
        w0, c0 = time.perf_counter(), time.process_time()
        out = model.render(o[idx], d[idx], training=True, generator=g)
        loss = torch.mean((srgb_encode(out.rgb) - srgb_encode(target[idx])) ** 2)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        points.append(out.n_points)
    return {"wall_s": walls[2:], "cpu_s": cpus[2:], "points_per_step": statistics.median(points)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_nerf_threads", description=__doc__.splitlines()[0],
                                 allow_abbrev=False)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=12, help="steps per process (the first two not timed)")
    ap.add_argument("--rays", type=int, default=256, help="rays per step (FastConfig.min_rays: the first steps' batch)")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(_child(VARIANTS[a.child][0], a.steps, a.rays)))
        return 0
    if a.steps < 3:
        ap.error("--steps must be at least 3 (the first two are not timed)")
    from bench.common import write_result

    rounds = []
    for r in range(a.rounds):
        row = {"load_avg_1min": os.getloadavg()[0]}
        order = list(VARIANTS) if r % 2 == 0 else list(reversed(VARIANTS))
        for name in order:
            env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
            if VARIANTS[name][1]:
                env["OMP_WAIT_POLICY"] = VARIANTS[name][1]
            out = subprocess.run([sys.executable, "-m", "bench.bench_nerf_threads", "--child", name, "--steps",
                                  str(a.steps), "--rays", str(a.rays)], env=env, capture_output=True, text=True,
                                 check=True)
            got = json.loads(out.stdout.strip().splitlines()[-1])
            row[name] = {"wall_s_per_step": statistics.median(got["wall_s"]),
                         "cpu_s_per_step": statistics.median(got["cpu_s"]), "points_per_step": got["points_per_step"]}
        for name in VARIANTS:
            row[name]["default_wall_over_this"] = row["default"]["wall_s_per_step"] / row[name]["wall_s_per_step"]
        rounds.append(row)
        print(json.dumps(row), flush=True)
    summary = {name: {k: statistics.median(r[name][k] for r in rounds)
                      for k in ("wall_s_per_step", "cpu_s_per_step", "default_wall_over_this")} for name in VARIANTS}
    write_result("bench_nerf_threads", {"rounds": rounds, "median": summary, "steps": a.steps, "rays": a.rays,
                                        "load_avg_1min": [r["load_avg_1min"] for r in rounds]})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
