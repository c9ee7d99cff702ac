"""The Embree library embreex ships, loaded with ctypes (no numba): scenes the compiled kernels query.

:class:`DirectScene` builds an Embree scene from the same float32 triangles :class:`render.accel.Accel`
gives embreex (same library, same build settings: static scene, medium quality, not robust), whose
``handle`` the path tracer's kernels pass to ``rtcIntersect8`` / ``rtcOccluded8``
(:mod:`render.embree_direct`, numba; or the ahead-of-time extension of :mod:`render.path_aot`).

The library is the one inside the installed embreex wheel (``embreex.libs/libembree4*.so*``), loaded
``RTLD_GLOBAL`` so that the ahead-of-time extension's undefined ``rtcIntersect8`` / ``rtcOccluded8``
resolve to it when that extension is imported; when it cannot be found or loaded, :data:`AVAILABLE`
is False and callers use embreex alone.
"""
from __future__ import annotations

import ctypes
import glob
import os

import numpy as np

__all__ = ["AVAILABLE", "DirectScene", "library_path"]

_INVALID = np.uint32(0xFFFFFFFF)
_RTC_GEOMETRY_TYPE_TRIANGLE = 0
_RTC_BUFFER_TYPE_INDEX, _RTC_BUFFER_TYPE_VERTEX = 0, 1
_RTC_FORMAT_UINT3, _RTC_FORMAT_FLOAT3 = 0x5003, 0x9003


def library_path() -> str | None:
    """The path of embreex's libembree4, or None."""
    try:
        import embreex
    except ImportError:  # pragma: no cover - embreex is a dependency
        return None
    base = os.path.dirname(os.path.abspath(embreex.__file__))
    hits = sorted(glob.glob(os.path.join(base, "..", "embreex.libs", "libembree4*.so*"))
                  + glob.glob(os.path.join(base, "libembree4*.so*")))
    return hits[0] if hits else None


def _load():
    path = library_path()
    if path is None:
        return None
    try:
        lib = ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)  # the AOT extension resolves rtcIntersect8 here
        vp, sz = ctypes.c_void_p, ctypes.c_size_t
        sigs = {"rtcNewDevice": (vp, [ctypes.c_char_p]), "rtcReleaseDevice": (None, [vp]),
                "rtcGetDeviceError": (ctypes.c_int, [vp]), "rtcNewScene": (vp, [vp]),
                "rtcReleaseScene": (None, [vp]), "rtcCommitScene": (None, [vp]),
                "rtcNewGeometry": (vp, [vp, ctypes.c_int]),
                "rtcSetNewGeometryBuffer": (vp, [vp, ctypes.c_int, ctypes.c_uint, ctypes.c_int, sz, sz]),
                "rtcCommitGeometry": (None, [vp]), "rtcAttachGeometry": (ctypes.c_uint, [vp, vp]),
                "rtcReleaseGeometry": (None, [vp]), "rtcIntersect8": (None, [vp, vp, vp, vp]),
                "rtcOccluded8": (None, [vp, vp, vp, vp])}
        for name, (res, args) in sigs.items():
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
        return lib
    except (OSError, AttributeError, RuntimeError):  # pragma: no cover - depends on the wheel
        return None


_LIB = _load()
AVAILABLE = _LIB is not None


class DirectScene:
    """An Embree scene over float32 triangles (P, 3, 3); Embree primID p is triangle p.

    ``handle`` is the RTCScene pointer (an int) the kernels take; :meth:`close` releases it.
    """

    def __init__(self, tris: np.ndarray):
        if not AVAILABLE:
            raise RuntimeError("the Embree library of embreex was not found")
        tris = np.ascontiguousarray(tris, dtype=np.float32).reshape(-1, 3, 3)
        lib = _LIB
        self._device = lib.rtcNewDevice(None)
        if not self._device:
            raise RuntimeError("rtcNewDevice failed")
        self._scene = lib.rtcNewScene(self._device)
        geom = lib.rtcNewGeometry(self._device, _RTC_GEOMETRY_TYPE_TRIANGLE)
        p = len(tris)
        vb = lib.rtcSetNewGeometryBuffer(geom, _RTC_BUFFER_TYPE_VERTEX, 0, _RTC_FORMAT_FLOAT3, 12, 3 * p)
        ib = lib.rtcSetNewGeometryBuffer(geom, _RTC_BUFFER_TYPE_INDEX, 0, _RTC_FORMAT_UINT3, 12, p)
        if not vb or not ib:
            raise RuntimeError("rtcSetNewGeometryBuffer failed")
        verts = tris.reshape(-1, 3)
        index = np.arange(3 * p, dtype=np.uint32).reshape(p, 3)
        ctypes.memmove(vb, verts.ctypes.data, verts.nbytes)
        ctypes.memmove(ib, index.ctypes.data, index.nbytes)
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(self._scene, geom)
        lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(self._scene)
        err = lib.rtcGetDeviceError(self._device)
        if err != 0:
            self.close()
            raise RuntimeError(f"Embree error {err} building the scene")
        self.handle = int(self._scene)

    def close(self) -> None:
        if getattr(self, "_scene", None):
            _LIB.rtcReleaseScene(self._scene)
            self._scene = None
            self.handle = 0
        if getattr(self, "_device", None):
            _LIB.rtcReleaseDevice(self._device)
            self._device = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
