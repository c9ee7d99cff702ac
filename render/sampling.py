"""Sampling warps, their densities, MIS heuristics and a counter-based random number generator.

Every warp maps uniform numbers in [0, 1) to a domain and has a matching density; densities of
directions are per unit solid angle, densities of points per unit area.

Random numbers are a pure function of (seed, pixel, sample index, dimension): a stateless
hash (splitmix64's finalizer, as pbrt-v4's hashing samplers) keyed by those four integers. A
render is therefore identical however its samples are split into batches, threads or machines,
and two renders of disjoint sample ranges merge exactly into the render of their union.

Local shading frames are z-up: a direction ``w`` in the frame of unit normal ``n`` has
``w.z = dot(w, n)``.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "path_keys", "uniform", "uniform_block", "INV_PI",
    "concentric_disk", "cosine_hemisphere", "cosine_hemisphere_pdf",
    "uniform_sphere",
    "uniform_triangle", "balance_heuristic", "power_heuristic", "mis_weight",
    "orthonormal_frame", "to_local", "to_world", "dot3", "max3",
]

INV_PI = 1.0 / np.pi

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


def _mix64(x: np.ndarray) -> np.ndarray:
    """splitmix64 finalizer on a (N,) uint64 array (wrapping arithmetic), returns a new array."""
    x = x ^ (x >> _S30)
    x *= _M1
    x ^= x >> _S27
    x *= _M2
    x ^= x >> _S31
    return x


def path_keys(seed: int, pixel: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Per-path hash keys: (N,) uint64 from a seed, (N,) pixel indices and (N,) sample indices."""
    s = _mix64(np.array([np.uint64(seed & 0xFFFFFFFFFFFFFFFF)], dtype=np.uint64) + _GOLDEN)[0]
    k = _mix64(np.asarray(pixel, dtype=np.uint64) * _GOLDEN ^ s)
    return _mix64(k ^ (np.asarray(sample, dtype=np.uint64) * _M2 + _GOLDEN))


def uniform(keys: np.ndarray, dim: int) -> np.ndarray:
    """(N,) float64 uniform numbers in [0, 1) for dimension ``dim`` of each path key.

    Dimension ``dim`` of a key is the ``dim``-th output of the splitmix64 stream seeded by it.
    """
    x = _mix64(keys + np.uint64((int(dim) + 1) * 0x9E3779B97F4A7C15 & 0xFFFFFFFFFFFFFFFF))
    return (x >> _S11).astype(np.float64) * (1.0 / 9007199254740992.0)


def uniform_block(keys: np.ndarray, dim0: int, count: int) -> np.ndarray:
    """(N, count) float64 uniforms for dimensions dim0 .. dim0 + count - 1 (same values as
    :func:`uniform` per dimension), in one vectorized hash."""
    steps = (np.arange(dim0 + 1, dim0 + count + 1, dtype=np.uint64) * _GOLDEN)[None, :]
    x = _mix64(keys[:, None] + steps)
    return (x >> _S11).astype(np.float64) * (1.0 / 9007199254740992.0)


def _concentric(u: np.ndarray, out: np.ndarray) -> None:
    """Write the concentric map of u (N, 2) into out[:, 0:2]."""
    a = 2.0 * u[:, 0] - 1.0
    b = 2.0 * u[:, 1] - 1.0
    big_a = np.abs(a) > np.abs(b)
    num = np.where(big_a, b, a)
    den = np.where(big_a, a, b)
    zero = den == 0
    ratio = num / np.where(zero, 1.0, den)
    theta = np.where(big_a, (np.pi / 4) * ratio, np.pi / 2 - (np.pi / 4) * ratio)
    r = np.where(zero, 0.0, den)
    out[:, 0] = r * np.cos(theta)
    out[:, 1] = r * np.sin(theta)


def concentric_disk(u: np.ndarray) -> np.ndarray:
    """Shirley-Chiu concentric map, u (N, 2) in [0,1)^2 -> (N, 2) points on the unit disk."""
    out = np.empty((len(u), 2))
    _concentric(u, out)
    return out


def cosine_hemisphere(u: np.ndarray) -> np.ndarray:
    """Cosine-weighted directions about +z: u (N, 2) -> (N, 3) unit vectors.

    Malley's method on the polar disk map (r = sqrt(u0), phi = 2 pi u1): fewer operations than
    the concentric map, the same density cos(theta) / pi.
    """
    out = np.empty((len(u), 3))
    r = np.sqrt(u[:, 0])
    phi = (2.0 * np.pi) * u[:, 1]
    out[:, 0] = r * np.cos(phi)
    out[:, 1] = r * np.sin(phi)
    out[:, 2] = np.sqrt(np.maximum(0.0, 1.0 - u[:, 0]))
    return out


def cosine_hemisphere_pdf(cos_theta: np.ndarray) -> np.ndarray:
    """Solid-angle density cos(theta) / pi of :func:`cosine_hemisphere` (0 below the horizon)."""
    return np.maximum(cos_theta, 0.0) * INV_PI


def uniform_sphere(u: np.ndarray) -> np.ndarray:
    """Uniform directions on the unit sphere: u (N, 2) -> (N, 3); density 1 / (4 pi)."""
    z = 1.0 - 2.0 * u[:, 0]
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def uniform_triangle(u: np.ndarray) -> np.ndarray:
    """Uniform barycentrics (b1, b2) on a triangle: u (N, 2) -> (N, 2); point = v0 + b1 e1 + b2 e2.

    Density 1 / area per unit area (square-root warp, pbrt-v3's UniformSampleTriangle).
    """
    su = np.sqrt(u[:, 0])
    return np.stack([1.0 - su, u[:, 1] * su], axis=1)


def balance_heuristic(pdf_f: np.ndarray, pdf_g: np.ndarray) -> np.ndarray:
    """Veach's balance heuristic weight of strategy f: pdf_f / (pdf_f + pdf_g), 0 where both are 0."""
    return mis_weight(pdf_f, pdf_g, 1.0)


def power_heuristic(pdf_f: np.ndarray, pdf_g: np.ndarray) -> np.ndarray:
    """Veach's power heuristic (beta = 2) weight of strategy f: pdf_f^2 / (pdf_f^2 + pdf_g^2)."""
    return mis_weight(pdf_f, pdf_g, 2.0)


def mis_weight(pdf_f: np.ndarray, pdf_g: np.ndarray, beta: float) -> np.ndarray:
    """MIS weight 1 / (1 + (pdf_g / pdf_f)^beta) of strategy f, overflow-safe, in [0, 1].

    pdf_f, pdf_g: (N,) non-negative densities of the same sample under both strategies.
    """
    pf = np.asarray(pdf_f, dtype=np.float64)
    pg = np.asarray(pdf_g, dtype=np.float64)
    ok = pf > 0
    ratio = np.where(ok, pg / np.where(ok, pf, 1.0), 0.0)
    with np.errstate(over="ignore"):
        w = 1.0 / (1.0 + np.minimum(ratio, 1e150) ** beta)
    return np.where(ok, w, 0.0)


def orthonormal_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangents (s, t) completing unit normals n (N, 3) to right-handed frames (s, t, n).

    Branchless construction of Duff et al. 2017 ("Building an orthonormal basis, revisited").
    """
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return s, t


def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (N, 3) arrays -> (N,)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def max3(a: np.ndarray) -> np.ndarray:
    """Row-wise maximum of an (N, 3) array -> (N,) (faster than a.max(axis=1) for 3 columns)."""
    return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])


def to_local(w: np.ndarray, s: np.ndarray, t: np.ndarray, n: np.ndarray) -> np.ndarray:
    """World directions (N, 3) -> local frame coordinates (N, 3) (z along n)."""
    out = np.empty_like(w)
    out[:, 0], out[:, 1], out[:, 2] = dot3(w, s), dot3(w, t), dot3(w, n)
    return out


def to_world(w: np.ndarray, s: np.ndarray, t: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Local directions (N, 3) -> world (N, 3)."""
    return w[:, 0:1] * s + w[:, 1:2] * t + w[:, 2:3] * n
