"""Density grids for heterogeneous media named in scene specs.

A grid is a (X, Y, Z) float64 array of non-negative scales of a medium's coefficients over its
bounds' axis-aligned box (the convention of :class:`render.scene.Medium` and
:mod:`render.media`: cell (i, j, k) covers lo + (i, j, k) (hi - lo) / (X, Y, Z) to the next
corner). Two sources: a ``.npy`` file, or :func:`smoke_density`, a procedural plume.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["smoke_density", "load_density_file", "MAX_DENSITY_CELLS"]

#: cells of a density grid file (256^3 float64: 134 MB)
MAX_DENSITY_CELLS = 256 ** 3


def smoke_density(resolution: int, seed: int = 0, octaves: int = 4, up_axis: int = 2) -> np.ndarray:
    """A rising smoke plume on a ``resolution``^3 grid: (R, R, R) float64 in [0, 1], max 1.

    Fractal value noise (``octaves`` octaves of random lattices, each twice as fine and half as
    strong, upsampled by cubic splines) shapes a column along ``up_axis`` that widens with
    height and fades towards the top and the sides, so the grid is zero at its boundary (no
    visible box edges). Deterministic for (resolution, seed, octaves).
    """
    if resolution < 4:
        raise ValueError(f"smoke resolution must be >= 4, got {resolution}")
    if octaves < 1:
        raise ValueError(f"smoke octaves must be >= 1, got {octaves}")
    from scipy import ndimage  # here, not at the top: rig.build imports this module for every scene (~1 s)

    rng = np.random.default_rng(seed)
    r = int(resolution)
    noise = np.zeros((r, r, r))
    amp = 1.0
    for o in range(octaves):
        cells = min(r, 3 * 2 ** o)
        lattice = rng.random((cells + 1,) * 3)
        noise += amp * ndimage.zoom(lattice, r / (cells + 1), order=3, mode="nearest", grid_mode=True)[:r, :r, :r]
        amp *= 0.5
    noise /= 2.0 - 0.5 ** (octaves - 1)  # the amplitudes' sum: noise in about [0, 1]
    c = (np.arange(r) + 0.5) / r  # cell centres in [0, 1]
    axes = np.meshgrid(c, c, c, indexing="ij")
    h = axes[up_axis]
    side = [a for i, a in enumerate(axes) if i != up_axis]
    radius = 0.12 + 0.25 * h  # the plume widens as it rises (and never reaches the sides)
    rho = np.hypot(side[0] - 0.5, side[1] - 0.5) / radius
    column = np.clip(1.0 - rho, 0.0, 1.0) * np.sqrt(np.clip(1.0 - h, 0.0, 1.0)) * np.clip(6.0 * h - 0.25, 0.0, 1.0)
    dens = np.clip(column * (0.5 + noise) - 0.05, 0.0, None)
    peak = dens.max()
    if peak <= 0:
        raise ValueError("smoke density is empty (a bug: please report)")
    return dens / peak


def load_density_file(path: Path) -> np.ndarray:
    """A (X, Y, Z) density grid from a ``.npy`` file, checked finite and non-negative."""
    try:
        # memory-mapped first, so an oversized grid is refused from its header before it is read
        grid = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise ValueError(f"{path}: not a readable .npy array ({' '.join(str(exc).split())})") from None
    if not isinstance(grid, np.ndarray) or grid.dtype.kind not in "biuf":
        raise ValueError(f"{path}: a density grid must be a numeric array")
    if grid.ndim != 3 or min(grid.shape) < 1:
        raise ValueError(f"{path}: a density grid must be a 3-D (X, Y, Z) array, got shape {grid.shape}")
    if grid.size > MAX_DENSITY_CELLS:
        raise ValueError(f"{path}: a density grid of shape {grid.shape} has {grid.size} cells, "
                         f"at most {MAX_DENSITY_CELLS} (256^3)")
    grid = np.array(grid, dtype=np.float64)
    if not np.all(np.isfinite(grid)) or grid.min() < 0:
        raise ValueError(f"{path}: density must be finite and non-negative")
    return grid
