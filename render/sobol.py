"""Shuffled, Owen-scrambled 2-D Sobol points, counter-based: a pure function of (seed, pixel,
sample index, dimension).

The low-discrepancy sampler of the path tracer (``sampler="sobol"``; the compiled twin of these
functions is in :mod:`render.integrators.path_kernels`, and tests compare the two). It is pbrt-v4's
``PaddedSobolSampler`` made progressive as in Burley 2020 ("Practical hash-based Owen
scrambling"): the path's dimensions are grouped as the path tracer consumes them
(:func:`dimension_group`: the pixel jitter (0, 1), per bounce the light point and the BSDF
direction as 2-D pairs, the light pick, Fresnel lobe, roulette and spare as 1-D; the kernels
pick the light with the light point's first number and rescale it, so the pick dimension goes
unused and each light's points stay stratified), and every group
draws Sobol dimensions 0 and 1 (Joe and Kuo's direction numbers, scipy's table; a (0, 2)-sequence)
at an index that is itself Owen-scrambled per group (a nested permutation of the index bits,
XORed by its image of 0, maps every prefix [0, 2^m) onto itself, so each 2^m prefix stays a net
and groups are decorrelated without knowing the sample count), then the value is Owen-scrambled per
(group, component).

Replicates. For each pixel, the samples are split into R interleaved replicates (R =
:func:`replicates_for` of the render's spp: 4, 8 or 16): sample s is point i = s div R of
replicate r = s mod R, and every scramble is keyed by (seed,
pixel, replicate, group). A render of samples [0, R 2^m) gives every replicate of every pixel a
2^m-point prefix: in each 2-D group a (0, m, 2)-net (each elementary interval of volume 2^-m
holds exactly one point), in each 1-D group one point per interval [k 2^-m, (k+1) 2^-m).
Disjoint sample ranges are disjoint points of the same sequences, so they merge exactly. A
stratified estimate's per-pixel variance is not the sample variance over n (the samples are
negatively correlated): the R replicates are independent randomizations of the same estimator,
so the variance of the pixel mean is estimated from the spread of the R replicate means
(:meth:`render.film.Film.variance`): R - 1 degrees of freedom per pixel, unbiased whenever every
replicate holds as many samples (spp a multiple of R).

Scrambling (pbrt-v4's ``FastOwenScrambler``: Laine and Karras 2011 on the bit-reversed value)
is a nested permutation of the 32 bits (a bit's flip depends only on the bits above it), so nets
stay nets; the values are then XORed by a random 32-bit digital shift, which makes each single
coordinate exactly uniform on the 2^-32 grid whatever the hash: every estimator unbiased under
independent uniforms stays unbiased.

Matching the groups (issue 16, session 39). The index shuffle decides which point of one group
goes with which point of another. A nested scramble alone matches them by a structured map
(the low bits of every group's index are one fixed permutation of the sample's): on integrands
that couple two groups (the pixel jitter against a light point) that measured 1.14-1.38x the
variance of a random matching (tests/render/test_sobol.py). So each group's shuffled index then
has its low q bits permuted by Kensler's hash (:func:`kensler_permute`, keyed per pixel and
group), q = :func:`shuffle_bits` of the render (carried in the key's bits 27 .. 31): every
aligned block of 2^q indices maps onto itself, so every net stays a net, and 2^q divides the
render's count, since a partial block would be a random subset of a net (2.3x the variance at
3500 spp, max_depth 1). The reference stage rounds its spp up to whole nets
(:func:`stratified_spp`).

Blocks (``sampler="sobol-blocks"``). The replicates cost stratification: a render of n samples
is R independent nets of n / R points, whose mean is about R^(1/4) noisier in RMSE than one net of
n points where the error falls as n^(-3/4) (measured on the Cornell box at 256 spp: 0.0061
with R = 16 against 0.0032 with one sequence, bench/bench_mitsuba_equal_time.py). This sampler
gives each pixel ONE scrambled sequence (the keys of R = 1: sample s is Sobol point s) and
estimates the variance from R = :func:`replicates_for` consecutive blocks of B = spp div R
samples (:func:`block_size`; sample s in block min(s div B, R - 1)): with spp a power of two
each block is itself a net. The blocks are not independent: the estimator is the variance of
the mean of R independent B-point nets (the "sobol" sampler's estimate at this spp), which
exceeds the actual variance of the whole sequence's mean whenever the blocks are negatively
correlated, as the points of a scrambled net are (measured: bench/bench_sampler.py,
tests/render/test_sobol.py). So the film does not report that spread: it fits the rate of the
last two halvings (halves against quarters, pooled over a window) and extrapolates to the whole
sequence (:func:`render.film.blocks_variance`, a model calibrated against the spread over seeds).
This is the default sampler of path, direct and volpath (its dimension layout with media:
render.integrators.volpath_kernels, "Random numbers"): a mean as good as one net's, a variance image
within about 0.75-1.1x of the actual (slightly conservative on the Cornell box).

Why "sobol" is noisier than "sobol-blocks" (issue 16, measured): only the split into replicates.
Cornell 128x128, path, 3 seeds (one-off run, load 1-5): "sobol" at 64 spp (R = 4 nets of 16
points) RMSE 0.0120, and the mean of 4 independent 16-point nets predicts 0.0254 / 2 = 0.0127
from "sobol-blocks" at 16 spp; "sobol-blocks" at 64 spp 0.0083 (Mitsuba's multijitter 0.0081).
Per pixel one sequence is what pbrt-v4's ZSobol gives too (a pixel's samples are an aligned
block of one global sequence, a net); its Morton order and global per-dimension scramble shape
the error across pixels (blue noise), not a pixel's variance. A count that is not a power of two
costs as well: 52 spp gives 0.0112 ("sobol-blocks") and 0.0201 ("sobol", 13 points a replicate).

Path keys (uint64, one per camera sample): the high 32 bits hash (seed, pixel, replicate), the
low 27 bits are the Sobol index i (so sample indices up to R 2^27), bits 27 .. 31 the shuffle q. Uniforms are float64 in
[0, 1) on a 2^-32 grid.
"""
from __future__ import annotations

import os

import numpy as np

from .sampling import _GOLDEN, _M2, _mix64

__all__ = ["REPLICATES", "MIN_REPLICATES", "replicates_for", "SAMPLERS", "DIRECTIONS", "direction_numbers", "dimension_group", "sobol_u32",
           "owen_scramble", "nested_scramble", "kensler_permute", "sobol_keys", "sobol_uniform", "sobol_block", "replicate_of",
           "block_size", "key_replicates", "shuffle_bits", "stratified_spp", "whole_net_step", "INDEX_BITS"]

#: independent scramblings per pixel at most, interleaved over the sample index (sample s:
#: replicate s mod R); renders of fewer samples use fewer (:func:`replicates_for`)
REPLICATES = 16
#: the fewest replicates (3 degrees of freedom in a pixel's variance estimate)
MIN_REPLICATES = 4
#: points per replicate that :func:`replicates_for` aims for before adding replicates
_POINTS_PER_REPLICATE = 16


def replicates_for(spp: int) -> int:
    """R, the replicates of a render of ``spp`` samples per pixel (a power of two in
    [MIN_REPLICATES, REPLICATES]): the largest R <= spp / 16, so that each replicate's points
    are a 16-point (or larger) net before more replicates sharpen the variance estimate (4 at
    spp < 128, 8 at spp < 256, 16 from 256 on). Stratification works within a replicate only:
    with 16 replicates a 16-spp render holds one point per replicate and nothing is stratified
    (measured on the Cornell box: bench/bench_sampler.py). R is a function of the render's
    planned total spp (RenderSettings.spp), never of a sample range, so every unit of work of
    one render (and its refinements) shares it; films of different R refuse to merge."""
    r = MIN_REPLICATES
    while r < REPLICATES and 2 * r * _POINTS_PER_REPLICATE <= int(spp):
        r *= 2
    return r

#: the samplers of the compiled integrators (path, direct): name -> code in PathConfig.sampler
#: ("sobol-blocks" draws the same Sobol points, from one sequence per pixel: :func:`key_replicates`)
SAMPLERS = {"independent": 0, "sobol": 1, "sobol-blocks": 1}


def key_replicates(sampler: str, spp: int) -> int:
    """The R the path keys are built with (:func:`sobol_keys`): replicates_for(spp) for "sobol",
    1 for "sobol-blocks" (one sequence per pixel; its variance comes from blocks)."""
    return 1 if sampler == "sobol-blocks" else replicates_for(spp)


def block_size(sampler: str, spp: int) -> int:
    """Samples per variance block: spp div replicates_for(spp) (at least 1) for "sobol-blocks",
    0 for "sobol" (interleaved replicates: sample s is in replicate s mod R)."""
    return max(1, int(spp) // replicates_for(spp)) if sampler == "sobol-blocks" else 0


def stratified_spp(spp: int) -> int:
    """The sample count the reference stage renders under the Sobol samplers for a requested
    ``spp``: rounded up to a multiple of 2^(K - 3), K = floor(log2 spp) (at most four binary
    digits, at most 12.5% more samples; counts below 16 unchanged). Why: a scrambled Sobol
    prefix of n points is the union of the nets of n's binary digits, and the small ones are
    barely stratified; where nets converge fast that dominates (Cornell box, direct light only,
    per-sample variance: 3500 spp 1.44x that of 3584; 4096 lower again), as pbrt-v4 rounds its
    Sobol samplers up to a power of two and Mitsuba its multijitter up to a grid. A multiple of
    2^(K - 3) also lets :func:`shuffle_bits` shuffle whole blocks."""
    step = whole_net_step(spp)
    return -(-int(spp) // step) * step


def whole_net_step(spp: int) -> int:
    """2^(K - 3), K = floor(log2 spp) (1 below 16): the counts with K + 1 bits that are multiples
    of it have at most four binary digits (:func:`stratified_spp`)."""
    return 1 << max(0, int(spp).bit_length() - 4)


def shuffle_bits(sampler: str, spp: int) -> int:
    """q, the low index bits each group's index shuffle permutes at random (:func:`sobol_uniform`):
    the groups' points are then matched at random within aligned blocks of 2^q Sobol points
    (a nested scramble alone matches them by a structured map), while every aligned block stays
    the same set of points. 2^q is the largest power of two that fits a variance unit (a block
    of :func:`block_size` under "sobol-blocks", a replicate's spp / R under "sobol") and divides
    the unit's points (under "sobol-blocks" also the quarters' spp / 4, whose nets
    :func:`render.film.blocks_variance` fits): a partial block would be a random subset of a
    net, not a smaller net (measured on the Cornell box, max_depth 1, 3500 spp: 2.3x the
    variance). 0 for "independent"."""
    def trailing_zeros(n: int) -> int:
        return (n & -n).bit_length() - 1 if n > 0 else 0

    spp, r = int(spp), replicates_for(spp)
    if sampler == "sobol-blocks":
        unit, divides = block_size(sampler, spp), trailing_zeros(spp) - 2
    elif sampler == "sobol":
        unit = spp // r
        divides = min(trailing_zeros(unit), trailing_zeros(-(-spp // r)))
    else:
        return 0
    return max(0, min(unit.bit_length() - 1, divides))

_MASK32 = np.uint64(0xFFFFFFFF)
_HI32 = np.uint64(0xFFFFFFFF00000000)
_S32 = np.uint64(32)
#: bits of a Sobol key's index (sample div R); the key's bits INDEX_BITS .. 31 hold shuffle_bits
INDEX_BITS = 27
_INDEX_MASK = np.uint64((1 << INDEX_BITS) - 1)
_SHUFFLE_SHIFT = np.uint64(INDEX_BITS)


def _joe_kuo_table() -> tuple[np.ndarray, np.ndarray]:
    """(poly, vinit) of scipy's bundled Joe-Kuo file, read with numpy (the bare ``scipy`` package
    only locates it: importing scipy.stats would cost a third of a second of start-up)."""
    import scipy

    path = os.path.join(os.path.dirname(scipy.__file__), "stats", "_sobol_direction_numbers.npz")
    with np.load(path) as z:
        return z["poly"].astype(np.int64), z["vinit"].astype(np.int64)


def direction_numbers(dims: int = 2) -> np.ndarray:
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


def _first_two_dimensions() -> np.ndarray:
    """direction_numbers(2) without reading scipy's table (start-up): dimension 0 is van der
    Corput's, dimension 1's polynomial is x + 1 with m_1 = 1, so m_j = m_(j-1) XOR 2 m_(j-1)."""
    m = np.zeros((2, 32), np.int64)
    m[0] = 1
    m[1, 0] = 1
    for j in range(1, 32):
        m[1, j] = m[1, j - 1] ^ (m[1, j - 1] << 1)
    return (m << (31 - np.arange(32))).astype(np.uint32)


#: (2, 32) uint32 direction numbers of Sobol dimensions 0 and 1 (the compiled kernels read the same
#: table; tests/render/test_sobol.py checks it against scipy's Joe-Kuo file)
DIRECTIONS = _first_two_dimensions()

#: position in a bounce's 8 dimensions (2 + 8 depth + j, render.integrators.path_kernels.shade_bounce)
#: -> component in its group: the light point (j = 1, 2) and the BSDF direction (j = 4, 5) are 2-D
_BOUNCE_COMPONENT = np.array([0, 0, 1, 0, 0, 1, 0, 0], np.int64)


def dimension_group(dim):
    """(first dimension of the group, component 0 or 1) of path dimension(s) ``dim`` (int or
    array): (0, 1) is the pixel jitter, then per bounce [pick, light point (2), Fresnel, BSDF
    direction (2), roulette, spare]."""
    d = np.asarray(dim, dtype=np.int64)
    comp = np.where(d < 2, d, _BOUNCE_COMPONENT[np.maximum(d - 2, 0) % 8])
    return d - comp, comp


def sobol_u32(index: np.ndarray, dim: int) -> np.ndarray:
    """(N,) uint64 holding the 32-bit unscrambled Sobol value of dimension ``dim`` (0 or 1)
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
    """Owen scramble of 32-bit values v (N,) uint64 by 64-bit hashes h (N,) uint64: the nested
    permutation keyed by h's low 32 bits (:func:`nested_scramble`), then an XOR by h's high 32
    bits (the digital shift that makes each value exactly uniform). Returns (N,) uint64 < 2^32."""
    return nested_scramble(v, h) ^ (h >> _S32)


def nested_scramble(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Owen's nested scramble of 32-bit integers x (N,) uint64 keyed by hashes h (low 32 bits):
    bit k flips as a function of the bits above it, so every aligned block of 2^m values maps
    onto an aligned block (the index shuffle). Returns (N,) uint64 < 2^32."""
    seed = h & _MASK32
    x = _reverse32(x)
    x = (x ^ (x * np.uint64(0x3D20ADEA))) & _MASK32
    x = (x + seed) & _MASK32
    x = (x * ((seed >> np.uint64(16)) | np.uint64(1))) & _MASK32
    x = (x ^ (x * np.uint64(0x05526C56))) & _MASK32
    x = (x ^ (x * np.uint64(0x53A22864))) & _MASK32
    return _reverse32(x)


def kensler_permute(x: np.ndarray, p: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Kensler's hashed permutation (2013, "Correlated multi-jittered sampling", ``permute``) of
    [0, w] for w = 2^q - 1, keyed by the 32-bit p: x (N,) uint64 <= w, p and w (N,) uint64.
    Every step is a bijection of the low q bits that reads only low bits (a product's, an XOR
    with a right shift of the masked value), so at a power of two no cycle walking is needed.
    Returns (N,) uint64 <= w."""
    m = _MASK32
    i, p, w = (np.asarray(a, dtype=np.uint64) for a in (x, p, w))
    i = ((i ^ p) * np.uint64(0xE170893D)) & m
    i = i ^ (p >> np.uint64(16))
    i = i ^ ((i & w) >> np.uint64(4))
    i = ((i ^ (p >> np.uint64(8))) * np.uint64(0x0929EB3F)) & m
    i = i ^ (p >> np.uint64(23))
    i = ((i ^ ((i & w) >> np.uint64(1))) * (np.uint64(1) | (p >> np.uint64(27)))) & m
    i = (i * np.uint64(0x6935FA69)) & m
    i = ((i ^ ((i & w) >> np.uint64(11))) * np.uint64(0x74DCB303)) & m
    i = ((i ^ ((i & w) >> np.uint64(2))) * np.uint64(0x9E501CC3)) & m
    i = ((i ^ ((i & w) >> np.uint64(2))) * np.uint64(0xC860A3DF)) & m
    i = i & w
    i = i ^ (i >> np.uint64(5))
    return (i + p) & w


def sobol_keys(seed: int, pixel: np.ndarray, sample: np.ndarray, replicates: int = REPLICATES,
               shuffle: int = 0) -> np.ndarray:
    """Per-path keys of the Sobol sampler: (N,) uint64 from a seed, (N,) pixel and (N,) sample
    indices: high 32 bits hash (seed, pixel, sample mod R), low 27 bits (INDEX_BITS) sample div R
    (the Sobol index), bits 27 .. 31 ``shuffle`` (:func:`shuffle_bits`), R = ``replicates``."""
    s = _mix64(np.array([np.uint64(seed & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    sample = np.asarray(sample, dtype=np.uint64)
    k = _mix64(np.asarray(pixel, dtype=np.uint64) * _GOLDEN ^ s)
    r = np.uint64(replicates)
    k = _mix64(k ^ ((sample % r) * _M2 + _GOLDEN))
    return (k & _HI32) | ((sample // r) & _INDEX_MASK) | (np.uint64(shuffle) << _SHUFFLE_SHIFT)


def replicate_of(sample: np.ndarray, replicates: int = REPLICATES, block: int = 0) -> np.ndarray:
    """(N,) int64 replicate of each sample index: sample mod ``replicates``, or with ``block`` > 0
    (:func:`block_size`) its block min(sample div block, replicates - 1)."""
    s = np.asarray(sample, dtype=np.int64)
    if block > 0:
        return np.minimum(s // int(block), int(replicates) - 1)
    return s % int(replicates)


def sobol_uniform(keys: np.ndarray, dim: int) -> np.ndarray:
    """(N,) float64 in [0, 1): dimension ``dim`` of each Sobol path key (:func:`sobol_keys`):
    component c of group g (:func:`dimension_group`) is Sobol dimension c at the index
    shuffled by a hash of (key, g) (a nested scramble, then a random permutation of its low q
    bits, q the key's :func:`shuffle_bits`), Owen-scrambled by a hash of (key, g, c)."""
    g, c = (int(x) for x in dimension_group(int(dim)))
    h_index = _mix64((keys & _HI32) + np.uint64((g + 1) * 0x9E3779B97F4A7C15 & 0xFFFFFFFFFFFFFFFF))
    h_value = _mix64(h_index ^ np.uint64((c + 1) * 0xBF58476D1CE4E5B9 & 0xFFFFFFFFFFFFFFFF))
    # the index shuffle, XORed by its image of 0: still nested, and it maps [0, 2^m) onto itself,
    # so shuffled indices stay as small as the index (fewer set bits for the Sobol XOR loop)
    zero = np.zeros_like(keys)
    j = nested_scramble(keys & _INDEX_MASK, h_index) ^ nested_scramble(zero, h_index)
    # the groups' points matched at random within aligned 2^q blocks (a nested shuffle alone
    # matches them by a structured map: 1.14-1.38x the variance of random matching across groups)
    w = (np.uint64(1) << ((keys & _MASK32) >> _SHUFFLE_SHIFT)) - np.uint64(1)
    j = (j & ~w) | kensler_permute(j & w, h_index >> _S32, w)
    v = owen_scramble(sobol_u32(j, c), h_value)
    return v.astype(np.float64) * (1.0 / 4294967296.0)


def sobol_block(keys: np.ndarray, dim0: int, count: int) -> np.ndarray:
    """(N, count) float64: dimensions dim0 .. dim0 + count - 1 of :func:`sobol_uniform`."""
    return np.stack([sobol_uniform(keys, d) for d in range(dim0, dim0 + count)], axis=1)
