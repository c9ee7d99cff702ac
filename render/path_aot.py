"""The path tracer's kernels compiled ahead of time (numba.pycc), or the JIT ones: :func:`kernels`.

A fresh process that renders with ``path`` or ``direct`` used to spend about half a second on
numba alone (its import, target initialisation, loading the cached kernels) before tracing a
ray. `make setup` (pipeline/warm_kernels.py, :mod:`render.path_aot_build`) compiles the same
kernels (``sample_camera_rays``, ``shade_bounce``, ``last_bounce_queue``, ``add_unoccluded``,
``accumulate``, ``accumulate_replicates`` of :mod:`render.integrators.path_kernels`,
``intersect_many``, ``occluded_many`` of :mod:`render.embree_direct`: same Python source, same
flags) into a CPython extension that imports without numba. When a build matching this tree is
there, :func:`kernels` returns its functions; otherwise, or with ``LUMIGRAPH_AOT=0``, the JIT
dispatchers. Renders are the same bytes either way (tests/render/test_path_aot.py).

The extension lives in :func:`render._kernel_cache.kernel_cache_dir` (keyed by render/'s
sources: any edit leaves it behind) under ``aot-<key>``, the key hashing those sources with the
numpy, numba and Python versions and the CPU's features; the module exports ``key_<key>``,
checked before use. Any failure to find, import or verify it falls back to JIT, silently.

pycc's wrappers check no types: an argument of another dtype, rank or layout than the one
exported is read as if it were the exported one. The call sites (render.integrators.path,
render.accel) make every array themselves with the exported types; :func:`for_scene` and
:func:`rays_ok` still check what comes from elsewhere (a scene's packed arrays, caller rays) and
hand those to the JIT kernels when they differ.
"""
from __future__ import annotations

import glob
import hashlib
import os
import platform
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ._kernel_cache import kernel_cache_dir, render_digest

__all__ = ["KERNELS", "MODULE", "build_key", "extension_dir", "kernels", "jit_kernels", "for_scene", "rays_ok"]

#: the extension's module name (its file: MODULE + the interpreter's extension suffix)
MODULE = "lumigraph_path_aot"
#: what the extension exports besides its key marker
KERNELS = ("sample_camera_rays", "shade_bounce", "last_bounce_queue", "add_unoccluded", "accumulate",
           "accumulate_replicates", "intersect_many", "occluded_many")


def _numba_version() -> str:
    """The installed numba's version, read from its dist-info folder (importing numba is what the
    extension avoids)."""
    for entry in sys.path:
        hits = sorted(glob.glob(os.path.join(entry or ".", "numba-*.dist-info")))
        if hits:
            return os.path.basename(hits[-1])[len("numba-"):-len(".dist-info")]
    return "none"


def _cpu() -> str:
    """The machine and its CPU's feature flags (the extension is compiled for the host CPU)."""
    flags = ""
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((ln for ln in f if ln.startswith(("flags", "Features"))), "")
    except OSError:
        pass
    return platform.machine() + " " + " ".join(sorted(flags.partition(":")[2].split()))


def build_key(digest: str | None = None) -> str:
    """16 hex digits over render/'s sources digest, the numpy, numba and Python versions and the CPU."""
    parts = (digest or render_digest(), np.__version__, _numba_version(), sys.version, sys.platform, _cpu())
    return hashlib.sha1("\n".join(parts).encode()).hexdigest()[:16]


def extension_dir(key: str | None = None) -> Path:
    """The folder this tree's extension is built into: <kernel cache folder>/aot-<key>."""
    return kernel_cache_dir() / f"aot-{key or build_key()}"


def _load_aot() -> SimpleNamespace | None:
    """The extension's kernels, or None (disabled, missing, stale, or not importable)."""
    if os.environ.get("LUMIGRAPH_AOT", "1").strip() == "0":
        return None
    try:
        from . import embree_lib

        if not embree_lib.AVAILABLE:  # its rtcIntersect8 / rtcOccluded8 resolve in embreex's libembree4
            return None
        key = build_key()
        folder = str(extension_dir(key))
        if not glob.glob(os.path.join(folder, MODULE + ".*")):
            return None
        module = sys.modules.get(MODULE)
        if module is None:
            sys.path.insert(0, folder)
            try:
                import lumigraph_path_aot as module
            finally:
                sys.path.remove(folder)
        if not hasattr(module, "key_" + key):  # built for other sources or versions
            return None
        return SimpleNamespace(aot=True, origin=module.__file__, **{k: getattr(module, k) for k in KERNELS})
    except Exception:  # ImportError, a missing symbol, a broken file: the JIT kernels render the same
        return None


_JIT = None
_KERNELS = None


def jit_kernels() -> SimpleNamespace:
    """The numba dispatchers of the same kernels (imports numba)."""
    global _JIT
    if _JIT is None:
        from . import embree_direct
        from .integrators import path_kernels as pk

        _JIT = SimpleNamespace(aot=False, origin="numba", intersect_many=embree_direct.intersect_many,
                               occluded_many=embree_direct.occluded_many,
                               **{k: getattr(pk, k) for k in KERNELS[:6]})
    return _JIT


def kernels() -> SimpleNamespace:
    """The kernels this process renders with (loaded once): the extension's when a build for this
    tree is there and ``LUMIGRAPH_AOT`` is not 0, else :func:`jit_kernels`. Attributes: the
    :data:`KERNELS`, ``aot`` (bool) and ``origin`` (the extension's file, or "numba")."""
    global _KERNELS
    if _KERNELS is None:
        _KERNELS = _load_aot() or jit_kernels()
    return _KERNELS


def _layout(a) -> tuple:
    return (a.dtype.str, a.ndim, bool(a.flags.c_contiguous))


def _scene_layout() -> tuple:
    """The exported KernelScene's (dtype, rank, contiguity) per field; () when it cannot be made
    (then no scene matches and the JIT kernels render)."""
    try:
        from .integrators.path_types import example_kernel_scene

        return tuple(_layout(a) for a in example_kernel_scene())
    except Exception:  # noqa: BLE001
        return ()


_SCENE_LAYOUT = None


def for_scene(ks) -> SimpleNamespace:
    """:func:`kernels`, unless they are the extension's and a packed scene's arrays ``ks`` (a
    KernelScene) differ in dtype, rank or contiguity from those it was compiled for: then the JIT ones."""
    global _SCENE_LAYOUT
    k = kernels()
    if k.aot:
        if _SCENE_LAYOUT is None:
            _SCENE_LAYOUT = _scene_layout()
        if tuple(_layout(a) for a in ks) != _SCENE_LAYOUT:
            return jit_kernels()
    return k


def rays_ok(*arrays) -> bool:
    """Whether ray arrays are what the extension's Embree queries take: float32, C-contiguous
    (origins and directions (N, 3), tmax (N,))."""
    for a in arrays:
        if a.dtype != np.float32 or not a.flags.c_contiguous:
            return False
    return arrays[0].ndim == 2 and arrays[1].ndim == 2 and arrays[0].shape[1] == 3 and arrays[1].shape[1] == 3
