"""Input encodings for radiance fields, pure PyTorch.

* :class:`PositionalEncoding` - NeRF's gamma(p) = (p, sin(2^k pi p), cos(2^k pi p)), k < L
  (Mildenhall et al. 2020, eq. 4), applied per coordinate.
* :func:`sh_encoding` - real spherical harmonics of degree < 4 (16 values) for view directions.
"""
from __future__ import annotations

import math

import torch
from torch import nn

__all__ = ["PositionalEncoding", "sh_encoding", "SH_DIM"]

SH_DIM = 16


class PositionalEncoding(nn.Module):
    """gamma(p) for (N, D) inputs -> (N, D (1 + 2 L)); ``n_freqs = 0`` is the identity (the
    "no positional encoding" ablation). Inputs are expected in about [-1, 1]."""

    def __init__(self, in_dim: int, n_freqs: int, include_input: bool = True):
        super().__init__()
        self.in_dim, self.n_freqs, self.include_input = in_dim, n_freqs, include_input
        self.register_buffer("freqs", (2.0 ** torch.arange(n_freqs, dtype=torch.float32)) * math.pi, persistent=False)

    @property
    def out_dim(self) -> int:
        return self.in_dim * (int(self.include_input or self.n_freqs == 0) + 2 * self.n_freqs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.n_freqs == 0:
            return x
        xf = (x[..., None, :] * self.freqs[:, None]).flatten(-2)  # (N, L D)
        parts = ([x] if self.include_input else []) + [torch.sin(xf), torch.cos(xf)]
        return torch.cat(parts, dim=-1)


def sh_encoding(d: torch.Tensor) -> torch.Tensor:
    """Real spherical harmonics basis up to degree 3 of unit directions: (N, 3) -> (N, 16).

    Coefficients as in Instant-NGP / tiny-cuda-nn (Sloan's "Stupid SH tricks" normalisation).
    """
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    return torch.stack([
        torch.full_like(x, 0.28209479177387814),
        -0.48860251190291987 * y, 0.48860251190291987 * z, -0.48860251190291987 * x,
        1.0925484305920792 * xy, -1.0925484305920792 * yz, 0.94617469575755997 * zz - 0.31539156525251999,
        -1.0925484305920792 * xz, 0.54627421529603959 * (xx - yy),
        0.59004358992664352 * y * (-3.0 * xx + yy), 2.8906114426405538 * xy * z,
        0.45704579946446572 * y * (1.0 - 5.0 * zz), 0.3731763325901154 * z * (5.0 * zz - 3.0),
        0.45704579946446572 * x * (1.0 - 5.0 * zz), 1.4453057213202769 * z * (xx - yy),
        0.59004358992664352 * x * (-xx + 3.0 * yy),
    ], dim=-1)
