"""`python -m pipeline.warm_kernels` (run by `make setup`) compiles the NeRF's held-out march
(recon/nerf/march_kernels.py) into the tree's kernel cache, where the nerf stage then loads it."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pipeline.warm_kernels import MARKER
from render._kernel_cache import sources_digest

REPO = Path(__file__).resolve().parents[2]


def test_warm_kernels_compiles_the_nerf_march_into_the_tree_cache(tmp_path):
    """With every integrator already warm (the marker present) the command still warms the march:
    its cached kernel appears in <base>/<digest of render/>, the folder the stage's processes use
    (render/ points numba there), and a second run loads it (no second compiled copy)."""
    folder = tmp_path / sources_digest()
    folder.mkdir()
    (folder / MARKER).write_text("path 1.0\n")
    env = {**os.environ, "LUMIGRAPH_NUMBA_CACHE_BASE": str(tmp_path)}
    for _ in range(2):
        r = subprocess.run([sys.executable, "-m", "pipeline.warm_kernels"], cwd=REPO, env=env, capture_output=True,
                           text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        assert "nerf march kernel ready" in r.stdout and "already compiled" in r.stdout, r.stdout
        compiled = list(folder.rglob("march_kernels._march_range-*.nbc"))
        assert len(compiled) == 1 and list(folder.rglob("march_kernels._march_range-*.nbi")), compiled
