"""The ``slab`` stage: light slabs built from a capture, held-out views rendered from them.

Layout (DESIGN.md)::

    slab/slabs/slabs.json, <name>.radiance.npy, <name>.depth.npy   the slab set (render.lightfield.storage;
                                           float16 samples by default: ``precision``)
    slab/renders/<view>.exr, <view>.png    held-out views in the primary mode (capture's names)
    slab/errors/<view>.png, <view>.exr     |render - reference| (PNG: mean over RGB, x8, grey)
    slab/modes/<mode>/<view>.png           previews of every interpolation mode (Fig. 13)
    slab/compressed/                       the slab set vector-quantized (render.lightfield.storage; when
                                           ``compress``), and renders_vq/<view>.png from it
    slab/metrics.json                      display PSNR / SSIM (8-bit sRGB) and linear PSNR per view
                                           and per mode, coverage, sizes, compression ratio and its
                                           display PSNR cost (ꟻLIP and the subject's figures: validate)
    slab/manifest.json

Split between layers: this stage reads the capture (images, depth, cameras: the layout is
pipeline's), chooses the slab layout (:func:`recon.slab.slab_layout`: st sampled at the train
cameras' pixel footprint unless the layout fixes ``st_res``), refuses a slab set that cannot fit
the machine before allocating anything (:func:`check_slab_fits`), and acquires the slabs
either ``direct`` (sheared-perspective renders by the rig's rasterizer, or its path tracer when
the scene's effects require it, handed to :func:`recon.slab.acquire_direct` as a callback: recon
never imports rig) or by ``rebin`` (:func:`recon.slab.rebin_slabs` from the captured train views
and their depth maps, with the cameras of ``poses_dir`` when given). Rendering is
:mod:`render.lightfield`.

Reference for the metrics: ``reference_dir/linear/<view>.exr`` when given, else the sibling
``reference`` stage folder of the capture (``artifacts/<scene>/reference``) when it is finished,
else the capture's own held-out ``linear/<view>.exr`` (exact for direct-only scenes, which the
rasterizer renders exactly).

Units of work (pipeline.distributed; ``cluster``): direct acquisition renders one row of uv
cameras per unit (:func:`slab_row`: the scene shared once, its renderer built once per process),
and the held-out views are rendered from the slabs and scored one view per unit
(:func:`score_slab_view`: the slab set shared once). The client assembles the rows into the
memory-mapped arrays and writes every file; the bytes are the same in process and on a cluster of
any size. Rebinning runs in this process.
"""
from __future__ import annotations

import resource
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from recon.slab import (SourceView, DirectConfig, LayoutConfig, RebinConfig, VQConfig, acquire_direct, acquire_row,
                        compress_slabs, content_bounds, layout_rays, rebin_slabs, renders_per_uv, slab_layout)
from recon.undistort import undistort_view
from render.camera import Camera
from render.image_io import write_exr, write_png, write_preview
from render.metrics import psnr, ssim, to_display
from render.lightfield import MODES, LightSlab, load_slabs, render_pinhole, save_slabs, slab_file_bytes

from ..artifacts import MANIFEST, BadInput, Manifest, atomic_stage, check_out, read_json, write_json
from ..distributed import ClusterConfig, DaskEngine, LocalEngine, engine, map_units
from ..io import error_image, read_image
from ..progress import progress_bar
from ..renderers import prepared_scene, raster_pool

__all__ = ["SlabStageConfig", "run_slab", "load_views", "build_slabs", "score_slab_views", "score_slab_view", "slab_row",
           "find_reference", "held_out_references", "check_slab_fits", "slab_set_bytes", "PRECISIONS"]

Cluster = ClusterConfig | LocalEngine | DaskEngine | None

METHODS = ("direct", "rebin")
#: sample precision of the slab arrays: bytes per value
PRECISIONS = {"half": np.float16, "single": np.float32}
#: multiplier of the error PNGs (errors/<view>.png), as the validate stage's default
ERROR_GAIN = 8.0


@dataclass(frozen=True)
class SlabStageConfig:
    """method: ``direct`` or ``rebin``; mode: interpolation of ``renders/``; min_radiance: capture
    pixels brighter than this (max over RGB, linear) bound the content the slabs must cover
    (darker surfaces such as black velvet are left to the background); seed: path tracer seed;
    compress: also vector-quantize the slabs (``vq``) and score the held-out views from them;
    precision: ``half`` (float16 radiance and depth, the default: half the memory, a relative
    rounding of 2^-11, below an 8-bit display step) or ``single`` (float32)."""

    method: str = "direct"
    mode: str = "depth"
    layout: LayoutConfig = field(default_factory=LayoutConfig)
    direct: DirectConfig = field(default_factory=DirectConfig)
    rebin: RebinConfig = field(default_factory=RebinConfig)
    min_radiance: float = 0.05
    spp: int = 64
    seed: int = 0
    compress: bool = True
    vq: VQConfig = field(default_factory=VQConfig)
    precision: str = "half"

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"slab method must be one of {list(METHODS)}, got {self.method!r}")
        if self.mode not in MODES:
            raise ValueError(f"interpolation mode must be one of {list(MODES)}, got {self.mode!r}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"slab precision must be one of {list(PRECISIONS)}, got {self.precision!r}")


# ------------------------------------------------------------------------------------- inputs


def _cameras(folder: Path) -> tuple[list[Camera], list[str]]:
    from .capture import read_cameras

    return read_cameras(Path(folder) / "cameras.json")


def load_views(capture_dir: Path, cameras: list[Camera]) -> list[SourceView]:
    """Linear radiance and z-depth of ``cameras`` from the capture (BadInput on missing files),
    undistorted to each camera's pinhole (rebinning projects with an ideal pinhole)."""
    views = []
    for cam in cameras:
        k = cam.intrinsics
        rgb = read_image(Path(capture_dir) / "linear" / f"{cam.name}.exr", (k.height, k.width, 3))
        depth = read_image(Path(capture_dir) / "depth" / f"{cam.name}.exr", (k.height, k.width))
        pinhole, rgb, depth, _ = undistort_view(cam, rgb, depth)
        views.append(SourceView(pinhole, rgb, depth))
    return views


def find_reference(capture_dir: Path, reference_dir: Path | None) -> tuple[Path, str]:
    """(folder with linear/<view>.exr, its kind): the given reference, the sibling reference stage,
    or the capture itself."""
    if reference_dir is not None:
        if not (Path(reference_dir) / "linear").is_dir():
            raise BadInput(f"{reference_dir}: no linear/ folder of reference renders")
        return Path(reference_dir), "reference"
    sibling = Path(capture_dir).parent / "reference"
    if (sibling / MANIFEST).is_file() and (sibling / "linear").is_dir():
        return sibling, "reference"
    return Path(capture_dir), "capture"


def held_out_references(capture_dir: Path, cams: list[Camera], splits: list[str], reference_dir: Path | None
                        ) -> tuple[list[Camera], list[np.ndarray], Path, str]:
    """(held-out cameras, their (H, W, 3) float32 reference images, the reference folder, its kind:
    :func:`find_reference`); BadInput when the capture has no held-out camera or a reference image
    is missing, damaged or of another size."""
    test = [c for c, s in zip(cams, splits) if s == "test"]
    if not test:
        raise BadInput(f"{capture_dir / 'cameras.json'}: no held-out (test) cameras to render")
    ref_dir, ref_kind = find_reference(capture_dir, reference_dir)
    refs = [read_image(ref_dir / "linear" / f"{c.name}.exr", (c.intrinsics.height, c.intrinsics.width, 3))
            for c in test]
    return test, refs, ref_dir, ref_kind


def _scene_file(capture_dir: Path) -> Path | None:
    man = read_json(Path(capture_dir) / MANIFEST) if (Path(capture_dir) / MANIFEST).is_file() else {}
    for p in man.get("inputs", {}):
        if p.endswith((".yaml", ".yml")) and Path(p).is_file():
            return Path(p)
    return None


def _content_points(views: list[SourceView], min_radiance: float, stride: int = 2) -> np.ndarray:
    pts = []
    for v in views:
        d, rgb = v.depth[::stride, ::stride], v.rgb[::stride, ::stride]
        ii, jj = np.nonzero((d > 0) & (rgb.max(axis=2) > min_radiance))
        if len(ii) == 0:
            continue
        o, r = v.camera.pixel_rays(np.stack([jj * stride + 0.5, ii * stride + 0.5], axis=1))
        z = d[ii, jj].astype(np.float64)
        pts.append(o + r * (z / (r @ v.camera.cam_to_world[:3, 2]))[:, None])
    if not pts:
        raise BadInput(f"no captured pixel brighter than min_radiance={min_radiance} has depth: nothing to cover")
    return np.concatenate(pts)


# ------------------------------------------------------------------------------------- building


def _row_renderer(scene, scene_key: str, renderer: str, settings, gl_threads: int | None):
    """A render(camera) -> (rgb, depth) callback over this process's renderer of the shared scene:
    the rasterizer (one context per image size) or the path tracer (its BVH built once)."""
    if renderer == "raster":
        pool = raster_pool(scene, scene_key, gl_threads)

        def render(cam: Camera):
            f = pool.render(cam)
            return f.rgb, f.depth
    else:
        from render import integrators
        from render.gbuffer import first_hit_buffers

        prepared = prepared_scene(scene, scene_key, settings.threads)

        def render(cam: Camera):
            res = integrators.render(scene, cam, settings, prepared=prepared)
            depth, _ = first_hit_buffers(scene, cam, prepared.accel)
            return res.mean, depth
    return render


def slab_row(scene, scene_key: str, renderer: str, settings, gl_threads: int | None, geom, j: int,
             direct: DirectConfig) -> tuple[np.ndarray, np.ndarray]:
    """One unit of work: uv row ``j`` of slab ``geom`` (:func:`recon.slab.acquire_row`), rendered
    by this process's ``renderer`` ("raster" or "pathtracer") of the shared scene ``scene_key``."""
    return acquire_row(geom, j, _row_renderer(scene, scene_key, renderer, settings, gl_threads), direct)


def build_slabs(capture_dir: Path, folder: Path, config: SlabStageConfig, poses_dir: Path | None = None,
                quiet: bool = True, cluster: Cluster = None) -> tuple[list[LightSlab], dict]:
    """Fit the layout to the capture and acquire the slabs into ``folder``; returns the slabs and
    build figures (bounds, renderer, build time, coverage for ``rebin``). cluster: where the rows
    of a direct acquisition run (module docstring); None in this process."""
    capture_dir = Path(capture_dir)
    cams, splits = _cameras(poses_dir if poses_dir is not None else capture_dir)
    train = [c for c, s in zip(cams, splits) if s == "train"]
    if not train:
        raise BadInput(f"{(poses_dir or capture_dir) / 'cameras.json'}: no train cameras")
    views = load_views(capture_dir, train)
    try:
        bounds = content_bounds(_content_points(views, config.min_radiance))
    except ValueError as exc:
        raise BadInput(f"{capture_dir}: cannot bound the content ({str(exc).splitlines()[0]})") from None
    scene_file = _scene_file(capture_dir)
    up = np.array([0.0, 0.0, 1.0])
    info: dict = {"bounds": bounds.tolist()}
    t0 = time.perf_counter()
    if config.method == "direct":
        if scene_file is None:
            raise BadInput(f"{capture_dir / MANIFEST}: names no readable scene file (direct acquisition renders the scene)")
        from render import integrators
        from rig.build import load_scene
        from rig.capture import plan_capture

        rig = load_scene(scene_file)
        renderer = plan_capture(rig).renderer
        up = np.asarray(rig.scene.up, dtype=np.float64)
        geoms = _layout(config, bounds, train, up)
        info["fit"] = check_slab_fits(geoms, config, folder)
        per_uv = renders_per_uv(config.direct)
        total = sum(g.shape[0] * g.shape[1] for g in geoms) * per_uv
        with engine(cluster, quiet) as eng, progress_bar(quiet) as bar:
            task = bar.add_task("slab: direct", total=total, info=renderer)
            scene = eng.share(rig.scene)
            settings = integrators.RenderSettings(integrator="auto", spp=config.spp, seed=config.seed,
                                                 threads=eng.render_threads)
            gl_threads = eng.render_threads if isinstance(eng, DaskEngine) else None

            def rows(units, put) -> None:
                def got(k: int, row: tuple[np.ndarray, np.ndarray]) -> None:
                    put(k, *row)
                    bar.advance(task, units[k][0].shape[0] * per_uv)

                map_units(eng, slab_row, [(scene.key, renderer, settings, gl_threads, g, j, config.direct)
                                          for g, j in units], shared=[scene], on_result=got, name="slab-row")

            try:
                slabs = acquire_direct(geoms, None, folder, config.direct, rows=rows, dtype=PRECISIONS[config.precision])
            finally:
                eng.release(scene)
        info.update(renderer=renderer, renders=total)
    else:
        if scene_file is not None:
            from rig.spec import load_spec

            up = np.asarray(load_spec(scene_file)[0].up, dtype=np.float64)
        geoms = _layout(config, bounds, train, up)
        info["fit"] = check_slab_fits(geoms, config, folder)
        bg = _background(views)
        with progress_bar(quiet) as bar:
            task = bar.add_task("slab: rebin", total=sum(g.shape[0] * g.shape[1] for g in geoms), info="")
            try:
                slabs, stats = rebin_slabs(geoms, views, folder, config.rebin, bg, lambda n: bar.advance(task, n),
                                           dtype=PRECISIONS[config.precision])
            except ValueError as exc:
                raise BadInput(f"rebinning failed: {str(exc).splitlines()[0]}") from None
        info.update(stats.to_dict(), background=bg.tolist())
    info["build_s"] = round(time.perf_counter() - t0, 3)
    info["slabs"] = {s.geometry.name: {"shape": list(s.geometry.shape), "bytes": s.nbytes} for s in slabs}
    info["rays"] = layout_rays([s.geometry for s in slabs])
    info["precision"] = config.precision
    info["bytes"] = int(sum(s.nbytes for s in slabs))
    info["radiance_bytes"] = int(sum(s.radiance.nbytes for s in slabs))
    return slabs, info


def _layout(config: SlabStageConfig, bounds: np.ndarray, train: list[Camera], up: np.ndarray):
    """The layout's slabs for the train cameras (their focal lengths size st when the layout does
    not fix st_res: the larger of fx, fy, pixels)."""
    focal = np.array([max(c.intrinsics.fx, c.intrinsics.fy) for c in train])
    try:
        return slab_layout(config.layout, bounds, np.stack([c.center for c in train]), up, focal)
    except ValueError as exc:
        raise BadInput(f"slab layout: {str(exc).splitlines()[0]}") from None


def slab_set_bytes(geometries, precision: str) -> int:
    """Bytes of a slab set's arrays: radiance (3 values) and depth (1 value) per ray at ``precision``."""
    return layout_rays(geometries) * 4 * np.dtype(PRECISIONS[precision]).itemsize


#: bytes per ray of the largest slab's transient float32 copies: VQ encoding's tiles and decoded
#: check (12 + 12) and its depth (4); without compression, rebinning's splatted proxy depth (4)
#: and slack (4)
WORKING_BYTES_PER_RAY = {True: 28, False: 8}


def _available_memory() -> int:
    import psutil

    return int(psutil.virtual_memory().available)


def check_slab_fits(geometries, config: SlabStageConfig, folder: Path) -> dict:
    """Refuse (BadInput: one line naming the layout's st field) a slab set that cannot fit this
    machine, before anything is allocated: its arrays plus the largest slab's working copies
    (:data:`WORKING_BYTES_PER_RAY`) must fit the memory available now (the arrays are memory
    mapped, and the held-out renders read them at random: a set larger than memory would page
    from disk for every view), and the arrays the free disk space under ``folder``. Returns the
    figures (bytes) for metrics.json."""
    arrays = slab_set_bytes(geometries, config.precision)
    working = max(g.n_rays for g in geometries) * WORKING_BYTES_PER_RAY[bool(config.compress)]
    avail = _available_memory()
    where = Path(folder)
    while not where.exists() and where != where.parent:
        where = where.parent
    disk = shutil.disk_usage(where).free
    lay = config.layout
    knob = f"st_res={lay.st_res}" if lay.st_res is not None else f"st_per_pixel={lay.st_per_pixel:g}"
    gib = 2.0 ** 30
    rays = layout_rays(geometries)
    if arrays + working > avail or arrays > disk:
        short = (f"{(arrays + working) / gib:.2f} GiB of memory, {avail / gib:.2f} GiB available"
                 if arrays + working > avail else f"{arrays / gib:.2f} GiB of disk, {disk / gib:.2f} GiB free")
        raise BadInput(f"slab layout {knob}: {len(geometries)} slabs of {rays / 1e6:.1f}M rays ({config.precision} "
                       f"samples) need {short}: lower {knob.split('=')[0]}")
    return {"rays": rays, "array_bytes": arrays, "working_bytes": working, "available_memory_bytes": avail,
            "free_disk_bytes": disk}


def _background(views: list[SourceView]) -> np.ndarray:
    """Median radiance of the pixels that saw nothing (the scene's background), black if none."""
    samples = [v.rgb[v.depth == 0][::97] for v in views]
    s = np.concatenate(samples) if samples else np.zeros((0, 3))
    return np.median(s, axis=0).astype(np.float32) if len(s) else np.zeros(3, np.float32)


# ------------------------------------------------------------------------------------- evaluation


def score_slab_view(slabs: list[LightSlab], cam: Camera, ref: np.ndarray, modes=MODES, background=(0.0, 0.0, 0.0),
                  ssim_modes=None) -> dict:
    """One unit of work: ``cam``'s view rendered from ``slabs`` in every mode and scored against
    ``ref``: {mode: (metrics {"display_psnr"[, "display_ssim"], "linear_psnr"}, image, render seconds)}:
    display figures of the 8-bit sRGB images (:func:`render.metrics.to_display`), linear PSNR of
    the radiance clipped to [0, 1]."""
    out = {}
    shown_ref = to_display(ref)  # once per view, not per mode: the sRGB encoding of 1280x960 costs ~50 ms
    for mode in modes:
        t0 = time.perf_counter()
        img = render_pinhole(slabs, cam, mode, background)
        t = time.perf_counter() - t0
        with_ssim = ssim_modes is None or mode in ssim_modes
        shown = to_display(img)
        out[mode] = ({"display_psnr": psnr(shown, shown_ref),
                      **({"display_ssim": ssim(shown, shown_ref)} if with_ssim else {}),
                      "linear_psnr": psnr(img, ref)}, img, t)
    return out


def score_slab_views(slabs: list[LightSlab], cameras: list[Camera], references: list[np.ndarray],
                   modes=MODES, background=(0.0, 0.0, 0.0), ssim_modes=None, cluster: Cluster = None,
                   on_view=None) -> tuple[dict, dict]:
    """Render every camera in every mode; returns ``(metrics per mode, images per mode)`` with
    metrics {mode: {"per_view": {view: {"display_psnr", "display_ssim", "linear_psnr"}}, "display_psnr_mean",
    "display_ssim_mean", "linear_psnr_mean", "render_s_per_view"}}.

    SSIM is computed for ``ssim_modes`` only (None: every mode; elsewhere "display_ssim" is absent
    and "display_ssim_mean" None): at 1280x960 one SSIM (render.metrics, float64) costs ~3 CPU seconds, a
    render from the slabs ~0.3. One view per unit of work (:func:`score_slab_view`) on ``cluster``
    (None: in this process), the slab set shared once; ``on_view()`` as each view is done."""
    modes = tuple(modes)
    done: list = [None] * len(cameras)

    def got(k: int, result: dict) -> None:
        done[k] = result
        if on_view is not None:
            on_view()

    with engine(cluster, quiet=True) as eng:
        shared = eng.share(slabs)
        units = [(cam, ref, modes, background, ssim_modes) for cam, ref in zip(cameras, references)]
        map_units(eng, score_slab_view, units, shared=[shared], on_result=got, name="slab-view")
        del shared
    metrics, images = {}, {}
    for mode in modes:
        with_ssim = ssim_modes is None or mode in ssim_modes
        per_view = {cam.name: r[mode][0] for cam, r in zip(cameras, done)}
        t = sum(r[mode][2] for r in done)
        metrics[mode] = {"per_view": per_view,
                         "display_psnr_mean": float(np.mean([m["display_psnr"] for m in per_view.values()])),
                         "display_ssim_mean": float(np.mean([m["display_ssim"] for m in per_view.values()]))
                         if with_ssim else None,
                         "linear_psnr_mean": float(np.mean([m["linear_psnr"] for m in per_view.values()])),
                         "render_s_per_view": t / max(len(cameras), 1)}
        images[mode] = {cam.name: r[mode][1] for cam, r in zip(cameras, done)}
    return metrics, images


def _compress(slabs: list[LightSlab], test: list[Camera], refs: list[np.ndarray], bg: np.ndarray, by_mode: dict,
              config: SlabStageConfig, tmp: Path, quiet: bool, cluster: Cluster = None) -> dict:
    """Vector-quantize the slabs into ``tmp/compressed``, render the held-out views from them (the
    primary mode and quadrilinear, through the codebook) and return sizes, ratios and PSNR cost."""
    t0 = time.perf_counter()
    with progress_bar(quiet) as bar:
        task = bar.add_task("slab: compress (VQ)", total=len(slabs), info="")
        vq, stats = compress_slabs(slabs, config.vq, lambda n: bar.advance(task, n))
    save_slabs(tmp / "compressed", vq)
    compress_s = time.perf_counter() - t0
    vq = load_slabs(tmp / "compressed")
    modes = tuple(dict.fromkeys((config.mode, "quadrilinear")))
    m_vq, images = score_slab_views(vq, test, refs, modes, bg, ssim_modes=(config.mode,), cluster=cluster)
    for cam in test:
        write_preview(tmp / "renders_vq" / f"{cam.name}.png", images[config.mode][cam.name])
    files = slab_file_bytes(tmp / "compressed")
    stored = files["codes"] + files["codebook"]
    return {**stats.to_dict(), "files": files, "compress_s": round(compress_s, 2),
            "ratio_vs_float32": stats.float32_bytes / stored,      # radiance: our float32 arrays -> stored VQ
            "ratio_vs_rgb8": 3 * stats.rays / stored,               # the paper's baseline: 24-bit RGB per ray
            "lossless_ratio": stats.codes_bytes / max(files["codes"], 1),  # the LZMA stage on the indices
            "display_psnr": {m: m_vq[m]["display_psnr_mean"] for m in modes},
            "display_ssim": m_vq[config.mode]["display_ssim_mean"],
            "linear_psnr": {m: m_vq[m]["linear_psnr_mean"] for m in modes},
            "display_psnr_cost": {m: by_mode[m]["display_psnr_mean"] - m_vq[m]["display_psnr_mean"] for m in modes},
            "per_view": m_vq[config.mode]["per_view"]}


def run_slab(capture_dir: Path, poses_dir: Path | None, out: Path, config: SlabStageConfig = SlabStageConfig(),
             reference_dir: Path | None = None, quiet: bool = False, cluster: Cluster = None,
             overwrite: bool = False) -> dict:
    """Build slabs from ``capture_dir`` into ``out`` (atomically), render the held-out views in
    every interpolation mode and score them; returns the manifest.

    Inputs are checked before any work (:func:`pipeline.stages.capture.check_capture_folder`, and
    :func:`pipeline.stages.poses.check_poses` for ``poses_dir``); ``out`` may be absent, empty or
    a finished slab folder, anything else is refused unless ``overwrite``.

    cluster: where the units of work run (module docstring): None (default) in this process; a
    :class:`ClusterConfig` for a local or existing Dask cluster, or an engine already open. The
    output files are the same bytes either way (metrics.json's timings aside)."""
    from .capture import check_capture_folder
    from .poses import check_poses

    capture_dir = Path(capture_dir)
    check_out(out, "slab", overwrite)
    cams, splits = check_capture_folder(capture_dir, need=("linear", "depth"))
    if poses_dir is not None:
        check_poses(poses_dir, capture_dir, cams, splits)
    test, refs, ref_dir, ref_kind = held_out_references(capture_dir, cams, splits, reference_dir)
    params = {"method": config.method, "mode": config.mode, "layout": asdict(config.layout),
              "direct": asdict(config.direct), "rebin": asdict(config.rebin), "min_radiance": config.min_radiance,
              "compress": config.compress, "vq": asdict(config.vq), "reference": ref_kind}
    manifest = Manifest("slab", params=params)
    manifest.add_input(capture_dir / "cameras.json")
    if poses_dir is not None:
        manifest.add_input(Path(poses_dir) / "cameras.json")
    for c in test:
        manifest.add_input(ref_dir / "linear" / f"{c.name}.exr")
    with atomic_stage(out, "slab", overwrite) as tmp, engine(cluster, quiet) as eng:
        slabs, info = build_slabs(capture_dir, tmp / "slabs", config, poses_dir, quiet, eng)
        slabs = load_slabs(tmp / "slabs")  # memory-mapped read-only, as a reader will see them
        bg = np.asarray(info.get("background", (0.0, 0.0, 0.0)), np.float32)
        with progress_bar(quiet) as bar:
            task = bar.add_task("slab: render held-out views", total=len(test), info=f"{len(MODES)} modes")
            by_mode, images = score_slab_views(slabs, test, refs, MODES, bg, ssim_modes=(config.mode,), cluster=eng,
                                             on_view=lambda: bar.advance(task))
        for cam, ref in zip(test, refs):
            img = images[config.mode][cam.name]
            write_exr(tmp / "renders" / f"{cam.name}.exr", img)
            write_preview(tmp / "renders" / f"{cam.name}.png", img)
            write_exr(tmp / "errors" / f"{cam.name}.exr", np.abs(img - ref))
            write_png(tmp / "errors" / f"{cam.name}.png", error_image(img, ref, ERROR_GAIN))
            for mode in MODES:
                write_preview(tmp / "modes" / mode / f"{cam.name}.png", images[mode][cam.name])
        primary = by_mode[config.mode]
        compression = _compress(slabs, test, refs, bg, by_mode, config, tmp, quiet, eng) if config.compress else None
        metrics = {"display_psnr_mean": primary["display_psnr_mean"], "display_ssim_mean": primary["display_ssim_mean"],
                   "linear_psnr_mean": primary["linear_psnr_mean"], "mode": config.mode, "method": config.method,
                   "reference": ref_kind, "per_view": primary["per_view"],
                   "modes": by_mode, "build": info, **({"compression": compression} if compression else {})}
        # this process's high-water mark (ru_maxrss: KiB on Linux); a Dask cluster's workers not included
        metrics["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        write_json(tmp / "metrics.json", metrics)
        manifest.metrics = {"display_psnr_mean": primary["display_psnr_mean"],
                            "display_ssim_mean": primary["display_ssim_mean"],
                            "linear_psnr_mean": primary["linear_psnr_mean"],
                            "mode": config.mode, "slab_bytes": info["bytes"], "build_s": info["build_s"],
                            **({"coverage": info["coverage"]} if "coverage" in info else {}),
                            **{f"display_psnr_{m}": by_mode[m]["display_psnr_mean"] for m in MODES},
                            **({"vq_ratio_vs_float32": compression["ratio_vs_float32"],
                                "vq_display_psnr_cost": compression["display_psnr_cost"][config.mode]}
                               if compression else {}),
                            "engine": eng.name, "workers": eng.workers, "peak_rss_mb": metrics["peak_rss_mb"]}
        result = manifest.write(tmp)
    return result

