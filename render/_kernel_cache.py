"""Numba's on-disk kernel cache, in a folder named by a hash of render/'s sources.

Numba invalidates a cached kernel when the file that defines it changes, not when a function
or a module-level array it compiles in from another file does: volpath_kernels, bdpt_kernels and
the pssmlt sampler inline path_kernels' helpers, and path_kernels freezes sobol's direction
table into its machine code. After an edit to one of those files alone, numba would load a
stale copy and render with the old code, silently. Keying the folder by every source under
render/ makes any edit start a fresh cache (the price: a recompile after any change to render/).

Imported first by render/__init__.py, before any kernel module is decorated. A user's
``NUMBA_CACHE_DIR`` is kept as the parent folder.
"""
from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

_RENDER = Path(__file__).resolve().parent


def sources_digest(root: Path = _RENDER) -> str:
    """12 hex digits of a SHA-1 over every ``*.py`` under ``root`` (relative path and bytes)."""
    h = hashlib.sha1()
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:12]


def kernel_cache_dir() -> Path:
    """The folder numba caches this tree's kernels in: ``$NUMBA_CACHE_DIR`` (or
    render/__pycache__/numba) / <sources digest>."""
    base = os.environ.get("LUMIGRAPH_NUMBA_CACHE_BASE") or os.environ.get("NUMBA_CACHE_DIR") \
        or str(_RENDER / "__pycache__" / "numba")
    return Path(base) / sources_digest()


def use_keyed_cache() -> Path:
    """Point numba's cache at :func:`kernel_cache_dir` (before numba is imported, through the
    environment; after, through numba.config, which the cache locator reads when a kernel is
    decorated). Returns the folder."""
    folder = kernel_cache_dir()
    os.environ.setdefault("LUMIGRAPH_NUMBA_CACHE_BASE", str(folder.parent))
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = str(folder)
    return folder
