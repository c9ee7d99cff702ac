"""Scale-out benchmark: the reference stage in process and on 1 and 2 local Dask workers.

Workload: the default scene (turntable), its 8 held-out views at 320x240, 16 spp = 2 batches
of 8 samples per view: 16 batch tasks of 614,400 camera paths each (plus 8 folds and 8
finishes). Timed, each ``REPEATS`` times (median), the whole ``run_reference`` call:

* ``in_process``: no Dask (the library default), the renderer's 2 threads: the baseline.
* ``dask_1`` / ``dask_2``: a local cluster of 1 or 2 single-threaded worker processes
  (:func:`pipeline.distributed.local_cluster`, as the stage starts it), started once beforehand
  (its start-up is timed separately as ``cluster_start_s_N``), reached through its address like
  any existing cluster; render threads per task = cores // Dask threads.

The ratio the issue asks for is ``speedup_1_to_2 = dask_1 / dask_2``. CPU seconds of every
process involved (client, local scheduler, workers) are recorded too: on a loaded machine the
wall time mostly says how much CPU the OS granted, ``cpu_per_wall`` says how much that was,
and the CPU seconds say what the engine itself costs. Also measured, to back
the projection in docs/scaling.md: bytes per task (arguments, batch result, finished view,
the shared scene), and the scheduler's per-task overhead from a flood of no-op tasks on the
2-worker cluster (how many tasks per second the scheduler sustains here).

Projection (:func:`simulate`): a discrete-event model of the stage on W single-core workers
and one scheduler that spends ``c_s`` seconds of its single thread on every task, fed with the
constants measured here (batch render time per path on one core, fold and finish times, bytes
per task, c_s). It is checked against the measured 1- and 2-worker times (``model_check``) and
then evaluated on a views x spp x workers grid at 640x480 (``projection``).

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
SPP = 16
VIEWS = "test"
REPEATS = 3
FLOOD = 1000
#: projection grid: views x spp x workers at the default scene's full 640x480
GRID_VIEWS = (8, 56, 512)
GRID_SPP = (64, 1024)
GRID_WORKERS = (1, 2, 8, 32, 128, 512, 2048)


def _load():
    return os.getloadavg() if hasattr(os, "getloadavg") else None


def _worker_cpu() -> float:
    import psutil

    t = psutil.Process().cpu_times()
    return t.user + t.system


def _cpu_now(client) -> float:
    """CPU seconds used so far by this process (client, and scheduler of a local cluster) and
    by every worker process."""
    own = time.process_time()
    return own + (sum(client.run(_worker_cpu).values()) if client is not None else 0.0)


def _time_runs(rig, scene_file, root: Path, cluster, label: str, repeats: int = REPEATS,
               client=None) -> tuple[list[float], list[float]]:
    """Wall and CPU seconds (all processes involved) of ``repeats`` runs."""
    from pipeline.stages.reference import run_reference

    times, cpu = [], []
    for i in range(repeats):
        c0 = _cpu_now(client)
        t0 = time.perf_counter()
        run_reference(rig, scene_file, root / f"{label}-{i}", spp=SPP, size=SIZE, views=VIEWS, quiet=True,
                      cluster=cluster)
        times.append(time.perf_counter() - t0)
        cpu.append(_cpu_now(client) - c0)
    return times, cpu


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


def simulate(views: int, spp: int, workers: int, t_batch: float, t_fold: float, t_finish: float, t_client: float,
             c_sched: float, transfer_s: float = 0.0, batch: int = 8) -> float:
    """Predicted wall time (s) of one reference run (engine start-up excluded).

    Model: ``views`` x ceil(spp / batch) batch tasks of ``t_batch`` s, each view's batches
    folded in order (tasks of ``t_fold`` s plus ``transfer_s`` when the batch result crosses
    workers, probability (W-1)/W) and finished (``t_finish`` s on a worker, then ``t_client``
    s of the client writing files, serially). A single scheduler serves every task submission
    and completion in order at ``c_sched`` s each; ``workers`` single-slot workers take ready
    tasks in priority order (view, then batch) as Dask does.
    """
    import heapq

    nb = -(-spp // batch)
    cross = transfer_s * (workers - 1) / workers
    free = [0.0] * workers                      # when each worker is next free
    heapq.heapify(free)
    sched = 0.0                                 # when the scheduler is next free
    # batches in priority order; each view's fold chain runs as its batches complete
    fold_ready = [0.0] * views
    client = 0.0
    done_batches: list[list[float]] = [[] for _ in range(views)]
    for v in range(views):
        for b in range(nb):
            sched += c_sched                    # dispatch
            start = max(heapq.heappop(free), sched)
            end = start + t_batch
            heapq.heappush(free, end)
            done_batches[v].append(end)
    for v in range(views):
        t = done_batches[v][0]
        for end in done_batches[v][1:]:
            sched = max(sched, end) + c_sched  # completion + fold dispatch
            t = max(t, end, sched) + t_fold + cross
        sched = max(sched, t) + c_sched
        fold_ready[v] = t + t_finish
        client = max(client, fold_ready[v]) + t_client
    return max(client, sched, max(free))


def _constants(rig) -> dict:
    """Per-task times measured in process on one core at SIZE, and at 640x480 by scaling with
    the pixel count (work per path is independent of the image size)."""
    from render import pathtracer
    from render.effects import scene_effects
    from render.image_io import write_exr, write_preview
    from pipeline.stages.reference import fold_batches, finish_view, render_batch, resize_camera, select_views

    cam = resize_camera(select_views(rig, VIEWS)[0][1], *SIZE)
    eff = frozenset(scene_effects(rig.scene))
    st = pathtracer.RenderSettings(integrator="direct", spp=SPP, threads=1)
    render_batch(rig.scene, "bench-const", cam, st, (0, 8), eff)  # warm-up, builds the BVH
    t0 = time.perf_counter()
    parts = [render_batch(rig.scene, "bench-const", cam, st, (a, a + 8), eff) for a in (0, 8)]
    t_batch = (time.perf_counter() - t0) / 2
    t0 = time.perf_counter()
    acc = fold_batches(*parts)
    t_fold = time.perf_counter() - t0
    t0 = time.perf_counter()
    mean, var, _ = finish_view(acc)
    t_finish = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        write_exr(Path(tmp) / "a.exr", mean)
        write_exr(Path(tmp) / "b.exr", var)
        write_preview(Path(tmp) / "c.png", mean)
        t_client = time.perf_counter() - t0
    px = SIZE[0] * SIZE[1]
    return {"pixels": px, "t_batch_s": t_batch, "paths_per_s_one_core": 8 * px / t_batch, "t_fold_s": t_fold,
            "t_finish_s": t_finish, "t_client_write_s": t_client}


def _projection(k: dict, c_sched: float, bandwidth: float = 1.0e9) -> dict:
    """The model at 640x480 on the grid; transfers at ``bandwidth`` B/s (10 GbE ~ 1.2e9)."""
    scale = 640 * 480 / k["pixels"]
    tb, tf, tfin, tc = (k[n] * scale for n in ("t_batch_s", "t_fold_s", "t_finish_s", "t_client_write_s"))
    transfer = 56 * 640 * 480 / bandwidth
    rows = []
    for v in GRID_VIEWS:
        for spp in GRID_SPP:
            serial = simulate(v, spp, 1, tb, tf, tfin, tc, c_sched, transfer)
            for w in GRID_WORKERS:
                t = simulate(v, spp, w, tb, tf, tfin, tc, c_sched, transfer)
                rows.append({"views": v, "spp": spp, "workers": w, "seconds": round(t, 2),
                             "speedup": round(serial / t, 2), "efficiency": round(serial / t / w, 3)})
    return {"size": [640, 480], "t_batch_s": round(tb, 3), "c_sched_s": c_sched, "bandwidth_Bps": bandwidth,
            "scheduler_bound_workers": round(tb / (2 * c_sched)), "rows": rows}


def main() -> dict:
    from distributed import Client

    from pipeline.distributed import ClusterConfig, local_cluster, machine_cores
    from rig.build import load_scene
    from rig.spec import resolve_scene_path

    rig, scene_file = load_scene("turntable"), resolve_scene_path("turntable")
    load_before = _load()
    figures: dict = {"workload": {"scene": "turntable", "views": VIEWS, "size": list(SIZE), "spp": SPP,
                                  "batch_tasks": 8 * -(-SPP // 8), "paths_per_batch": SIZE[0] * SIZE[1] * 8},
                     "cores": machine_cores(), "repeats": REPEATS}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        times, cpus = {}, {}
        times["in_process"], cpus["in_process"] = _time_runs(rig, scene_file, root, None, "local")
        for n in (1, 2):
            t0 = time.perf_counter()
            with local_cluster(n, dashboard=False) as cluster, Client(cluster) as client:
                start = time.perf_counter() - t0
                cfg = ClusterConfig(scheduler=cluster.scheduler_address)
                _time_runs(rig, scene_file, root, cfg, f"warm{n}", repeats=1)  # warm-up: imports on the workers
                times[f"dask_{n}"], cpus[f"dask_{n}"] = _time_runs(rig, scene_file, root, cfg, f"dask{n}",
                                                                    client=client)
                figures[f"cluster_start_s_{n}"] = round(start, 2)
                if n == 2:
                    figures["scheduler_overhead"] = _scheduler_overhead(client)
    med = {k: statistics.median(v) for k, v in times.items()}
    const = _constants(rig)
    c_sched = figures["scheduler_overhead"]["ms_per_task"] / 1e3
    n_views = 8
    figures["model_constants"] = {k: round(v, 5) for k, v in const.items()}
    # apples to apples: the model's single-core workers against the 2 single-threaded workers
    # on a loaded machine compare work (CPU seconds), and wall time at the CPU share we were granted
    n_tasks = n_views * (2 * -(-SPP // 8)) + 1
    work = (n_views * -(-SPP // 8) * const["t_batch_s"] + n_views * (const["t_finish_s"] + const["t_client_write_s"])
            + n_tasks * c_sched)
    dedicated = simulate(n_views, SPP, 2, const["t_batch_s"], const["t_fold_s"], const["t_finish_s"],
                         const["t_client_write_s"], c_sched)
    share = statistics.median(cpus["dask_2"]) / med["dask_2"]
    figures["model_check"] = {"dask_2_measured_s": round(med["dask_2"], 3), "dask_2_predicted_on_2_free_cores_s":
                              round(dedicated, 3), "dask_2_predicted_at_granted_share_s": round(dedicated * 2 / share, 3),
                              "model_work_cpu_s": round(work, 3), "dask_2_measured_cpu_s": round(
                                  statistics.median(cpus["dask_2"]), 3)}
    figures["projection_measured_scheduler"] = _projection(const, c_sched)
    figures["projection_1ms_scheduler"] = _projection(const, 1e-3)  # Dask's documented ~1 ms per task
    figures["seconds"] = {k: {"median": round(med[k], 3), "all": [round(t, 3) for t in v]} for k, v in times.items()}
    figures["cpu_seconds"] = {k: round(statistics.median(v), 3) for k, v in cpus.items()}
    figures["cpu_per_wall"] = {k: round(statistics.median(cpus[k]) / med[k], 3) for k in cpus}
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
