"""`python -m pipeline.warm_kernels` (run by `make setup`): every integrator compiled ahead of use."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pipeline.warm_kernels import MARKER, WARM_RENDERS
from render._kernel_cache import sources_digest
from render.integrators import INTEGRATORS

REPO = Path(__file__).resolve().parents[2]


def test_every_registered_integrator_is_warmed():
    """A new integrator added to the registry without a warm-up render fails here (its first
    user would wait for numba instead)."""
    assert sorted(i for _, i in WARM_RENDERS) == sorted(INTEGRATORS)


def test_a_warm_tree_is_a_no_op_through_the_process(tmp_path):
    """With the marker in this tree's cache folder the command renders nothing and exits 0 at once;
    the folder it reads is <base>/<digest of render/>."""
    folder = tmp_path / sources_digest()
    folder.mkdir()
    (folder / MARKER).write_text("path 1.0\n")
    env = {**os.environ, "LUMIGRAPH_NUMBA_CACHE_BASE": str(tmp_path), "LUMIGRAPH_AOT": "0"}  # no AOT build
    r = subprocess.run([sys.executable, "-m", "pipeline.warm_kernels"], cwd=REPO, env=env, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "already compiled" in r.stdout and str(folder) in r.stdout


def test_only_a_subset_and_its_markers_through_the_process(tmp_path):
    """``--only path`` with path's own marker present is a no-op naming nothing to compile; an
    unknown name exits 2 with one line naming it; without ``--only`` the missing rest is what
    would be compiled (checked by a marker for every integrator: then a no-op)."""
    folder = tmp_path / sources_digest()
    folder.mkdir()
    (folder / f"{MARKER}.path").write_text("path 1.0\n")
    env = {**os.environ, "LUMIGRAPH_NUMBA_CACHE_BASE": str(tmp_path), "LUMIGRAPH_AOT": "0"}  # no AOT build
    run = lambda *a: subprocess.run([sys.executable, "-m", "pipeline.warm_kernels", *a], cwd=REPO, env=env,
                                    capture_output=True, text=True, timeout=60)
    r = run("--only", "path")
    assert r.returncode == 0 and "already compiled" in r.stdout, r.stdout + r.stderr
    r = run("--only", "path,nope")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "nope" in r.stderr and not r.stdout
    for _, i in WARM_RENDERS:
        (folder / f"{MARKER}.{i}").write_text(f"{i} 1.0\n")
    r = run()
    assert r.returncode == 0 and "already compiled" in r.stdout, r.stdout + r.stderr


def test_lumigraph_run_compiles_the_reference_kernels_beside_the_capture(tmp_path, monkeypatch):
    """``lumigraph run`` starts ``warm_kernels --only NAME`` in the background for the integrator
    the reference stage will choose (direct on the default scene, volpath on a foggy one) when that
    integrator's marker is missing, and starts nothing once the marker is there."""
    from pipeline.pipeline_run import warm_reference_kernels
    from rig.build import load_scene

    monkeypatch.setenv("LUMIGRAPH_NUMBA_CACHE_BASE", str(tmp_path))
    for scene, chosen in (("turntable", "direct"), ("cornell_fog", "volpath")):
        rig = load_scene(scene)
        proc = warm_reference_kernels(rig)
        try:
            assert proc is not None and proc.args[-2:] == ["--only", chosen], proc and proc.args
        finally:
            if proc is not None:
                proc.kill()
                proc.wait()
        folder = tmp_path / sources_digest()
        folder.mkdir(exist_ok=True)
        (folder / f"{MARKER}.{chosen}").write_text(f"{chosen} 1.0\n")
        assert warm_reference_kernels(rig) is None
    (folder / f"{MARKER}.volpath").unlink()
    (folder / MARKER).write_text("all 1.0\n")  # `make setup`'s marker: every integrator warm
    assert warm_reference_kernels(rig) is None


def test_setup_builds_the_aot_extension_and_survives_its_failure(tmp_path, monkeypatch, capsys):
    """Without ``--only`` (make setup) the path tracer's ahead-of-time extension is built after the
    kernels are warm; a failed build (or one that raises) leaves the exit status 0; LUMIGRAPH_AOT=0
    and ``--only`` skip it."""
    import pipeline.warm_kernels as wk

    folder = tmp_path / sources_digest()
    folder.mkdir()
    (folder / MARKER).write_text("all 1.0\n")
    monkeypatch.setenv("LUMIGRAPH_NUMBA_CACHE_BASE", str(tmp_path))
    monkeypatch.setattr(wk, "warm_nerf_march", lambda: 0.0)
    calls = []
    for outcome in (0, 1, RuntimeError("no compiler")):
        def fake_build(outcome=outcome):
            calls.append(outcome)
            if isinstance(outcome, Exception):
                raise outcome
            return outcome
        monkeypatch.setattr(wk, "build_aot", fake_build)
        assert wk.main([]) == 0
    assert calls[0] == 0 and calls[1] == 1 and len(calls) == 3
    assert capsys.readouterr().err.count("JIT ones will be used") == 2
    assert wk.main(["--only", "path"]) == 0 and len(calls) == 3
    monkeypatch.setenv("LUMIGRAPH_AOT", "0")
    assert wk.main([]) == 0 and len(calls) == 3
