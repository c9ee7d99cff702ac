"""Renderers held once per process for units of work on the engine (:mod:`pipeline.distributed`).

A unit of work (a captured view, a row of slab cameras) receives the shared scene and its key;
the costly renderer state is built on first use in each process and kept in
:func:`pipeline.distributed.worker_cache` under that key, so every later unit on the same worker
reuses it:

* :func:`raster_pool`: the rasterizer (:class:`rig.raster.RasterRenderer`): one EGL context per
  image size, the scene uploaded and its shadow maps drawn once. A GL context is used by one
  thread at a time, so renders go through a lock (a multi-threaded worker serializes them).
* :func:`prepared_scene`: the path tracer's prepared scene (Embree BVH, light tables), which
  cannot be pickled.

Stages free both with ``eng.release(shared)`` when they finish. Neither changes a result: a
rasterizer renders the same bytes in any process and with any llvmpipe thread count, and the
path tracer's result does not depend on its threads.
"""
from __future__ import annotations

import os
import threading

from .distributed import worker_cache

__all__ = ["RasterPool", "raster_pool", "prepared_scene"]


class RasterPool:
    """A scene's rasterizers in this process, one per image size, used under a lock.

    gl_threads: llvmpipe's rasterizer threads (``LP_NUM_THREADS``, read when the process's
    first context is made; only set when not already set). Local Dask workers pass their task's
    share of the cores so that workers x llvmpipe threads do not oversubscribe them; None (in
    process) leaves llvmpipe its default (every core)."""

    def __init__(self, scene, gl_threads: int | None = None):
        if gl_threads:
            os.environ.setdefault("LP_NUM_THREADS", str(int(gl_threads)))
        self.scene = scene
        self._by_size: dict = {}
        self._lock = threading.Lock()

    def render(self, camera):
        """:meth:`rig.raster.RasterRenderer.render` of ``camera`` by the renderer of its size."""
        from rig.raster import RasterRenderer

        k = camera.intrinsics
        with self._lock:
            r = self._by_size.get((k.width, k.height))
            if r is None:
                r = self._by_size[(k.width, k.height)] = RasterRenderer(self.scene, k.width, k.height)
            return r.render(camera)

    def close(self) -> None:
        with self._lock:
            for r in self._by_size.values():
                r.close()
            self._by_size.clear()


def raster_pool(scene, scene_key: str, gl_threads: int | None = None) -> RasterPool:
    """This process's :class:`RasterPool` of the shared scene ``scene_key``."""
    return worker_cache(f"{scene_key}-raster", lambda: RasterPool(scene, gl_threads))


def prepared_scene(scene, scene_key: str, threads: int):
    """This process's :func:`render.integrators.prepare` of the shared scene ``scene_key`` (the
    same key as the reference stage's batches: ``<key>-<threads>``)."""
    from render import integrators

    return worker_cache(f"{scene_key}-{threads}", lambda: integrators.prepare(scene, threads=threads))
