"""Film moments: the variance image is the variance of the per-pixel mean; merging is exact."""
from __future__ import annotations

import numpy as np
import pytest

from render.film import Film, RenderResult, merge_results


def test_mean_and_variance_of_the_mean_match_numpy():
    rng = np.random.default_rng(0)
    w, h, spp = 3, 2, 50
    samples = rng.exponential(size=(spp, w * h, 3))
    f = Film(w, h)
    for s in samples:
        f.add(np.arange(w * h), s)
    assert np.allclose(f.mean().reshape(-1, 3), samples.mean(0), rtol=1e-6)
    assert np.allclose(f.variance().reshape(-1, 3), samples.var(0, ddof=1) / spp, rtol=1e-5)
    assert f.mean().dtype == np.float32 and f.variance().dtype == np.float32


def test_merge_is_the_film_of_the_union_and_guards_small_counts():
    rng = np.random.default_rng(1)
    pix = rng.integers(0, 4, 1000)
    vals = rng.random((1000, 3))
    a, b, whole = Film(2, 2), Film(2, 2), Film(2, 2)
    a.add(pix[:300], vals[:300])
    b.add(pix[300:], vals[300:])
    whole.add(pix, vals)
    m = a.merged(b)
    assert np.allclose(m.s1, whole.s1, rtol=1e-14) and np.array_equal(m.n, whole.n)
    one = Film(2, 2)
    one.add(np.array([0]), np.array([[1.0, 2.0, 3.0]]))
    assert np.all(np.isfinite(one.variance())) and np.all(one.variance() == 0)
    ra = RenderResult.from_film(a, (0, 3), "path", {"rays": 1})
    rb = RenderResult.from_film(b, (3, 7), "path", {"rays": 2})
    r = merge_results(ra, rb)
    assert r.sample_range == (0, 7) and r.stats["rays"] == 3
    with pytest.raises(ValueError):
        merge_results(ra, RenderResult.from_film(b, (2, 5), "path", {}))
    with pytest.raises(ValueError):
        merge_results(ra, RenderResult.from_film(b, (3, 7), "direct", {}))


def test_merge_in_place_is_merged_bit_for_bit():
    """Film.merge_in_place (the in-process fold of the reference stage) gives merged()'s sums to
    the bit, adding replicate sums only where the incoming film holds samples; films of
    different samplers are refused as by merged()."""
    rng = np.random.default_rng(4)

    def film(rn):
        f = Film(5, 3)
        f.s1, f.s2, f.n = rng.random((15, 3)), rng.random((15, 3)), rng.integers(0, 9, 15)
        f.r1 = np.where(np.asarray(rn)[:, None, None] > 0, rng.random((4, 15, 3)), 0.0)
        f.rn = np.asarray(rn, np.int64)
        f.blocks = True
        return f

    a, b = film([3, 2, 0, 0]), film([0, 1, 4, 0])
    want = a.merged(b)
    a.merge_in_place(b)
    for field in ("s1", "s2", "n", "r1", "rn"):
        assert getattr(a, field).tobytes() == getattr(want, field).tobytes(), field
    other = film([1, 0, 0, 0])
    other.blocks = False
    with pytest.raises(ValueError, match="samplers"):
        a.merge_in_place(other)
