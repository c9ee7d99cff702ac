"""Direct acquisition (Levoy and Hanrahan 1996): one sheared-perspective render per uv sample.

The renderer is handed in as a function ``render(camera) -> (rgb, depth)`` (the pipeline wraps
the rig's rasterizer or path tracer; recon never imports rig). For uv sample (i, j) the camera
sits at the sample's centre on the uv plane and images exactly the st quad
(:func:`render.lightfield.sheared_camera`), so its pixels are the slab's st samples.

Prefiltering against aliasing, as in the paper: ``uv_supersample = K`` renders K x K cameras
spread over the uv cell and averages them (an aperture the size of the uv spacing);
``st_supersample = F`` renders F times more pixels per side and box-filters them down (the
rasterizer's own multisampling already box-filters each pixel). Depth is the centre camera's
z-depth at the st sample centres (for an even K, one more render at the cell centre).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from render.camera import Camera
from render.lightfield import LightSlab, SlabGeometry, create_slab_arrays, sheared_camera, write_slab_index

__all__ = ["DirectConfig", "RenderFn", "RowsFn", "uv_subsamples", "renders_per_uv", "acquire_row", "acquire_direct"]

#: render(camera) -> (rgb (H, W, 3) float32 linear, depth (H, W) float32 z-depth, 0 = empty)
RenderFn = Callable[[Camera], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class DirectConfig:
    """uv_supersample: K x K cameras per uv cell (aperture prefilter, 1 = none);
    st_supersample: render F x F pixels per st sample and box-filter (1 = none)."""

    uv_supersample: int = 1
    st_supersample: int = 1

    def __post_init__(self):
        if self.uv_supersample < 1 or self.st_supersample < 1:
            raise ValueError(f"supersampling factors must be >= 1, got {self}")


def uv_subsamples(i: int, n: int, k: int) -> np.ndarray:
    """(k,) parameters of k cameras spread evenly over uv cell ``i`` of ``n`` (cell-centred)."""
    return (i + (np.arange(k) + 0.5) / k) / n


def _downsample(img: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return img
    h, w = img.shape[0] // f, img.shape[1] // f
    return img.reshape(h, f, w, f, *img.shape[2:]).mean(axis=(1, 3))


def _check_frame(rgb, depth, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    k = cam.intrinsics
    rgb, depth = np.asarray(rgb, np.float32), np.asarray(depth, np.float32)
    if rgb.shape != (k.height, k.width, 3) or depth.shape != (k.height, k.width):
        raise ValueError(f"renderer returned {rgb.shape} / {depth.shape} for a {k.width}x{k.height} camera")
    if not (np.all(np.isfinite(rgb)) and np.all(np.isfinite(depth))):
        raise ValueError(f"renderer returned non-finite values for camera {cam.name!r}")
    return rgb, depth


def renders_per_uv(config: DirectConfig) -> int:
    """Renders one uv sample takes: K x K, plus the cell centre's depth render for an even K."""
    k = config.uv_supersample
    return k * k + (1 if k % 2 == 0 else 0)


def acquire_row(geom: SlabGeometry, j: int, render: RenderFn, config: DirectConfig = DirectConfig(),
                progress: Callable[[int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Row ``j`` of uv samples of slab ``geom`` (every i for this v): radiance (Nu, Nt, Ns, 3) and
    depth (Nu, Nt, Ns) float32, i.e. ``radiance[j]`` and ``depth[j]`` of the slab's arrays.

    A pure function of (geometry, j, config, the renderer's scene): rows may be rendered
    anywhere and in any order. ``progress(n)`` after each uv sample (n renders)."""
    K, F = config.uv_supersample, config.st_supersample
    nu, nv, ns, nt = geom.shape
    if not 0 <= j < nv:
        raise ValueError(f"row {j} outside slab {geom.name!r} ({nv} rows)")
    rad = np.empty((nu, nt, ns, 3), np.float32)
    depth = np.empty((nu, nt, ns), np.float32)
    for i in range(nu):
        acc = np.zeros((nt * F, ns * F, 3), np.float64)
        z = None
        for v in uv_subsamples(j, nv, K):
            for u in uv_subsamples(i, nu, K):
                cam = sheared_camera(geom, float(u), float(v), F)
                rgb, d = _check_frame(*render(cam), cam)
                acc += rgb
                if K % 2 == 1 and np.isclose(u, (i + 0.5) / nu) and np.isclose(v, (j + 0.5) / nv):
                    z = d
        n = K * K
        if z is None:  # even K: the cell centre was not among the subsamples
            cam = sheared_camera(geom, (i + 0.5) / nu, (j + 0.5) / nv, F)
            z = _check_frame(*render(cam), cam)[1]
            n += 1
        rad[i] = _downsample(acc / (K * K), F).astype(np.float32)
        depth[i] = z[F // 2::F, F // 2::F]  # the subpixel at (or next to) each st centre
        if progress is not None:
            progress(n)
    return rad, depth


#: rows(units, put): compute every (geometry, j) row of ``units`` in any order and place, calling
#: put(k, radiance_row, depth_row) for units[k] (e.g. a pool of processes running acquire_row)
RowsFn = Callable[[list[tuple[SlabGeometry, int]], Callable[[int, np.ndarray, np.ndarray], None]], None]


def acquire_direct(geometries: Sequence[SlabGeometry], render: RenderFn | None, folder,
                   config: DirectConfig = DirectConfig(), progress: Callable[[int], None] | None = None,
                   rows: RowsFn | None = None, dtype=np.float32) -> list[LightSlab]:
    """Render and assemble slabs into memory-mapped arrays of ``dtype`` (float32 or float16: the
    rows are rounded as they are placed) in ``folder`` (and its slabs.json).

    ``render`` is called with cameras of size (Ns, Nt) x ``st_supersample`` (one size per slab).
    ``progress(n)`` is called after each uv sample with the number of renders it took.
    ``rows``: how to compute the uv rows (:data:`RowsFn`; then ``render`` and ``progress`` are
    unused); default: :func:`acquire_row` with ``render``, in order, in this process. Every
    row is the same bytes wherever it was rendered.
    Returns the slabs, backed by the memmaps in ``folder``.
    """
    folder = Path(folder)
    slabs = [LightSlab(geom, *create_slab_arrays(folder, geom, with_depth=True, dtype=dtype)) for geom in geometries]
    units = [(s, j) for s in slabs for j in range(s.geometry.shape[1])]

    def put(k: int, rad: np.ndarray, depth: np.ndarray) -> None:
        slab, j = units[k]
        slab.radiance[j] = rad
        slab.depth[j] = depth

    if rows is None:
        for k, (slab, j) in enumerate(units):
            put(k, *acquire_row(slab.geometry, j, render, config, progress))
    else:
        rows([(s.geometry, j) for s, j in units], put)
    write_slab_index(folder, slabs)
    return slabs
