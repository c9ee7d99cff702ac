"""Owen-scrambled Sobol points, counter-based: a pure function of (seed, pixel, sample index, dimension).

The low-discrepancy sampler of the path tracer (``sampler="sobol"``; the compiled twin of these
functions is in :mod:`render.integrators.path_kernels`, and tests compare the two). For each
pixel, the samples of a render are split into ``REPLICATES`` interleaved *replicates*: sample s
belongs to replicate r = s mod R and is point i = s div R of a Sobol sequence (Joe and Kuo's
``new-joe-kuo-6.21201`` direction numbers, the table scipy ships, in natural order) that is
scrambled independently per (seed, pixel, replicate, dimension). A render of samples [0, R 2^m)
therefore gives every replicate of every pixel a full 2^m-point prefix, a (t, m, s)-net:
stratified in every elementary interval of the first two dimensions (a (0, m, 2)-net). Disjoint
sample ranges are disjoint point sets of the same sequences, so they merge exactly.

Scrambling (pbrt-v4's ``FastOwenScrambler``, Laine and Karras 2011 / Burley 2020, on the
bit-reversed value, followed by a random XOR digital shift): both are *nested* permutations of
the 32 bits (a bit's flip depends only on the bits above it), so nets stay nets; the digital
shift makes each single point exactly uniform on the 2^-32 grid whatever the hash, so every
estimator that is unbiased under independent uniforms stays unbiased. Dimensions from
``SOBOL_DIMS`` on are independent hash uniforms (:func:`render.sampling.uniform`).

Why replicates: a stratified estimate's per-pixel variance is not the sample variance over n
(the samples are negatively correlated). The R replicates are independent randomizations of the
same estimator, so the variance of the pixel mean is estimated from the spread of the R
replicate means (:class:`render.film.Film` keeps per-replicate sums): R - 1 degrees of freedom
per pixel, unbiased whenever every replicate holds as many samples (spp a multiple of R).

Path keys (uint64, one per camera sample): the high 32 bits hash (seed, pixel, replicate), the
low 32 bits are the Sobol index i (so sample indices up to R 2^32).

Uniforms are float64 in [0, 1) on a 2^-32 grid.
"""
from __future__ import annotations

import importlib.util
import os

import numpy as np

from .sampling import _GOLDEN, _M2, _mix64, uniform

__all__ = ["SOBOL_DIMS", "REPLICATES", "SAMPLERS", "direction_numbers", "sobol_u32", "owen_scramble",
           "sobol_keys", "sobol_uniform", "sobol_block", "replicate_of"]

#: Sobol dimensions used (camera 2 + 8 per bounce: enough for max_depth 31); later dimensions hash
SOBOL_DIMS = 256
#: independent scramblings per pixel, interleaved over the sample index (sample s: replicate s mod R)
REPLICATES = 16
#: the samplers of the compiled integrators (path, direct): name -> code in PathConfig.sampler
SAMPLERS = {"independent": 0, "sobol": 1}

_MASK32 = np.uint64(0xFFFFFFFF)
_HI32 = np.uint64(0xFFFFFFFF00000000)
_S32 = np.uint64(32)


def _joe_kuo_table() -> tuple[np.ndarray, np.ndarray]:
    """(poly, vinit) of scipy's bundled Joe-Kuo file, read with numpy alone (importing scipy.stats
    costs a third of a second of start-up that the ``reference`` command does not need)."""
    spec = importlib.util.find_spec("scipy")
    path = os.path.join(spec.submodule_search_locations[0], "stats", "_sobol_direction_numbers.npz")
    with np.load(path) as z:
        return z["poly"][:SOBOL_DIMS].astype(np.int64), z["vinit"][:SOBOL_DIMS].astype(np.int64)


def direction_numbers(dims: int = SOBOL_DIMS) -> np.ndarray:
    """(dims, 32) uint32 Sobol direction numbers v[d, k] (bit k of the index XORs v[d, k] into
    dimension d), from Joe and Kuo's primitive polynomials and initial numbers by Bratley and
    Fox's recurrence (scipy's ``_initialize_v``; dimension 0 is van der Corput's)."""
    poly, vinit = _joe_kuo_table()
    v = np.zeros((dims, 32), np.int64)
    v[0] = 1
    for d in range(1, dims):
        p = int(poly[d])
        m = p.bit_length() - 1  # the polynomial's degree
        v[d, :m] = vinit[d, :m]
        for j in range(m, 32):
            x = v[d, j - m]
            for k in range(m):
                if (p >> (m - 1 - k)) & 1:
                    x ^= v[d, j - k - 1] << (k + 1)
            v[d, j] = x
    return (v << (31 - np.arange(32))).astype(np.uint32)


#: (SOBOL_DIMS, 32) uint32 direction numbers (the compiled kernels read the same table)
DIRECTIONS = direction_numbers()


def sobol_u32(index: np.ndarray, dim: int) -> np.ndarray:
    """(N,) uint64 holding the 32-bit unscrambled Sobol value of dimension ``dim`` (< SOBOL_DIMS)
    at natural-order indices ``index`` (N,) (x_i = XOR of v[dim, k] over the set bits k of i)."""
    i = np.asarray(index, dtype=np.uint64) & _MASK32
    out = np.zeros(i.shape, np.uint64)
    for k in range(32):
        out ^= np.where((i >> np.uint64(k)) & np.uint64(1), np.uint64(DIRECTIONS[dim, k]), np.uint64(0))
    return out


def _reverse32(v: np.ndarray) -> np.ndarray:
    """Bit reversal of the low 32 bits of (N,) uint64 values."""
    v = ((v >> np.uint64(1)) & np.uint64(0x55555555)) | ((v & np.uint64(0x55555555)) << np.uint64(1))
    v = ((v >> np.uint64(2)) & np.uint64(0x33333333)) | ((v & np.uint64(0x33333333)) << np.uint64(2))
    v = ((v >> np.uint64(4)) & np.uint64(0x0F0F0F0F)) | ((v & np.uint64(0x0F0F0F0F)) << np.uint64(4))
    v = ((v >> np.uint64(8)) & np.uint64(0x00FF00FF)) | ((v & np.uint64(0x00FF00FF)) << np.uint64(8))
    return ((v >> np.uint64(16)) | (v << np.uint64(16))) & _MASK32


def owen_scramble(v: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Nested scramble of 32-bit values v (N,) uint64 by 64-bit hashes h (N,) uint64: the
    Laine-Karras permutation keyed by h's low 32 bits on the reversed bits, then an XOR by h's
    high 32 bits. Returns (N,) uint64 < 2^32."""
    seed = h & _MASK32
    x = _reverse32(v)
    x = (x ^ (x * np.uint64(0x3D20ADEA))) & _MASK32
    x = (x + seed) & _MASK32
    x = (x * ((seed >> np.uint64(16)) | np.uint64(1))) & _MASK32
    x = (x ^ (x * np.uint64(0x05526C56))) & _MASK32
    x = (x ^ (x * np.uint64(0x53A22864))) & _MASK32
    return _reverse32(x) ^ (h >> _S32)


def sobol_keys(seed: int, pixel: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Per-path keys of the Sobol sampler: (N,) uint64 from a seed, (N,) pixel and (N,) sample
    indices: high 32 bits hash (seed, pixel, sample mod REPLICATES), low 32 bits sample div
    REPLICATES (the Sobol index)."""
    s = _mix64(np.array([np.uint64(seed & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    sample = np.asarray(sample, dtype=np.uint64)
    k = _mix64(np.asarray(pixel, dtype=np.uint64) * _GOLDEN ^ s)
    k = _mix64(k ^ ((sample % np.uint64(REPLICATES)) * _M2 + _GOLDEN))
    return (k & _HI32) | ((sample // np.uint64(REPLICATES)) & _MASK32)


def replicate_of(sample: np.ndarray) -> np.ndarray:
    """(N,) int64 replicate of each sample index (sample mod REPLICATES)."""
    return np.asarray(sample, dtype=np.int64) % REPLICATES


def sobol_uniform(keys: np.ndarray, dim: int) -> np.ndarray:
    """(N,) float64 in [0, 1): dimension ``dim`` of each Sobol path key (:func:`sobol_keys`);
    independent hash uniforms of the whole key from SOBOL_DIMS on."""
    if dim >= SOBOL_DIMS:
        return uniform(keys, dim)
    scramble_key = keys & _HI32  # one scramble per (seed, pixel, replicate, dimension)
    h = _mix64(scramble_key + np.uint64((int(dim) + 1) * 0x9E3779B97F4A7C15 & 0xFFFFFFFFFFFFFFFF))
    v = owen_scramble(sobol_u32(keys & _MASK32, dim), h)
    return v.astype(np.float64) * (1.0 / 4294967296.0)


def sobol_block(keys: np.ndarray, dim0: int, count: int) -> np.ndarray:
    """(N, count) float64: dimensions dim0 .. dim0 + count - 1 of :func:`sobol_uniform`."""
    return np.stack([sobol_uniform(keys, d) for d in range(dim0, dim0 + count)], axis=1)
