"""The reference stage on Dask: a real scheduler and workers as separate processes on loopback.

Every run renders the tiny scene's 6 views (128x96) at 36 spp = 5 batches per view (the last
one ragged, 4 samples): 30 batch tasks. The undisturbed single-process run (no Dask) is the
reference; every distributed run must produce exactly its bytes (the manifest's content hashes
of every output file), whatever the number of workers and even when a worker is killed mid-run.
"""
import operator
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from pipeline.artifacts import BadInput, atomic_stage, read_manifest
from pipeline.cli import main
from pipeline.distributed import ClusterConfig, DaskEngine, LocalEngine, engine
from pipeline.stages.reference import ReferenceConfig, run_reference

from .conftest import TINY_SCENE, write_scene

SPP = 36
VIEWS = "all"
N_VIEWS = 6
DASK = str(Path(sys.executable).with_name("dask"))


class LoopbackCluster:
    """``dask scheduler`` and ``dask worker`` processes (no nanny: a killed worker stays dead)."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.file = folder / "scheduler.json"
        self.procs: list[subprocess.Popen] = []
        self.workers: list[subprocess.Popen] = []
        self.names: dict[int, str] = {}  # pid -> worker name
        self.log = open(folder / "dask.log", "w")
        self.procs.append(subprocess.Popen(
            [DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--idle-timeout", "600s", "--scheduler-file", str(self.file)], stdout=self.log, stderr=subprocess.STDOUT))
        deadline = time.monotonic() + 60
        while not self.file.exists():
            assert time.monotonic() < deadline, "dask scheduler did not start"
            assert self.procs[0].poll() is None, "dask scheduler exited"
            time.sleep(0.2)
        import json

        self.address = json.loads(self.file.read_text())["address"]
        from distributed import Client

        self.client = Client(self.address, timeout="30s", set_as_default=False)

    def _n(self) -> int:
        return len(self.client.nthreads())

    def _wait(self, n: int) -> None:
        deadline = time.monotonic() + 90
        while self._n() != n:
            assert time.monotonic() < deadline, f"cluster did not reach {n} workers"
            time.sleep(0.2)

    def ensure(self, n: int) -> None:
        """Exactly ``n`` live workers."""
        self.workers = [w for w in self.workers if w.poll() is None]
        while len(self.workers) < n:
            name = f"w{len(self.procs)}"
            self.workers.append(subprocess.Popen(
                [DASK, "worker", self.address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                 "--host", "127.0.0.1", "--death-timeout", "60s", "--name", name],
                stdout=self.log, stderr=subprocess.STDOUT))
            self.procs.append(self.workers[-1])
            self.names[self.workers[-1].pid] = name
        while len(self.workers) > n:
            w = self.workers.pop()
            w.terminate()
            w.wait(30)
        self._wait(n)

    def address_of(self, worker: subprocess.Popen) -> str:
        infos = self.client.scheduler_info(n_workers=-1)["workers"]
        return next(a for a, w in infos.items() if w.get("name") == self.names[worker.pid])

    def kill(self, worker: subprocess.Popen) -> None:
        worker.send_signal(signal.SIGKILL)
        worker.wait(30)
        self.workers.remove(worker)

    def close(self) -> None:
        self.client.close()
        for p in reversed(self.procs):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(20)
                except subprocess.TimeoutExpired:
                    p.kill()
        self.log.close()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("dist")
    path = write_scene(root / "scenes", TINY_SCENE)
    from rig.build import load_scene

    return load_scene(str(path)), path, root


@pytest.fixture(scope="module")
def undisturbed(tiny):
    """Output hashes of the single-process run (no Dask)."""
    rig, path, root = tiny
    m = run_reference(rig, path, root / "single", ReferenceConfig(spp=SPP, views=VIEWS), quiet=True)
    assert m["metrics"]["engine"] == "in process" and len(m["outputs"]) == 3 * N_VIEWS + 1
    return m["outputs"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = LoopbackCluster(tmp_path_factory.mktemp("dask"))
    yield c
    c.close()


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_same_bytes_for_1_2_3_workers(tiny, undisturbed, cluster, workers):
    rig, path, root = tiny
    cluster.ensure(workers)
    out = root / f"w{workers}"
    m = run_reference(rig, path, out, ReferenceConfig(spp=SPP, views=VIEWS),
                      quiet=True, cluster=ClusterConfig(cluster.address))
    assert m["metrics"]["workers"] == workers and m["metrics"]["engine"] == "dask cluster"
    assert m["outputs"] == undisturbed


def test_worker_killed_mid_run_gives_the_same_image(tiny, undisturbed, cluster):
    """Two workers; as soon as one holds finished batch renders or folds (results the run still
    needs), it is SIGKILLed: its running tasks and the results it held are recomputed on the
    survivor, and the image is the undisturbed run's, byte for byte."""
    rig, path, root = tiny
    cluster.ensure(2)
    victim = cluster.workers[-1]
    victim_addr = cluster.address_of(victim)
    out = root / "killed"
    box: dict = {}

    def run():
        try:
            box["m"] = run_reference(rig, path, out, ReferenceConfig(spp=SPP, views=VIEWS),
                                     quiet=True, cluster=ClusterConfig(cluster.address))
        except BaseException as exc:  # surfaced below
            box["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    deadline = time.monotonic() + 120
    held: list[str] = []
    while not held:
        assert t.is_alive(), f"the run ended before the victim held a result: {box}"
        assert time.monotonic() < deadline
        held = [k for k in cluster.client.has_what().get(victim_addr, ())
                if str(k).startswith(("reference-batch-", "fold-"))]
        time.sleep(0.01)
    written = len(list(root.glob(".killed.partial-*/linear/*.exr")))
    cluster.kill(victim)
    assert t.is_alive() and not out.exists() and written < N_VIEWS  # the kill was mid-run
    t.join(180)
    assert not t.is_alive()
    assert "error" not in box, box.get("error")
    assert box["m"]["outputs"] == undisturbed
    assert cluster._n() == 1


def test_float64_moments_bit_identical_to_the_in_process_fold(tiny, cluster):
    """The exact guarantee, below the float32 files: each view's float64 film moments from 2
    workers equal the in-process left fold bit for bit. Merge order matters at this level (a
    reversed fold changes some sums' last bits, asserted here), so the equality is not vacuous;
    the float32 mean and variance files hide such differences, the moments do not."""
    from functools import reduce

    from render import integrators
    from render.effects import scene_effects
    from pipeline.stages.reference import LOCAL_UNITS_AT_ONCE, fold_batches, fold_batches_in_place, render_batch

    rig, _, _ = tiny
    cluster.ensure(2)
    settings = integrators.RenderSettings(integrator="direct", spp=SPP, threads=1)
    effects = frozenset(scene_effects(rig.scene))
    cams = [c for c in rig.cameras["train"] + rig.cameras["test"]]
    batches = [(a, min(a + 8, SPP)) for a in range(0, SPP, 8)]
    films = {}
    # the in-process engine one unit at a time, and as the reference stage runs it: units side by
    # side, folded in place (render.film.Film.merge_in_place)
    for name, config, fold, concurrent in (("local", None, fold_batches, 1),
                                           ("local concurrent", None, fold_batches_in_place, LOCAL_UNITS_AT_ONCE),
                                           ("dask", ClusterConfig(cluster.address), fold_batches, 1)):
        with engine(config, quiet=True) as eng:
            scene = eng.share(rig.scene)
            units = [[(scene.key, cam, settings, rng, effects) for rng in batches] for cam in cams]
            got = {}
            eng.fold_groups(render_batch, units, fold, operator.itemgetter(0), shared=[scene],
                            on_group=lambda g, film: got.__setitem__(g, film), concurrent=concurrent)
            films[name] = got
    local, dask = films["local"], films["dask"]
    assert sorted(local) == sorted(dask) == sorted(films["local concurrent"]) == list(range(len(cams)))
    for g in local:
        for field in ("s1", "s2", "n"):
            assert getattr(local[g], field).tobytes() == getattr(dask[g], field).tobytes()
            assert getattr(films["local concurrent"][g], field).tobytes() == getattr(dask[g], field).tobytes()
    parts = [render_batch(rig.scene, "reversed", cams[0], settings, rng, effects) for rng in batches]
    rev = reduce(fold_batches, parts[::-1])[0]
    assert (rev.s1 != local[0].s1).any() and rev.s1.tobytes() != local[0].s1.tobytes()


def test_cli_uses_the_cluster_from_the_environment(tiny, undisturbed, cluster, monkeypatch):
    rig, path, root = tiny
    cluster.ensure(2)
    monkeypatch.setenv("LUMIGRAPH_SCHEDULER", cluster.address)
    out = root / "cli-env"
    assert main(["reference", str(path), "--spp", str(SPP), "--views", VIEWS, "--out", str(out), "--quiet"]) == 0
    m = read_manifest(out)
    assert m["metrics"]["engine"] == "dask cluster" and m["outputs"] == undisturbed


def test_cli_local_cluster_started_and_stopped_with_the_command(tiny, undisturbed, capsys):
    """--workers 2: a LocalCluster of two processes; the dashboard address is printed."""
    rig, path, root = tiny
    out = root / "cli-local"
    assert main(["reference", str(path), "--spp", str(SPP), "--views", VIEWS, "--out", str(out), "--workers", "2"]) == 0
    m = read_manifest(out)
    assert m["metrics"]["engine"] == "dask local cluster" and m["metrics"]["workers"] == 2
    assert m["outputs"] == undisturbed
    err = capsys.readouterr().err
    assert "dashboard http://127.0.0.1:" in err


def test_failing_task_stops_the_stage_with_its_error_and_leaves_nothing(cluster, tmp_path):
    """A unit that always raises: retried (ClusterConfig.retries), then its own exception
    reaches the caller promptly (no hang), the other units are cancelled and the atomic stage
    folder is gone. The same happens in process."""
    cluster.ensure(1)
    out = tmp_path / "stage"
    units = [[(i, 0) for i in range(4)] for _ in range(3)]  # operator.truediv(i, 0) always raises
    cfg = ClusterConfig(cluster.address, retries=1)
    for config in (cfg, None):
        t0 = time.monotonic()
        with pytest.raises(ZeroDivisionError):
            with atomic_stage(out) as tmp, engine(config, quiet=True) as eng:
                assert isinstance(eng, DaskEngine if config else LocalEngine)
                (tmp / "half.txt").write_text("half-written")
                eng.fold_groups(operator.truediv, units, operator.add, abs)
        assert time.monotonic() - t0 < 60
        assert not out.exists() and not list(tmp_path.glob(".stage.partial-*"))


def test_unreachable_scheduler_is_bad_input(tiny, capsys):
    rig, path, root = tiny
    out = root / "unreachable"
    with pytest.raises(BadInput, match="--scheduler"):
        run_reference(rig, path, out, ReferenceConfig(spp=8, views="test"),
                      quiet=True, cluster=ClusterConfig("tcp://127.0.0.1:9", connect_timeout_s=2))
    assert not out.exists()


def test_workers_0_is_in_process_and_negative_is_bad_input(tiny, undisturbed, capsys):
    rig, path, root = tiny
    m = run_reference(rig, path, root / "w0", ReferenceConfig(spp=SPP, views=VIEWS),
                      quiet=True, cluster=ClusterConfig(workers=0))
    assert m["metrics"]["engine"] == "in process" and m["outputs"] == undisturbed
    assert main(["reference", str(path), "--workers", "-1", "--out", str(root / "neg"), "--quiet"]) == 2
    assert "--workers" in capsys.readouterr().err
    assert not (root / "neg").exists()


def test_no_worker_left_stops_the_stage_instead_of_hanging(tiny, cluster):
    """Every worker gone (none restarted): the stage stops after no_workers_timeout_s with a
    RuntimeError naming the cluster, and leaves no folder."""
    rig, path, root = tiny
    cluster.ensure(0)
    out = root / "no-workers"
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="no worker"):
        run_reference(rig, path, out, ReferenceConfig(spp=8, views="test"),
                      quiet=True, cluster=ClusterConfig(cluster.address, no_workers_timeout_s=2, poll_s=0.5))
    assert time.monotonic() - t0 < 30
    assert not out.exists() and not list(root.glob(".no-workers.partial-*"))


def test_local_engine_side_by_side_units_fold_in_order_with_a_bounded_window():
    """LocalEngine.fold_groups(concurrent=2): units run on two threads at once (observed: two in
    flight), at most ``concurrent`` ahead of the fold (never more alive than that plus the one
    being folded), and the fold sees them in unit order even when later units finish first
    (their sleeps decrease)."""
    lock = threading.Lock()
    live, peak = [0], [0]

    def work(base, i, delay):
        with lock:
            live[0] += 1
            peak[0] = max(peak[0], live[0])
        time.sleep(delay)
        with lock:
            live[0] -= 1
        return [base + i]

    groups = [[(i, 0.02 * (6 - i)) for i in range(6)], [(10 + i, 0.005) for i in range(3)]]
    out = {}
    LocalEngine().fold_groups(work, groups, operator.add, None, shared=[LocalEngine().share(100)],
                              on_group=out.__setitem__, concurrent=2)
    assert out == {0: [100 + i for i in range(6)], 1: [110, 111, 112]}
    assert peak[0] == 2
