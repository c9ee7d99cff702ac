"""Slab compression as in Levoy and Hanrahan (1996, section 4): vector quantization of 2 x 2 x 2 x 2
ray tiles (48 numbers of linear RGB), then a lossless coder over the codeword indices.

The codebook (``codebook_size`` entries, 16,384 in the paper) is trained on a random sample of
tiles from every slab of a set and shared by the set. Full-search k-means with 16,384 entries is
too slow on two cores (each Lloyd step over a 260k-tile sample is ~200 GFLOP), so the codebook is
tree-structured in two levels (Gersho and Gray, *Vector Quantization and Signal Compression*,
12.4): a coarse k-means into ``groups`` cells, then each cell's own k-means with a share of the
entries proportional to the cell's distortion (a cell of identical background tiles gets one).
A tile is coded by its nearest coarse cell, then its nearest entry of that cell: 2 x ~128
distances instead of 16,384. Distances are squared errors of linear radiance, the quantity PSNR
measures. The codebook is rounded to float16 (what is stored) before encoding.

Decoding is :class:`render.lightfield.VQRadiance`: the renderer looks rays up through the codebook
directly. Files: :func:`render.lightfield.storage.save_slabs` (indices deflate-compressed, as the paper's
gzip stage).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from render.lightfield import LightSlab, VQRadiance

__all__ = ["VQConfig", "VQStats", "tiles_of", "sample_tiles", "kmeans", "TreeCodebook", "train_codebook",
           "encode_slab", "compress_slabs"]

TILE_DIM = 48  # 2 x 2 x 2 x 2 rays x RGB


@dataclass(frozen=True)
class VQConfig:
    """codebook_size: entries (at most; 16,384 as in the paper, uint16 indices); groups: coarse
    cells of the tree-structured codebook; sample: training tiles drawn from the slab set;
    iterations: Lloyd iterations per k-means; seed: the sample and the initial centroids."""

    codebook_size: int = 16384
    groups: int = 128
    sample: int = 262144
    iterations: int = 8
    seed: int = 0

    def __post_init__(self):
        if not (2 <= self.codebook_size <= 2**32 and 1 <= self.groups <= self.codebook_size
                and self.sample >= self.codebook_size and self.iterations >= 1):
            raise ValueError(f"bad VQ config {self}")


@dataclass
class VQStats:
    """Sizes in bytes and the quantization error over every ray of the set."""

    rays: int = 0
    float32_bytes: int = 0
    codes_bytes: int = 0
    codebook_entries: int = 0
    codebook_bytes: int = 0
    sq_error: float = 0.0
    train_s: float = 0.0
    encode_s: float = 0.0

    @property
    def rmse(self) -> float:
        return float(np.sqrt(self.sq_error / max(3 * self.rays, 1)))

    def to_dict(self) -> dict:
        return {"rays": self.rays, "float32_bytes": self.float32_bytes, "codes_bytes": self.codes_bytes,
                "codebook_entries": self.codebook_entries, "codebook_bytes": self.codebook_bytes,
                "vq_ratio_vs_float32": self.float32_bytes / max(self.codes_bytes + self.codebook_bytes, 1),
                "vq_ratio_vs_rgb8": 3 * self.rays / max(self.codes_bytes + self.codebook_bytes, 1),
                "radiance_rmse": self.rmse, "train_s": round(self.train_s, 2), "encode_s": round(self.encode_s, 2)}


def tiles_of(radiance: np.ndarray, rows: slice = slice(None)) -> np.ndarray:
    """(T, 48) float32 tiles of a (Nv, Nu, Nt, Ns, 3) radiance array for the uv tile rows ``rows``
    (all by default), in the order of :class:`render.lightfield.VQRadiance` codes (row-major over
    (Tv, Tu, Tt, Ts)); each tile's rays in order (v, u, t, s), RGB last. Odd counts repeat the
    edge sample (those rays are never looked up)."""
    nv, nu, nt, ns, _ = radiance.shape
    j0, j1, _ = rows.indices((nv + 1) // 2)
    r = np.asarray(radiance[2 * j0:2 * j1], dtype=np.float32)
    pad = [(0, 2 * (j1 - j0) - r.shape[0]), (0, nu % 2), (0, nt % 2), (0, ns % 2), (0, 0)]
    if any(p[1] for p in pad):
        r = np.pad(r, pad, mode="edge")
    tv, tu, tt, ts = r.shape[0] // 2, r.shape[1] // 2, r.shape[2] // 2, r.shape[3] // 2
    return r.reshape(tv, 2, tu, 2, tt, 2, ts, 2, 3).transpose(0, 2, 4, 6, 1, 3, 5, 7, 8).reshape(-1, TILE_DIM)


def sample_tiles(radiances: Sequence[np.ndarray], count: int, seed: int) -> np.ndarray:
    """(min(count, T), 48) float32 tiles drawn uniformly without replacement from all arrays."""
    tiles_per = [int(np.prod([(n + 1) // 2 for n in r.shape[:4]])) for r in radiances]
    total = sum(tiles_per)
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(total, size=min(count, total), replace=False))
    out, start = [], 0
    off = np.array([[a, b, c, d] for a in (0, 1) for b in (0, 1) for c in (0, 1) for d in (0, 1)])  # (16, 4)
    for r, n in zip(radiances, tiles_per):
        sel = pick[(pick >= start) & (pick < start + n)] - start
        start += n
        if len(sel) == 0:
            continue
        dims = np.array([(m + 1) // 2 for m in r.shape[:4]])
        t = np.stack(np.unravel_index(sel, dims), axis=1)                  # (m, 4) tile coordinates
        idx = np.minimum(2 * t[:, None, :] + off[None], np.array(r.shape[:4]) - 1)  # (m, 16, 4) rays
        out.append(np.asarray(r)[idx[..., 0], idx[..., 1], idx[..., 2], idx[..., 3]].reshape(-1, TILE_DIM))
    return np.concatenate(out).astype(np.float32, copy=False)


def _nearest(x: torch.Tensor, c: torch.Tensor, chunk: int = 4096) -> tuple[torch.Tensor, torch.Tensor]:
    """Index (n,) int64 of the nearest row of ``c`` (k, d) for every row of ``x`` (n, d), and its
    squared distance (n,), through ||c||^2 - 2 x.c (chunked: at most chunk x k distances at once)."""
    cn = (c * c).sum(1)
    idx, dist = [], []
    for a in range(0, len(x), chunk):
        xa = x[a:a + chunk]
        d = torch.addmm(cn, xa, c.T, alpha=-2.0)
        m, i = d.min(1)
        idx.append(i)
        dist.append((m + (xa * xa).sum(1)).clamp_min(0.0))
    if not idx:
        return torch.zeros(0, dtype=torch.int64), torch.zeros(0)
    return torch.cat(idx), torch.cat(dist)


def _cluster_sums(x: torch.Tensor, a: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-cluster sums (k, d) and counts (k,) of rows ``x`` (n, d) assigned to ``a`` (n,): one
    sort and segment sums (numpy reduceat; torch's index_add_ is slow with repeated indices)."""
    an = a.numpy()
    order = np.argsort(an, kind="stable")
    counts = np.bincount(an, minlength=k)
    sums = np.zeros((k, x.shape[1]), np.float32)
    nz = np.flatnonzero(counts)
    if len(nz):
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[nz]
        sums[nz] = np.add.reduceat(x.numpy()[order], starts, axis=0)
    return torch.from_numpy(sums), torch.from_numpy(counts)


def kmeans(x: torch.Tensor, k: int, iterations: int, generator: torch.Generator) -> torch.Tensor:
    """(min(k, n), d) centroids of ``x`` (n, d) float32 by Lloyd's algorithm from k distinct random
    samples; an emptied cluster is re-seeded with the sample farthest from its centroid."""
    n = len(x)
    k = min(k, n)
    c = x[torch.randperm(n, generator=generator)[:k]].clone()
    for _ in range(iterations):
        a, dist = _nearest(x, c)
        sums, counts = _cluster_sums(x, a, k)
        keep = counts > 0
        c[keep] = sums[keep] / counts[keep, None].to(x.dtype)
        empty = torch.nonzero(~keep).flatten()
        if len(empty):
            c[empty] = x[torch.topk(dist, len(empty)).indices]
    return c


@dataclass
class TreeCodebook:
    """A two-level codebook: ``coarse`` (G, 48) cell centroids; ``entries`` (K, 48) float32 (values
    exactly representable in float16); ``members`` (G, M) int64 entry indices of each cell, padded
    with -1 (cell g owns entries members[g, :sizes[g]]); ``fixed``: index of an entry that is the
    set's most frequent constant tile (the background: tiles equal to it are coded exactly and
    without a search), or -1."""

    coarse: torch.Tensor
    entries: torch.Tensor
    members: torch.Tensor
    sizes: torch.Tensor
    fixed: int = -1

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Codes (n,) int64 of tiles ``x`` (n, 48) float32."""
        codes = torch.full((len(x),), max(self.fixed, 0), dtype=torch.int64)
        rest = torch.arange(len(x))
        if self.fixed >= 0:
            rest = torch.nonzero(~(x == self.entries[self.fixed]).all(1)).flatten()
        xr = x[rest]
        cell, _ = _nearest(xr, self.coarse)
        order = torch.argsort(cell, stable=True)
        bounds = torch.searchsorted(cell[order], torch.arange(len(self.coarse) + 1)).tolist()
        for g in range(len(self.coarse)):
            sel = order[bounds[g]:bounds[g + 1]]
            if len(sel) == 0:
                continue
            own = self.members[g, :int(self.sizes[g])]
            i, _ = _nearest(xr[sel], self.entries[own])
            codes[rest[sel]] = own[i]
        return codes


def _most_frequent_constant(x: np.ndarray) -> tuple[np.ndarray, float]:
    """The most frequent constant tile of ``x`` (n, 48) (all 16 rays one colour: the background)
    and its frequency (0 when no tile is constant)."""
    rays = x.reshape(len(x), 16, 3)
    const = np.all(rays == rays[:, :1], axis=(1, 2))
    if not const.any():
        return x[0], 0.0
    colours, counts = np.unique(rays[const, 0], axis=0, return_counts=True)
    i = int(np.argmax(counts))
    return np.tile(colours[i], 16).astype(np.float32), counts[i] / len(x)


def train_codebook(sample: np.ndarray, config: VQConfig = VQConfig()) -> TreeCodebook:
    """Train the tree-structured codebook on tiles ``sample`` (n, 48) float32 (see module doc)."""
    x = torch.from_numpy(np.ascontiguousarray(sample, dtype=np.float32))
    if len(x) < 2 or not torch.isfinite(x).all():
        raise ValueError("the VQ training sample must hold at least 2 finite tiles")
    gen = torch.Generator().manual_seed(int(config.seed))
    fixed_tile, freq = _most_frequent_constant(np.asarray(sample, np.float32))
    fixed = None
    if freq >= 0.01 and np.array_equal(fixed_tile, fixed_tile.astype(np.float16).astype(np.float32)):
        fixed = torch.from_numpy(fixed_tile)
        x = x[~(x == fixed).all(1)]  # coded exactly without a search: no entries spent on it
        if len(x) < 2:
            x = torch.cat([x, fixed[None], fixed[None]])
    coarse = kmeans(x, config.groups - (fixed is not None), config.iterations, gen)
    cell, dist = _nearest(x, coarse)
    G = len(coarse)
    counts = torch.bincount(cell, minlength=G)
    energy = torch.zeros(G, dtype=torch.float64).index_add_(0, cell, dist.double())
    # entries per cell: proportional to the cell's distortion, at least one, at most its sample size
    share = energy / energy.sum() if energy.sum() > 0 else counts.double() / counts.sum()
    budget = config.codebook_size - G - (fixed is not None)
    sizes = torch.minimum(torch.clamp(torch.floor(share * budget).long() + 1, min=1), counts)
    sizes[counts == 0] = 0
    entries, members = [], torch.full((G, int(sizes.max())), -1, dtype=torch.int64)
    start = 0
    for g in range(G):
        if sizes[g] == 0:
            continue
        own = x[cell == g]
        e = kmeans(own, int(sizes[g]), config.iterations, gen) if sizes[g] > 1 else own.mean(0, keepdim=True)
        sizes[g] = len(e)
        entries.append(e)
        members[g, :len(e)] = torch.arange(start, start + len(e))
        start += len(e)
    entries = torch.cat(entries).half().float()  # what is stored: float16 values
    if fixed is None:
        return TreeCodebook(coarse, entries, members, sizes)
    return TreeCodebook(coarse, torch.cat([entries, fixed[None]]), members, sizes, len(entries))


def encode_slab(slab: LightSlab, book: TreeCodebook, stats: VQStats | None = None) -> LightSlab:
    """The slab with its radiance replaced by :class:`render.lightfield.VQRadiance` over ``book``'s
    entries and its depth rounded to float16 (stored so; ~1 mm at 1 m, far below a sample's
    footprint); ``stats`` accumulates sizes and the squared error over the slab's rays."""
    r = slab.radiance
    if isinstance(r, VQRadiance):
        raise ValueError(f"slab {slab.geometry.name!r} is already vector-quantized")
    tdims = tuple((n + 1) // 2 for n in r.shape[:4])
    dtype = np.uint16 if len(book.entries) <= 2**16 else np.uint32
    codes = book.encode(torch.from_numpy(tiles_of(r))).numpy().astype(dtype).reshape(tdims)
    vq = VQRadiance(codes, book.entries.numpy().reshape(-1, 2, 2, 2, 2, 3), r.shape)
    if stats is not None:
        n = int(np.prod(r.shape[:4]))
        stats.rays += n
        stats.float32_bytes += 12 * n
        stats.codes_bytes += codes.nbytes
        dec = vq.decode()
        dec -= r
        stats.sq_error += float(np.einsum("i,i->", dec.reshape(-1), dec.reshape(-1), dtype=np.float64))
    depth = None if slab.depth is None else np.asarray(slab.depth, np.float32).astype(np.float16).astype(np.float32)
    return LightSlab(slab.geometry, vq, depth, slab.focal_depth)


def compress_slabs(slabs: Sequence[LightSlab], config: VQConfig = VQConfig(),
                   progress: Callable[[int], None] | None = None) -> tuple[list[LightSlab], VQStats]:
    """Vector-quantize a slab set with one shared codebook trained on a sample of its tiles.

    Returns the compressed slabs (sharing one codebook array) and their statistics;
    ``progress(1)`` is called after each slab is encoded."""
    import time

    if not slabs:
        raise ValueError("no slabs to compress")
    t0 = time.perf_counter()
    book = train_codebook(sample_tiles([s.radiance for s in slabs], config.sample, config.seed), config)
    stats = VQStats(codebook_entries=len(book.entries), codebook_bytes=len(book.entries) * TILE_DIM * 2)
    stats.train_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = []
    for s in slabs:
        out.append(encode_slab(s, book, stats))
        if progress is not None:
            progress(1)
    shared = out[0].radiance.codebook
    for s in out[1:]:
        s.radiance.codebook = shared
    stats.encode_s = time.perf_counter() - t0
    return out, stats
