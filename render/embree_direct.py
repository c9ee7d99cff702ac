"""Embree called from compiled code: the library embreex ships, driven through its C API.

embreex wraps each batch query in a Python call that allocates its outputs and fills a ray
struct per ray (about 40 ns of its ~75 ns per camera ray on the Cornell box is that wrapper).
The path tracer's kernels instead call ``rtcIntersect8`` / ``rtcOccluded8`` themselves (packets
of 8 rays), on a scene built here from the same float32 triangles :class:`render.accel.Accel` gives embreex:
same library, same build settings (static scene, medium quality, not robust), so the same hits
(tests/render/test_accel.py compares the two bit for bit).

The library is the one inside the installed embreex wheel (``embreex.libs/libembree4*.so*``);
when it cannot be found or loaded, :data:`AVAILABLE` is False and callers use embreex alone.
Loading it and building scenes (:class:`DirectScene`) is :mod:`render.embree_lib` (ctypes, no
numba), re-exported here; this module holds the numba kernels that query those scenes.
Pointers cross into the kernels as integers (uintp), which the x86-64 and AArch64 calling
conventions pass exactly like pointers.
"""
from __future__ import annotations

import numpy as np

from .embree_lib import _INVALID, AVAILABLE, DirectScene, library_path

__all__ = ["AVAILABLE", "DirectScene", "intersect_many", "occluded_many"]

if AVAILABLE:
    import llvmlite.binding as llvm
    from numba import njit, types

    from ._kernel_cache import skip_numba_blas_probe

    llvm.load_library_permanently(library_path())  # compiled code resolves rtcIntersect8 / rtcOccluded8 by name

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
