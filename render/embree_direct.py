"""Embree called from compiled code: the library embreex ships, driven through its C API.

embreex wraps each batch query in a Python call that allocates its outputs and fills a ray
struct per ray (about 40 ns of its ~75 ns per camera ray on the Cornell box is that wrapper).
The path tracer's kernels instead call ``rtcIntersect8`` / ``rtcOccluded8`` themselves (packets
of 8 rays), on a scene built here from the same float32 triangles :class:`render.accel.Accel` gives embreex:
same library, same build settings (static scene, medium quality, not robust), so the same hits
(tests/render/test_accel.py compares the two bit for bit).

The library is the one inside the installed embreex wheel (``embreex.libs/libembree4*.so*``);
when it cannot be found or loaded, :data:`AVAILABLE` is False and callers use embreex alone.
Pointers cross into the kernels as integers (uintp), which the x86-64 and AArch64 calling
conventions pass exactly like pointers.
"""
from __future__ import annotations

import ctypes
import glob
import os

import numpy as np

__all__ = ["AVAILABLE", "DirectScene", "intersect_many", "occluded_many"]

_INVALID = np.uint32(0xFFFFFFFF)
_RTC_GEOMETRY_TYPE_TRIANGLE = 0
_RTC_BUFFER_TYPE_INDEX, _RTC_BUFFER_TYPE_VERTEX = 0, 1
_RTC_FORMAT_UINT3, _RTC_FORMAT_FLOAT3 = 0x5003, 0x9003


def _find_library() -> str | None:
    try:
        import embreex
    except ImportError:  # pragma: no cover - embreex is a dependency
        return None
    base = os.path.dirname(os.path.abspath(embreex.__file__))
    hits = sorted(glob.glob(os.path.join(base, "..", "embreex.libs", "libembree4*.so*"))
                  + glob.glob(os.path.join(base, "libembree4*.so*")))
    return hits[0] if hits else None


def _load():
    path = _find_library()
    if path is None:
        return None
    try:
        import llvmlite.binding as llvm

        lib = ctypes.CDLL(path)
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
        llvm.load_library_permanently(path)  # compiled code resolves rtcIntersect8 / rtcOccluded8 by name
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


if AVAILABLE:
    from numba import njit, types

    from ._kernel_cache import skip_numba_blas_probe

    skip_numba_blas_probe()  # before the first kernel loads (see _kernel_cache)

    #: rays per Embree packet query (rtcIntersect8 / rtcOccluded8, SoA): on the Cornell box 8-wide
    #: packets traced 1.22x the rays/s of rtcIntersect1 on incoherent bounce rays and 1.66x on
    #: camera rays (4: 1.17x / 1.51x, 16: 1.18x / 1.46x; one-off /tmp/s35/HC/embree16.py, same
    #: hits bit for bit); Embree reports the same hit per ray whatever the packet
    PACKET = 8
    _rtc_intersect8 = types.ExternalFunction("rtcIntersect8",
                                             types.void(types.uintp, types.uintp, types.uintp, types.uintp))
    _rtc_occluded8 = types.ExternalFunction("rtcOccluded8",
                                            types.void(types.uintp, types.uintp, types.uintp, types.uintp))

    @njit(cache=True, nogil=True)
    def _aligned(raw, align):
        """(index of the first ``align``-byte aligned element of 4-byte array raw, its address)."""
        b = ((align - (raw.ctypes.data & (align - 1))) & (align - 1)) >> 2
        return b, raw.ctypes.data + 4 * b

    @njit(inline="always", cache=True, nogil=True)
    def _fill_packet(f, raw, b, valid, vb, o32, d32, t32, s, m):
        """Rays s .. s + m - 1 into the RTCRay8 fields 0-11 at f/raw[b:] (tfar from t32, or
        infinity when t32 is empty), lanes m .. PACKET - 1 marked invalid."""
        W = PACKET
        for k in range(W):
            if k < m:
                i = s + k
                valid[vb + k] = -1
                f[b + k], f[b + W + k], f[b + 2 * W + k], f[b + 3 * W + k] = o32[i, 0], o32[i, 1], o32[i, 2], 0.0
                f[b + 4 * W + k], f[b + 5 * W + k], f[b + 6 * W + k] = d32[i, 0], d32[i, 1], d32[i, 2]
                f[b + 7 * W + k] = 0.0
                f[b + 8 * W + k] = t32[i] if len(t32) else np.inf
                raw[b + 9 * W + k], raw[b + 10 * W + k], raw[b + 11 * W + k] = _INVALID, 0, 0  # mask, id, flags
            else:
                valid[vb + k] = 0

    @njit(cache=True, nogil=True)
    def intersect_many(scene, o32, d32, prim, tfar, u, v):
        """First hits of rays o32, d32 (N, 3) float32 (t in (0, inf)) into prim (N,) int32
        (-1 on a miss), tfar, u, v (N,) float32: what embreex's run(output=True) returns.

        Packets of PACKET rays (an RTCRayHit8, structure of arrays: row r of field k at
        k * PACKET + r; fields as RTCRayHit's: org 0-2, tnear 3, dir 4-6, time 7, tfar 8, mask 9,
        id 10, flags 11, Ng 12-14, u 15, v 16, primID 17, geomID 18, instID 19, instPrimID 20),
        the last one padded with invalid lanes."""
        W = PACKET
        raw = np.zeros(21 * W + 16, np.uint32)  # 32-byte aligned RTCRayHit8 inside
        f = raw.view(np.float32)
        b, ptr = _aligned(raw, 32)
        valid = np.zeros(W + 8, np.int32)
        vb, vptr = _aligned(valid, 32)
        n = len(o32)
        no_limit = np.empty(0, np.float32)
        for s in range(0, n, W):
            m = min(W, n - s)
            _fill_packet(f, raw, b, valid, vb, o32, d32, no_limit, s, m)
            for k in range(m):
                raw[b + 17 * W + k], raw[b + 18 * W + k] = _INVALID, _INVALID  # primID, geomID
                raw[b + 19 * W + k], raw[b + 20 * W + k] = _INVALID, _INVALID  # instID, instPrimID
            _rtc_intersect8(vptr, scene, ptr, 0)
            for k in range(m):
                i = s + k
                if raw[b + 18 * W + k] == _INVALID:
                    prim[i] = -1
                else:
                    prim[i] = np.int32(raw[b + 17 * W + k])
                    tfar[i] = f[b + 8 * W + k]
                    u[i] = f[b + 15 * W + k]
                    v[i] = f[b + 16 * W + k]

    @njit(cache=True, nogil=True)
    def occluded_many(scene, o32, d32, t32, occ):
        """Occlusion of rays o32, d32 (N, 3) float32 over t in (0, t32): occ (N,) int32, -1
        where nothing lies on the ray (embreex's convention), 0 where something does. Packets
        of PACKET rays (an RTCRay8: fields 0-11 of :func:`intersect_many`'s layout)."""
        W = PACKET
        raw = np.zeros(12 * W + 16, np.uint32)  # 32-byte aligned RTCRay8 inside
        f = raw.view(np.float32)
        b, ptr = _aligned(raw, 32)
        valid = np.zeros(W + 8, np.int32)
        vb, vptr = _aligned(valid, 32)
        n = len(o32)
        for s in range(0, n, W):
            m = min(W, n - s)
            _fill_packet(f, raw, b, valid, vb, o32, d32, t32, s, m)
            _rtc_occluded8(vptr, scene, ptr, 0)
            for k in range(m):
                occ[s + k] = 0 if f[b + 8 * W + k] == -np.inf else -1
else:  # pragma: no cover
    PACKET = 0
    intersect_many = occluded_many = None
