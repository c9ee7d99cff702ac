"""Numba's kernel cache is keyed by render/'s sources (render/_kernel_cache.py).

Numba re-validates a cached kernel against its own file only; kernels that inline helpers from
another file (volpath_kernels, bdpt_kernels and pssmlt's sampler from path_kernels; path_kernels
from sobol's table) would load stale machine code after an edit to that other file alone.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from render._kernel_cache import kernel_cache_dir, sources_digest

REPO = Path(__file__).resolve().parents[2]


def _tree(root: Path) -> None:
    (root / "integrators").mkdir(parents=True)
    (root / "integrators" / "path_kernels.py").write_text("def helper():\n    return 1\n")
    (root / "integrators" / "volpath_kernels.py").write_text("from .path_kernels import helper\n")


def test_an_edit_to_an_inlined_helpers_file_alone_changes_the_cache_folder(tmp_path):
    """Editing path_kernels.py (not volpath_kernels.py, which inlines it) changes the digest;
    rewriting the same bytes does not (a fresh clone reuses nothing stale, a touch recompiles nothing)."""
    root = tmp_path / "render"
    _tree(root)
    before = sources_digest(root)
    (root / "integrators" / "path_kernels.py").write_text("def helper():\n    return 1\n")
    assert sources_digest(root) == before
    (root / "integrators" / "path_kernels.py").write_text("def helper():\n    return 2\n")
    assert sources_digest(root) != before
    # a moved file with the same bytes is another tree too
    (root / "integrators" / "path_kernels.py").rename(root / "path_kernels.py")
    assert sources_digest(root) not in (before,)


def test_numba_reads_the_keyed_folder_in_a_fresh_process(tmp_path):
    """In a new process, importing render points numba's config at <base>/<digest of render/>,
    with a user's NUMBA_CACHE_DIR kept as the base."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    env.pop("LUMIGRAPH_NUMBA_CACHE_BASE", None)
    code = "import render, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout.strip()
    assert Path(out) == tmp_path / sources_digest()
    assert kernel_cache_dir().name == sources_digest()
