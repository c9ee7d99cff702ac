"""The path tracer's ahead-of-time kernels (render.path_aot, built by render.path_aot_build).

* renders through the extension are the same bytes as through numba's JIT kernels (path under
  each sampler, light-only and BSDF-only, two threads; direct), each side in its own process;
* what the extension exports is what the JIT dispatchers compile for the same renders;
* a missing, stale or broken extension, and ``LUMIGRAPH_AOT=0``, fall back to the JIT kernels,
  and so does a packed scene or rays of other types than those exported;
* with the extension, a fresh ``lumigraph reference cornell`` imports no numba (issue 16).

The extension is this tree's (built by `make setup`); when it is missing the module builds it
once (about 20 s with numba's cache warm).
"""
from __future__ import annotations

import json
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from render import path_aot
from render.integrators.path_types import example_kernel_scene
from render.path_aot_build import SIGNATURES, build

ROOT = Path(__file__).resolve().parents[2]

_RENDERS = r"""
import json, sys
import numpy as np
sys.path.insert(0, "tests/render")
from cornell_box import cornell_camera, cornell_scene
from render import path_aot
from render.integrators import RenderSettings, render
from render.path_aot_build import _tiny_scene

k = path_aot.kernels()
scenes = ((cornell_scene(), cornell_camera(12, 10), None), _tiny_scene() + ({"interreflection"},))
fx = {"direct", "soft_shadows", "shadows", "specular"}
configs = [("path", 2, {"sampler": "sobol-blocks"}), ("path", 1, {"sampler": "sobol"}),
           ("path", 1, {"sampler": "independent"}), ("path", 1, {"strategy": "light"}),
           ("path", 2, {"strategy": "bsdf", "sampler": "sobol"}), ("direct", 1, {}),
           ("direct", 2, {"strategy": "light"})]
out = {}
for i, (integrator, threads, options) in enumerate(configs):
    for j, (scene, camera, extra) in enumerate(scenes):
        effects = None if extra is None and integrator == "path" else fx | (extra if integrator == "path" else set())
        r = render(scene, camera, RenderSettings(integrator=integrator, spp=8, threads=threads, batch_paths=100,
                                                 **options), effects=effects)
        out[f"{integrator}{i}-{j}-mean"], out[f"{integrator}{i}-{j}-var"] = r.mean, r.variance
np.savez(sys.argv[1], **out)
sigs = {}
if not k.aot:
    for name in path_aot.KERNELS:
        d = getattr(k, name)
        sigs[name] = [repr((tuple(s), d.overloads[s].signature.return_type)) for s in d.signatures]
print(json.dumps({"aot": k.aot, "origin": k.origin, "numba": "numba" in sys.modules, "sigs": sigs}))
"""


def _run(script: str, *args: str, **env) -> dict:
    proc = subprocess.run([sys.executable, "-c", script, *args], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYOPENGL_PLATFORM": "egl", **env}, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def extension() -> Path:
    """This tree's extension folder (built here when `make setup` has not)."""
    folder = path_aot.extension_dir()
    if not any(folder.glob(path_aot.MODULE + ".*")):
        assert build(quiet=True) == 0, "render.path_aot_build failed"
    return folder


def test_aot_renders_the_jit_bytes_and_exports_the_dispatchers_signatures(extension, tmp_path):
    aot = _run(_RENDERS, str(tmp_path / "aot.npz"))
    jit = _run(_RENDERS, str(tmp_path / "jit.npz"), LUMIGRAPH_AOT="0")
    assert aot["aot"] and Path(aot["origin"]).parent == extension and not aot["numba"], aot
    assert not jit["aot"] and jit["numba"]
    a, j = np.load(tmp_path / "aot.npz"), np.load(tmp_path / "jit.npz")
    assert sorted(a.files) == sorted(j.files) and len(a.files) == 28
    different = [f for f in a.files if a[f].tobytes() != j[f].tobytes()]
    assert different == [], different
    assert all(np.isfinite(a[f]).all() for f in a.files) and a["path0-0-mean"].mean() > 0
    # one signature per kernel over every render above, and it is the exported one
    exported = pickle.loads((extension / SIGNATURES).read_bytes())
    assert {n: [repr(s)] for n, s in exported.items()} == jit["sigs"]


def test_missing_stale_broken_or_disabled_falls_back_to_jit(extension, tmp_path, monkeypatch):
    so = next(extension.glob(path_aot.MODULE + ".*"))
    monkeypatch.setattr(path_aot, "kernel_cache_dir", lambda: tmp_path)
    key = path_aot.build_key()
    assert path_aot._load_aot() is None  # missing
    good = tmp_path / f"aot-{key}"
    good.mkdir()
    shutil.copy(so, good / so.name)
    loaded = path_aot._load_aot()
    assert loaded is not None and loaded.aot and set(path_aot.KERNELS) <= set(vars(loaded))
    monkeypatch.setenv("LUMIGRAPH_AOT", "0")
    assert path_aot._load_aot() is None  # disabled
    monkeypatch.delenv("LUMIGRAPH_AOT")
    # stale: a build for other sources (its key marker is not this tree's)
    monkeypatch.setattr(path_aot, "build_key", lambda digest=None: "0123456789abcdef")
    stale = tmp_path / "aot-0123456789abcdef"
    stale.mkdir()
    shutil.copy(so, stale / so.name)
    assert path_aot._load_aot() is None
    # broken: a file that is no extension (and nothing imported under its name yet)
    monkeypatch.delitem(sys.modules, path_aot.MODULE, raising=False)
    (stale / so.name).write_bytes(b"not an ELF file")
    assert path_aot._load_aot() is None
    monkeypatch.delitem(sys.modules, path_aot.MODULE, raising=False)
    monkeypatch.setattr(path_aot, "_KERNELS", None)
    assert path_aot.kernels().aot is False  # and what renders then is numba's
    assert path_aot.kernels() is path_aot.jit_kernels()


def test_other_array_types_go_to_the_jit_kernels(extension, monkeypatch):
    """pycc's wrappers check no types: a packed scene or rays of other dtypes, ranks or layouts
    than the exported ones are handed to numba's kernels instead."""
    fake = path_aot.jit_kernels().__class__(aot=True, origin="test")
    monkeypatch.setattr(path_aot, "_KERNELS", fake)
    ks = example_kernel_scene()
    assert path_aot.for_scene(ks) is fake
    assert path_aot.for_scene(ks._replace(tex_data=np.zeros(1))) is path_aot.jit_kernels()  # float64, not float32
    assert path_aot.for_scene(ks._replace(tri=np.zeros((12, 2)).T)) is path_aot.jit_kernels()  # not C-contiguous
    o = np.zeros((4, 3), np.float32)
    assert path_aot.rays_ok(o, o, np.zeros(4, np.float32))
    assert not path_aot.rays_ok(o.astype(np.float64), o)
    assert not path_aot.rays_ok(np.zeros((3, 4), np.float32).T, o)


def test_reference_with_the_extension_imports_no_numba(extension, tmp_path):
    script = r"""
import json, sys
from pipeline.cli import main
code = main(["reference", "cornell", "--spp", "1", "--size", "32", "32", "--out", sys.argv[1], "-q"])
from render import path_aot
jit_modules = sorted(m for m in sys.modules if m.split(".")[0] in ("numba", "llvmlite"))
print(json.dumps({"code": code, "aot": path_aot.kernels().aot, "numba": jit_modules}))
"""
    out = _run(script, str(tmp_path / "ref"))
    assert out == {"code": 0, "aot": True, "numba": []}
    # README's switch: LUMIGRAPH_AOT=0 renders with numba's kernels, the same bytes
    off = _run(script, str(tmp_path / "ref_jit"), LUMIGRAPH_AOT="0")
    assert off["code"] == 0 and off["aot"] is False and "numba" in off["numba"]
    exrs = sorted((tmp_path / "ref" / "linear").glob("*.exr"))
    assert exrs and all(f.read_bytes() == (tmp_path / "ref_jit" / "linear" / f.name).read_bytes() for f in exrs)
