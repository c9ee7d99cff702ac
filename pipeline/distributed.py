"""Scale-out engine: the pipeline's independent units of work on Dask distributed, or in process.

Renderers know nothing of this module; stages hand it plain functions and arguments.

The pattern every stage uses is an *ordered fold*: groups (e.g. a view) of independent units
(e.g. a batch of samples), each group reduced by a left fold in unit order on the workers and
finished into a small result that travels back to the client::

    result[g] = finish(fold(...fold(fold(work(*shared, *u0), work(*shared, *u1)), ...)))

Because every unit is a pure function and the fold order is fixed (sample order, left fold,
never a tree whose shape follows the number of workers), results are bit-identical for any
number of workers, in or out of process. Units run in parallel; the fold of a group is a chain of
cheap tasks on the workers, so only one finished result per group reaches the client. Stages
whose unit is a whole result (a captured view, a row of slab cameras, a held-out render) use
:func:`map_units`: groups of one unit, nothing folded.

Engines:

* :class:`LocalEngine`: in process, no Dask (the library default; what tests and small jobs use).
* :class:`DaskEngine`: a Dask ``Client``: a :class:`distributed.LocalCluster` of worker processes
  sized to the machine that starts and stops with the command, or an existing cluster given by
  ``--scheduler ADDRESS`` or the ``LUMIGRAPH_SCHEDULER`` environment variable.

Shared inputs (a scene with its textures) go to the cluster once (:meth:`DaskEngine.share`): as
one task whose result workers copy from each other, recomputable if every copy is lost. Costly
derived state that cannot be pickled (an Embree BVH) is built once per worker process through
:func:`worker_cache`.

Faults: a worker lost mid-run has its tasks (and lost intermediate folds) recomputed elsewhere by
the scheduler; a task that raises is retried ``retries`` times, then the stage stops with that
task's own exception; a task that kills its worker ``allowed-failures`` (3) times stops it with
``KilledWorker``; a cluster left with no worker for ``no_workers_timeout_s`` stops it with a
``RuntimeError``. On any error the remaining tasks are cancelled, and stages write their folder
through :func:`pipeline.artifacts.atomic_stage`, so nothing half-written looks finished.
"""
from __future__ import annotations

import logging
import os
import threading
import time
import uuid
from collections import OrderedDict, deque
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

from .artifacts import BadInput

__all__ = ["ENV_SCHEDULER", "TASK_THREADS", "ClusterConfig", "default_workers", "LocalEngine", "DaskEngine", "engine", "worker_cache",
           "release_cached", "map_units", "machine_cores", "resolve_scheduler", "local_cluster"]

#: environment variable naming an existing scheduler (same as ``--scheduler``)
ENV_SCHEDULER = "LUMIGRAPH_SCHEDULER"
#: environment of local worker processes: Dask's default less MALLOC_TRIM_THRESHOLD_, which
#: disables glibc's adaptive mmap threshold and made every large numpy temporary of a render a
#: fresh mmap (+50% time per batch measured here); see docs/scaling.md
LOCAL_WORKER_ENV = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}
#: threads a unit of work uses on a machine sized by default (the path tracer's own default)
TASK_THREADS = 2


def machine_cores() -> int:
    """Cores this process may use (CPU affinity, else ``os.cpu_count()``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def resolve_scheduler(scheduler: str | None) -> str | None:
    """The scheduler address to use: ``scheduler``, else ``$LUMIGRAPH_SCHEDULER``, else None."""
    if scheduler:
        return scheduler
    return os.environ.get(ENV_SCHEDULER) or None


@dataclass(frozen=True)
class ClusterConfig:
    """Where a stage's units of work run.

    scheduler: address of an existing Dask scheduler (``tcp://host:8786``); None: the
    ``LUMIGRAPH_SCHEDULER`` environment variable, else a local cluster.
    workers: local cluster size, in single-threaded worker processes; None: sized to the machine,
    :func:`default_workers` (cores // TASK_THREADS), and in process when that is one (a
    one-worker cluster only adds start-up and transfers: docs/scaling.md); 0: in process, no
    Dask. Ignored with a scheduler.
    retries: extra attempts for a task that raised before the stage stops with its error.
    no_workers_timeout_s: stop when the cluster has had no worker this long (never hang).
    poll_s: how often the client checks the cluster while waiting.
    connect_timeout_s: how long to wait for an existing scheduler to answer.
    task_threads: render threads per task; None: fill each host's cores (:func:`render_threads`).
    Benchmarks set 1 to measure scaling in workers alone.
    """

    scheduler: str | None = None
    workers: int | None = None
    retries: int = 1
    no_workers_timeout_s: float = 120.0
    poll_s: float = 1.0
    connect_timeout_s: float = 10.0
    task_threads: int | None = None

    def __post_init__(self):
        if self.workers is not None and self.workers < 0:
            raise BadInput(f"--workers must be 0 (in process) or more, got {self.workers}")
        if self.retries < 0 or min(self.no_workers_timeout_s, self.poll_s, self.connect_timeout_s) <= 0:
            raise BadInput("retries must be >= 0; no_workers_timeout_s, poll_s, connect_timeout_s positive")

    @property
    def address(self) -> str | None:
        return resolve_scheduler(self.scheduler)

    @property
    def local_workers(self) -> int:
        """Worker processes of the local cluster (0: in process)."""
        return default_workers() if self.workers is None else self.workers

    @property
    def in_process(self) -> bool:
        if self.address is not None:
            return False
        return self.workers == 0 or (self.workers is None and default_workers() == 1)


def default_workers() -> int:
    """Local workers on this machine by default: cores // TASK_THREADS, at least 1."""
    return max(1, machine_cores() // TASK_THREADS)


# --------------------------------------------------------------------------------------------
# worker-side cache

_CACHE: OrderedDict[str, Any] = OrderedDict()
_CACHE_LOCK = threading.Lock()
_CACHE_SIZE = 2


def worker_cache(key: str, build: Callable[[], Any]) -> Any:
    """Process-wide memo: ``build()`` once per ``key`` in this process (a Dask worker, or the
    client for :class:`LocalEngine`); keeps the ``_CACHE_SIZE`` most recently used values.

    For state that is costly and cannot be pickled, e.g. the Embree BVH of a shared scene: key it
    by the shared handle's key, which is unique per run."""
    with _CACHE_LOCK:
        if key in _CACHE:
            _CACHE.move_to_end(key)
            return _CACHE[key]
        value = build()
        _CACHE[key] = value
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
        return value


def release_cached(prefix: str) -> int:
    """Drop this process's :func:`worker_cache` entries whose key starts with ``prefix``, calling
    ``close()`` on values that have one (a GL context); returns how many were dropped."""
    with _CACHE_LOCK:
        keys = [k for k in _CACHE if k.startswith(prefix)]
        values = [_CACHE.pop(k) for k in keys]
    for v in values:
        close = getattr(v, "close", None)
        if callable(close):
            close()
    return len(values)


# --------------------------------------------------------------------------------------------
# the ordered fold, in process

@dataclass(frozen=True)
class Shared:
    """A shared input: ``value`` (in process) or a Dask future, and a key unique to this run."""

    key: str
    value: Any


class LocalEngine:
    """Runs units in this process, in order (today's single-process behaviour)."""

    name = "in process"
    workers = 1
    render_threads = TASK_THREADS

    def share(self, obj) -> Shared:
        return Shared(f"shared-{uuid.uuid4().hex}", obj)

    def release(self, shared: Shared) -> None:
        """Free what units built from ``shared`` in :func:`worker_cache` (keys starting with its key)."""
        release_cached(shared.key)

    def fold_groups(self, work: Callable, groups: Sequence[Sequence[tuple]], fold: Callable, finish: Callable | None,
                    shared: Sequence[Shared] = (), on_unit: Callable[[], None] | None = None,
                    on_group: Callable[[int, Any], None] | None = None, name: str = "unit",
                    concurrent: int = 1) -> None:
        """For each group g: ``on_group(g, finish(left fold of work(*shared values, *unit)))``;
        ``on_unit()`` after every unit. Arguments as :meth:`DaskEngine.fold_groups`, and
        ``concurrent``: units run on that many threads at once (for work that releases the GIL
        and is thread-safe), at most that many ahead of the fold, which still takes them in unit
        order: the same result as one at a time."""
        args = [s.value for s in shared]
        pool = ThreadPoolExecutor(concurrent) if concurrent > 1 else None
        try:
            for g, units in enumerate(groups):
                acc = None
                for part in self._in_order(pool, concurrent, work, args, units):
                    acc = part if acc is None else fold(acc, part)
                    if on_unit:
                        on_unit()
                if on_group:
                    on_group(g, acc if finish is None else finish(acc))
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)

    @staticmethod
    def _in_order(pool, ahead: int, work: Callable, args: list, units: Sequence[tuple]):
        """work(*args, *unit) for each unit, yielded in order; on ``pool`` with at most ``ahead``
        units submitted and not yet yielded, besides the one the caller is folding (a bounded
        number of results in memory)."""
        if pool is None:
            for unit in units:
                yield work(*args, *unit)
            return
        window = deque()
        it = iter(units)
        for unit in it:
            window.append(pool.submit(work, *args, *unit))
            if len(window) >= ahead:
                break
        while window:
            part = window.popleft().result()
            nxt = next(it, None)
            if nxt is not None:
                window.append(pool.submit(work, *args, *nxt))
            yield part


# --------------------------------------------------------------------------------------------
# the ordered fold, on Dask

def _identity(x):
    return x


def render_threads(client) -> int:
    """Threads one task may use so that a host's concurrent tasks fill its cores without
    oversubscribing them: min over hosts of (host cores // Dask threads on that host), >= 1.
    (A render's result never depends on its thread count.)"""
    from urllib.parse import urlparse

    nthreads = client.nthreads()
    if not nthreads:
        return 1
    cores = client.run(machine_cores, on_error="ignore")
    per_host: dict[str, int] = {}
    for addr, n in nthreads.items():
        host = urlparse(addr).hostname or addr
        per_host[host] = per_host.get(host, 0) + n
    shares = [cores[a] // per_host[urlparse(a).hostname or a] for a in nthreads if isinstance(cores.get(a), int)]
    return max(1, min(shares)) if shares else 1


class DaskEngine:
    """Runs units on a Dask cluster through ``client``; see the module docstring."""

    def __init__(self, client, config: ClusterConfig = ClusterConfig(), local: bool = False):
        self.client = client
        self.config = config
        self.workers = len(client.nthreads())
        self.render_threads = config.task_threads or render_threads(client)
        self.name = "dask local cluster" if local else "dask cluster"

    def share(self, obj) -> Shared:
        """Send ``obj`` to the cluster once (a task whose result workers copy from each other)."""
        import warnings

        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*large graph.*")
            fut = self.client.submit(_identity, obj, key=f"shared-{uuid.uuid4().hex}", pure=False)
        return Shared(fut.key, fut)

    def release(self, shared: Shared) -> None:
        """Free what units built from ``shared`` in each worker's :func:`worker_cache` (best effort:
        a worker that does not answer is skipped)."""
        try:
            self.client.run(release_cached, shared.key, on_error="ignore")
        except Exception:  # noqa: BLE001 - a cluster in trouble: the stage's own error matters more
            pass

    def _check_workers(self, since: list[float]) -> None:
        if self.client.nthreads():
            since[0] = time.monotonic()
        elif time.monotonic() - since[0] > self.config.no_workers_timeout_s:
            raise RuntimeError(f"dask cluster at {self.client.scheduler.address} has had no worker for "
                               f"{self.config.no_workers_timeout_s:.0f} s")

    def fold_groups(self, work: Callable, groups: Sequence[Sequence[tuple]], fold: Callable, finish: Callable | None,
                    shared: Sequence[Shared] = (), on_unit: Callable[[], None] | None = None,
                    on_group: Callable[[int, Any], None] | None = None, name: str = "unit",
                    concurrent: int = 1) -> None:
        """Submit every unit ``work(*shared, *unit)``, chain ``fold`` over each group's results in
        unit order and ``finish`` the last (None: the group's result is the fold itself, no
        task), all on the workers; call ``on_unit()`` as units finish (any order) and
        ``on_group(g, result)`` as groups finish (any order). Raises the first failed task's
        exception after cancelling the rest. ``concurrent`` is the in-process engine's (the
        cluster runs units side by side already)."""
        from distributed import wait

        client, run = self.client, uuid.uuid4().hex[:8]
        args = [s.value for s in shared]
        units, finals = {}, {}
        try:
            for g, group in enumerate(groups):
                if not group:
                    raise ValueError(f"group {g} has no units")
                acc = None
                for i, unit in enumerate(group):
                    part = client.submit(work, *args, *unit, key=f"{name}-{run}-{g}-{i}", retries=self.config.retries)
                    units[part.key] = part
                    acc = part if acc is None else client.submit(fold, acc, part, key=f"fold-{run}-{g}-{i}",
                                                                  retries=self.config.retries)
                fin = acc if finish is None else client.submit(finish, acc, key=f"finish-{run}-{g}",
                                                                retries=self.config.retries)
                finals[fin.key] = (g, fin)
                del acc, part  # the client holds units (for progress) and finals only
            pending = set(units.values()) | {f for _, f in finals.values()}
            since = [time.monotonic()]
            while pending:
                try:
                    with client.as_current():  # wait() uses the current client
                        done, pending = wait(pending, timeout=self.config.poll_s, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    self._check_workers(since)
                    continue
                since[0] = time.monotonic()
                for fut in done:
                    if fut.status != "finished":
                        fut.result()  # re-raises the task's own exception (or CancelledError)
                        raise RuntimeError(f"dask task {fut.key} ended as {fut.status}")
                    if fut.key in units:  # (a one-unit group without finish: a unit and a final)
                        del units[fut.key]
                        if on_unit:
                            on_unit()
                    if fut.key in finals:
                        g, _ = finals.pop(fut.key)
                        value = fut.result()
                        if on_group:
                            on_group(g, value)
                del done
        finally:
            left = list({f.key: f for f in list(units.values()) + [f for _, f in finals.values()]}.values())
            if left:
                client.cancel(left)


def _no_fold(acc, part):  # pragma: no cover - map_units' groups have one unit
    raise AssertionError("map_units folds nothing")


def map_units(eng: "LocalEngine | DaskEngine", work: Callable, units: Sequence[tuple], shared: Sequence[Shared] = (),
              on_result: Callable[[int, Any], None] | None = None, name: str = "unit") -> None:
    """Independent units, no fold: ``on_result(i, work(*shared values, *units[i]))`` as each
    finishes (in unit order in process, any order on Dask; one task per unit). For stages whose
    unit is a whole view, a row of slab cameras, etc."""
    eng.fold_groups(work, [[u] for u in units], _no_fold, None, shared=shared, on_group=on_result, name=name)


# --------------------------------------------------------------------------------------------
# the engine context

def local_cluster(workers: int, dashboard: bool = True):
    """A :class:`distributed.LocalCluster` of ``workers`` single-threaded worker processes on
    loopback, with :data:`LOCAL_WORKER_ENV` (dashboard on a free port unless ``dashboard`` is
    False). The caller closes it (it is a context manager)."""
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.nanny.pre-spawn-environ": LOCAL_WORKER_ENV}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address="127.0.0.1:0" if dashboard else None, silence_logs=logging.ERROR)


@contextmanager
def engine(config: "ClusterConfig | LocalEngine | DaskEngine | None" = None, quiet: bool = False,
           echo: Callable[[str], None] | None = None) -> Iterator[LocalEngine | DaskEngine]:
    """The engine a stage runs on, started and stopped with the stage.

    An engine already open (``lumigraph run`` opens one for all its stages): that engine, left
    open. None or ``workers=0`` without a scheduler: :class:`LocalEngine`. A scheduler address (argument
    or ``LUMIGRAPH_SCHEDULER``): a client of that cluster (BadInput naming it if unreachable).
    Otherwise a :class:`distributed.LocalCluster` of ``config.local_workers`` single-threaded
    worker processes on loopback, dashboard on a free port. Unless ``quiet``,
    prints the cluster and its dashboard address through ``echo`` (default: stderr).
    """
    if isinstance(config, (LocalEngine, DaskEngine)):
        yield config
        return
    if config is None or config.in_process:
        yield LocalEngine()
        return
    import dask
    from distributed import Client

    if echo is None:
        from .progress import console

        def echo(line: str) -> None:
            console.print(line, soft_wrap=True, highlight=False)
    address = config.address
    cluster = None
    with dask.config.set({"distributed.scheduler.allowed-failures": 3,
                          "distributed.scheduler.no-workers-timeout": f"{config.no_workers_timeout_s}s"}):
        try:
            if address:
                try:
                    client = Client(address, timeout=f"{config.connect_timeout_s}s")
                except (OSError, TimeoutError) as exc:
                    raise BadInput(f"--scheduler {address}: no Dask scheduler answered within "
                                   f"{config.connect_timeout_s:g} s") from None
            else:
                cluster = local_cluster(config.local_workers)
                client = Client(cluster)
            try:
                eng = DaskEngine(client, config, local=cluster is not None)
                if not quiet:
                    echo(f"dask: {eng.workers} workers at {client.scheduler.address}, "
                         f"dashboard {client.dashboard_link}")
                yield eng
            finally:
                client.close()
        finally:
            if cluster is not None:
                cluster.close()
