"""Scale-out benchmark: the reference stage in process and on 1 and 2 local Dask workers.

Workload: the default scene (turntable), its 8 held-out views at 320x240, 32 spp = 4 batches
of 8 samples per view: 32 batch tasks of 614,400 camera paths each (plus 32 folds and 8
finishes). Timed, each ``REPEATS`` times (median), the whole ``run_reference`` call:

* ``in_process``: no Dask (the library default), the renderer's 2 threads: the baseline.
* ``dask_1`` / ``dask_2``: a local cluster of 1 or 2 single-threaded worker processes, started
  once beforehand (its start-up is timed separately as ``cluster_start_s``), reached through
  its address like any existing cluster; render threads per task = cores // Dask threads.

The ratio the issue asks for is ``speedup_1_to_2 = dask_1 / dask_2``. Also measured, to back
the projection in docs/scaling.md: bytes per task (arguments, batch result, finished view,
the shared scene), and the scheduler's per-task overhead from a flood of no-op tasks on the
2-worker cluster (how many tasks per second the scheduler sustains here).

The machine is shared: the load average before and after is recorded, and the figures are
ratios measured in the same run. Run: ``.venv/bin/python -m bench.bench_distributed``; writes
bench/results/distributed.json.
"""
from __future__ import annotations

import os
import pickle
import statistics
import tempfile
import time
from pathlib import Path

from bench.common import write_result

SIZE = (320, 240)
SPP = 32
VIEWS = "test"
REPEATS = 3
FLOOD = 2000


def _load():
    return os.getloadavg() if hasattr(os, "getloadavg") else None


def _time_runs(rig, scene_file, root: Path, cluster, label: str, repeats: int = REPEATS) -> list[float]:
    from pipeline.stages.reference import run_reference

    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        run_reference(rig, scene_file, root / f"{label}-{i}", spp=SPP, size=SIZE, views=VIEWS, quiet=True,
                      cluster=cluster)
        times.append(time.perf_counter() - t0)
    return times


def _noop(i):
    return i


def _scheduler_overhead(client) -> dict:
    """Wall time per no-op task over FLOOD tasks (submitted at once, gathered): the scheduler's
    and the comms' cost per task, the floor under any unit of work."""
    client.gather(client.map(_noop, range(50), pure=False))  # warm up
    t0 = time.perf_counter()
    client.gather(client.map(_noop, range(FLOOD), pure=False))
    dt = time.perf_counter() - t0
    return {"tasks": FLOOD, "seconds": round(dt, 3), "ms_per_task": round(1e3 * dt / FLOOD, 3),
            "tasks_per_s": round(FLOOD / dt, 1)}


def _task_bytes(rig) -> dict:
    """Pickled sizes of what moves per unit of work (protocol 5, as Dask sends it)."""
    from render import pathtracer
    from render.effects import scene_effects
    from pipeline.stages.reference import SAMPLE_BATCH, finish_view, render_batch, resize_camera, select_views

    cam = resize_camera(select_views(rig, VIEWS)[0][1], *SIZE)
    eff = frozenset(scene_effects(rig.scene))
    st = pathtracer.RenderSettings(integrator="auto", spp=SPP)
    args = ("shared-0123456789abcdef0123456789abcdef", cam, st, (0, SAMPLE_BATCH), eff)
    part = render_batch(rig.scene, *args)
    nbytes = lambda x: len(pickle.dumps(x, protocol=5))  # noqa: E731
    return {"size": list(SIZE), "task_args": nbytes(args), "batch_result": nbytes(part),
            "finished_view": nbytes(finish_view(part)), "shared_scene": nbytes(rig.scene),
            "batch_result_per_pixel": round(nbytes(part) / (SIZE[0] * SIZE[1]), 2)}


def main() -> dict:
    from distributed import Client, LocalCluster

    from pipeline.distributed import ClusterConfig, machine_cores
    from rig.build import load_scene
    from rig.spec import resolve_scene_path

    rig, scene_file = load_scene("turntable"), resolve_scene_path("turntable")
    load_before = _load()
    figures: dict = {"workload": {"scene": "turntable", "views": VIEWS, "size": list(SIZE), "spp": SPP,
                                  "batch_tasks": 8 * -(-SPP // 8), "paths_per_batch": SIZE[0] * SIZE[1] * 8},
                     "cores": machine_cores(), "repeats": REPEATS}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        times = {"in_process": _time_runs(rig, scene_file, root, None, "local")}
        for n in (1, 2):
            t0 = time.perf_counter()
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None) as cluster, Client(cluster) as client:
                start = time.perf_counter() - t0
                cfg = ClusterConfig(scheduler=cluster.scheduler_address)
                _time_runs(rig, scene_file, root, cfg, f"warm{n}", repeats=1)  # warm-up: imports on the workers
                times[f"dask_{n}"] = _time_runs(rig, scene_file, root, cfg, f"dask{n}")
                figures[f"cluster_start_s_{n}"] = round(start, 2)
                if n == 2:
                    figures["scheduler_overhead"] = _scheduler_overhead(client)
    med = {k: statistics.median(v) for k, v in times.items()}
    figures["seconds"] = {k: {"median": round(med[k], 3), "all": [round(t, 3) for t in v]} for k, v in times.items()}
    figures["speedup_1_to_2"] = round(med["dask_1"] / med["dask_2"], 3)
    figures["dask_2_vs_in_process"] = round(med["in_process"] / med["dask_2"], 3)
    figures["dask_1_overhead_vs_in_process"] = round(med["dask_1"] / med["in_process"], 3)
    figures["bytes"] = _task_bytes(rig)
    figures["load_average_before"] = load_before
    figures["load_average_after"] = _load()
    figures["note"] = ("shared 2-core machine under load from colleagues' test runs: absolute times are "
                       "inflated and noisy; ratios were measured in the same run")
    write_result("distributed", figures)
    return figures


if __name__ == "__main__":
    main()
