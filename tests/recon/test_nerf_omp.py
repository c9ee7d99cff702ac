"""OpenMP's wait policy for the NeRF entry points (recon/nerf/omp.py): set before torch loads
OpenMP, a user's own policy kept, and reported as not in effect when torch came first. Each case
runs in a fresh interpreter (libgomp reads the variable once, when it is loaded)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

_PROBE = """
import json, os, sys
{before}
from recon.nerf.omp import openmp_loaded
loaded_before = openmp_loaded()
{entry}
import torch
print(json.dumps({{"policy": POLICY, "env": os.environ.get("OMP_WAIT_POLICY"), "loaded_before": loaded_before,
                  "loaded_after": openmp_loaded()}}))
"""


def _run(before: str, entry: str, user_policy: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if user_policy is not None:
        env["OMP_WAIT_POLICY"] = user_policy
    env["PYTHONPATH"] = str(ROOT)
    out = subprocess.run([sys.executable, "-c", _PROBE.format(before=before, entry=entry)], env=env, cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_nerf_stage_sets_passive_wait_before_torch_loads_openmp():
    """Importing the stage module (what ``lumigraph nerf`` does first) sets PASSIVE while OpenMP
    is not yet mapped, and torch then maps it (so the variable was read)."""
    got = _run("", "from pipeline.stages.nerf import OMP_WAIT_POLICY as POLICY", None)
    assert got == {"policy": "PASSIVE", "env": "PASSIVE", "loaded_before": False, "loaded_after": True}


@pytest.mark.parametrize("user", ["active", "PASSIVE"])
def test_users_own_policy_is_kept(user):
    got = _run("", "from recon.nerf.omp import passive_omp_wait; POLICY = passive_omp_wait()", user)
    assert got["env"] == user and got["policy"] == user.upper()


def test_policy_reported_not_in_effect_when_torch_loaded_first():
    """torch imported first: OpenMP already read its (unset) variable; nothing is set, and the
    stage says so (metrics.json's omp_wait_policy) instead of claiming PASSIVE."""
    got = _run("import torch", "from recon.nerf.omp import passive_omp_wait; POLICY = passive_omp_wait()", None)
    assert got["loaded_before"] is True
    assert got["env"] is None and got["policy"].startswith("default")
