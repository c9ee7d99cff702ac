"""Volume rendering: the emission-absorption integral along rays (the lecture's last step).

The expected colour of a ray r(t) = o + t d between t_n and t_f is (Mildenhall et al. 2020, eq. 1)

    C(r) = int_{t_n}^{t_f} T(t) sigma(r(t)) c(r(t), d) dt,   T(t) = exp(-int_{t_n}^t sigma(r(s)) ds)

and its quadrature over segments i of length delta_i with constant sigma_i, c_i (eq. 3) is

    C = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i,   T_i = exp(-sum_{j<i} sigma_j delta_j).

For fields that *are* piecewise constant along the ray (voxels with nearest lookup) the sum is
the exact integral, provided the segments are the exact voxel crossings: :func:`voxel_segments`
computes them and :func:`render_voxels_exact` integrates such a field exactly.

Numerics (REFERENCES.md, "Numerical pitfalls"): optical depths tau_i = sigma_i delta_i are
clamped to [0, TAU_MAX] (negative densities or lengths are invalid, and beyond TAU_MAX the
segment is opaque to float64 precision anyway, which keeps inf - inf out of gradients);
alpha_i = -expm1(-tau_i) is accurate for tiny tau; T_i is the exponential of an *exclusive*
cumulative sum (never a product of (1 - alpha), never cumsum minus tau); samples whose incoming
transmittance has dropped below ``stop_transmittance`` get zero weight (early termination: they
could change the colour by at most that much). Everything is differentiable torch and works in
float32 and float64; the composited weights lie in [0, 1] and sum to at most 1 per ray.

Conventions: ``t`` is the distance along unit-length ray directions (ray length, *not* z-depth:
callers convert with the cosine to the optical axis). Shapes are (R, S) for R rays of S samples.

It lives with the NeRF because the NeRF is its only user in the library (the path tracer's media
are numpy delta tracking, :mod:`render.media`); ``tests/render/test_media.py`` borrows its exact voxel
integral as a closed form for ``volpath``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["TAU_MAX", "STOP_TRANSMITTANCE", "Composite", "optical_depth", "alpha_from_tau",
           "exclusive_transmittance", "composite", "composite_constant",
           "VoxelField", "voxel_segments", "render_voxels_exact", "render_voxels_quadrature",
           "ray_aabb"]

#: optical depth beyond which a segment counts as opaque (exp(-TAU_MAX) underflows float64)
TAU_MAX = 1.0e3
#: default early-termination threshold on the transmittance (REFERENCES.md: 1e-4)
STOP_TRANSMITTANCE = 1.0e-4


@dataclass(frozen=True)
class Composite:
    """Result of compositing R rays of S samples.

    rgb: (R, C) colour, background included; opacity: (R,) sum of weights in [0, 1];
    distance: (R,) expected termination distance along the ray of the absorbed part
    (sum w_i t_i / opacity, 0 where opacity is 0; ray length, not z-depth);
    weights: (R, S) w_i = T_i alpha_i; transmittance: (R, S) T_i, the light reaching sample i.
    """

    rgb: torch.Tensor
    opacity: torch.Tensor
    distance: torch.Tensor
    weights: torch.Tensor
    transmittance: torch.Tensor


def optical_depth(sigma: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """tau = sigma * delta clamped to [0, TAU_MAX]; (R, S) like the inputs (broadcast)."""
    return torch.clamp(sigma * delta, min=0.0, max=TAU_MAX)


def alpha_from_tau(tau: torch.Tensor) -> torch.Tensor:
    """alpha = 1 - exp(-tau) computed as -expm1(-tau) (no cancellation for tiny tau)."""
    return -torch.expm1(-tau)


def exclusive_transmittance(tau: torch.Tensor) -> torch.Tensor:
    """T_i = exp(-sum_{j<i} tau_j) for (R, S) optical depths: exclusive cumsum in log space."""
    zeros = torch.zeros_like(tau[..., :1])
    return torch.exp(-torch.cat([zeros, torch.cumsum(tau[..., :-1], dim=-1)], dim=-1))


def composite(sigma: torch.Tensor, rgb: torch.Tensor, delta: torch.Tensor, t_mid: torch.Tensor | None = None,
              background: torch.Tensor | float | None = None,
              stop_transmittance: float = STOP_TRANSMITTANCE) -> Composite:
    """Composite samples front to back.

    sigma: (R, S) densities >= 0 (1 / world unit); rgb: (R, S, C) emitted colours;
    delta: (R, S) segment lengths >= 0 (world units; zero-length segments contribute nothing);
    t_mid: (R, S) sample distances along the ray for the expected distance (default: the
    cumulative segment midpoints); background: colour behind the volume, a scalar, (C,) or
    (R, C), default black; stop_transmittance: samples reached by less light than this get
    zero weight (0 disables early termination).
    Masked-out samples (outside occupied space, padding) are passed with sigma = 0.
    """
    if sigma.shape != delta.shape or rgb.shape[:-1] != sigma.shape:
        raise ValueError(f"composite: shapes sigma {tuple(sigma.shape)}, delta {tuple(delta.shape)}, "
                         f"rgb {tuple(rgb.shape)} do not match (R, S), (R, S), (R, S, C)")
    tau = optical_depth(sigma, delta)
    alpha = alpha_from_tau(tau)
    trans = exclusive_transmittance(tau)
    weights = trans * alpha
    if stop_transmittance > 0:
        weights = torch.where(trans >= stop_transmittance, weights, torch.zeros_like(weights))
    opacity = weights.sum(dim=-1).clamp(max=1.0)
    color = (weights[..., None] * rgb).sum(dim=-2)
    if background is not None:
        bg = torch.as_tensor(background, dtype=color.dtype, device=color.device)
        color = color + (1.0 - opacity)[..., None] * bg
    if t_mid is None:
        t_mid = torch.cumsum(delta, dim=-1) - 0.5 * delta
    # expected distance of the absorbed part; the clamp guards the division for empty rays
    dist = (weights * t_mid).sum(dim=-1) / opacity.clamp(min=1e-10)
    dist = torch.where(opacity > 0, dist, torch.zeros_like(dist))
    return Composite(color, opacity, dist, weights, trans)


def composite_constant(sigma: float, rgb, length: float, background=0.0) -> np.ndarray:
    """Closed form for constant sigma and c along a ray of length T (the lecture's I(0)):
    c (1 - exp(-sigma T)) + background exp(-sigma T). Returns (C,) float64."""
    c = np.asarray(rgb, dtype=np.float64)
    a = -np.expm1(-sigma * length)
    return c * a + np.asarray(background, dtype=np.float64) * (1.0 - a)


# --------------------------------------------------------------------------- rays and boxes


def ray_aabb(origins: torch.Tensor, dirs: torch.Tensor, lo, hi) -> tuple[torch.Tensor, torch.Tensor]:
    """Slab test: entry and exit distances of rays with an axis-aligned box.

    origins, dirs: (R, 3); lo, hi: (3,) box corners. Returns (t0, t1), both (R,), with
    t0 >= 0; rays that miss have t1 <= t0. Axis-parallel rays (d = 0 on an axis) are handled
    without division by zero (a tiny substitute keeps the slab test's signs right).
    """
    lo = torch.as_tensor(lo, dtype=origins.dtype, device=origins.device)
    hi = torch.as_tensor(hi, dtype=origins.dtype, device=origins.device)
    tiny = torch.finfo(origins.dtype).tiny ** 0.5
    safe = torch.where(dirs.abs() < tiny, torch.full_like(dirs, tiny) * torch.where(dirs < 0, -1.0, 1.0), dirs)
    ta, tb = (lo - origins) / safe, (hi - origins) / safe
    t0 = torch.minimum(ta, tb).amax(dim=-1).clamp(min=0.0)
    t1 = torch.maximum(ta, tb).amin(dim=-1)
    return t0, t1


# --------------------------------------------------------------------------- voxel fields


@dataclass(frozen=True)
class VoxelField:
    """A piecewise-constant field on a regular grid of cells spanning the box [lo, hi].

    sigma: (X, Y, Z) densities >= 0; rgb: (X, Y, Z, C) colours; cell (i, j, k) covers
    lo + (i, j, k) * size / (X, Y, Z) to the next corner ("nearest" lookup, cell-centred).
    Outside the box the density is zero.
    """

    sigma: torch.Tensor
    rgb: torch.Tensor
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def __post_init__(self) -> None:
        if self.sigma.ndim != 3 or self.rgb.shape[:3] != self.sigma.shape:
            raise ValueError(f"VoxelField: sigma {tuple(self.sigma.shape)} and rgb {tuple(self.rgb.shape)} "
                             "must be (X, Y, Z) and (X, Y, Z, C)")
        if not all(h > l for l, h in zip(self.lo, self.hi)):
            raise ValueError(f"VoxelField: empty box lo={self.lo} hi={self.hi}")

    @property
    def resolution(self) -> tuple[int, int, int]:
        return tuple(self.sigma.shape)

    def cell_of(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(N, 3) points -> ((N, 3) int64 cell indices clamped into the grid, (N,) bool inside)."""
        lo = torch.as_tensor(self.lo, dtype=points.dtype)
        hi = torch.as_tensor(self.hi, dtype=points.dtype)
        res = torch.as_tensor(self.resolution, dtype=points.dtype)
        u = (points - lo) / (hi - lo) * res
        inside = ((u >= 0) & (u < res)).all(dim=-1)
        idx = torch.minimum(u.floor().clamp(min=0), res - 1).long()
        return idx, inside

    def lookup(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Nearest lookup at (..., 3) points: ((...,) sigma, zero outside; (..., C) rgb)."""
        shape = points.shape[:-1]
        idx, inside = self.cell_of(points.reshape(-1, 3))
        s = self.sigma[idx[:, 0], idx[:, 1], idx[:, 2]] * inside
        c = self.rgb[idx[:, 0], idx[:, 1], idx[:, 2]]
        return s.reshape(shape), c.reshape(*shape, -1)


def voxel_segments(field: VoxelField, origins: torch.Tensor, dirs: torch.Tensor,
                   near: float = 0.0, far: float = float("inf")) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Exact crossings of rays with the grid's cells.

    origins, dirs: (R, 3) rays (dirs unit length). Every cell-boundary plane crossing inside the
    box and inside [near, far] splits the ray, so each segment lies in one cell. Returns
    (t_start, t_end, cells): (R, K) and (R, K) distances and (R, K, 3) int64 cell indices with
    K = X + Y + Z + 2; unused segments have t_end == t_start (zero length).
    """
    t0, t1 = ray_aabb(origins, dirs, field.lo, field.hi)
    t0 = t0.clamp(min=near)
    t1 = torch.minimum(t1, torch.full_like(t1, far))
    t1 = torch.maximum(t1, t0)  # misses: empty interval
    planes = []
    for a, n in enumerate(field.resolution):
        p = torch.linspace(field.lo[a], field.hi[a], n + 1, dtype=origins.dtype)
        d = dirs[:, a:a + 1]
        parallel = d == 0
        t = (p[None, :] - origins[:, a:a + 1]) / torch.where(parallel, torch.ones_like(d), d)
        planes.append(torch.where(parallel, t0[:, None].expand_as(t), t))  # parallel: no crossing
    t = torch.cat([t0[:, None]] + planes + [t1[:, None]], dim=1)
    t = torch.minimum(torch.maximum(t, t0[:, None]), t1[:, None])
    t, _ = torch.sort(t, dim=1)
    ts, te = t[:, :-1], t[:, 1:]
    mid = origins[:, None, :] + 0.5 * (ts + te)[..., None] * dirs[:, None, :]
    cells, _ = field.cell_of(mid.reshape(-1, 3))
    return ts, te, cells.reshape(*ts.shape, 3)


def render_voxels_exact(field: VoxelField, origins: torch.Tensor, dirs: torch.Tensor, background=None,
                        near: float = 0.0, far: float = float("inf")) -> Composite:
    """The exact emission-absorption integral of a piecewise-constant voxel field.

    Within one cell sigma and c are constant, so the segment's contribution
    T_in (1 - exp(-sigma l)) c is exact, and so is the sum over the exact crossings
    (:func:`voxel_segments`). No early termination (stop_transmittance = 0): exact.
    Returns a :class:`Composite` over the (R, K) segments.
    """
    ts, te, cells = voxel_segments(field, origins, dirs, near, far)
    sigma = field.sigma[cells[..., 0], cells[..., 1], cells[..., 2]]
    rgb = field.rgb[cells[..., 0], cells[..., 1], cells[..., 2]]
    return composite(sigma, rgb, te - ts, 0.5 * (ts + te), background, stop_transmittance=0.0)


def render_voxels_quadrature(field: VoxelField, origins: torch.Tensor, dirs: torch.Tensor, n_samples: int,
                             background=None, near: float = 0.0, far: float = float("inf"),
                             stop_transmittance: float = 0.0) -> Composite:
    """The quadrature of eq. 3 with ``n_samples`` equal segments across the box per ray, the field
    looked up at each segment's midpoint (what a NeRF renderer does): converges to
    :func:`render_voxels_exact` as ``n_samples`` grows (error O(1 / n_samples) at cell edges)."""
    t0, t1 = ray_aabb(origins, dirs, field.lo, field.hi)
    t0 = t0.clamp(min=near)
    t1 = torch.maximum(torch.minimum(t1, torch.full_like(t1, far)), t0)
    u = (torch.arange(n_samples, dtype=origins.dtype) + 0.5) / n_samples
    t_mid = t0[:, None] + (t1 - t0)[:, None] * u[None, :]
    delta = ((t1 - t0) / n_samples)[:, None].expand_as(t_mid)
    pts = origins[:, None, :] + t_mid[..., None] * dirs[:, None, :]
    sigma, rgb = field.lookup(pts)
    return composite(sigma, rgb, delta, t_mid, background, stop_transmittance)
