"""Sample placement along rays: stratified bins, inverse-CDF (hierarchical) sampling, and
fixed-step marching through an occupancy grid.

Distances ``t`` are along unit ray directions (ray length). Shapes: R rays, S samples.
"""
from __future__ import annotations

import torch

__all__ = ["stratified", "sample_pdf", "march_steps"]


def stratified(t0: torch.Tensor, t1: torch.Tensor, n: int, perturb: bool,
               generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """n stratified samples per ray in [t0, t1] (NeRF eq. 2): one uniform draw per bin when
    ``perturb`` (training), bin midpoints otherwise.

    t0, t1: (R,). Returns (t_mid, edges): (R, n) sample distances and (R, n + 1) bin edges.
    """
    u = torch.linspace(0.0, 1.0, n + 1, dtype=t0.dtype, device=t0.device)
    edges = t0[:, None] + (t1 - t0)[:, None] * u[None, :]
    if perturb:
        r = torch.rand(t0.shape[0], n, dtype=t0.dtype, generator=generator)
    else:
        r = torch.full((t0.shape[0], n), 0.5, dtype=t0.dtype)
    t = edges[:, :-1] + (edges[:, 1:] - edges[:, :-1]) * r
    return t, edges


def sample_pdf(edges: torch.Tensor, weights: torch.Tensor, n: int, perturb: bool,
               generator: torch.Generator | None = None) -> torch.Tensor:
    """Inverse-transform sampling of the piecewise-constant pdf given by ``weights`` over bins
    (NeRF section 5.2, hierarchical volume sampling).

    edges: (R, S + 1) increasing bin edges; weights: (R, S) >= 0 (detached by the caller).
    Returns (R, n) sorted samples. A ray with all-zero weights samples uniformly (a small
    constant added to every weight guards the 0/0 of the normalisation).
    """
    w = weights + 1e-5
    pdf = w / w.sum(dim=-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, dim=-1)], dim=-1).clamp(max=1.0)
    if perturb:
        u = torch.rand(edges.shape[0], n, dtype=edges.dtype, generator=generator)
        u, _ = torch.sort(u, dim=-1)
    else:
        u = torch.linspace(0.0, 1.0, n + 2, dtype=edges.dtype)[1:-1].expand(edges.shape[0], n)
    idx = torch.searchsorted(cdf.contiguous(), u.contiguous(), right=True)
    below = (idx - 1).clamp(min=0, max=cdf.shape[-1] - 1)
    above = idx.clamp(max=cdf.shape[-1] - 1)
    c0, c1 = torch.gather(cdf, 1, below), torch.gather(cdf, 1, above)
    e0, e1 = torch.gather(edges, 1, below), torch.gather(edges, 1, above)
    denom = c1 - c0
    frac = torch.where(denom > 1e-12, (u - c0) / denom.clamp(min=1e-12), torch.zeros_like(u))
    return e0 + frac * (e1 - e0)


def march_steps(t0: torch.Tensor, t1: torch.Tensor, step: float, max_steps: int, perturb: bool,
                generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Fixed-step marching from t0 to t1 (Instant-NGP / TensoRF style).

    t0, t1: (R,). Returns (t_mid, valid): (R, max_steps) sample distances (one random offset
    per ray when ``perturb``, else half a step) and the mask of samples before t1.
    """
    off = torch.rand(t0.shape[0], 1, dtype=t0.dtype, generator=generator) if perturb else torch.full(
        (t0.shape[0], 1), 0.5, dtype=t0.dtype)
    k = torch.arange(max_steps, dtype=t0.dtype)[None, :]
    t = t0[:, None] + (k + off) * step
    return t, t < t1[:, None]
