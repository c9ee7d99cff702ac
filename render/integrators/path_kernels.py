"""Compiled (numba) wavefront kernels of the path tracer: one pass over the live paths per bounce.

:mod:`render.integrators.path` drives the wavefront: Embree (through :class:`render.accel.Accel`)
finds hits for a whole batch, then one kernel here shades every hit in a single loop (emission,
next-event estimation, BSDF sampling, Russian roulette, compaction of the survivors) and writes
the next rays and the shadow rays straight into the float32 arrays Embree reads. Loops over
rays run inside compiled code and release the GIL, so two render threads overlap (one traces
while the other shades).

Inside shade_bounce the work that is the same for every hit runs first, in block passes over
128 paths (:func:`_bounce_numbers`, :func:`_block_geometry`, :func:`_light_samples`,
:func:`_block_vertices`): branch-free loops over a struct-of-arrays scratch that LLVM vectorizes
(the random numbers, the light samples, the Lambertian vertex's MIS weight, contribution scale,
shadow ray and BSDF direction); the per-path loop keeps the control flow, the material lookups,
the queue writes and the compaction. The passes compute the scalar helpers' expressions in the
same order (selects for their early returns), so the bytes are those of a one-loop kernel. Two
things keep LLVM from vectorizing here and are avoided: calls (math.sqrt is a libm call:
:func:`_sqrt`) and loads from rows picked by data (vector gathers are slow on the machines this
runs on, so such loads stay in scalar passes that copy what the vector passes read).

The math is the same as the numpy reference implementations, which stay the public, tested
interfaces for other integrators: warps and the hash RNG of :mod:`render.sampling`, the BSDFs of
:mod:`render.bsdf`, light sampling of :mod:`render.lights`, texture lookup of
:mod:`render.texture`. tests/render/test_pathtracer_kernels.py checks each compiled piece against them.

Precision: shading is float64 (as the numpy code); ray origins, directions and tmax are
rounded to float32 once, where Embree consumes them (it intersects in float32), and hit
distances and barycentrics come back as float32. Offsets (:func:`render.accel.spawn_origin`)
are computed in float64 before the rounding, as before; their bound (1e-6 |p|, ~16 ulps of
float32) covers the rounding.

Every kernel is a pure function of its inputs, processes rays in index order and compacts
survivors in that order: results do not depend on threads or batch boundaries.
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .._kernel_cache import skip_numba_blas_probe
from ..sobol import INDEX_BITS, REPLICATES
# the numba-free definitions, re-exported (render.path_aot's processes import them without numba)
from .path_types import (LAMBERT, MIRROR, DIELECTRIC, EMISSIVE, POINT, SPOT, DIRECTIONAL, STRAT_MIS,
                         STRAT_LIGHT, STRAT_BSDF, SAMPLER_INDEPENDENT, SAMPLER_SOBOL, F_DELTA, F_AFTER_DIFF,
                         _INV_PI, _GOLDEN, _M1, _M2, _S30, _S27, _S31, _S11, _INV_2_53, _COS_FLOOR,
                         _OFFSET_REL, _TMAX_CAP, KernelScene, kernel_scene, PinholeCamera, PathConfig)  # noqa: F401

skip_numba_blas_probe()  # before the first kernel loads: numba's BLAS probe would import scipy.linalg

__all__ = ["KernelScene", "kernel_scene", "sample_camera_rays", "shade_bounce", "last_bounce_queue", "add_unoccluded",
           "accumulate", "accumulate_replicates", "uniform_dims", "PathConfig", "PinholeCamera",
           "SAMPLER_INDEPENDENT", "SAMPLER_SOBOL"]


_JIT = dict(cache=True, nogil=True, error_model="numpy")


_MASK32 = np.uint64(0xFFFFFFFF)
_HI32 = np.uint64(0xFFFFFFFF00000000)
_INDEX = np.uint64((1 << INDEX_BITS) - 1)  # a Sobol key's index bits; bits 27 .. 31: its shuffle q
_SHUFFLE_SHIFT = np.uint64(INDEX_BITS)
_U0, _U1, _U2, _U4, _U8, _U16, _U32 = (np.uint64(x) for x in (0, 1, 2, 4, 8, 16, 32))
_INV_2_32 = 1.0 / 4294967296.0
_ONE_MINUS = 1.0 - 2.0 ** -53  # the largest float64 below 1



# ------------------------------------------------------------------ borrowed arrays
@intrinsic
def _borrow(typingctx, arr):
    """``arr`` as a borrowed view: the same data, shape and strides with a NULL meminfo, so
    numba's reference counting skips it (NRT_incref / NRT_decref return at once on NULL).

    Why: the helpers below are inlined into the bounce kernel at numba's IR level, and every
    array argument of an inlined call costs an atomic NRT_incref / NRT_decref pair per call
    (per path and bounce) that LLVM's refcount pruning cannot remove across the branches. On
    the Cornell box that was half of shade_bounce's time on one thread, more on two (both
    threads' atomics hit the same shared scene arrays' counters). Use only on arrays the
    caller keeps alive for the whole kernel call (arguments), and never return or store the
    view."""
    def codegen(context, builder, signature, args):
        src = context.make_array(arr)(context, builder, value=args[0])
        out = context.make_array(arr)(context, builder)
        out.meminfo = cgutils.get_null_value(src.meminfo.type)
        out.parent = cgutils.get_null_value(src.parent.type)
        out.nitems = src.nitems
        out.itemsize = src.itemsize
        out.data = src.data
        out.shape = src.shape
        out.strides = src.strides
        return out._getvalue()

    return arr(arr), codegen


@intrinsic
def _sqrt(typingctx, x):
    """math.sqrt of a float64 as LLVM's llvm.sqrt (the same correctly rounded square root):
    numba lowers math.sqrt to a call of libm's sqrt (for errno), and a loop holding a call is
    never vectorized."""
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        return builder.call(builder.module.declare_intrinsic("llvm.sqrt", [args[0].type]), args)

    return types.float64(types.float64), codegen


# ------------------------------------------------------------------ RNG (render.sampling's hash)
@njit(inline="always", **_JIT)
def _mix64(x):
    x = x ^ (x >> _S30)
    x = x * _M1
    x = x ^ (x >> _S27)
    x = x * _M2
    return x ^ (x >> _S31)


@njit(inline="always", **_JIT)
def _uniform(key, dim):
    """render.sampling.uniform for one key and dimension."""
    x = _mix64(key + np.uint64(dim + 1) * _GOLDEN)
    return np.float64(x >> _S11) * _INV_2_53


@intrinsic
def _reverse32(typingctx, v):
    """Bit reversal of the low 32 bits of a uint64 (the high ones dropped): LLVM's
    llvm.bitreverse.i32, which x86 lowers to a few byte shuffles (one GF(2) affine instruction
    per vector with GFNI) where the five swap stages of shifts and masks it replaces took ~20
    instructions; the same integer, so the same bits downstream."""
    if v != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        fn = builder.module.declare_intrinsic("llvm.bitreverse", [i32])
        return builder.zext(builder.call(fn, [builder.trunc(args[0], i32)]), ir.IntType(64))

    return types.uint64(types.uint64), codegen


@intrinsic
def _laine_karras(typingctx, x, h):
    """The permutation inside render.sobol.nested_scramble, on a bit-reversed 32-bit value x
    (in a uint64) keyed by h's low 32 bits: _nested(x, h) = _reverse32(_laine_karras(_reverse32(x), h)).
    Computed in 32-bit integers (every step of the reference is masked to 32 bits, and a
    product's low 32 bits depend on its factors' low 32 bits only: the same value), so the
    block passes multiply four or eight lanes at once with vpmulld, not 64-bit vpmullq."""
    if x != types.uint64 or h != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        c = lambda v: ir.Constant(i32, v)  # noqa: E731
        v, seed = builder.trunc(args[0], i32), builder.trunc(args[1], i32)
        v = builder.xor(v, builder.mul(v, c(0x3D20ADEA)))
        v = builder.add(v, seed)
        v = builder.mul(v, builder.or_(builder.lshr(seed, c(16)), c(1)))
        v = builder.xor(v, builder.mul(v, c(0x05526C56)))
        v = builder.xor(v, builder.mul(v, c(0x53A22864)))
        return builder.zext(v, ir.IntType(64))

    return types.uint64(types.uint64, types.uint64), codegen


@intrinsic
def _kensler(typingctx, x, p, w):
    """render.sobol.kensler_permute of x <= w (w = 2^q - 1) keyed by p's low 32 bits, in 32-bit
    integers (every step of the reference is masked to 32 bits) so the block passes vectorize it."""
    if x != types.uint64 or p != types.uint64 or w != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        c = lambda v: ir.Constant(i32, v)  # noqa: E731
        i, key, mask = (builder.trunc(a, i32) for a in args)
        xs = lambda v, s: builder.xor(v, builder.lshr(builder.and_(v, mask), c(s)))  # noqa: E731
        i = builder.mul(builder.xor(i, key), c(0xE170893D))
        i = builder.xor(i, builder.lshr(key, c(16)))
        i = xs(i, 4)
        i = builder.mul(builder.xor(i, builder.lshr(key, c(8))), c(0x0929EB3F))
        i = builder.xor(i, builder.lshr(key, c(23)))
        i = builder.mul(xs(i, 1), builder.or_(builder.lshr(key, c(27)), c(1)))
        i = builder.mul(i, c(0x6935FA69))
        i = builder.mul(xs(i, 11), c(0x74DCB303))
        i = builder.mul(xs(i, 2), c(0x9E501CC3))
        i = builder.mul(xs(i, 2), c(0xC860A3DF))
        i = builder.and_(i, mask)
        i = builder.xor(i, builder.lshr(i, c(5)))
        return builder.zext(builder.and_(builder.add(i, key), mask), ir.IntType(64))

    return types.uint64(types.uint64, types.uint64, types.uint64), codegen


@njit(inline="always", **_JIT)
def _shuffle_mask(key):
    """w = 2^q - 1, q the Sobol key's shuffle bits (render.sobol.shuffle_bits)."""
    return (_U1 << ((key & _MASK32) >> _SHUFFLE_SHIFT)) - _U1


@njit(inline="always", **_JIT)
def _low_shuffle(j, h_index, w):
    """j with its low bits (mask w) permuted by Kensler's hash keyed by h_index's high half."""
    return (j & ~w) | _kensler(j & w, h_index >> _U32, w)


@njit(inline="always", **_JIT)
def _nested(x, h):
    """render.sobol.nested_scramble of a 32-bit value (in a uint64) by hash h."""
    return _reverse32(_laine_karras(_reverse32(x), h))


@njit(inline="always", **_JIT)
def _shuffled_index(key, h_index):
    """The group's shuffled Sobol index of the key's index i: j = _nested(i, h) ^ _nested(0, h)
    (one bit reversal fewer: the two scrambles' outer reversals merge), its low bits then
    permuted (:func:`_low_shuffle`, render.sobol.sobol_uniform)."""
    j = _reverse32(_laine_karras(_reverse32(key & _INDEX), h_index) ^ _laine_karras(_U0, h_index))
    return _low_shuffle(j, h_index, _shuffle_mask(key))


@njit(inline="always", **_JIT)
def _scrambled_dim0(j, h):
    """Owen-scrambled Sobol dimension 0 at index j: _nested(_reverse32(j), h) ^ (h >> 32), the
    van der Corput value's two reversals cancelled."""
    return _reverse32(_laine_karras(j, h)) ^ (h >> _U32)


@njit(inline="always", **_JIT)
def _v1_reversed(j):
    """reverse32 of Sobol dimension 1 at index j < 2^32 (the XOR of the direction numbers
    DIRECTIONS[1] over j's set bits). Dimension 1's generator is Pascal's matrix mod 2: by
    Lucas's theorem, bit i of the reversed value is the XOR of j's bits at the positions k whose
    binary digits include i's (k & i == i), a superset sum over the five bits of the position,
    one shift-mask-XOR per bit. It replaces four lookups in a byte table, which the block passes
    vectorized into gathers (slow on this machine: microcode-mitigated vpgatherqq)."""
    v = j ^ ((j >> _U1) & np.uint64(0x55555555))
    v = v ^ ((v >> _U2) & np.uint64(0x33333333))
    v = v ^ ((v >> _U4) & np.uint64(0x0F0F0F0F))
    v = v ^ ((v >> _U8) & np.uint64(0x00FF00FF))
    return v ^ ((v >> _U16) & np.uint64(0x0000FFFF))


@njit(inline="always", **_JIT)
def _scrambled_dim1(j, h):
    """Owen-scrambled Sobol dimension 1 at index j: _nested(v, h) ^ (h >> 32) with v the XOR of
    the direction numbers over j's set bits, computed bit-reversed by :func:`_v1_reversed`."""
    return _reverse32(_laine_karras(_v1_reversed(j), h)) ^ (h >> _U32)


@njit(inline="always", **_JIT)
def _sobol(key, dim):
    """render.sobol.sobol_uniform for one Sobol path key and dimension."""
    comp = 0
    if dim < 2:
        comp = dim
    elif (dim - 2) % 8 == 2 or (dim - 2) % 8 == 5:  # second of the light point / BSDF direction pairs
        comp = 1
    h_index = _mix64((key & _HI32) + np.uint64(dim - comp + 1) * _GOLDEN)
    h_value = _mix64(h_index ^ (np.uint64(comp + 1) * _M1))
    j = _shuffled_index(key, h_index)  # maps [0, 2^m) onto itself
    x = _scrambled_dim0(j, h_value) if comp == 0 else _scrambled_dim1(j, h_value)
    return np.float64(x) * _INV_2_32


@njit(inline="always", **_JIT)
def _sobol2(key, dim0):
    """(_sobol(key, dim0), _sobol(key, dim0 + 1)) of a 2-D group starting at dim0 (the pixel
    jitter, a light point, a BSDF direction): the group's index shuffle is hashed and applied
    once for both components."""
    h_index = _mix64((key & _HI32) + np.uint64(dim0 + 1) * _GOLDEN)
    h0 = _mix64(h_index ^ _M1)
    h1 = _mix64(h_index ^ (np.uint64(2) * _M1))
    j = _shuffled_index(key, h_index)
    return np.float64(_scrambled_dim0(j, h0)) * _INV_2_32, np.float64(_scrambled_dim1(j, h1)) * _INV_2_32


@njit(inline="always", **_JIT)
def _sample2(sampler, key, dim0):
    """Dimensions dim0 and dim0 + 1 (a 2-D group under the Sobol sampler) of a path key:
    equal to (_sample(sampler, key, dim0), _sample(sampler, key, dim0 + 1))."""
    if sampler == SAMPLER_SOBOL:
        return _sobol2(key, dim0)
    return _uniform(key, dim0), _uniform(key, dim0 + 1)


@njit(inline="always", **_JIT)
def _sample(sampler, key, dim):
    """Dimension ``dim`` of a path key under ``sampler`` (SAMPLER_INDEPENDENT: the hash of
    render.sampling.uniform; SAMPLER_SOBOL: render.sobol.sobol_uniform)."""
    if sampler == SAMPLER_SOBOL:
        return _sobol(key, dim)
    return _uniform(key, dim)


@njit(inline="always", **_JIT)
def _key_parts(key):
    """The halves of a Sobol key that all of a path's groups share: (khi = key & _HI32, its
    reversed index rkey, its shuffle mask w)."""
    return key & _HI32, _reverse32(key & _INDEX), _shuffle_mask(key)


@njit(inline="always", **_JIT)
def _group_index(khi, rkey, w, dim0):
    """A Sobol group's hash and shuffled index from the shared parts of :func:`_key_parts`:
    (h_index, j) as in :func:`_sobol2`."""
    h_index = _mix64(khi + np.uint64(dim0 + 1) * _GOLDEN)
    j = _reverse32(_laine_karras(rkey, h_index) ^ _laine_karras(_U0, h_index))
    return h_index, _low_shuffle(j, h_index, w)


@njit(inline="always", **_JIT)
def _sobol2_shared(khi, rkey, w, dim0):
    """_sobol2(key, dim0) from the shared parts of :func:`_key_parts`."""
    h_index, j = _group_index(khi, rkey, w, dim0)
    h0 = _mix64(h_index ^ _M1)
    h1 = _mix64(h_index ^ (np.uint64(2) * _M1))
    return np.float64(_scrambled_dim0(j, h0)) * _INV_2_32, np.float64(_scrambled_dim1(j, h1)) * _INV_2_32


@njit(inline="always", **_JIT)
def _sobol1_shared(khi, rkey, w, dim):
    """_sobol(key, dim) of a 1-D group (component 0) from the shared parts of :func:`_key_parts`."""
    h_index, j = _group_index(khi, rkey, w, dim)
    return np.float64(_scrambled_dim0(j, _mix64(h_index ^ _M1))) * _INV_2_32


# Taylor coefficients of sin(pi y / 2) / y and cos(pi y / 2) in y^2 (|y| <= 1/2: truncation < 1e-17)
_SIN_C = tuple((-1) ** k * (math.pi / 2) ** (2 * k + 1) / math.factorial(2 * k + 1) for k in range(9))
_COS_C = tuple((-1) ** k * (math.pi / 2) ** (2 * k) / math.factorial(2 * k) for k in range(10))
_S0, _S1, _S2, _S3, _S4, _S5, _S6, _S7, _S8 = _SIN_C
_C0, _C1, _C2, _C3, _C4, _C5, _C6, _C7, _C8, _C9 = _COS_C


@njit(inline="always", **_JIT)
def _cos_sin_2pi(u):
    """(cos 2 pi u, sin 2 pi u) for u in [0, 1) on a grid no finer than 2^-50 (the samplers'
    numbers): the quarter turn and the eighth are split off exactly (4 u, its fractional part x
    and 1 - x are exact), the rest is a Taylor polynomial of degree 17 (sin) or 18 (cos) in an
    angle of at most pi / 4: |error| < 1e-15, so c^2 + s^2 = 1 to 1e-15. Branch-free (selects), so
    it vectorizes; libm's cos was about a tenth of the bounce's time."""
    t = 4.0 * u
    qd = math.floor(t)
    x = t - qd
    big = x > 0.5
    y = 1.0 - x if big else x
    y2 = y * y
    sv = y * (_S0 + y2 * (_S1 + y2 * (_S2 + y2 * (_S3 + y2 * (_S4 + y2 * (_S5 + y2 * (_S6 + y2 * (_S7 + y2 * _S8))))))))
    cv = _C0 + y2 * (_C1 + y2 * (_C2 + y2 * (_C3 + y2 * (_C4 + y2 * (_C5 + y2 * (_C6 + y2 * (_C7 + y2 * (_C8 + y2 * _C9))))))))
    c = sv if big else cv
    sn = cv if big else sv
    q = np.int64(qd)
    c, sn = (-sn if q & 1 else c), (c if q & 1 else sn)  # a quarter turn
    c, sn = (-c if q & 2 else c), (-sn if q & 2 else sn)  # a half turn
    return c, sn


_BLOCK = 128  # paths whose bounce numbers one pass of _bounce_numbers draws (a few KiB: stays in L1)


@njit(**_JIT)
def _bounce_numbers(sampler, keys, i0, i1, base, roulette, U):
    """The random numbers a bounce reads, for paths i0 .. i1 - 1 (U[:, i - i0]): [0] light pick
    (dimension base; the independent sampler only), [1], [2] light point (base + 1, base + 2),
    [3], [4], [6] the cosine-weighted direction in the local frame from dimensions base + 4,
    base + 5 (:func:`_sample_cosine`), [5] roulette (base + 6, when ``roulette``).
    The Fresnel lobe (base + 3) is drawn where it is read (dielectric hits only). A branch-free
    pass over a block of paths, so LLVM vectorizes the uint64 hashing; the values are
    _sample / _sample2's, bit for bit."""
    n = i1 - i0
    if sampler == SAMPLER_SOBOL:
        if roulette:
            for k in range(n):
                key = keys[i0 + k]
                khi, rkey, w = _key_parts(key)
                U[1, k], U[2, k] = _sobol2_shared(khi, rkey, w, base + 1)
                U[3, k], U[4, k] = _sobol2_shared(khi, rkey, w, base + 4)
                U[5, k] = _sobol1_shared(khi, rkey, w, base + 6)
        else:
            for k in range(n):
                key = keys[i0 + k]
                khi, rkey, w = _key_parts(key)
                U[1, k], U[2, k] = _sobol2_shared(khi, rkey, w, base + 1)
                U[3, k], U[4, k] = _sobol2_shared(khi, rkey, w, base + 4)
    else:
        for k in range(n):
            key = keys[i0 + k]
            U[0, k] = _uniform(key, base)
            U[1, k] = _uniform(key, base + 1)
            U[2, k] = _uniform(key, base + 2)
            U[3, k] = _uniform(key, base + 4)
            U[4, k] = _uniform(key, base + 5)
            U[5, k] = _uniform(key, base + 6)
    for k in range(n):  # the polar warp of render.sampling.cosine_hemisphere, vectorized
        u4 = U[3, k]
        r = math.sqrt(u4)
        c, sn = _cos_sin_2pi(U[4, k])
        U[3, k], U[4, k], U[6, k] = r * c, r * sn, math.sqrt(max(0.0, 1.0 - u4))


# rows of a block's scratch W (row r of path k at W[r * _BLOCK + k]: constant row distances, so
# the vectorized passes need no runtime alias checks between rows)
_W_P, _W_NG, _W_D = 0, 3, 6  # hit point, geometric normal, traced direction (3 each; :func:`_block_geometry`)
_W_OK, _W_L, _W_DIST, _W_LE, _W_LPDF, _W_LN = 9, 10, 13, 14, 17, 18  # light sample (:func:`_light_samples`)
_W_EPS, _W_COSI, _W_S = 21, 22, 23  # offset, cos at the vertex, contribution scale (:func:`_block_vertices`)
_W_SO, _W_SD, _W_ST = 24, 27, 30  # shadow ray origin (3), direction (3), tmax
_W_WI, _W_SPDF, _W_COSS, _W_NO = 31, 34, 35, 36  # BSDF direction (3), its pdf and cosine, next origin (3)
_W_ROWS = 39


@njit(inline="always", **_JIT)
def _block_geometry(ids, tris, prim, hu, hv, d32, i0, n, W):
    """The hit point, geometric normal and traced direction (float64 of the float32 one) of paths
    i0 .. i0 + n - 1 into W (garbage for misses, never read): a scalar pass (the rows are picked
    by data, and gathers are slow here), so the next passes read them at constant distances."""
    for k in range(n):
        i = i0 + k
        t = ids[max(prim[i], 0)]
        px, py, pz = _hit_point(tris, t, np.float64(hu[i]), np.float64(hv[i]))
        W[(_W_P + 0) * _BLOCK + k], W[(_W_P + 1) * _BLOCK + k], W[(_W_P + 2) * _BLOCK + k] = px, py, pz
        W[(_W_NG + 0) * _BLOCK + k], W[(_W_NG + 1) * _BLOCK + k], W[(_W_NG + 2) * _BLOCK + k] = tris[t, 9], tris[t, 10], tris[t, 11]
        W[(_W_D + 0) * _BLOCK + k] = np.float64(d32[i, 0])
        W[(_W_D + 1) * _BLOCK + k] = np.float64(d32[i, 1])
        W[(_W_D + 2) * _BLOCK + k] = np.float64(d32[i, 2])


_A_ROWS = 19  # a block's picked area-light rows (LightSet._packed's 17 columns), then the pick's CDF interval
_A_LO, _A_WIDTH = 17, 18


@njit(inline="always", **_JIT)
def _light_samples(sampler, cdf, area, n_area, floor, n, U, K, W, A):
    """The next-event light samples of a block's paths from their numbers U
    (:func:`_bounce_numbers`) and hit points (:func:`_block_geometry`): K[k] the light picked,
    W's light rows the area entry's sample from the hit point (valid, wi (3), dist, Li (3), pdf
    of :func:`_sample_area`, and the light's normal; garbage for misses and delta lights, which
    are not read). The Sobol sampler picks with dimension base + 1 and reuses it, rescaled within
    the picked light's CDF interval, as the point's first coordinate: uniform again, so each
    light's points keep the pair's stratification (pbrt's remapped u).

    Two passes: a scalar one picks (its search has a data-dependent length) and copies the
    picked area row and CDF interval into the block scratch A (row r of path k at
    A[r * _BLOCK + k]); a branch-free one then evaluates :func:`_sample_area`'s expressions, in
    its order (the same bits), over the block, so LLVM vectorizes it."""
    total = cdf[len(cdf) - 1]
    last = max(n_area - 1, 0)
    sobol = sampler == SAMPLER_SOBOL
    for k in range(n):
        kk = _pick(cdf, U[1, k] if sobol else U[0, k])
        K[k] = kk
        if sobol:
            lo = cdf[kk - 1] if kk > 0 else 0.0
            A[_A_LO * _BLOCK + k] = lo
            A[_A_WIDTH * _BLOCK + k] = cdf[kk] - lo
        kc = min(kk, last)
        for col in range(17):
            A[col * _BLOCK + k] = area[kc, col]
    for k in range(n):
        if sobol:
            width = A[_A_WIDTH * _BLOCK + k]
            u1 = min((U[1, k] * total - A[_A_LO * _BLOCK + k]) / width, _ONE_MINUS) if width > 0.0 else 0.5
            u1 = max(u1, 0.0)
        else:
            u1 = U[1, k]
        # _sample_area(area, kc, floor, p, u1, U[2, k])
        su = _sqrt(u1)
        b1 = 1.0 - su
        b2 = U[2, k] * su
        dx = A[0 * _BLOCK + k] + b1 * A[3 * _BLOCK + k] + b2 * A[6 * _BLOCK + k] - W[(_W_P + 0) * _BLOCK + k]
        dy = A[1 * _BLOCK + k] + b1 * A[4 * _BLOCK + k] + b2 * A[7 * _BLOCK + k] - W[(_W_P + 1) * _BLOCK + k]
        dz = A[2 * _BLOCK + k] + b1 * A[5 * _BLOCK + k] + b2 * A[8 * _BLOCK + k] - W[(_W_P + 2) * _BLOCK + k]
        r2 = max(dx * dx + dy * dy + dz * dz, floor)
        r = _sqrt(r2)
        wx, wy, wz = dx / r, dy / r, dz / r
        lnx, lny, lnz = A[9 * _BLOCK + k], A[10 * _BLOCK + k], A[11 * _BLOCK + k]
        cos_l = -(wx * lnx + wy * lny + wz * lnz)
        emits = (A[16 * _BLOCK + k] > 0.0) | (cos_l > 0.0)
        e = 1.0 if emits else 0.0
        W[_W_OK * _BLOCK + k] = 1.0 if emits & (cos_l != 0.0) else 0.0
        W[(_W_L + 0) * _BLOCK + k], W[(_W_L + 1) * _BLOCK + k], W[(_W_L + 2) * _BLOCK + k] = wx, wy, wz
        W[_W_DIST * _BLOCK + k] = r
        W[(_W_LE + 0) * _BLOCK + k] = A[13 * _BLOCK + k] * e
        W[(_W_LE + 1) * _BLOCK + k] = A[14 * _BLOCK + k] * e
        W[(_W_LE + 2) * _BLOCK + k] = A[15 * _BLOCK + k] * e
        W[_W_LPDF * _BLOCK + k] = A[12 * _BLOCK + k] * r2 / max(abs(cos_l), _COS_FLOOR)
        W[(_W_LN + 0) * _BLOCK + k], W[(_W_LN + 1) * _BLOCK + k], W[(_W_LN + 2) * _BLOCK + k] = lnx, lny, lnz


@njit(inline="always", **_JIT)
def _block_vertices(n, U, W, extent, nee, mis, mis_exponent):
    """What a Lambertian vertex computes from its hit and its numbers, for a block's paths at
    once (W's rows from :func:`_block_geometry`, :func:`_light_samples`; garbage for other hits,
    never read): the offset eps; when ``nee``, the area light sample's cosine at the vertex, its
    contribution scale (1 / pi) cos w / pdf (w the MIS weight when ``mis``) and its shadow ray
    (:func:`_queue_shadow_to`: origin, unit direction, tmax); the cosine-weighted BSDF direction
    (:func:`_sample_cosine`: direction, pdf, cosine) and the next ray's origin
    (:func:`_queue_ray`). The same expressions as the scalar helpers, as selects: a branch-free
    loop over constant-distance rows, which LLVM vectorizes (divisions and square roots four
    at a time), so the same bits."""
    for k in range(n):
        px, py, pz = W[(_W_P + 0) * _BLOCK + k], W[(_W_P + 1) * _BLOCK + k], W[(_W_P + 2) * _BLOCK + k]
        ngx, ngy, ngz = W[(_W_NG + 0) * _BLOCK + k], W[(_W_NG + 1) * _BLOCK + k], W[(_W_NG + 2) * _BLOCK + k]
        dx, dy, dz = W[(_W_D + 0) * _BLOCK + k], W[(_W_D + 1) * _BLOCK + k], W[(_W_D + 2) * _BLOCK + k]
        cos_o = -(dx * ngx + dy * ngy + dz * ngz)
        flip = cos_o < 0.0  # _facing_normal of a two-sided (Lambertian) surface
        nx, ny, nz = (-ngx if flip else ngx), (-ngy if flip else ngy), (-ngz if flip else ngz)
        eps = _offset(px, py, pz, extent)
        W[_W_EPS * _BLOCK + k] = eps
        if nee:
            lx, ly, lz = W[(_W_L + 0) * _BLOCK + k], W[(_W_L + 1) * _BLOCK + k], W[(_W_L + 2) * _BLOCK + k]
            ldist, lpdf = W[_W_DIST * _BLOCK + k], W[_W_LPDF * _BLOCK + k]
            lnx, lny, lnz = W[(_W_LN + 0) * _BLOCK + k], W[(_W_LN + 1) * _BLOCK + k], W[(_W_LN + 2) * _BLOCK + k]
            cos_i = lx * nx + ly * ny + lz * nz
            w = 1.0
            if mis:  # _mis(lpdf, cos_i / pi, mis_exponent) as a select
                r = min((cos_i * _INV_PI) / lpdf, 1e150)
                if mis_exponent == 2.0:
                    r = r * r
                w = 1.0 / (1.0 + r) if lpdf > 0.0 else 0.0
            W[_W_COSI * _BLOCK + k] = cos_i
            W[_W_S * _BLOCK + k] = _INV_PI * cos_i * w / lpdf
            # _queue_shadow_to for an area light (finite distance)
            side = eps if lx * ngx + ly * ngy + lz * ngz >= 0.0 else -eps
            ox, oy, oz = px + side * ngx, py + side * ngy, pz + side * ngz
            yx, yy, yz = px + ldist * lx, py + ldist * ly, pz + ldist * lz
            e = _offset(yx, yy, yz, extent)
            e = -e if lx * lnx + ly * lny + lz * lnz > 0.0 else e
            yx, yy, yz = yx + e * lnx, yy + e * lny, yz + e * lnz
            sx, sy, sz = yx - ox, yy - oy, yz - oz
            r = _sqrt(sx * sx + sy * sy + sz * sz)
            good = r > 0.0
            W[(_W_SO + 0) * _BLOCK + k], W[(_W_SO + 1) * _BLOCK + k], W[(_W_SO + 2) * _BLOCK + k] = ox, oy, oz
            W[(_W_SD + 0) * _BLOCK + k] = sx / r if good else lx
            W[(_W_SD + 1) * _BLOCK + k] = sy / r if good else ly
            W[(_W_SD + 2) * _BLOCK + k] = sz / r if good else lz
            W[_W_ST * _BLOCK + k] = min(r * (1.0 - 1e-4), _TMAX_CAP) if good else 0.0
        wx, wy, wz, spdf, cos_s = _sample_cosine(U[3, k], U[4, k], U[6, k], nx, ny, nz)
        W[(_W_WI + 0) * _BLOCK + k], W[(_W_WI + 1) * _BLOCK + k], W[(_W_WI + 2) * _BLOCK + k] = wx, wy, wz
        W[_W_SPDF * _BLOCK + k], W[_W_COSS * _BLOCK + k] = spdf, cos_s
        side = eps if wx * ngx + wy * ngy + wz * ngz >= 0.0 else -eps
        W[(_W_NO + 0) * _BLOCK + k] = px + side * ngx
        W[(_W_NO + 1) * _BLOCK + k] = py + side * ngy
        W[(_W_NO + 2) * _BLOCK + k] = pz + side * ngz


@njit(**_JIT)
def uniform_dims(keys, dim0, count, sampler=SAMPLER_INDEPENDENT):
    """(N, count) uniforms of dimensions dim0.. (equals render.sampling.uniform_block, or
    render.sobol.sobol_block when ``sampler`` is SAMPLER_SOBOL)."""
    out = np.empty((len(keys), count))
    for i in range(len(keys)):
        for j in range(count):
            out[i, j] = _sample(sampler, keys[i], dim0 + j)
    return out


# ------------------------------------------------------------------ camera rays

@njit(**_JIT)
def sample_camera_rays(start, stop, npix, width, sample0, seed_mix, cam, pinhole, keys, pix, o32, d32, jit,
                       sampler=SAMPLER_INDEPENDENT, replicates=REPLICATES, shuffle=0):
    """Camera samples of flat indices [start, stop): flat = (sample - sample0) * npix + pixel.

    seed_mix: uint64 mix64(seed + golden) (render.sampling.path_keys). cam: a
    :class:`PinholeCamera`. Writes keys (N,) uint64 (render.sampling.path_keys, or
    render.sobol.sobol_keys with ``replicates`` and ``shuffle`` when ``sampler`` is SAMPLER_SOBOL), pix (N,) int64, jit (N, 2)
    jittered pixel positions (dims 0, 1), and when ``pinhole`` the unit rays o32, d32 (N, 3)
    float32 (what Embree traces and shading reads).
    """
    rot, origin = cam.rotation, cam.origin
    nrep = np.uint64(replicates)
    tag = np.uint64(shuffle) << _SHUFFLE_SHIFT
    n = stop - start
    # pixel (and its column, row), sample, and the sample's replicate and index within it,
    # advanced by counters: no integer division per path
    p = start % npix
    s = sample0 + start // npix
    rep, q = np.uint64(s) % nrep, np.uint64(s) // nrep
    px, py = p % width, p // width
    for i in range(n):
        k = _mix64(np.uint64(p) * _GOLDEN ^ seed_mix)
        if sampler == SAMPLER_SOBOL:  # hash of (seed, pixel, replicate) over the Sobol index
            key = (_mix64(k ^ (rep * _M2 + _GOLDEN)) & _HI32) | (q & _INDEX) | tag
        else:
            key = _mix64(k ^ (np.uint64(s) * _M2 + _GOLDEN))
        keys[i] = key
        pix[i] = p
        jit[i, 0] = px
        jit[i, 1] = py
        p += 1
        px += 1
        if px == width:
            px = 0
            py += 1
        if p == npix:
            p, px, py, s = 0, 0, 0, s + 1
            rep += _U1
            if rep == nrep:
                rep = _U0
                q += _U1
    # the pixel jitter (dimensions 0, 1) in a pass of its own: branch-free, vectorized hashing.
    # The passes index flat views (jf[2 i + c], df[3 i + c]): with the 2-D arrays' strides
    # unknown at compile time LLVM assumed jit[i, 1] might be jit[i + 1, 0] and kept them scalar.
    jf = jit[:n].reshape(2 * n)
    if sampler == SAMPLER_SOBOL:
        for i in range(n):
            ux, uy = _sobol2(keys[i], 0)
            jf[2 * i] = ux + jf[2 * i]
            jf[2 * i + 1] = uy + jf[2 * i + 1]
    else:
        for i in range(n):
            key = keys[i]
            jf[2 * i] = _uniform(key, 0) + jf[2 * i]
            jf[2 * i + 1] = _uniform(key, 1) + jf[2 * i + 1]
    if pinhole:
        df, of = d32[:n].reshape(3 * n), o32[:n].reshape(3 * n)
        r00, r01, r02, r10, r11, r12 = rot[0, 0], rot[0, 1], rot[0, 2], rot[1, 0], rot[1, 1], rot[1, 2]
        r20, r21, r22, o0, o1, o2 = rot[2, 0], rot[2, 1], rot[2, 2], origin[0], origin[1], origin[2]
        for i in range(n):
            x = (jf[2 * i] - cam.cx) / cam.fx
            y = (jf[2 * i + 1] - cam.cy) / cam.fy
            nrm = _sqrt(x * x + y * y + 1.0)
            x, y, z = x / nrm, y / nrm, 1.0 / nrm
            df[3 * i] = r00 * x + r01 * y + r02 * z
            df[3 * i + 1] = r10 * x + r11 * y + r12 * z
            df[3 * i + 2] = r20 * x + r21 * y + r22 * z
            of[3 * i], of[3 * i + 1], of[3 * i + 2] = o0, o1, o2


# ------------------------------------------------------------------ small helpers
@njit(inline="always", **_JIT)
def _mis(pf, pg, power):
    """render.sampling.mis_weight for scalars (power: 2.0 power heuristic, 1.0 balance)."""
    if not pf > 0.0:
        return 0.0
    r = min(pg / pf, 1e150)
    if power == 2.0:
        r = r * r
    return 1.0 / (1.0 + r)


@njit(inline="always", **_JIT)
def _offset(px, py, pz, extent):
    return _OFFSET_REL * (max(max(abs(px), abs(py)), abs(pz)) + 1e-2 * extent)


@njit(inline="always", **_JIT)
def _frame(nx, ny, nz):
    """render.sampling.orthonormal_frame (Duff et al. 2017) for one normal: (s, t)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx), (b, sign + ny * ny * a, -ny)


@njit(inline="always", **_JIT)
def _pick(cdf, u):
    """min(searchsorted(cdf, u * cdf[-1], side='right'), len - 1)."""
    x = u * cdf[len(cdf) - 1]
    lo, hi = 0, len(cdf)
    while lo < hi:
        mid = (lo + hi) >> 1
        if cdf[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return min(lo, len(cdf) - 1)


@njit(inline="always", **_JIT)
def _albedo(albedo, tex, uv, d, obj, t, u, v):
    """MaterialTable.diffuse_albedo for one hit: tint times the bilinear texture lookup
    (render.texture.sample_bilinear, repeat wrapping) on textured objects. (Helpers take
    arrays, never the KernelScene tuple: passing it would reference-count every array.)"""
    h = tex[obj, 1]
    w = tex[obj, 2]
    off = tex[obj, 0]
    b0 = 1.0 - u - v
    tu = b0 * uv[t, 0, 0] + u * uv[t, 1, 0] + v * uv[t, 2, 0]
    tv = b0 * uv[t, 0, 1] + u * uv[t, 1, 1] + v * uv[t, 2, 1]
    x = tu * w - 0.5
    y = (1.0 - tv) * h - 0.5
    fx0, fy0 = math.floor(x), math.floor(y)
    fx, fy = x - fx0, y - fy0
    x0 = np.int64(fx0) % w
    y0 = np.int64(fy0) % h
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    i00, i01, i10, i11 = off + (y0 * w + x0) * 3, off + (y0 * w + x1) * 3, off + (y1 * w + x0) * 3, off + (y1 * w + x1) * 3
    f00, f01, f10, f11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    return ((f00 * d[i00] + f01 * d[i01] + f10 * d[i10] + f11 * d[i11]) * albedo[obj, 0],
            (f00 * d[i00 + 1] + f01 * d[i01 + 1] + f10 * d[i10 + 1] + f11 * d[i11 + 1]) * albedo[obj, 1],
            (f00 * d[i00 + 2] + f01 * d[i01 + 2] + f10 * d[i10 + 2] + f11 * d[i11 + 2]) * albedo[obj, 2])


@njit(inline="always", **_JIT)
def _hit_point(tris, t, u, v):
    """World position at barycentrics (u, v) of packed triangle ``t`` (``tris`` rows: corner 0,
    edges 1 and 2, geometric normal; render.accel.Geometry): corner 0 + u e1 + v e2."""
    return (tris[t, 0] + u * tris[t, 3] + v * tris[t, 6], tris[t, 1] + u * tris[t, 4] + v * tris[t, 7],
            tris[t, 2] + u * tris[t, 5] + v * tris[t, 8])


@njit(inline="always", **_JIT)
def _facing_normal(ngx, ngy, ngz, cos_o, kind):
    """The shading normal: the geometric one flipped to face wo (``cos_o`` < 0: wo on its back)
    on two-sided materials, kept outward on dielectrics (their inside matters for eta)."""
    if cos_o < 0.0 and kind != DIELECTRIC:
        return -ngx, -ngy, -ngz
    return ngx, ngy, ngz


@njit(inline="always", **_JIT)
def _fresnel_dielectric(woz, ior):
    """Unpolarised Fresnel reflectance of a smooth dielectric (render.bsdf.fresnel_dielectric)
    for wo at cosine ``woz`` to the outward normal, and the relative eta across the surface
    (inside over outside when wo is outside): (F, eta); F = 1 under total internal reflection."""
    ci = min(max(woz, -1.0), 1.0)
    eta_f = 1.0 / ior if ci < 0.0 else ior
    aci = abs(ci)
    s2 = (1.0 - aci * aci) / (eta_f * eta_f)
    if s2 >= 1.0:
        F = 1.0
    else:
        ct = math.sqrt(max(0.0, 1.0 - s2))
        rpa = (eta_f * aci - ct) / (eta_f * aci + ct)
        rpe = (aci - eta_f * ct) / (aci + eta_f * ct)
        F = 0.5 * (rpa * rpa + rpe * rpe)
    return F, (ior if woz >= 0.0 else 1.0 / ior)


@njit(inline="always", **_JIT)
def _lambert_albedo(albedo, tex, uv, d, obj, t, u, v):
    """A Lambertian object's albedo (3 floats) at a hit: its constant (untextured: ``tex[obj, 1]``
    is 0) or the texture lookup times it (:func:`_albedo`)."""
    if tex[obj, 1] == 0:
        return albedo[obj, 0], albedo[obj, 1], albedo[obj, 2]
    return _albedo(albedo, tex, uv, d, obj, t, u, v)


@njit(inline="always", **_JIT)
def _sample_area(area, k, floor, px, py, pz, u1, u2):
    """LightSet.sample on area entry k (a row of LightSet._packed) from point p:
    (valid, wi (3), dist, Li (3), solid-angle pdf)."""
    su = math.sqrt(u1)
    b1 = 1.0 - su
    b2 = u2 * su
    dx = area[k, 0] + b1 * area[k, 3] + b2 * area[k, 6] - px
    dy = area[k, 1] + b1 * area[k, 4] + b2 * area[k, 7] - py
    dz = area[k, 2] + b1 * area[k, 5] + b2 * area[k, 8] - pz
    r2 = max(dx * dx + dy * dy + dz * dz, floor)
    r = math.sqrt(r2)
    wx, wy, wz = dx / r, dy / r, dz / r
    cos_l = -(wx * area[k, 9] + wy * area[k, 10] + wz * area[k, 11])
    emits = area[k, 16] > 0.0 or cos_l > 0.0
    e = 1.0 if emits else 0.0
    return (emits and cos_l != 0.0, wx, wy, wz, r, area[k, 13] * e, area[k, 14] * e, area[k, 15] * e,
            area[k, 12] * r2 / max(abs(cos_l), _COS_FLOOR))


@njit(**_JIT)
def _sample_delta(d_kind, d_pos, d_dir, d_I, d_cos, li, floor, px, py, pz):
    """LightSet.sample on point/spot/directional light li from point p: (valid, wi (3),
    dist, Li (3)) (the pdf is the light's selection probability)."""
    kind = d_kind[li]
    if kind == DIRECTIONAL:
        return True, -d_dir[li, 0], -d_dir[li, 1], -d_dir[li, 2], np.inf, d_I[li, 0], d_I[li, 1], d_I[li, 2]
    dx, dy, dz = d_pos[li, 0] - px, d_pos[li, 1] - py, d_pos[li, 2] - pz
    r2 = max(dx * dx + dy * dy + dz * dz, floor)
    r = math.sqrt(r2)
    wx, wy, wz = dx / r, dy / r, dz / r
    fall = 1.0
    if kind == SPOT:  # render.scene.spot_falloff
        ct = -(wx * d_dir[li, 0] + wy * d_dir[li, 1] + wz * d_dir[li, 2])
        ci, co = d_cos[li, 0], d_cos[li, 1]
        x = min(max((ct - co) / max(ci - co, 1e-9), 0.0), 1.0)
        fall = x * x * (3.0 - 2.0 * x)
    s = fall / r2
    return fall > 0.0, wx, wy, wz, r, d_I[li, 0] * s, d_I[li, 1] * s, d_I[li, 2] * s


# ------------------------------------------------------------------ one bounce

@njit(inline="always", **_JIT)
def _emission_weight(cfg, prev_delta, pruned, pdf_prev, pdf_area, t_hit, cos_o):
    """MIS weight of emission found by a ray sampled with density pdf_prev (solid angle) that hit
    an emitter at distance t_hit, cosine cos_o, area density pdf_area under light sampling."""
    w = 1.0
    if not prev_delta:
        if cfg.strategy == STRAT_LIGHT and cfg.has_area:
            w = 0.0
        elif cfg.mis_on_hits:
            w = _mis(pdf_prev, pdf_area * t_hit * t_hit / max(abs(cos_o), _COS_FLOOR), cfg.mis_exponent)
    if pruned:
        w = 0.0
    return w


@njit(inline="always", **_JIT)
def _queue_ray(o32, d32, n, px, py, pz, ngx, ngy, ngz, eps, wx, wy, wz):
    """Row n of a ray queue: origin p offset by eps along the geometric normal on wi's side, direction wi."""
    side = eps if wx * ngx + wy * ngy + wz * ngz >= 0.0 else -eps
    o32[n, 0], o32[n, 1], o32[n, 2] = px + side * ngx, py + side * ngy, pz + side * ngz
    d32[n, 0], d32[n, 1], d32[n, 2] = wx, wy, wz


@njit(inline="always", **_JIT)
def _queue_shadow_to(o32, d32, t32, n, px, py, pz, ngx, ngy, ngz, eps, wx, wy, wz, dist, lnx, lny, lnz, extent):
    """Row n of a shadow-ray queue from point p (geometric normal ng, offset eps) to the light
    point y = p + dist w (unit w; dist inf: a directional light, tmax the cap). As pbrt's
    SpawnRayTo between two interactions: the origin is p offset along ng on w's side, the end
    is y offset off the light's surface (unit normal ln; zero for point and spot lights) toward
    p by render.accel's bound at y, and the ray is aimed from the one to the other, tmax its
    length less 1e-4 of it. Aimed along w from the offset origin instead, a ray meeting the
    light's plane at a grazing angle crossed it before tmax (the offset moved the crossing by
    eps / sin(angle), more than the 1e-4 margin): with a light 1e-4 above a floor every
    light sample from beside it was occluded by the light itself
    (tests/render/test_hard_cases.py::test_shading_point_almost_touching_an_area_source)."""
    side = eps if wx * ngx + wy * ngy + wz * ngz >= 0.0 else -eps
    ox, oy, oz = px + side * ngx, py + side * ngy, pz + side * ngz
    o32[n, 0], o32[n, 1], o32[n, 2] = ox, oy, oz
    if dist == math.inf:
        d32[n, 0], d32[n, 1], d32[n, 2] = wx, wy, wz
        t32[n] = _TMAX_CAP
        return
    yx, yy, yz = px + dist * wx, py + dist * wy, pz + dist * wz
    e = _offset(yx, yy, yz, extent)
    if wx * lnx + wy * lny + wz * lnz > 0.0:  # toward p: against w along the light's normal
        e = -e
    yx, yy, yz = yx + e * lnx, yy + e * lny, yz + e * lnz
    dx, dy, dz = yx - ox, yy - oy, yz - oz
    r = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not r > 0.0:
        d32[n, 0], d32[n, 1], d32[n, 2] = wx, wy, wz
        t32[n] = 0.0
        return
    d32[n, 0], d32[n, 1], d32[n, 2] = dx / r, dy / r, dz / r
    t32[n] = min(r * (1.0 - 1e-4), _TMAX_CAP)


@njit(inline="always", **_JIT)
def _next_event(cfg, pmf, area, d_kind, d_pos, d_dir, d_I, d_cos, n_area, floor, pre,
                p, n, ng, eps, b, a, slot, q_o32, q_d32, q_t32, q_idx, q_val, nq, extent):
    """Next-event estimation at a Lambertian vertex p (shading normal n, geometric ng; 3-tuples)
    of albedo a and throughput b (3-tuples): one light sample (pre: the pick k and, when k is an
    area entry, its sample (valid, wi (3), dist, Li (3), pdf), drawn by :func:`_light_samples`),
    queued as a shadow ray (:func:`_queue_shadow_to`) with its unoccluded contribution. Returns
    the new queue length. (Points and colours travel as tuples: CPython passes calls of more
    than 30 arguments as *args, which numba cannot inline.)"""
    px, py, pz = p
    nx, ny, nz = n
    ngx, ngy, ngz = ng
    b0, b1, b2 = b
    a0, a1, a2 = a
    k, ok, lx, ly, lz, ldist, L0, L1, L2, lpdf = pre
    if k < n_area:
        ldelta = False
    else:
        ok, lx, ly, lz, ldist, L0, L1, L2 = _sample_delta(d_kind, d_pos, d_dir, d_I, d_cos, k - n_area,
                                                          floor, px, py, pz)
        lpdf = pmf[k]
        ldelta = True
    if not ok:
        return nq
    cos_i = lx * nx + ly * ny + lz * nz
    if not (cos_i > 0.0 and (cfg.nee_area or ldelta)):
        return nq
    w = 1.0
    if cfg.strategy == STRAT_MIS and not ldelta:
        w = _mis(lpdf, cos_i * _INV_PI, cfg.mis_exponent)
    if ldelta:
        lnx = lny = lnz = 0.0  # no surface at a point or spot light; a directional one is at infinity
    else:
        lnx, lny, lnz = area[k, 9], area[k, 10], area[k, 11]
    _queue_shadow_to(q_o32, q_d32, q_t32, nq, px, py, pz, ngx, ngy, ngz, eps, lx, ly, lz, ldist, lnx, lny, lnz, extent)
    s = _INV_PI * cos_i * w / lpdf
    q_val[nq, 0] = b0 * a0 * L0 * s
    q_val[nq, 1] = b1 * a1 * L1 * s
    q_val[nq, 2] = b2 * a2 * L2 * s
    q_idx[nq] = slot
    return nq + 1


@njit(inline="always", **_JIT)
def _sample_cosine(lx, ly, lz, nx, ny, nz):
    """Cosine-weighted direction about n from its local coordinates (the polar warp of
    render.sampling.cosine_hemisphere, drawn by :func:`_bounce_numbers`): (wi (3), pdf, its cosine)."""
    (sx, sy, sz), (tx, ty, tz) = _frame(nx, ny, nz)
    wx = lx * sx + ly * tx + lz * nx
    wy = lx * sy + ly * ty + lz * ny
    wz = lx * sz + ly * tz + lz * nz
    return wx, wy, wz, lz * _INV_PI, lz


@njit(inline="always", **_JIT)
def _sample_specular(kind, r0, r1, r2, ior, sampler, key, base, dx, dy, dz, nx, ny, nz):
    """Mirror (reflectance r) or dielectric (ior; Fresnel lobe choice at dimension base + 3)
    sample for a ray travelling along d, in the local frame of n (render.bsdf.mirror_sample /
    dielectric_sample): (valid, wi (3), weight (3), discrete lobe probability)."""
    (sx, sy, sz), (tx, ty, tz) = _frame(nx, ny, nz)
    ox, oy, oz = -dx, -dy, -dz
    wox = ox * sx + oy * sy + oz * sz
    woy = ox * tx + oy * ty + oz * tz
    woz = ox * nx + oy * ny + oz * nz
    if kind == MIRROR:
        lx, ly, lz = -wox, -woy, woz
        valid = woz != 0.0
        w0, w1, w2 = r0, r1, r2
        spdf = 1.0
    else:
        F, eta = _fresnel_dielectric(woz, ior)
        if _sample(sampler, key, base + 3) < F:
            lx, ly, lz = -wox, -woy, woz
            spdf = F
            sc = 1.0
        else:
            c = abs(woz)
            s2t = (1.0 - c * c) / (eta * eta)
            cos_t = math.sqrt(max(0.0, 1.0 - s2t))
            sgn = 1.0 if woz >= 0.0 else -1.0
            lx, ly, lz = -wox / eta, -woy / eta, -sgn * cos_t
            spdf = 1.0 - F
            sc = 1.0 / (eta * eta)
        valid = woz != 0.0 and spdf > 0.0
        w0 = w1 = w2 = sc
    wx = lx * sx + ly * tx + lz * nx
    wy = lx * sy + ly * ty + lz * ny
    wz = lx * sz + ly * tz + lz * nz
    return valid, wx, wy, wz, w0, w1, w2, spdf


@njit(**_JIT)
def shade_bounce(ks, cfg, depth, prim, tfar, hu, hv, idx, keys, beta, d32, pdf, flags, L,
                 n_idx, n_keys, n_beta, n_pdf, n_flags, n_o32, n_d32,
                 q_o32, q_d32, q_t32, q_idx, q_val,
                 l_o32, l_d32, l_beta, l_pdf, l_idx):
    """Shade the first hits (prim, tfar, hu, hv from Embree) of the live paths at ``depth``.

    cfg: a :class:`PathConfig`. State of live path i: idx (output slot), keys (RNG), beta (3),
    d32 (the ray's direction), pdf (density the ray was sampled with), flags (F_DELTA,
    F_AFTER_DIFF). L (paths, 3): radiance, accumulated in place (emission found, background).
    Random dimensions per bounce from 2 + 8 depth: light pick, light point (2), Fresnel lobe,
    BSDF direction (2), roulette, spare (camera jitter takes 0 and 1).

    Writes the survivors, compacted in order, to n_* (their next rays to n_o32 / n_d32); the
    shadow rays of next-event estimation to the queue q_* (origin, direction, tmax, path slot,
    unoccluded contribution); for `direct`, the last BSDF rays to l_* (origin, direction,
    throughput, pdf, slot). Returns (survivors, shadow rays, last rays).
    """
    roulette = cfg.roulette and depth >= cfg.rr_depth
    extent, floor, n_area = ks.scal[0], ks.scal[1], np.int64(ks.scal[2])
    base = 2 + 8 * depth
    bg = _borrow(ks.bg)
    B = _borrow  # no atomic reference counting per inlined helper call (see _borrow)
    ids, tri_obj, tris, kinds, albedo, iors, Le = B(ks.ids), B(ks.tri_obj), B(ks.tri), B(ks.kind), B(ks.albedo), B(ks.ior), B(ks.Le)
    emits, two_sided, tex, uv = B(ks.emits), B(ks.two_sided), B(ks.tex), B(ks.uv)
    tex_data, tri_pdf_area = B(ks.tex_data), B(ks.tri_pdf_area)
    cdf, pmf, area, d_kind, d_pos = B(ks.cdf), B(ks.pmf), B(ks.area), B(ks.d_kind), B(ks.d_pos)
    d_dir, d_I, d_cos = B(ks.d_dir), B(ks.d_I), B(ks.d_cos)
    prim, tfar, hu, hv, idx, keys, beta, d32 = B(prim), B(tfar), B(hu), B(hv), B(idx), B(keys), B(beta), B(d32)
    pdf, flags, L = B(pdf), B(flags), B(L)
    n_idx, n_keys, n_beta, n_pdf, n_flags, n_o32, n_d32 = B(n_idx), B(n_keys), B(n_beta), B(n_pdf), B(n_flags), B(n_o32), B(n_d32)
    q_o32, q_d32, q_t32, q_idx, q_val = B(q_o32), B(q_d32), B(q_t32), B(q_idx), B(q_val)
    l_o32, l_d32, l_beta, l_pdf, l_idx = B(l_o32), B(l_d32), B(l_beta), B(l_pdf), B(l_idx)
    has_lights = cdf[len(cdf) - 1] > 0.0  # LightSet.empty is False
    nn = 0
    nq = 0
    nl = 0
    U = np.empty((7, _BLOCK))
    K = np.empty(_BLOCK, np.int64)
    W = np.empty(_W_ROWS * _BLOCK)
    A = np.empty(_A_ROWS * _BLOCK)
    nee = cfg.nee_any and has_lights
    mis = cfg.strategy == STRAT_MIS
    for i in range(len(prim)):
        k = i % _BLOCK
        if k == 0:  # the next block's random numbers, light samples and Lambertian vertices, in block passes
            i1 = min(i + _BLOCK, len(prim))
            _bounce_numbers(cfg.sampler, keys, i, i1, base, roulette, U)
            _block_geometry(ids, tris, prim, hu, hv, d32, i, i1 - i, W)
            if nee:
                _light_samples(cfg.sampler, cdf, area, n_area, floor, i1 - i, U, K, W, A)
            _block_vertices(i1 - i, U, W, extent, nee, mis, cfg.mis_exponent)
        slot = idx[i]
        fl = flags[i]
        prev_delta = (fl & F_DELTA) != 0
        after_diff = (fl & F_AFTER_DIFF) != 0
        pruned = (not cfg.caustics) and prev_delta and after_diff
        # the float32 direction Embree traced (rounding 6e-8: only cosines and specular
        # reflection/refraction read it, hit points come from barycentrics)
        dx, dy, dz = np.float64(d32[i, 0]), np.float64(d32[i, 1]), np.float64(d32[i, 2])
        b0, b1, b2 = beta[i, 0], beta[i, 1], beta[i, 2]
        if prim[i] < 0:
            if cfg.has_bg and not pruned:
                L[slot, 0] += b0 * bg[0]
                L[slot, 1] += b1 * bg[1]
                L[slot, 2] += b2 * bg[2]
            continue
        t = ids[prim[i]]
        obj = tri_obj[t]
        kind = kinds[obj]
        ngx, ngy, ngz = tris[t, 9], tris[t, 10], tris[t, 11]
        cos_o = -(dx * ngx + dy * ngy + dz * ngz)
        if emits[obj] and (two_sided[obj] or cos_o > 0.0):
            w = _emission_weight(cfg, prev_delta, pruned, pdf[i], tri_pdf_area[t], np.float64(tfar[i]), cos_o)
            L[slot, 0] += b0 * Le[obj, 0] * w
            L[slot, 1] += b1 * Le[obj, 1] * w
            L[slot, 2] += b2 * Le[obj, 2] * w
        if depth == cfg.max_depth or kind == EMISSIVE or (cfg.direct and after_diff):
            continue
        u, v = np.float64(hu[i]), np.float64(hv[i])
        px, py, pz = W[(_W_P + 0) * _BLOCK + k], W[(_W_P + 1) * _BLOCK + k], W[(_W_P + 2) * _BLOCK + k]
        key = keys[i]
        eps = W[_W_EPS * _BLOCK + k]
        if kind == LAMBERT:
            a0, a1, a2 = _lambert_albedo(albedo, tex, uv, tex_data, obj, t, u, v)
            if nee:
                if K[k] < n_area:  # an area light: the sample, its weight and shadow ray are _block_vertices'
                    if W[_W_OK * _BLOCK + k] > 0.0 and W[_W_COSI * _BLOCK + k] > 0.0 and cfg.nee_area:
                        q_o32[nq, 0], q_o32[nq, 1], q_o32[nq, 2] = (W[(_W_SO + 0) * _BLOCK + k], W[(_W_SO + 1) * _BLOCK + k],
                                                                    W[(_W_SO + 2) * _BLOCK + k])
                        q_d32[nq, 0], q_d32[nq, 1], q_d32[nq, 2] = (W[(_W_SD + 0) * _BLOCK + k], W[(_W_SD + 1) * _BLOCK + k],
                                                                    W[(_W_SD + 2) * _BLOCK + k])
                        q_t32[nq] = W[_W_ST * _BLOCK + k]
                        s = W[_W_S * _BLOCK + k]
                        q_val[nq, 0] = b0 * a0 * W[(_W_LE + 0) * _BLOCK + k] * s
                        q_val[nq, 1] = b1 * a1 * W[(_W_LE + 1) * _BLOCK + k] * s
                        q_val[nq, 2] = b2 * a2 * W[(_W_LE + 2) * _BLOCK + k] * s
                        q_idx[nq] = slot
                        nq += 1
                else:
                    nx, ny, nz = _facing_normal(ngx, ngy, ngz, cos_o, kind)
                    nq = _next_event(cfg, pmf, area, d_kind, d_pos, d_dir, d_I, d_cos, n_area, floor,
                                     (K[k], False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                                     (px, py, pz), (nx, ny, nz), (ngx, ngy, ngz), eps, (b0, b1, b2), (a0, a1, a2), slot,
                                     q_o32, q_d32, q_t32, q_idx, q_val, nq, extent)
            if not cfg.continue_diffuse:
                continue
            wx, wy, wz = W[(_W_WI + 0) * _BLOCK + k], W[(_W_WI + 1) * _BLOCK + k], W[(_W_WI + 2) * _BLOCK + k]
            spdf = W[_W_SPDF * _BLOCK + k]
            ox, oy, oz = W[(_W_NO + 0) * _BLOCK + k], W[(_W_NO + 1) * _BLOCK + k], W[(_W_NO + 2) * _BLOCK + k]
            w0, w1, w2 = a0, a1, a2
            valid = W[_W_COSS * _BLOCK + k] > 0.0 and cos_o != 0.0
            delta = False
            if cfg.direct:  # the path ends here: queue its last BSDF ray
                if valid and max(max(w0, w1), w2) > 0.0:
                    l_o32[nl, 0], l_o32[nl, 1], l_o32[nl, 2] = ox, oy, oz
                    l_d32[nl, 0], l_d32[nl, 1], l_d32[nl, 2] = wx, wy, wz
                    l_beta[nl, 0], l_beta[nl, 1], l_beta[nl, 2] = b0 * w0, b1 * w1, b2 * w2
                    l_pdf[nl] = spdf
                    l_idx[nl] = slot
                    nl += 1
                continue
        else:
            nx, ny, nz = _facing_normal(ngx, ngy, ngz, cos_o, kind)
            valid, wx, wy, wz, w0, w1, w2, spdf = _sample_specular(kind, albedo[obj, 0], albedo[obj, 1],
                                                                   albedo[obj, 2], iors[obj], cfg.sampler, key, base,
                                                                   dx, dy, dz, nx, ny, nz)
            side = eps if wx * ngx + wy * ngy + wz * ngz >= 0.0 else -eps  # _queue_ray's origin
            ox, oy, oz = px + side * ngx, py + side * ngy, pz + side * ngz
            delta = True
        if not valid:
            continue
        b0, b1, b2 = b0 * w0, b1 * w1, b2 * w2
        if roulette:
            survive = min(1.0, max(max(b0, b1), b2))
            if not U[5, k] < survive:
                continue
            b0, b1, b2 = b0 / survive, b1 / survive, b2 / survive
        if not max(max(b0, b1), b2) > 0.0:
            continue
        n_idx[nn] = slot
        n_keys[nn] = key
        n_beta[nn, 0], n_beta[nn, 1], n_beta[nn, 2] = b0, b1, b2
        n_o32[nn, 0], n_o32[nn, 1], n_o32[nn, 2] = ox, oy, oz
        n_d32[nn, 0], n_d32[nn, 1], n_d32[nn, 2] = wx, wy, wz
        n_pdf[nn] = spdf
        nf = fl & F_AFTER_DIFF
        if kind == LAMBERT:
            nf = F_AFTER_DIFF
        if delta:
            nf |= F_DELTA
        n_flags[nn] = nf
        nn += 1
    return nn, nq, nl


@njit(**_JIT)
def last_bounce_queue(ks, cfg, n, prim, tfar, l_beta, l_pdf, l_idx, l_o32, l_d32,
                      q0, q_o32, q_d32, q_t32, q_idx, q_val):
    """`direct`'s last BSDF rays: n rays l_* and their hits in the emitter-only BVH (prim,
    tfar; prim None-like (length 0) when not queried). cfg: a :class:`PathConfig`. An emitter
    hit on its emitting side queues an occlusion query up to it with the MIS-weighted
    emission; a miss queues one to infinity with the background (when lit). Appends to the
    shadow queue from q0; returns the new queue length."""
    queried = len(prim) > 0
    bg = _borrow(ks.bg)
    nq = q0
    for j in range(n):
        if queried and prim[j] >= 0:
            t = ks.emit_ids[prim[j]]
            obj = ks.tri_obj[t]
            cos_hit = -(np.float64(l_d32[j, 0]) * ks.tri[t, 9] + np.float64(l_d32[j, 1]) * ks.tri[t, 10]
                        + np.float64(l_d32[j, 2]) * ks.tri[t, 11])
            if not (ks.two_sided[obj] or cos_hit > 0.0):
                continue
            th = np.float64(tfar[j])
            w = 1.0
            if cfg.strategy == STRAT_MIS and cfg.has_area:
                w = _mis(l_pdf[j], ks.tri_pdf_area[t] * th * th / max(abs(cos_hit), _COS_FLOOR), cfg.mis_exponent)
            q_t32[nq] = th * (1.0 - 1e-6)
            for c in range(3):
                q_val[nq, c] = l_beta[j, c] * ks.Le[obj, c] * w
        elif cfg.has_bg:
            q_t32[nq] = _TMAX_CAP
            for c in range(3):
                q_val[nq, c] = l_beta[j, c] * bg[c]
        else:
            continue
        for c in range(3):
            q_o32[nq, c] = l_o32[j, c]
            q_d32[nq, c] = l_d32[j, c]
        q_idx[nq] = l_idx[j]
        nq += 1
    return nq


@njit(**_JIT)
def add_unoccluded(L, q_idx, q_val, occ):
    """L[q_idx[k]] += q_val[k] for the shadow rays Embree found unoccluded (occ[k] == -1)."""
    for k in range(len(occ)):
        if occ[k] == -1:
            s = q_idx[k]
            L[s, 0] += q_val[k, 0]
            L[s, 1] += q_val[k, 1]
            L[s, 2] += q_val[k, 2]


@njit(**_JIT)
def accumulate(s1, s2, cnt, pix, L):
    """Film moments: s1[pix] += L, s2[pix] += L^2, cnt[pix] += 1, in sample order."""
    for i in range(len(pix)):
        p = pix[i]
        for c in range(3):
            x = L[i, c]
            s1[p, c] += x
            s2[p, c] += x * x
        cnt[p] += 1


@njit(**_JIT)
def accumulate_replicates(r1, start, npix, sample0, L, block=0):
    """Per-replicate sums of the Sobol sampler: r1[s mod R, pixel] += L for the paths of flat
    indices [start, start + len(L)) (flat = (s - sample0) * npix + pixel); r1 (R, npix, 3).
    block > 0 ("sobol-blocks", render.sobol.block_size): r1[min(s div block, R - 1), pixel]."""
    nrep = r1.shape[0]
    p = start % npix  # pixel and sample advanced by counters: no division per path
    s = sample0 + start // npix
    r = min(s // block, nrep - 1) if block > 0 else s % nrep
    for i in range(len(L)):
        for c in range(3):
            r1[r, p, c] += L[i, c]
        p += 1
        if p == npix:
            p = 0
            s += 1
            r = min(s // block, nrep - 1) if block > 0 else s % nrep
