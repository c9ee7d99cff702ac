"""The path kernels' bit tricks against their plain definitions (render.integrators.path_kernels):
Sobol dimension 1 by the Pascal-matrix superset sum, the 32-bit bit reversal and the 32-bit
Laine-Karras permutation. Each is an exact integer function, so the renders' bytes depend on
these being equal everywhere, not approximately."""
from __future__ import annotations

import numpy as np
from numba import njit

from render import sobol
from render.integrators.path_kernels import _laine_karras, _reverse32, _v1_reversed


@njit(cache=False)
def _apply(xs, hs):
    out = np.empty((3, len(xs)), np.uint64)
    for i in range(len(xs)):
        out[0, i] = _v1_reversed(xs[i] & np.uint64(0xFFFFFFFF))
        out[1, i] = _reverse32(xs[i])
        out[2, i] = _laine_karras(xs[i], hs[i])
    return out


def _rev32(v: int) -> int:
    return int(f"{v & 0xFFFFFFFF:032b}"[::-1], 2)


def _lk_reference(x: int, h: int) -> int:
    """render.sobol's permutation as written there: every step masked to 32 bits."""
    m = 0xFFFFFFFF
    seed = h & m
    x = (x ^ (x * 0x3D20ADEA)) & m
    x = (x + seed) & m
    x = (x * ((seed >> 16) | 1)) & m
    x = (x ^ (x * 0x05526C56)) & m
    return (x ^ (x * 0x53A22864)) & m


def test_kernel_bit_helpers_equal_their_definitions():
    """Dimension 1 of Sobol, bit-reversed, is the XOR of the reversed direction numbers over the
    index's set bits (checked on every basis vector, which fixes a GF(2)-linear map, and on random
    and small indices); the bit reversal and the permutation match their 64-bit masked forms,
    high input bits included."""
    v1 = [int(v) for v in sobol.DIRECTIONS[1]]
    rng = np.random.default_rng(7)
    xs = np.concatenate([np.uint64(1) << np.arange(32, dtype=np.uint64), np.arange(4096, dtype=np.uint64),
                         rng.integers(0, 2 ** 63, 20000, dtype=np.uint64) * np.uint64(2) + np.uint64(1)])
    hs = rng.integers(0, 2 ** 63, len(xs), dtype=np.uint64) * np.uint64(3)
    out = _apply(xs, hs)
    for i, (x, h) in enumerate(zip(xs.tolist(), hs.tolist())):
        j = x & 0xFFFFFFFF
        want = 0
        for t in range(32):
            if j >> t & 1:
                want ^= _rev32(v1[t])
        assert int(out[0, i]) == want, (x, "dim1")
        assert int(out[1, i]) == _rev32(x), (x, "reverse")
        assert int(out[2, i]) == _lk_reference(x, h), (x, h, "laine-karras")
