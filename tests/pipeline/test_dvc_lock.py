"""dvc.lock makes `dvc status` meaningful on a fresh clone (issue 18).

`make lock` (and `make demo` on the default scene) writes dvc.lock with `dvc commit` after a run of
the stages dvc.yaml wires. These tests check the committed lock describes the committed
dvc.yaml, and that what DVC hashes as a stage's code is the code only (not interpreter caches,
which differ between a fresh clone and the machine that wrote the lock).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]


def _substitute(value, params: dict):
    """dvc.yaml's ${a.b} templating with params.yaml's values."""
    def one(m):
        v = params
        for key in m.group(1).split("."):
            v = v[key]
        return str(v)
    return re.sub(r"\$\{([^}]+)\}", one, value) if isinstance(value, str) else value


def test_dvc_lock_describes_dvc_yaml():
    lock_file = REPO / "dvc.lock"
    if not lock_file.is_file():
        pytest.skip("no dvc.lock committed yet: `make lock` writes it (after the code it hashes has landed)")
    spec = yaml.safe_load((REPO / "dvc.yaml").read_text())
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    lock = yaml.safe_load(lock_file.read_text())
    assert set(lock["stages"]) == set(spec["stages"])
    for name, stage in spec["stages"].items():
        locked = lock["stages"][name]
        assert " ".join(locked["cmd"].split()) == " ".join(_substitute(stage["cmd"], params).split()), name
        assert sorted(d["path"] for d in locked.get("deps", [])) == sorted(_substitute(d, params) for d in stage["deps"])
        assert sorted(o["path"] for o in locked["outs"]) == sorted(_substitute(o, params) for o in stage["outs"])
        for key in stage.get("params", []):
            value = params
            for part in _substitute(key, params).split("."):
                value = value[part]
            assert locked["params"]["params.yaml"][key] == value, (name, key)


@pytest.mark.parametrize("path", ["render/__pycache__/camera.cpython-311.pyc", "rig/spec.pyc",
                                  "lumigraph.egg-info/PKG-INFO"])
def test_dvc_ignores_interpreter_caches_in_stage_code(path):
    dvc = Path(sys.executable).parent / "dvc"
    env = {**os.environ, "DVC_NO_ANALYTICS": "1"}
    r = subprocess.run([str(dvc), "check-ignore", path], cwd=REPO, capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, f"{path} is hashed as stage code: {r.stdout}{r.stderr}"
    r = subprocess.run([str(dvc), "check-ignore", "render/camera.py"], cwd=REPO, capture_output=True, text=True,
                       env=env, timeout=120)
    assert r.returncode == 1  # the code itself is not ignored
