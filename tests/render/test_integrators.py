"""The integrator package's contract: a plain registry, one options dataclass per integrator
(every field documented on its own line), options an integrator does not use refused naming
both, one type for ``heuristic``, and the compiled kernels' cache surviving the move."""
from __future__ import annotations

import ast
import inspect
import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest

from cornell_box import cornell_camera, cornell_scene
from render import integrators
from render.integrators import INTEGRATOR_EFFECTS, INTEGRATOR_OPTIONS, INTEGRATORS, RenderSettings, prepare, render
from render.integrators.settings import OPTION_NAMES

#: the options each integrator reads (what its module documents)
USES = {
    "direct": {"strategy", "heuristic", "sampler"},
    "path": {"roulette", "rr_depth", "strategy", "heuristic", "sampler"},
    "volpath": {"roulette", "rr_depth", "strategy", "heuristic", "sampler"},
    "bdpt": {"roulette", "rr_depth", "heuristic"},
    "sppm": {"photons_per_pass"},
    "pssmlt": {"heuristic", "roulette", "rr_depth"},
    "irradiance_cache": {"error_bound", "record_rays", "min_spacing", "max_spacing", "lookup_spp", "cache_direct", "roulette",
                         "rr_depth", "heuristic"},
}
VALUES = {"roulette": False, "rr_depth": 1, "strategy": "light", "heuristic": "balance", "photons_per_pass": 10,
          "sampler": "independent"}


def test_registry_is_one_table_of_modules():
    assert set(INTEGRATORS) == set(INTEGRATOR_EFFECTS) == set(INTEGRATOR_OPTIONS) == set(USES)
    for name, module in INTEGRATORS.items():
        assert module.__name__ == f"render.integrators.{name}"
        assert INTEGRATOR_OPTIONS[name] is module.Options and callable(module.render_result)
    assert {n for n, m in INTEGRATORS.items() if getattr(m, "GROUPS", None)} == {"sppm", "pssmlt", "irradiance_cache"}


@pytest.mark.parametrize("name", sorted(USES))
def test_options_fields_and_their_documentation(name):
    """Each Options has exactly the options its integrator reads, each field with a ``#:`` line
    above it, and ``heuristic`` (wherever it exists) is the string "power" by default."""
    opts = INTEGRATOR_OPTIONS[name]
    assert {f.name for f in fields(opts)} == USES[name]
    lines, _ = inspect.getsourcelines(opts)
    cls = ast.parse("".join(lines)).body[0]
    for node in cls.body:
        if isinstance(node, ast.AnnAssign):
            assert lines[node.lineno - 2].strip().startswith("#:"), f"{name}.Options.{node.target.id} undocumented"
    if "heuristic" in USES[name]:
        assert opts().heuristic == "power"
        with pytest.raises(ValueError, match="heuristic"):
            opts(heuristic=2.0)


@pytest.mark.parametrize("name", sorted(USES))
def test_unused_options_are_refused_naming_option_and_integrator(name):
    for option in OPTION_NAMES:
        st = RenderSettings(integrator=name, **{option: VALUES[option]})
        if option in USES[name]:
            assert getattr(st.options(name, INTEGRATOR_OPTIONS[name]), option) == VALUES[option]
        else:
            with pytest.raises(ValueError, match=rf"option '{option}' is not used by integrator '{name}'"):
                st.options(name, INTEGRATOR_OPTIONS[name])


def test_render_refuses_unused_options_before_rendering():
    """Through render(): photons_per_pass given to the integrator auto picks (path on the Cornell
    box), strategy to bdpt and pssmlt (formerly ignored silently)."""
    sc, cam = cornell_scene(), cornell_camera(4, 4)
    ps = prepare(sc, threads=1)
    for st, name in ((RenderSettings(photons_per_pass=10), "path"), (RenderSettings(integrator="bdpt", strategy="mis"), "bdpt"),
                     (RenderSettings(integrator="pssmlt", strategy="bsdf"), "pssmlt")):
        with pytest.raises(ValueError, match=f"is not used by integrator '{name}'"):
            render(sc, cam, st, prepared=ps)
    assert render(sc, cam, RenderSettings(spp=1, strategy="light", threads=1), prepared=ps).integrator == "path"


def test_kernel_cache_loads_in_a_second_process():
    """numba's on-disk cache of the compiled kernels (cache=True) still works in their new home:
    a second process loads shade_bounce and sample_camera_rays from it instead of compiling them
    (the JIT kernels: LUMIGRAPH_AOT=0, else the ahead-of-time extension of render.path_aot renders)."""
    probe = (
        "import sys; sys.path.insert(0, 'tests/render')\n"
        "from cornell_box import cornell_camera, cornell_scene\n"
        "from render.integrators import RenderSettings, render, path_kernels as pk\n"
        "render(cornell_scene(), cornell_camera(4, 4), RenderSettings(integrator='path', spp=1, threads=1))\n"
        "print(sum(sum(getattr(pk, f).stats.cache_hits.values()) for f in ('shade_bounce', 'sample_camera_rays')),"
        " sum(sum(getattr(pk, f).stats.cache_misses.values()) for f in ('shade_bounce', 'sample_camera_rays')))\n")
    root = Path(integrators.__file__).resolve().parents[2]
    env = {**os.environ, "LUMIGRAPH_AOT": "0"}
    runs = [subprocess.run([sys.executable, "-c", probe], cwd=root, capture_output=True, text=True, timeout=600,
                           env=env) for _ in range(2)]
    assert all(r.returncode == 0 for r in runs), runs[-1].stderr[-2000:]
    hits, misses = map(int, runs[1].stdout.split())
    assert (hits, misses) == (2, 0)


def test_reference_help_names_every_registered_integrator():
    """The CLI's --integrator help is written out by hand (importing the registry at start-up would
    load the compiled kernels for every verb): it must name exactly auto and the registry's keys."""
    import re

    from render.integrators import INTEGRATORS
    out = subprocess.run([sys.executable, "-m", "pipeline", "reference", "--help"], capture_output=True, text=True,
                         env={**os.environ, "COLUMNS": "400"}, timeout=120)
    assert out.returncode == 0, out.stderr
    text = " ".join(out.stdout.split())
    listed = re.search(r"auto \(from the scene's effects\) ((?:\| \w+ ?)+)", text)
    assert listed, text
    assert set(re.findall(r"\| (\w+)", listed.group(1))) == set(INTEGRATORS)
