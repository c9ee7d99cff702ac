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


_import_digest: str | None = None


def render_digest() -> str:
    """render/'s :func:`sources_digest` as this process first read it (when render was imported):
    numba's cache folder, the AOT extension's key and the scene cache's all name that tree, and
    it is read once (~6 ms) instead of by each."""
    global _import_digest
    if _import_digest is None:
        _import_digest = sources_digest()
    return _import_digest


def kernel_cache_dir() -> Path:
    """The folder numba caches this tree's kernels in: ``$NUMBA_CACHE_DIR`` (or
    render/__pycache__/numba) / <sources digest>."""
    base = os.environ.get("LUMIGRAPH_NUMBA_CACHE_BASE") or os.environ.get("NUMBA_CACHE_DIR") \
        or str(_RENDER / "__pycache__" / "numba")
    return Path(base) / render_digest()


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


def skip_numba_blas_probe() -> None:
    """Spare every process that loads a kernel numba's BLAS probe (about 0.2 s of CPU, a fifth of
    numba's fixed cost: bench/bench_startup.py): when numba first loads or compiles a kernel it
    imports ``numba.np.arraymath``, whose module-level ``_check_blas`` imports ``scipy.linalg``
    (and through it scipy's array-API layer) only to decide whether ``np.correlate`` /
    ``np.convolve`` inside jitted code take BLAS's dot or a plain loop. No kernel of ours calls
    them, so the probe is made to fail (``scipy.linalg`` blocked in ``sys.modules`` while
    ``numba.np.arraymath`` is imported, then unblocked); np.dot and np.linalg in jitted code are
    unaffected (they check BLAS when typed). Call it from the main thread, as the kernel modules
    are imported (another thread importing scipy.linalg in that window would fail); a no-op
    when numba.np.arraymath or scipy.linalg is already imported."""
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return
    sys.modules["scipy.linalg"] = None  # an import of it raises ImportError: the probe answers "no BLAS"
    try:
        import numba.np.arraymath  # noqa: F401  (the probe runs here, once per process)
    finally:
        del sys.modules["scipy.linalg"]
