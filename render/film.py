"""Per-pixel sample moments: the mean image and its variance image, and exact merging.

A film keeps, per pixel, the sample count n, the sum of samples S1 and the sum of their squares
S2 (float64). The mean is S1 / n and the variance *of the mean* (the squared standard error)
is (S2 - S1^2 / n) / (n (n - 1)): every render carries its own error bars. Two films of
disjoint sample ranges merge by adding moments, which is exactly the film of the union (up to
float64 rounding of the sums).

Integrators whose samples are not independent (sppm's progressive passes, pssmlt's Markov
chains) split a render into independent *groups* instead (:func:`group_ranges`): each group is
one sample of the film (its image), so the mean is the mean of the group images and the
variance that of the mean across groups, and renders of whole groups merge like any other.

Stratified samplers (the Sobol sampler of :mod:`render.sobol`) make a pixel's samples negatively
correlated, so (S2 - S1^2 / n) / (n (n - 1)) no longer estimates the variance of the mean. Their
films also keep per-*replicate* sums r1 (R independent scramblings, sample s in replicate
s mod R) and counts rn, and the variance of the mean is estimated from the spread of the
replicate means (:meth:`Film.variance`); these sums merge by addition like the others.

One sequence per pixel (``sampler="sobol-blocks"``, ``Film.blocks``): the R sums are those of R
consecutive blocks of B = n / R samples of ONE scrambled sequence, each block a B-point net. The
blocks are negatively correlated, so the spread of their means overstates the variance of the
whole mean (by 2.7x at 64 spp, 4x at 256 on the Cornell box). No estimator free of assumptions
exists for one randomized net (the variance V(n) of the n-point mean is not identified by its
parts), so this one is a model, calibrated against the spread over seeds. For any aligned split
into R' groups (m_g their means, m the whole mean), E sum_g (m_g - m)^2 = R' (V(n / R') - V(n))
exactly; so D_R' = (R' - 1) / R' s^2 (s^2 the sample variance of the m_g) estimates V(n / R') -
V(n). Assuming the last two halvings share a rate t (V(n / 4) = t^2 V(n), V(n / 2) = t V(n);
t = 2 for Monte Carlo, 2^(3/2) for a 2-D discontinuity, up to 8 for smooth integrands under Owen
scrambling): D_4 / D_2 = t + 1 and V(n) = D_2 / (t - 1). The halves give one degree of freedom per
pixel and channel, so D_R, D_4 and D_2 are summed over the channels and a (2 RATE_WINDOW + 1)^2
window; t = clip(D_4 / D_2 - 1, 2, T_MAX), and a pixel's variance is its own D_R times the
window's V(n) / D_R (:func:`blocks_variance`). The coarsest levels are used because an
integrand's rate slows as n grows when a fast-converging part hides a discontinuity (MIS, BSDF
sampling hitting a light): a rate fitted at the finest blocks then overshoots (measured: up to
3.7x low on the direct-light probe at 1024 spp against 1.2x with the coarsest). Measured on the
Cornell box over 8 seeds (path, 64 and 256 spp): the mean empirical variance / mean estimate
0.82 and 0.75 (conservative; the old D_R alone 0.37 and 0.24), per decile band of the pixels'
variance 0.5-1.1 (architecture.md). Renders whose blocks are not all equally full (a partial
sample range, spp not a multiple of R) keep the conservative s^2 / R of the blocks.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: half-width (pixels) of the window the blocks estimator pools its convergence rate over
RATE_WINDOW = 7
#: the largest t = 2^(2a) it fits (a = 3/2: Owen's rate for smooth integrands)
T_MAX = 8.0

__all__ = ["Film", "RenderResult", "merge_results", "merge_stats", "group_ranges", "whole_groups", "blocks_variance",
           "RATE_WINDOW", "T_MAX"]


def group_ranges(spp: int, groups: int) -> list[tuple[int, int]]:
    """The independent groups of a render of ``spp`` samples: min(groups, spp) contiguous
    half-open sample ranges [g spp // K, (g + 1) spp // K) covering [0, spp), sizes differing
    by at most one. A unit of work of a grouped integrator is a run of whole groups."""
    spp, groups = int(spp), int(groups)
    if spp < 1 or groups < 1:
        raise ValueError(f"spp and groups must be >= 1, got {spp}, {groups}")
    k = min(groups, spp)
    return [(g * spp // k, (g + 1) * spp // k) for g in range(k)]


def whole_groups(sample_range: tuple[int, int], spp: int, groups: int, integrator: str) -> list[tuple[int, int]]:
    """The groups of :func:`group_ranges` (spp, groups) that ``sample_range`` covers exactly;
    ValueError naming ``integrator`` when the range does not start and end on group boundaries."""
    a, b = int(sample_range[0]), int(sample_range[1])
    ranges = group_ranges(spp, groups)
    inside = [r for r in ranges if a <= r[0] and r[1] <= b]
    if not inside or inside[0][0] != a or inside[-1][1] != b:
        starts = [r[0] for r in ranges] + [spp]
        raise ValueError(f"integrator '{integrator}' renders whole groups of samples: sample_range must start and "
                         f"end on the group boundaries {starts} of its {spp} samples (no split inside a group, "
                         f"no refine), got {(a, b)}")
    return inside


def merge_stats(a: dict, b: dict) -> dict:
    """Stats of two merged renders: numbers (not bools) present in either are summed (render
    stats are additive counters: time_s, paths, rays, ...); anything else is kept where both
    agree and dropped where they differ."""
    out = {}
    for k in a.keys() | b.keys():
        x, y = a.get(k, 0), b.get(k, 0)
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (x, y)):
            out[k] = x + y
        elif k in a and k in b and x == y:
            out[k] = x
    return out


@dataclass
class Film:
    """Moments of a (height, width) RGB film. s1, s2: (H*W, 3) float64; n: (H*W,) int64.
    Optionally (stratified samplers) r1: (R, H*W, 3) float64 per-replicate sums and rn: (R,)
    int64 samples per replicate (every pixel receives every sample index of a render);
    blocks: the R sums are consecutive blocks of one sequence per pixel, not independent
    replicates (the variance model of the module docstring)."""

    width: int
    height: int
    s1: np.ndarray = None
    s2: np.ndarray = None
    n: np.ndarray = None
    r1: np.ndarray | None = None
    rn: np.ndarray | None = None
    blocks: bool = False

    def __post_init__(self):
        p = self.width * self.height
        if self.s1 is None:
            self.s1 = np.zeros((p, 3))
        if self.s2 is None:
            self.s2 = np.zeros((p, 3))
        if self.n is None:
            self.n = np.zeros(p, np.int64)

    def add(self, pixel: np.ndarray, values: np.ndarray) -> None:
        """Accumulate samples: pixel (N,) int row-major indices, values (N, 3) finite radiance."""
        p = self.width * self.height
        for c in range(3):
            self.s1[:, c] += np.bincount(pixel, weights=values[:, c], minlength=p)
            self.s2[:, c] += np.bincount(pixel, weights=values[:, c] * values[:, c], minlength=p)
        self.n += np.bincount(pixel, minlength=p)

    def add_moments(self, s1: np.ndarray, s2: np.ndarray, n: np.ndarray) -> None:
        """Accumulate precomputed per-pixel moments (same shapes as the film's)."""
        self.s1 += s1
        self.s2 += s2
        self.n += n

    def _check_mergeable(self, other: "Film") -> None:
        if (self.width, self.height) != (other.width, other.height):
            raise ValueError("cannot merge films of different sizes")
        if (self.r1 is None) != (other.r1 is None) or (self.r1 is not None and self.r1.shape != other.r1.shape):
            raise ValueError("cannot merge films of different samplers (replicate sums on one side only)")
        if self.blocks != other.blocks:
            raise ValueError("cannot merge films of different samplers (blocks of one sequence against replicates)")

    def merged(self, other: "Film") -> "Film":
        """A new film holding both films' samples."""
        self._check_mergeable(other)
        if self.r1 is None:
            return Film(self.width, self.height, self.s1 + other.s1, self.s2 + other.s2, self.n + other.n)
        return Film(self.width, self.height, self.s1 + other.s1, self.s2 + other.s2, self.n + other.n,
                    self.r1 + other.r1, self.rn + other.rn, self.blocks)

    def merge_in_place(self, other: "Film") -> None:
        """Add ``other``'s samples to this film: the sums of :meth:`merged`, bit for bit, without
        new arrays (replicate sums only where ``other`` holds samples: a batch of a few samples
        fills one or two of the R blocks, and x + 0.0 is x: sums that start at +0.0 never hold -0.0)."""
        self._check_mergeable(other)
        self.s1 += other.s1
        self.s2 += other.s2
        self.n += other.n
        if self.r1 is not None:
            for r in np.flatnonzero(other.rn):
                self.r1[r] += other.r1[r]
            self.rn += other.rn

    def mean(self) -> np.ndarray:
        """(H, W, 3) float32 per-pixel mean (0 where a pixel has no samples)."""
        n = np.maximum(self.n, 1)[:, None]
        return (self.s1 / n).reshape(self.height, self.width, 3).astype(np.float32)

    def variance(self) -> np.ndarray:
        """(H, W, 3) float32 variance of the per-pixel mean (0 where fewer than 2 samples).

        With replicate sums: R' / (R' - 1) sum_r (n_r / n)^2 (m_r - m)^2 over the R' replicates
        holding samples (m_r their means, m the pixel mean; 0 when R' < 2), the variance of a
        mean of R' independent replicate means; unbiased when the n_r are equal. Blocks of one
        sequence (``blocks``) with all R blocks equally full: the power-law model of the module
        docstring (:func:`blocks_variance`)."""
        if self.r1 is not None:
            return self._replicate_variance()
        n = self.n.astype(np.float64)[:, None]
        ok = n >= 2
        nn = np.where(ok, n, 2.0)
        var = (self.s2 - self.s1 * self.s1 / nn) / (nn * (nn - 1.0))
        var = np.where(ok, np.maximum(var, 0.0), 0.0)
        return var.reshape(self.height, self.width, 3).astype(np.float32)

    def _replicate_variance(self) -> np.ndarray:
        filled = self.rn > 0
        k = int(filled.sum())
        if k < 2:
            return np.zeros((self.height, self.width, 3), np.float32)
        nr = self.rn[filled].astype(np.float64)
        if self.blocks and k == len(self.rn) and k >= 4 and np.all(self.rn == self.rn[0]):
            var = blocks_variance(self.r1 / nr[:, None, None], self.width, self.height)
            return var.reshape(self.height, self.width, 3).astype(np.float32)
        total = nr.sum()
        means = self.r1[filled] / nr[:, None, None]  # (R', P, 3)
        m = self.r1[filled].sum(0) / total
        w2 = (nr / total) ** 2
        var = k / (k - 1.0) * np.einsum("r,rpc->pc", w2, (means - m) ** 2)
        return var.reshape(self.height, self.width, 3).astype(np.float32)


def _box_sum(x: np.ndarray, w: int) -> np.ndarray:
    """(H, W) sums of (H, W) float64 ``x`` over the (2w + 1)^2 window around each pixel (zero
    outside the image), by summed-area table."""
    n = 2 * w + 1
    c = np.pad(np.pad(x, w).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    return c[n:, n:] - c[:-n, n:] - c[n:, :-n] + c[:-n, :-n]


def _level_spread(means: np.ndarray, blocks: int) -> np.ndarray:
    """(P, 3) D = (R' - 1) / R' s^2 of the means of ``blocks`` = R' aligned groups of the R block
    means ``means`` (R, P, 3) (s^2 their sample variance): E D = V(n / R') - V(n) exactly,
    the variance of one group's mean less the whole mean's (module docstring)."""
    m = means.reshape(blocks, means.shape[0] // blocks, *means.shape[1:]).mean(1)
    return m.var(0, ddof=1) * ((blocks - 1.0) / blocks)


def blocks_variance(means: np.ndarray, width: int, height: int, window: int = RATE_WINDOW,
                    t_max: float = T_MAX) -> np.ndarray:
    """(P, 3) float64 variance of the mean of R (a power of two >= 4) equal consecutive blocks of
    one scrambled sequence per pixel, from their means ``means`` (R, P, 3), P = width * height
    row-major (module docstring): with D_R, D_4, D_2 the spreads of the R blocks, the quarters
    and the halves, each summed over the channels and a window, t = clip(D_4 / D_2 - 1, 2,
    t_max) and V = D_R max(D_2 / (t - 1), D_4 / (t^2 - 1)) / D_R's window sum (the two agree
    unless t was clipped). Finite and >= 0 (no spread in a window: 0)."""
    r = means.shape[0]
    if r < 4 or r & (r - 1):
        raise ValueError(f"blocks_variance needs a power of two >= 4 blocks, got {r}")
    d_r = _level_spread(means, r)  # (P, 3)
    a, q, h = (_box_sum(d.sum(1).reshape(height, width), window).ravel()
               for d in (d_r, _level_spread(means, 4), _level_spread(means, 2)))
    t = np.clip(q / np.where(h > 0, h, 1.0) - 1.0, 2.0, float(t_max))  # h = 0 and q = 0: no spread
    # V(n) from the halves or the quarters: equal unless t was clipped, then the larger (a
    # rate beyond t_max, halves that agree exactly, is not believed)
    v = np.maximum(h / (t - 1.0), q / (t * t - 1.0))
    rho = np.where(a > 0, v / np.where(a > 0, a, 1.0), 0.0)  # V(n) / D_R, pooled
    return d_r * rho[:, None]


@dataclass
class RenderResult:
    """A render: mean (H, W, 3) float32 linear radiance, variance (H, W, 3) float32 variance of
    that mean, spp, the half-open ``sample_range`` rendered, the raw ``film`` moments, the
    ``integrator`` used and ``stats``: additive counters (:func:`merge_stats` sums them), at
    least time_s and paths; rays where the integrator counts them."""

    mean: np.ndarray
    variance: np.ndarray
    spp: int
    sample_range: tuple[int, int]
    film: Film
    integrator: str
    stats: dict = field(default_factory=dict)

    @classmethod
    def from_film(cls, film: Film, sample_range, integrator: str, stats: dict) -> "RenderResult":
        a, b = sample_range
        return cls(film.mean(), film.variance(), int(b - a), (int(a), int(b)), film, integrator, dict(stats))

    @property
    def stderr(self) -> np.ndarray:
        """(H, W, 3) float32 standard error of the mean."""
        return np.sqrt(self.variance)


def merge_results(a: RenderResult, b: RenderResult) -> RenderResult:
    """Merge two renders of the same view over disjoint sample ranges (e.g. [0, 8) and [8, 16))."""
    (a0, a1), (b0, b1) = a.sample_range, b.sample_range
    if a0 < b1 and b0 < a1:
        raise ValueError(f"sample ranges overlap: {a.sample_range} and {b.sample_range}")
    if a.integrator != b.integrator:
        raise ValueError(f"cannot merge renders of different integrators ({a.integrator}, {b.integrator})")
    lo, hi = min(a0, b0), max(a1, b1)
    film = a.film.merged(b.film)
    return RenderResult(film.mean(), film.variance(), a.spp + b.spp, (lo, hi), film, a.integrator,
                        merge_stats(a.stats, b.stats))
