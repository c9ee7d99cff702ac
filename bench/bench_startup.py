"""Start-up cost of the ``reference`` command against ``lumigraph --help``, measured in one run.

Figures (bench/results/startup.json; shared, noisy machines: medians and ratios, never absolute
thresholds):

* whole-process wall time, median of N interleaved runs each, of ``lumigraph --help`` and of
  ``lumigraph reference cornell --spp 1 --size 32 32`` (the issue's command), and their ratio
  (goal: <= 1.2);
* what the ``reference`` verb imports (``python -X importtime``): the heavy packages present
  (torch, pyrender, dask, trimesh, scipy.spatial must not be: tests/pipeline/test_startup_imports.py),
  and the largest cumulative imports;
* the phases of the same work in one process: imports, scene load, scene preparation (BVH,
  materials, lights), first render (compiled kernels loaded from numba's cache), a second
  render, their difference (the kernel-cache load), and numba's cache hits / misses per kernel
  (a miss means compilation on first use).

Run: ``.venv/bin/python -m bench.bench_startup`` (``--quick``: 2 runs each instead of 7).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.common import write_result

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "pyrender", "dask", "distributed", "trimesh", "networkx", "scipy", "scipy.spatial", "scipy.ndimage",
         "scipy.stats", "numba", "cv2", "pydantic", "OpenGL", "recon")

_PHASES = r"""
import json, time
t0 = time.perf_counter()
from render.integrators import RenderSettings, prepare, render
from rig.build import load_scene
t1 = time.perf_counter()
rig = load_scene("cornell")
cam = rig.cameras["scene"][0]
from pipeline.stages.reference import resize_camera
cam = resize_camera(cam, 32, 32)
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


def _env() -> dict:
    return {**os.environ, "PYOPENGL_PLATFORM": "egl"}


def _timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
    return elapsed


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


def main(argv: list[str]) -> None:
    runs = 2 if "--quick" in argv else 7
    lumigraph = [sys.executable, "-m", "pipeline"]
    with tempfile.TemporaryDirectory() as tmp:
        reference = [*lumigraph, "reference", "cornell", "--spp", "1", "--size", "32", "32", "--out",
                     str(Path(tmp) / "reference"), "--overwrite", "-q"]
        help_cmd = [*lumigraph, "--help"]
        _timed(reference)  # warm the OS file cache and numba's cache (a fresh checkout compiles here)
        help_s, ref_s = [], []
        for _ in range(runs):  # interleaved: both see the same machine load
            help_s.append(_timed(help_cmd))
            ref_s.append(_timed(reference))
        imports_ref = _imports(["-m", "pipeline", "reference", "cornell", "--spp", "1", "--size", "32", "32", "--out",
                                str(Path(tmp) / "reference"), "--overwrite", "-q"])
        imports_help = _imports(["-m", "pipeline", "--help"])
    phases = subprocess.run([sys.executable, "-c", _PHASES], cwd=ROOT, env=_env(), capture_output=True, text=True)
    phase_figures = json.loads(phases.stdout.strip().splitlines()[-1]) if phases.returncode == 0 else {
        "error": phases.stderr.strip()[-500:]}
    help_med, ref_med = statistics.median(help_s), statistics.median(ref_s)
    write_result("startup", {
        "runs": runs,
        "command": "lumigraph reference cornell --spp 1 --size 32 32 (against lumigraph --help)",
        "help_median_s": round(help_med, 3), "reference_median_s": round(ref_med, 3),
        "ratio_reference_to_help": round(ref_med / help_med, 3), "goal_ratio": 1.2,
        "help_runs_s": [round(t, 3) for t in help_s], "reference_runs_s": [round(t, 3) for t in ref_s],
        "load_average": os.getloadavg(),
        "imports_reference": imports_ref, "imports_help": imports_help,
        "phases_in_process": phase_figures,
    })


if __name__ == "__main__":
    main(sys.argv[1:])
