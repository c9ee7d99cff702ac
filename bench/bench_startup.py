"""Start-up cost of the ``reference`` command against ``lumigraph --help``, measured in one run.

Figures (bench/results/startup.json; shared, noisy machines: medians and ratios, never absolute
thresholds):

* whole-process wall time, median of N interleaved runs each, of ``lumigraph --help`` and of
  ``lumigraph reference cornell --spp 1 --size 32 32`` (the issue's command), and their ratio
  (goal: <= 1.2); the scene comes from the scene cache (rig/scene_cache.py, a folder of the
  bench's own, filled by the first run, whose time is reported apart), and the same command with
  the cache off (``LUMIGRAPH_SCENE_CACHE=0``: the spec validated by pydantic every run, as a new
  or edited scene's first run) is interleaved with them;
* what the ``reference`` verb imports (``python -X importtime``): the heavy packages present
  (torch, pyrender, dask, trimesh, scipy.spatial must not be: tests/pipeline/test_startup_imports.py),
  and the largest cumulative imports;
* numba's floor: in a fresh process (interleaved with the two commands) the seconds of importing
  numba and calling one trivial kernel from its cache; ``floor_ratio_to_help`` = (help + floor) /
  help, the least ratio a reference rendered by numba kernels can reach; CPU seconds of each
  command beside the wall (a busy machine inflates them less);
* the phases of the same work in one process: imports, scene load, scene preparation (BVH,
  materials, lights), first render (compiled kernels loaded from numba's cache), a second
  render, their difference (the kernel-cache load), and numba's cache hits / misses per kernel
  (a miss means compilation on first use).

Run: ``.venv/bin/python -m bench.bench_startup`` (``--quick``: 2 runs each instead of 7).
"""
from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.common import parse_flags, write_result

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "pyrender", "dask", "distributed", "trimesh", "networkx", "scipy", "scipy.spatial", "scipy.ndimage",
         "scipy.stats", "numba", "cv2", "pydantic", "OpenGL", "recon")

#: numba's own fixed cost, the floor of any process whose render runs numba kernels: a fresh
#: process imports numba and calls a trivial kernel from numba's on-disk cache (in ``tmp``), with
#: numba's BLAS probe skipped as render's kernel modules do (render._kernel_cache)
_NUMBA_FLOOR = r"""
import json, sys, time
import numpy as np
from render._kernel_cache import skip_numba_blas_probe
sys.path.insert(0, sys.argv[1])
t0 = time.perf_counter()
import numba
skip_numba_blas_probe()
import trivial_kernel
t1 = time.perf_counter()
trivial_kernel.total(np.ones(3))
t2 = time.perf_counter()
print(json.dumps({"import_numba_s": t1 - t0, "first_kernel_s": t2 - t1}))
"""
_TRIVIAL_KERNEL = """import numba
@numba.njit(cache=True)
def total(x):
    return x.sum()
"""

_PHASES = r"""
import json, time
t0 = time.perf_counter()
from render.integrators import RenderSettings, prepare, render
from rig.scene_cache import load_scene
from pipeline.stages.reference import resize_camera
t1 = time.perf_counter()
rig = load_scene("cornell")  # a hit: the bench's runs before filled the scene cache
cam = resize_camera(rig.cameras["scene"][0], 32, 32)
t2 = time.perf_counter()
ps = prepare(rig.scene)
t3 = time.perf_counter()
render(rig.scene, cam, RenderSettings(integrator="path", spp=1), prepared=ps)
t4 = time.perf_counter()
render(rig.scene, cam, RenderSettings(integrator="path", spp=1), prepared=ps)
t5 = time.perf_counter()
from numba.core.registry import CPUDispatcher
from render.integrators import path_kernels
import render.embree_direct as ed
stats = {}
for mod in (path_kernels, ed):
    for name in dir(mod):
        f = getattr(mod, name)
        if isinstance(f, CPUDispatcher) and f.signatures:
            stats[f"{mod.__name__.split('.')[-1]}.{name}"] = {"cache_hits": sum(f.stats.cache_hits.values()),
                                                              "cache_misses": sum(f.stats.cache_misses.values())}
# the first render's extra over the second is loading the kernels from numba's cache (and numba's
# lowering registries, which the first kernel load initialises); prepare is the BVH, lights, materials
print(json.dumps({"import_s": t1 - t0, "load_scene_s": t2 - t1, "prepare_bvh_s": t3 - t2, "first_render_s": t4 - t3,
                  "second_render_s": t5 - t4, "kernel_cache_load_s": (t4 - t3) - (t5 - t4), "kernels": stats}))
"""


#: the bench's own scene cache (rig/scene_cache.py), empty at the start: set in main
_CACHE_ENV: dict[str, str] = {}


def _env(**extra: str) -> dict:
    return {**os.environ, "PYOPENGL_PLATFORM": "egl", **_CACHE_ENV, **extra}


def _timed(cmd: list[str], cpu: list | None = None, **env: str) -> float:
    """Wall seconds of ``cmd`` in a fresh process; its CPU seconds (user + system, less inflated
    by a busy machine than the wall) appended to ``cpu`` when given."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=_env(**env), capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
    if cpu is not None:
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return elapsed


def _numba_floor(cmd: list[str]) -> dict:
    """In-process seconds of numba's part (import, first cached kernel) of one fresh process."""
    proc = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _imports(cmd: list[str]) -> dict:
    proc = subprocess.run([sys.executable, "-X", "importtime", *cmd], cwd=ROOT, env=_env(), capture_output=True,
                          text=True)
    rows = []
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        _, self_us, cum_us, name = (x.strip() for x in line.replace("import time:", "|").split("|"))
        rows.append((name, int(cum_us)))
    top = {name: cum for name, cum in rows if "." not in name}
    loaded = {name for name, _ in rows}
    return {"heavy_packages": sorted(p for p in HEAVY if p in loaded),
            "largest_top_level_s": {n: round(c / 1e6, 3) for n, c in sorted(top.items(), key=lambda r: -r[1])[:12]}}


def main(argv: list[str] | None = None) -> None:
    args = parse_flags("bench_startup", "Start-up cost of `lumigraph reference` against `lumigraph --help`.", argv,
                       {"--quick": "2 runs of each command instead of 7"})
    runs = 2 if args.quick else 7
    lumigraph = [sys.executable, "-m", "pipeline"]
    with tempfile.TemporaryDirectory() as tmp:
        _CACHE_ENV["LUMIGRAPH_CACHE_DIR"] = str(Path(tmp) / "cache")
        reference = [*lumigraph, "reference", "cornell", "--spp", "1", "--size", "32", "32", "--out",
                     str(Path(tmp) / "reference"), "--overwrite", "-q"]
        help_cmd = [*lumigraph, "--help"]
        # the first run: the scene cache is empty (a miss: the spec is validated and the entry
        # written); numba's cache or the AOT kernels are make setup's (a checkout without them compiles here)
        first_s = _timed(reference)
        (Path(tmp) / "trivial_kernel.py").write_text(_TRIVIAL_KERNEL)
        floor_cmd = [sys.executable, "-c", _NUMBA_FLOOR, tmp]
        _timed(floor_cmd)  # compiles the trivial kernel into its cache
        help_s, ref_s, cold_s, floor_s = [], [], [], []
        cpu = {"help": [], "reference": [], "reference_no_scene_cache": []}
        for _ in range(runs):  # interleaved: all see the same machine load
            help_s.append(_timed(help_cmd, cpu["help"]))
            ref_s.append(_timed(reference, cpu["reference"]))
            cold_s.append(_timed(reference, cpu["reference_no_scene_cache"], LUMIGRAPH_SCENE_CACHE="0"))
            floor_s.append(_numba_floor(floor_cmd))
        imports_ref = _imports(["-m", "pipeline", "reference", "cornell", "--spp", "1", "--size", "32", "32", "--out",
                                str(Path(tmp) / "reference"), "--overwrite", "-q"])
        imports_help = _imports(["-m", "pipeline", "--help"])
        phases = subprocess.run([sys.executable, "-c", _PHASES], cwd=ROOT, env=_env(), capture_output=True,
                                text=True)
    phase_figures = json.loads(phases.stdout.strip().splitlines()[-1]) if phases.returncode == 0 else {
        "error": phases.stderr.strip()[-500:]}
    help_med, ref_med, cold_med = statistics.median(help_s), statistics.median(ref_s), statistics.median(cold_s)
    floor_med = statistics.median(f["import_numba_s"] + f["first_kernel_s"] for f in floor_s)
    write_result("startup", {
        "runs": runs,
        "command": "lumigraph reference cornell --spp 1 --size 32 32 (against lumigraph --help)",
        "help_median_s": round(help_med, 3), "reference_median_s": round(ref_med, 3),
        "ratio_reference_to_help": round(ref_med / help_med, 3), "goal_ratio": 1.2,
        "help_runs_s": [round(t, 3) for t in help_s], "reference_runs_s": [round(t, 3) for t in ref_s],
        # the scene cache's share: the same command with the cache off (every run validates the
        # spec with pydantic, as the first run of a new or edited scene does), and that first run
        "reference_no_scene_cache_median_s": round(cold_med, 3),
        "ratio_no_scene_cache_to_help": round(cold_med / help_med, 3),
        "reference_no_scene_cache_runs_s": [round(t, 3) for t in cold_s],
        "reference_first_run_s": round(first_s, 3),
        # numba's floor: in a fresh process (interleaved with the two commands) the seconds of
        # importing numba and calling one trivial kernel from its cache: help plus that is the
        # least a reference rendered by numba kernels can take, whatever the CLI does
        "numba_floor_runs": floor_s,
        "numba_floor_median_s": round(floor_med, 3),
        "floor_ratio_to_help": round((help_med + floor_med) / help_med, 3),
        # the same in CPU seconds (user + system of each process): the load inflates them less
        "cpu_median_s": {k: round(statistics.median(v), 3) for k, v in cpu.items()},
        "cpu_ratio_reference_to_help": round(statistics.median(cpu["reference"]) / statistics.median(cpu["help"]), 3),
        "load_average": os.getloadavg(),
        "imports_reference": imports_ref, "imports_help": imports_help,
        "phases_in_process": phase_figures,
    })


if __name__ == "__main__":
    main(sys.argv[1:])
