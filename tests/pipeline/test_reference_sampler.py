"""`lumigraph reference --sampler` through the real process: the sampler recorded in the manifest,
bad values and integrators that do not read it refused (exit 2, one stderr line naming the
option, nothing written)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from render.image_io import read_exr


def _reference(out, *extra, spp="16"):
    return subprocess.run([sys.executable, "-m", "pipeline", "reference", "cornell", "--views", "scene", "--spp", spp,
                           "--size", "8", "8", "--out", str(out), "--quiet", *extra],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("extra,rendered,max_depth", [([], 104, 64), (["--sampler", "independent"], 100, 64),
                                                       (["--sampler", "sobol", "--max-depth", "5"], 104, 5),
                                                       (["--integrator", "bdpt"], 100, 8)])
def test_spp_rounds_up_to_whole_nets_and_max_depth_follows_the_integrator(tmp_path, extra, rendered, max_depth):
    """--spp 100 under a Sobol sampler renders 104 (a multiple of 8: whole nets,
    render.sobol.stratified_spp), says so on stdout and records both counts; the independent
    sampler and integrators without a sampler render what was asked. Without --max-depth, path
    goes to 64 bounces (roulette ends it) and bdpt to 8."""
    out = tmp_path / "reference"
    proc = _reference(out, *extra, spp="100")
    assert proc.returncode == 0, proc.stderr
    params = json.loads((out / "manifest.json").read_text())["params"]
    assert (params["spp"], params["spp_requested"], params["max_depth"]) == (rendered, 100, max_depth)
    assert f"at {rendered} spp" in proc.stdout and (("100 asked" in proc.stdout) == (rendered != 100)), proc.stdout


@pytest.mark.parametrize("integrator,samplers", [("path", (None, "independent", "sobol")),
                                                  ("volpath", (None, "independent"))])
def test_sampler_is_recorded_and_changes_the_render(tmp_path, integrator, samplers):
    """path and volpath read --sampler (issue 16: sobol-blocks the default of both): recorded in the
    manifest with its replicates, and every other sampler gives other bytes."""
    runs = {}
    for sampler in samplers:
        out = tmp_path / (sampler or "default") / "reference"
        proc = _reference(out, "--integrator", integrator, *(["--sampler", sampler] if sampler else []))
        assert proc.returncode == 0, proc.stderr
        manifest = json.loads((out / "manifest.json").read_text())
        assert manifest["params"]["sampler"] == (sampler or "sobol-blocks")
        # the variance image's degrees of freedom (validate's thresholds): none for independent
        assert manifest["params"]["replicates"] == (None if sampler == "independent" else 4)
        runs[sampler] = read_exr(next((out / "linear").glob("*.exr")))
        assert np.all(np.isfinite(runs[sampler]))
    assert all(not np.array_equal(runs[None], runs[s]) for s in samplers if s is not None)


@pytest.mark.parametrize("extra,names", [(["--sampler", "halton"], ["--sampler", "halton"]),
                                         (["--sampler", "sobol", "--integrator", "bdpt"], ["--sampler", "bdpt"])])
def test_bad_or_unused_sampler_exits_2_with_one_line(tmp_path, extra, names):
    out = tmp_path / "reference"
    proc = _reference(out, *extra)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and all(n in lines[0] for n in names), lines
    assert not out.exists() and not any(tmp_path.glob(".reference.partial-*"))
