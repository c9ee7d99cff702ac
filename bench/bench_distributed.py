"""Scale-out benchmark: the reference stage in process and on 1 and 2 local Dask workers.

Workload: the default scene (turntable), its 8 held-out views at 640x480, 16 spp = 2 batches
of 8 samples per view: 16 batch tasks of 2,457,600 camera paths each (plus 8 folds and 8
finishes). Timed, each ``REPEATS`` times (median), the whole ``run_reference`` call:

* ``in_process``: no Dask (the library default), the renderer's 2 threads: the baseline.
* ``dask_1`` / ``dask_2``: a local cluster of 1 or 2 single-threaded worker processes
  (:func:`pipeline.distributed.local_cluster`, as the stage starts it), started once beforehand
  (its start-up is timed separately as ``cluster_start_s_N``), reached through its address like
  any existing cluster; render threads per task = cores // Dask threads.

The ratio the issue asks for is ``speedup_1_to_2 = dask_1 / dask_2``. On 2 cores one worker
already renders on both (render threads fill the host's cores), so that ratio is about 1;
``speedup_1_to_2_one_thread_per_task`` pins every task to one render thread and measures the
scaling in workers alone. CPU seconds of every
process involved (client, local scheduler, workers) are recorded too: on a loaded machine the
wall time mostly says how much CPU the OS granted, ``cpu_per_wall`` says how much that was,
and the CPU seconds say what the engine itself costs. Also measured, to back
the projection in docs/scaling.md: bytes per task (arguments, batch result, finished view,
the shared scene), and the scheduler's per-task overhead from a flood of no-op tasks on the
2-worker cluster (how many tasks per second the scheduler sustains here).

Projection (:func:`simulate`): a discrete-event model of the stage on W single-core workers
and one scheduler that spends ``c_s`` seconds of its single thread on every task, fed with the
constants measured here (batch render time per path on one core, fold and finish times, bytes
per task, c_s, all as CPU seconds: what a free core takes, whatever the load). It is checked
against the 2-worker run (``model_check``: work in CPU seconds, and wall time at the CPU share
the OS granted us) and then evaluated on a views x spp x workers grid at 640x480
(``projection_*``).

The machine is shared: the load average before and after is recorded, and the figures are
ratios measured in the same run. Run: ``.venv/bin/python -m bench.bench_distributed``; writes
bench/results/distributed.json.
"""
from __future__ import annotations

import os
import pickle
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench.common import parse_flags, write_result

SIZE = (640, 480)
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
    from pipeline.stages.reference import ReferenceConfig, run_reference

    times, cpu = [], []
    for i in range(repeats):
        c0 = _cpu_now(client)
        t0 = time.perf_counter()
        run_reference(rig, scene_file, root / f"{label}-{i}", ReferenceConfig(spp=SPP, size=SIZE, views=VIEWS),
                      quiet=True, cluster=cluster)
        times.append(time.perf_counter() - t0)
        cpu.append(_cpu_now(client) - c0)
    return times, cpu


def _noop(i):
    return i


def _scheduler_overhead(client) -> dict:
    """Per no-op task over FLOOD tasks (submitted at once, gathered): wall time, and CPU time of
    this process, which runs the client and the local cluster's scheduler (the scheduler's cost
    per task on a free core): the floor under any unit of work."""
    client.gather(client.map(_noop, range(50), pure=False))  # warm up
    t0, c0 = time.perf_counter(), time.process_time()
    client.gather(client.map(_noop, range(FLOOD), pure=False))
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    return {"tasks": FLOOD, "seconds": round(dt, 3), "ms_per_task": round(1e3 * dt / FLOOD, 3),
            "cpu_ms_per_task": round(1e3 * dc / FLOOD, 3), "tasks_per_s": round(FLOOD / dt, 1)}


def _task_bytes(rig) -> dict:
    """Pickled sizes of what moves per unit of work (protocol 5, as Dask sends it)."""
    from render import integrators
    from render.effects import scene_effects
    from pipeline.stages.reference import SAMPLE_BATCH, finish_view, render_batch, resize_camera, select_views

    cam = resize_camera(select_views(rig, VIEWS)[0][1], *SIZE)
    eff = frozenset(scene_effects(rig.scene))
    st = integrators.RenderSettings(integrator="auto", spp=SPP)
    args = ("shared-0123456789abcdef0123456789abcdef", cam, st, (0, SAMPLE_BATCH), eff)
    part = render_batch(rig.scene, *args)
    nbytes = lambda x: len(pickle.dumps(x, protocol=5))  # noqa: E731
    return {"size": list(SIZE), "task_args": nbytes(args), "batch_result": nbytes(part),
            "finished_view": nbytes(finish_view(part)), "shared_scene": nbytes(rig.scene),
            "batch_result_per_pixel": round(nbytes(part) / (SIZE[0] * SIZE[1]), 2)}


def simulate(views: int, spp: int, workers: int, t_batch: float, t_fold: float, t_finish: float, t_client: float,
             c_sched: float, transfer_s: float = 0.0, batch: int = 8) -> float:
    """Predicted wall time (s) of one reference run (engine start-up excluded): a discrete-event
    model of how the stage runs on Dask.

    ``views`` x ceil(spp / batch) batch tasks of ``t_batch`` s, in priority order (view, then
    batch), each started when one of ``workers`` single-slot workers is free. Each view's
    results are folded in batch order: fold i starts when batch i and fold i-1 are done and
    takes ``t_fold`` s plus ``transfer_s`` when the batch result was computed on another worker
    (probability (W-1)/W); folds are short and do not hold a worker slot. The last fold is
    finished (``t_finish`` s) and the client writes the view's files (``t_client`` s, one view
    at a time). One scheduler thread serves every task (batch, fold, finish) in order of
    readiness and spends ``c_sched`` s on each: that is where it becomes the bottleneck.
    """
    import heapq

    nb = -(-spp // batch)
    cross = transfer_s * (workers - 1) / workers
    events: list[tuple[float, int, str, int, int]] = []  # (ready time, seq, kind, view, batch)
    seq = 0

    def push(t, kind, v, i):
        nonlocal seq
        heapq.heappush(events, (t, seq, kind, v, i))
        seq += 1

    order = [(v, i) for v in range(views) for i in range(nb)]
    nxt = 0
    for _ in range(min(workers, len(order))):
        push(0.0, "batch", *order[nxt])
        nxt += 1
    sched = client = end = 0.0
    batch_done = [[None] * nb for _ in range(views)]
    acc_done = [None] * views          # when view v's accumulated result is ready
    acc_upto = [0] * views             # last batch folded into it (batch 0 is the first acc)
    folding = [False] * views

    def advance(v):                    # push view v's next fold (or its finish) when possible
        if folding[v] or acc_done[v] is None:
            return
        j = acc_upto[v] + 1
        if j == nb:
            push(acc_done[v], "finish", v, 0)
            acc_done[v] = None
        elif batch_done[v][j] is not None:
            folding[v] = True
            push(max(acc_done[v], batch_done[v][j]), "fold", v, j)

    while events:
        t, _, kind, v, i = heapq.heappop(events)
        if kind == "batch-done":
            batch_done[v][i] = t
            if nxt < len(order):       # the freed worker takes the next batch
                push(t, "batch", *order[nxt])
                nxt += 1
            if i == 0:
                acc_done[v] = t
            advance(v)
            continue
        s = max(sched, t)
        sched = s + c_sched
        if kind == "batch":
            push(sched + t_batch, "batch-done", v, i)
        elif kind == "fold":
            acc_done[v], acc_upto[v], folding[v] = sched + t_fold + cross, i, False
            advance(v)
        else:  # finish, then the client writes the view
            client = max(client, sched + t_finish) + t_client
        end = max(end, sched)
    return max(end, client)


def _constants(rig) -> dict:
    """Per-task CPU seconds measured in process on one thread at SIZE (the time on a free core,
    whatever the machine's load); :func:`_projection` scales them to 640x480 by pixel count."""
    from render import integrators
    from render.effects import scene_effects
    from render.image_io import write_exr, write_preview
    from pipeline.stages.reference import fold_batches, finish_view, render_batch, resize_camera, select_views

    cam = resize_camera(select_views(rig, VIEWS)[0][1], *SIZE)
    eff = frozenset(scene_effects(rig.scene))
    st = integrators.RenderSettings(integrator="direct", spp=SPP, threads=1)
    render_batch(rig.scene, "bench-const", cam, st, (0, 8), eff)  # warm-up, builds the BVH
    clock = time.process_time  # CPU seconds of this (single-threaded) work: what a free core would take
    t0 = clock()
    parts = [render_batch(rig.scene, "bench-const", cam, st, (a, a + 8), eff) for a in (0, 8)]
    t_batch = (clock() - t0) / 2
    t0 = clock()
    acc = fold_batches(*parts)
    t_fold = clock() - t0
    t0 = clock()
    mean, var, _ = finish_view(acc)
    t_finish = clock() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = clock()
        write_exr(Path(tmp) / "a.exr", mean)
        write_exr(Path(tmp) / "b.exr", var)
        write_preview(Path(tmp) / "c.png", mean)
        t_client = clock() - t0
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


def main(argv: list[str] | None = None) -> dict:
    parse_flags("bench_distributed", "Reference renders on a local Dask cluster against in process.", argv, {})
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
                # one render thread per task: scaling in workers alone (dask_1 above already fills
                # both cores through the renderer's threads)
                one = ClusterConfig(scheduler=cluster.scheduler_address, task_threads=1)
                times[f"dask_{n}_one_thread"], cpus[f"dask_{n}_one_thread"] = _time_runs(
                    rig, scene_file, root, one, f"dask{n}t1", client=client)
                figures[f"cluster_start_s_{n}"] = round(start, 2)
                if n == 2:
                    figures["scheduler_overhead"] = _scheduler_overhead(client)
    med = {k: statistics.median(v) for k, v in times.items()}
    const = _constants(rig)
    c_sched = figures["scheduler_overhead"]["cpu_ms_per_task"] / 1e3
    n_views = 8
    figures["model_constants"] = {k: round(v, 5) for k, v in const.items()}
    # the model's single-core workers against the 2 single-threaded workers; on a loaded machine
    # compare the work (CPU seconds), and the wall time at the CPU share the OS granted us
    n_tasks = n_views * (2 * -(-SPP // 8)) + 1
    work = (n_views * -(-SPP // 8) * const["t_batch_s"] + n_views * (const["t_finish_s"] + const["t_client_write_s"])
            + n_tasks * c_sched)
    dedicated = simulate(n_views, SPP, 2, const["t_batch_s"], const["t_fold_s"], const["t_finish_s"],
                         const["t_client_write_s"], c_sched)
    share = statistics.median(cpus["dask_2"]) / med["dask_2"]
    figures["model_check"] = {"dask_2_measured_s": round(med["dask_2"], 3), "dask_2_predicted_on_2_free_cores_s":
                              round(dedicated, 3), "dask_2_predicted_at_granted_share_s": round(max(dedicated, work / share), 3),
                              "granted_cores": round(share, 3),
                              "model_work_cpu_s": round(work, 3), "dask_2_measured_cpu_s": round(
                                  statistics.median(cpus["dask_2"]), 3)}
    figures["projection_measured_scheduler"] = _projection(const, c_sched)  # CPU cost per task here
    figures["projection_1ms_scheduler"] = _projection(const, 1e-3)  # Dask's documented ~1 ms per task
    figures["seconds"] = {k: {"median": round(med[k], 3), "all": [round(t, 3) for t in v]} for k, v in times.items()}
    figures["cpu_seconds"] = {k: round(statistics.median(v), 3) for k, v in cpus.items()}
    figures["cpu_per_wall"] = {k: round(statistics.median(cpus[k]) / med[k], 3) for k in cpus}
    figures["speedup_1_to_2"] = round(med["dask_1"] / med["dask_2"], 3)
    figures["speedup_1_to_2_one_thread_per_task"] = round(med["dask_1_one_thread"] / med["dask_2_one_thread"], 3)
    figures["dask_2_vs_in_process"] = round(med["in_process"] / med["dask_2"], 3)
    figures["dask_1_overhead_vs_in_process"] = round(med["dask_1"] / med["in_process"], 3)
    figures["bytes"] = _task_bytes(rig)
    figures["load_average_before"] = load_before
    figures["load_average_after"] = _load()
    figures["note"] = ("2-core machine; the load averages before and after say how busy it was (above ~2, "
                       "absolute times are inflated); ratios were measured in the same run")
    write_result("distributed", figures)
    return figures


if __name__ == "__main__":
    main(sys.argv[1:])
