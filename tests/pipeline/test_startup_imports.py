"""Start-up cost (issue 16): what the ``reference`` verb and ``--help`` import, checked in fresh
processes through ``sys.modules`` (timing is the benchmark's: bench/bench_startup.py).

* ``lumigraph reference cornell`` (a scene of quads, the path integrator) runs without torch,
  pyrender, dask, trimesh (and the networkx it pulls in), scipy.spatial / ndimage / stats / linalg
  (numba's BLAS probe, skipped: render._kernel_cache) or cv2, and scipy.linalg still imports after;
  importing ``render.integrators`` imports no integrator module (the registry is lazy) and the
  render imports only the one it uses.
* ``lumigraph --help`` imports none of rig, recon or numba.
* a scene the scene cache holds (rig/scene_cache.py) renders without pydantic, YAML or the
  schema (rig.spec, rig.build), to the same bytes as with the cache off.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: what the reference verb must not import (the packages the issue names, and what trimesh brings)
HEAVY = ("torch", "pyrender", "dask", "distributed", "trimesh", "networkx", "scipy.spatial", "scipy.ndimage",
         "scipy.stats", "cv2",
         # numba's BLAS probe imports it on the first kernel load unless render._kernel_cache skips it
         "scipy.linalg")

_REFERENCE = r"""
import json, sys
import render.integrators
after_package = sorted(m for m in sys.modules if m.startswith("render.integrators."))
from pipeline.cli import main
code = main(["reference", "cornell", "--spp", "1", "--size", "8", "8", "--integrator", "path", "--workers", "0",
             "--out", sys.argv[1], "-q"])
modules = sorted(sys.modules)
import scipy.linalg  # the skipped probe leaves it importable
print(json.dumps({"code": code, "after_package": after_package, "modules": modules}))
"""
_HELP = r"""
import json, sys
from pipeline.cli import main
code = main(["--help"])
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def _run(script: str, *args: str, **env: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", script, *args], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYOPENGL_PLATFORM": "egl", **env}, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_reference_imports_only_what_it_renders_with(tmp_path):
    out = _run(_REFERENCE, str(tmp_path / "reference"))
    assert out["code"] == 0
    assert out["after_package"] == ["render.integrators.choice", "render.integrators.prepared",
                                    "render.integrators.settings"], "the registry imported integrators eagerly"
    modules = set(out["modules"])
    assert sorted(m for m in HEAVY if m in modules) == []
    integrators = {"direct", "path", "volpath", "bdpt", "sppm", "pssmlt", "irradiance_cache"}
    assert {m.rpartition(".")[2] for m in modules if m.startswith("render.integrators.")} & integrators == {"path"}


def test_help_imports_no_stage():
    out = _run(_HELP)
    assert out["code"] == 0
    assert sorted(m for m in out["modules"] if m.split(".")[0] in ("rig", "recon", "numba", "torch")) == []


def test_a_cached_scene_renders_without_the_schema_to_the_same_bytes(tmp_path):
    cache = {"LUMIGRAPH_CACHE_DIR": str(tmp_path / "cache")}
    schema = ("pydantic", "yaml", "rig.spec", "rig.build")
    runs = {}
    for name, env in (("miss", cache), ("hit", cache), ("off", {**cache, "LUMIGRAPH_SCENE_CACHE": "0"})):
        out = _run(_REFERENCE, str(tmp_path / name), **env)
        assert out["code"] == 0
        runs[name] = sorted(m for m in schema if m in set(out["modules"]))
    assert runs == {"miss": sorted(schema), "hit": [], "off": sorted(schema)}
    for folder in ("linear", "variance"):
        hit = (tmp_path / "hit" / folder / "cornell_camera.exr").read_bytes()
        assert hit == (tmp_path / "off" / folder / "cornell_camera.exr").read_bytes()
        assert hit == (tmp_path / "miss" / folder / "cornell_camera.exr").read_bytes()
