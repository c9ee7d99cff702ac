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
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Film", "RenderResult", "merge_results", "merge_stats", "group_ranges", "whole_groups"]


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
    int64 samples per replicate (every pixel receives every sample index of a render)."""

    width: int
    height: int
    s1: np.ndarray = None
    s2: np.ndarray = None
    n: np.ndarray = None
    r1: np.ndarray | None = None
    rn: np.ndarray | None = None

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

    def merged(self, other: "Film") -> "Film":
        """A new film holding both films' samples."""
        if (self.width, self.height) != (other.width, other.height):
            raise ValueError("cannot merge films of different sizes")
        if (self.r1 is None) != (other.r1 is None) or (self.r1 is not None and self.r1.shape != other.r1.shape):
            raise ValueError("cannot merge films of different samplers (replicate sums on one side only)")
        if self.r1 is None:
            return Film(self.width, self.height, self.s1 + other.s1, self.s2 + other.s2, self.n + other.n)
        return Film(self.width, self.height, self.s1 + other.s1, self.s2 + other.s2, self.n + other.n,
                    self.r1 + other.r1, self.rn + other.rn)

    def mean(self) -> np.ndarray:
        """(H, W, 3) float32 per-pixel mean (0 where a pixel has no samples)."""
        n = np.maximum(self.n, 1)[:, None]
        return (self.s1 / n).reshape(self.height, self.width, 3).astype(np.float32)

    def variance(self) -> np.ndarray:
        """(H, W, 3) float32 variance of the per-pixel mean (0 where fewer than 2 samples).

        With replicate sums: R' / (R' - 1) sum_r (n_r / n)^2 (m_r - m)^2 over the R' replicates
        holding samples (m_r their means, m the pixel mean; 0 when R' < 2), the variance of a
        mean of R' independent replicate means; unbiased when the n_r are equal."""
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
        total = nr.sum()
        means = self.r1[filled] / nr[:, None, None]  # (R', P, 3)
        m = self.r1[filled].sum(0) / total
        w2 = (nr / total) ** 2
        var = k / (k - 1.0) * np.einsum("r,rpc->pc", w2, (means - m) ** 2)
        return var.reshape(self.height, self.width, 3).astype(np.float32)


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
