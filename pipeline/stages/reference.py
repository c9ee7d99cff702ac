"""The ``reference`` stage: path-traced renders of a scene's views, each with its variance image.

Layout::

    reference/linear/<view>.exr     mean linear radiance (float32)
    reference/variance/<view>.exr   per-pixel variance of that mean (the render's own error bars)
    reference/images/<view>.png     sRGB preview
    reference/cameras.json          the rendered cameras (split = where the view came from)
    reference/manifest.json         spp, integrator, effects, per-view time and noise

View names match the capture's, so any two stages' images of a view pair up by name.
Views (``--views``): auto (the default) renders the held-out ``test`` views when the scene has
them, else its ``scene`` camera; test, all (train + test) and scene choose explicitly.

A view is rendered in fixed units of work (render.integrators.work_units): batches of
SAMPLE_BATCH samples, or for sppm and pssmlt their independent groups of passes / chains. Their
film moments are summed by a left fold in sample order (as render.film.merge_results does), so
the result does not depend on where or in how many processes the units ran: byte-identical
outputs in process and on a Dask cluster of any size (pipeline.distributed). The progress bar
moves per unit. Stats are folded by render.film.merge_stats (integrators report different
counters: pssmlt counts no rays, so ``rays_per_s`` is null for it).

What cannot fit is refused before anything is allocated (BadInput, exit 2): --spp above
MAX_SPP, and a view whose film needs more than the available memory (BYTES_PER_PIXEL per pixel
per worker against MemAvailable).
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from render import integrators
from render.camera import Camera, Intrinsics
from render.camera_io import write_cameras_json
from render.integrators.settings import SAMPLER_NAMES
from render.sobol import replicates_for, stratified_spp
from render.film import Film, merge_stats
from render.image_io import write_exr, write_preview
from rig.rig_scene import RigScene

from ..artifacts import BadInput, Manifest, atomic_stage
from ..distributed import ClusterConfig, LocalEngine, engine, worker_cache
from ..progress import progress_bar

__all__ = ["ReferenceConfig", "run_reference", "select_views", "resize_camera", "render_batch", "fold_batches",
           "fold_batches_in_place", "finish_view", "check_fits", "available_memory", "SAMPLE_BATCH", "MAX_SPP",
           "BYTES_PER_PIXEL", "LOCAL_UNITS_AT_ONCE"]

#: samples per pixel rendered per unit of work; fixed, so results never depend on the split
SAMPLE_BATCH = 8
VIEW_CHOICES = ("auto", "test", "all", "scene")
#: the largest --spp: every unit of a view is scheduled up front (Dask keeps a future per unit),
#: so 65536 spp is 8192 units per view; 8x the largest reference the project renders (8192 spp)
MAX_SPP = 1 << 16
#: memory one view costs per pixel while it renders, per worker (bytes): the fold's films
#: (accumulated, incoming, merged: 3 x 56 B of float64 moments and int64 counts; with the Sobol
#: sampler 3 x 440 B, its 16 replicate sums adding 384 B each: path and direct ~1.5 kB), the float32
#: mean and variance and their EXR / PNG encodings (~100 B), and the integrators' own per-pixel
#: arrays, measured as tracemalloc's peak per unit at 256^2 and 512^2 on cornell: sppm 861 (one
#: photon per pixel per pass), pssmlt 181, bdpt 121, volpath 85 B/px (path and direct trace
#: fixed-size batches). The largest sum (~1130 B) rounded up for what tracemalloc does not see
#: (Embree, numba)
BYTES_PER_PIXEL = 2048
#: units the in-process engine renders at once, each on the engine's render threads (a lone unit
#: left cores idle at its end, waiting for its slowest thread: Cornell 128 x 128, 2048 spp,
#: max_depth 64, whole command 16.9 s one at a time, 12.9-13.6 s two at a time, 12.6-12.9 s three)
LOCAL_UNITS_AT_ONCE = 2


def resize_camera(cam: Camera, width: int, height: int) -> Camera:
    """The same camera rendering a (height, width) image: focal lengths and principal point
    scaled per axis (pixel centres at +0.5 are preserved)."""
    k = cam.intrinsics
    sx, sy = width / k.width, height / k.height
    return Camera(Intrinsics(width, height, k.fx * sx, k.fy * sy, k.cx * sx, k.cy * sy, k.dist),
                  cam.cam_to_world, cam.name)


def select_views(rig: RigScene, views: str) -> list[tuple[str, Camera]]:
    """(split, camera) pairs for ``views`` in auto | test | all | scene; BadInput when there are
    none. auto: the test views when the scene has any, else its scene camera."""
    if views not in VIEW_CHOICES:
        raise BadInput(f"--views must be one of {', '.join(VIEW_CHOICES)}, got '{views}'")
    if views == "auto":
        views = "test" if rig.cameras.get("test") else "scene" if rig.cameras.get("scene") else "test"
    splits = {"test": ("test",), "all": ("train", "test"), "scene": ("scene",)}[views]
    chosen = [(s, c) for s in splits for c in rig.cameras.get(s, [])]
    if not chosen:
        raise BadInput(f"scene '{rig.scene.name}' has no '{views}' views (it has: {', '.join(sorted(rig.cameras))})")
    return chosen


def available_memory() -> int | None:
    """Bytes of memory available to new allocations on this machine: /proc/meminfo's
    MemAvailable (page cache that can be reclaimed counts), else free physical pages
    (os.sysconf); None when neither is known."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (OSError, ValueError, AttributeError):
        return None


def _gib(n: float) -> str:
    return f"{n / 2 ** 40:.1f} TiB" if n >= 2 ** 40 else f"{n / 2 ** 30:.1f} GiB"


def _workers_here(cluster) -> int:
    """Units on this machine that may each hold a view's films at once: worker processes, or in
    process the units rendered side by side (LOCAL_UNITS_AT_ONCE)."""
    from ..distributed import DaskEngine

    if cluster is None or isinstance(cluster, LocalEngine):
        return LOCAL_UNITS_AT_ONCE
    if isinstance(cluster, DaskEngine):
        return cluster.workers if cluster.name == "dask local cluster" else 1
    if cluster.in_process:
        return LOCAL_UNITS_AT_ONCE
    return 1 if cluster.address else max(1, cluster.local_workers)


def check_fits(chosen: list[tuple[str, Camera]], size: tuple[int, int] | None, workers: int,
               available: int | None) -> None:
    """BadInput (one line naming --size or the view, and the bound) when the largest chosen view
    needs more than ``available`` bytes: pixels x BYTES_PER_PIXEL x ``workers``. Nothing is
    allocated here; ``available`` None skips the check."""
    if available is None or not chosen:
        return
    cam = max((c for _, c in chosen), key=lambda c: c.intrinsics.width * c.intrinsics.height)
    w, h = cam.intrinsics.width, cam.intrinsics.height
    need = w * h * BYTES_PER_PIXEL * workers
    if need <= available:
        return
    what = f"--size {w} {h}" if size is not None else f"view '{cam.name}' ({w} x {h} from the scene's cameras)"
    fit = available / (BYTES_PER_PIXEL * workers) / 1e6
    raise BadInput(f"{what}: a view needs about {_gib(need)} to render ({BYTES_PER_PIXEL} B per pixel x "
                   f"{workers} worker{'s' * (workers > 1)}), more than the {_gib(available)} available; at most "
                   f"{fit:.0f} megapixels per view fit{'' if size is not None else ' (pass a smaller --size)'}")


def render_batch(scene, scene_key: str, cam: Camera, settings: integrators.RenderSettings,
                 sample_range: tuple[int, int], effects: frozenset) -> tuple[Film, dict]:
    """One unit of work: the film moments of ``sample_range`` of ``cam``'s view, and its stats.

    Runs wherever the engine puts it; the scene's BVH is built once per process (keyed by
    ``scene_key``, unique per run) and reused across batches and views."""
    threads = settings.threads  # the BVH's query threads too: a task uses no more cores than it was given
    prepared = worker_cache(f"{scene_key}-{threads}", lambda: integrators.prepare(scene, threads=threads))
    result = integrators.render(scene, cam, settings, sample_range, effects, prepared)
    return result.film, result.stats


def fold_batches(acc: tuple[Film, dict], part: tuple[Film, dict]) -> tuple[Film, dict]:
    """Merge the next batch (in sample order) into the accumulated moments: the same sums, in
    the same order, as render.film.merge_results."""
    (fa, sa), (fb, sb) = acc, part
    return fa.merged(fb), merge_stats(sa, sb)


def fold_batches_in_place(acc: tuple[Film, dict], part: tuple[Film, dict]) -> tuple[Film, dict]:
    """:func:`fold_batches` adding into ``acc``'s film (the same bytes, no new arrays): for the
    in-process engine, where nothing else holds ``acc`` (a Dask task's inputs must stay as they
    were, for retries)."""
    (fa, sa), (fb, sb) = acc, part
    fa.merge_in_place(fb)
    return fa, merge_stats(sa, sb)


def finish_view(acc: tuple[Film, dict]) -> tuple[np.ndarray, np.ndarray, dict]:
    """(H, W, 3) float32 mean and variance of a view's merged film, and its stats: what the
    client needs (the float64 moments stay on the workers)."""
    film, stats = acc
    return film.mean(), film.variance(), stats


@dataclass(frozen=True)
class ReferenceConfig:
    """What the ``reference`` stage renders (the ``lumigraph reference`` options of the same names)."""

    #: samples per pixel, in [1, MAX_SPP]
    spp: int = 64
    #: render size (W, H); None: each view's own
    size: tuple[int, int] | None = None
    #: auto | test | all | scene (:func:`select_views`)
    views: str = "auto"
    #: auto (chosen from the scene's effects) or a name of render.integrators.INTEGRATORS
    integrator: str = "auto"
    #: render seed
    seed: int = 0
    #: maximum bounces; None: :func:`default_max_depth` of the chosen integrator
    max_depth: int | None = None
    #: random numbers of path / direct / volpath: "sobol-blocks", "sobol" or "independent" (render.sobol);
    #: None: sobol-blocks where the chosen integrator reads a sampler; given explicitly to one
    #: that does not: refused
    sampler: str | None = None


#: integrators whose paths Russian roulette ends (from vertex 5): their default max_depth is deep
DEEP_BY_DEFAULT = ("path", "volpath")


def default_max_depth(integrator: str) -> int:
    """The reference's max_depth when none is given: 64 for path and volpath (roulette ends their
    paths long before; at 8 the Cornell box lost 0.3% of its radiance for no measurable time,
    issue 16), 8 for the others (bdpt's subpaths and pssmlt's primary samples grow with it:
    bdpt took 2.4x the memory at 64)."""
    return 64 if integrator in DEEP_BY_DEFAULT else 8


def run_reference(rig: RigScene, scene_file: Path, out: Path, config: ReferenceConfig = ReferenceConfig(),
                  quiet: bool = False, cluster: ClusterConfig | None = None, overwrite: bool = False) -> dict:
    """Render the chosen views with the path tracer into ``out`` atomically; returns the manifest.

    spp is bounded by MAX_SPP and each view's memory by :func:`check_fits`, both before anything
    is allocated.

    cluster: where the batches run (pipeline.distributed): None (default) in this process; a
    :class:`ClusterConfig` for a local or existing Dask cluster. The output files are the same
    bytes either way."""
    spp, size, views, integrator, seed, max_depth = (config.spp, config.size, config.views, config.integrator,
                                                     config.seed, config.max_depth)
    if config.sampler is not None and config.sampler not in SAMPLER_NAMES:
        raise BadInput(f"--sampler must be one of {', '.join(SAMPLER_NAMES)}, got '{config.sampler}'")
    if not 1 <= spp <= MAX_SPP:
        raise BadInput(f"--spp must lie in [1, {MAX_SPP}], got {spp}")
    if size is not None and (size[0] < 1 or size[1] < 1):
        raise BadInput(f"--size must be positive, got {size[0]} x {size[1]}")
    chosen = select_views(rig, views)
    if size is not None:
        chosen = [(s, resize_camera(c, *size)) for s, c in chosen]
    check_fits(chosen, size, _workers_here(cluster), available_memory())
    try:
        settings = integrators.RenderSettings(integrator=integrator, spp=spp, seed=seed,
                                              max_depth=8 if max_depth is None else max_depth, sampler=config.sampler)
    except ValueError as exc:
        raise BadInput(f"--integrator/--max-depth: {exc}") from None
    from render.effects import scene_effects

    effects = frozenset(scene_effects(rig.scene))
    prepared = integrators.prepare(rig.scene)
    try:
        chosen_integrator = prepared.choose(effects, integrator)
    except ValueError as exc:
        raise BadInput(f"--integrator: {exc}") from None
    if max_depth is None:
        max_depth = default_max_depth(chosen_integrator)
    settings = replace(settings, integrator=chosen_integrator, max_depth=max_depth)
    reads_sampler = "sampler" in {f.name for f in fields(integrators.INTEGRATOR_OPTIONS[chosen_integrator])}
    if config.sampler is None and reads_sampler:
        settings = replace(settings, sampler="sobol-blocks")  # the stage's default: low-discrepancy where it applies
    try:  # an option the chosen integrator does not read is refused here, before any work
        options = settings.options(chosen_integrator, integrators.INTEGRATOR_OPTIONS[chosen_integrator])
    except ValueError as exc:
        raise BadInput(f"--sampler: {exc}") from None
    spp_requested = spp
    sobol_sampler = getattr(options, "sampler", None) in ("sobol", "sobol-blocks")
    if sobol_sampler:  # whole nets (render.sobol.stratified_spp)
        spp = min(stratified_spp(spp), MAX_SPP)
        settings = replace(settings, spp=spp)
    manifest = Manifest("reference", params={
        "scene": rig.scene.name, "views": views, "splits": sorted({s for s, _ in chosen}), "spp": spp,
        "spp_requested": spp_requested, "seed": seed, "max_depth": max_depth,
        "sampler": getattr(options, "sampler", None),
        # the Sobol sampler's replicates: the variance image has R - 1 degrees of freedom per pixel
        "replicates": replicates_for(spp) if sobol_sampler else None,
        "integrator_requested": integrator, "integrator": chosen_integrator, "effects": sorted(effects),
        "size": list(size) if size else None, "sample_batch": SAMPLE_BATCH})
    manifest.add_input(scene_file)
    batches = integrators.work_units(chosen_integrator, spp, SAMPLE_BATCH)  # spp <= MAX_SPP: a bounded list
    manifest.params["units_per_view"] = len(batches)
    per_view, totals = {}, {}
    with atomic_stage(out, "reference", overwrite) as tmp, engine(cluster, quiet) as eng, progress_bar(quiet) as bar:
        task = bar.add_task(f"reference {rig.scene.name}", total=len(chosen) * len(batches),
                            info=f"{chosen_integrator}, {spp} spp")
        scene = eng.share(rig.scene)
        # in process, LOCAL_UNITS_AT_ONCE units run side by side (each alone left cores idle at its
        # end, waiting for its slowest thread) and are folded in place; threads never change a
        # render's result, and the fold still takes units in order: the same bytes
        in_process = isinstance(eng, LocalEngine)
        concurrent = LOCAL_UNITS_AT_ONCE if in_process else 1
        worker_cache(f"{scene.key}-{settings.threads}", lambda: prepared)  # in process: reuse the BVH above
        if eng.render_threads != settings.threads:
            settings = replace(settings, threads=eng.render_threads)

        def write_view(g: int, done: tuple[np.ndarray, np.ndarray, dict]) -> None:
            mean, variance, stats = done
            name = chosen[g][1].name
            write_exr(tmp / "linear" / f"{name}.exr", mean)
            write_exr(tmp / "variance" / f"{name}.exr", variance)
            write_preview(tmp / "images" / f"{name}.png", mean)
            per_view[name] = {"time_s": round(stats["time_s"], 3), "mean_radiance": float(mean.mean()),
                              "mean_stderr": float(np.sqrt(variance).mean())}
            totals[name] = stats

        units = [[(scene.key, cam, settings, rng, effects) for rng in batches] for _, cam in chosen]
        fold = fold_batches_in_place if in_process else fold_batches
        t0 = time.perf_counter()
        eng.fold_groups(render_batch, units, fold, finish_view, shared=[scene], name="reference-batch",
                        on_unit=lambda: bar.advance(task), on_group=write_view, concurrent=concurrent)
        wall = time.perf_counter() - t0
        stats = {}
        for name in sorted(totals):  # view order never changes the sums' bytes
            stats = merge_stats(stats, totals[name])
        seconds = stats.get("time_s", 0.0)
        counted_rays = all("rays" in st for st in totals.values())  # pssmlt counts none
        write_cameras_json(tmp / "cameras.json", [c for _, c in chosen], [s for s, _ in chosen])
        # throughput over the fold's wall clock (units, merges, the views' files): units overlap, so
        # their summed times (render_time_s) count the overlap twice
        manifest.metrics = {"views": len(chosen), "paths_per_s": stats.get("paths", 0) / max(wall, 1e-9),
                            "rays_per_s": stats["rays"] / max(wall, 1e-9) if counted_rays else None,
                            "render_wall_s": round(wall, 3), "render_time_s": round(seconds, 3),
                            "per_view": per_view, "engine": eng.name, "workers": eng.workers}
        result_manifest = manifest.write(tmp)
    return result_manifest
