"""The ``reference`` stage: path-traced renders of a scene's views, each with its variance image.

Layout::

    reference/linear/<view>.exr     mean linear radiance (float32)
    reference/variance/<view>.exr   per-pixel variance of that mean (the render's own error bars)
    reference/images/<view>.png     sRGB preview
    reference/cameras.json          the rendered cameras (split = where the view came from)
    reference/manifest.json         spp, integrator, effects, per-view time and noise

View names match the capture's, so any two stages' images of a view pair up by name.
A view is rendered in fixed batches of SAMPLE_BATCH samples (the units of work), whose film
moments are summed by a left fold in sample order (as render.film.merge_results does), so the
result does not depend on where or in how many processes the batches ran: byte-identical
outputs in process and on a Dask cluster of any size (pipeline.distributed). The progress bar
moves per batch.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from render import pathtracer
from render.camera import Camera, Intrinsics
from render.camera_io import write_cameras_json
from render.film import Film, RenderResult
from render.image_io import write_exr, write_preview
from rig.build import RigScene

from ..artifacts import BadInput, Manifest, atomic_stage
from ..distributed import ClusterConfig, engine, worker_cache
from ..progress import progress_bar

__all__ = ["run_reference", "select_views", "resize_camera", "render_batch", "fold_batches", "finish_view", "SAMPLE_BATCH"]

#: samples per pixel rendered per unit of work; fixed, so results never depend on the split
SAMPLE_BATCH = 8
VIEW_CHOICES = ("test", "all", "scene")


def resize_camera(cam: Camera, width: int, height: int) -> Camera:
    """The same camera rendering a (height, width) image: focal lengths and principal point
    scaled per axis (pixel centres at +0.5 are preserved)."""
    k = cam.intrinsics
    sx, sy = width / k.width, height / k.height
    return Camera(Intrinsics(width, height, k.fx * sx, k.fy * sy, k.cx * sx, k.cy * sy, k.dist),
                  cam.cam_to_world, cam.name)


def select_views(rig: RigScene, views: str) -> list[tuple[str, Camera]]:
    """(split, camera) pairs for ``views`` in test | all | scene; BadInput when there are none."""
    if views not in VIEW_CHOICES:
        raise BadInput(f"--views must be one of {', '.join(VIEW_CHOICES)}, got '{views}'")
    splits = {"test": ("test",), "all": ("train", "test"), "scene": ("scene",)}[views]
    chosen = [(s, c) for s in splits for c in rig.cameras.get(s, [])]
    if not chosen:
        raise BadInput(f"scene '{rig.scene.name}' has no '{views}' views (it has: {', '.join(sorted(rig.cameras))})")
    return chosen


def render_batch(scene, scene_key: str, cam: Camera, settings: pathtracer.RenderSettings,
                 sample_range: tuple[int, int], effects: frozenset) -> tuple[Film, dict]:
    """One unit of work: the film moments of ``sample_range`` of ``cam``'s view, and its stats.

    Runs wherever the engine puts it; the scene's BVH is built once per process (keyed by
    ``scene_key``, unique per run) and reused across batches and views."""
    threads = settings.threads  # the BVH's query threads too: a task uses no more cores than it was given
    prepared = worker_cache(f"{scene_key}-{threads}", lambda: pathtracer.prepare(scene, threads=threads))
    result = pathtracer.render(scene, cam, settings, sample_range, effects, prepared)
    return result.film, result.stats


def fold_batches(acc: tuple[Film, dict], part: tuple[Film, dict]) -> tuple[Film, dict]:
    """Merge the next batch (in sample order) into the accumulated moments: the same sums, in
    the same order, as render.film.merge_results."""
    (fa, sa), (fb, sb) = acc, part
    stats = {k: sa.get(k, 0) + sb.get(k, 0) for k in set(sa) | set(sb)}
    return fa.merged(fb), stats


def finish_view(acc: tuple[Film, dict]) -> tuple[np.ndarray, np.ndarray, dict]:
    """(H, W, 3) float32 mean and variance of a view's merged film, and its stats: what the
    client needs (the float64 moments stay on the workers)."""
    film, stats = acc
    return film.mean(), film.variance(), stats


def run_reference(rig: RigScene, scene_file: Path, out: Path, spp: int = 64, size: tuple[int, int] | None = None,
                  views: str = "test", integrator: str = "auto", seed: int = 0, max_depth: int = 8,
                  quiet: bool = False, cluster: ClusterConfig | None = None) -> dict:
    """Render the chosen views with the path tracer into ``out`` atomically; returns the manifest.

    cluster: where the batches run (pipeline.distributed): None (default) in this process; a
    :class:`ClusterConfig` for a local or existing Dask cluster. The output files are the same
    bytes either way."""
    if spp < 1:
        raise BadInput(f"--spp must be at least 1, got {spp}")
    if size is not None and (size[0] < 1 or size[1] < 1):
        raise BadInput(f"--size must be positive, got {size[0]} x {size[1]}")
    chosen = select_views(rig, views)
    if size is not None:
        chosen = [(s, resize_camera(c, *size)) for s, c in chosen]
    try:
        settings = pathtracer.RenderSettings(integrator=integrator, spp=spp, seed=seed, max_depth=max_depth)
    except ValueError as exc:
        raise BadInput(f"--integrator/--max-depth: {exc}") from None
    from render.effects import scene_effects

    effects = frozenset(scene_effects(rig.scene))
    prepared = pathtracer.prepare(rig.scene)
    try:
        chosen_integrator = prepared.choose(effects, integrator)
    except ValueError as exc:
        raise BadInput(f"--integrator: {exc}") from None
    settings = replace(settings, integrator=chosen_integrator)
    manifest = Manifest("reference", params={
        "scene": rig.scene.name, "views": views, "spp": spp, "seed": seed, "max_depth": max_depth,
        "integrator_requested": integrator, "integrator": chosen_integrator, "effects": sorted(effects),
        "size": list(size) if size else None, "sample_batch": SAMPLE_BATCH})
    manifest.add_input(scene_file)
    batches = [(a, min(a + SAMPLE_BATCH, spp)) for a in range(0, spp, SAMPLE_BATCH)]
    per_view, totals = {}, {"paths": 0, "rays": 0, "time_s": 0.0}
    with atomic_stage(out) as tmp, engine(cluster, quiet) as eng, progress_bar(quiet) as bar:
        task = bar.add_task(f"reference {rig.scene.name}", total=len(chosen) * len(batches),
                            info=f"{chosen_integrator}, {spp} spp")
        scene = eng.share(rig.scene)
        worker_cache(f"{scene.key}-{settings.threads}", lambda: prepared)  # in process: reuse the BVH above
        if eng.render_threads != settings.threads:  # threads never change a render's result
            settings = replace(settings, threads=eng.render_threads)

        def write_view(g: int, done: tuple[np.ndarray, np.ndarray, dict]) -> None:
            mean, variance, stats = done
            name = chosen[g][1].name
            write_exr(tmp / "linear" / f"{name}.exr", mean)
            write_exr(tmp / "variance" / f"{name}.exr", variance)
            write_preview(tmp / "images" / f"{name}.png", mean)
            per_view[name] = {"time_s": round(stats["time_s"], 3), "mean_radiance": float(mean.mean()),
                              "mean_stderr": float(np.sqrt(variance).mean())}
            for k in totals:
                totals[k] += stats[k]

        units = [[(scene.key, cam, settings, rng, effects) for rng in batches] for _, cam in chosen]
        eng.fold_groups(render_batch, units, fold_batches, finish_view, shared=[scene], name="reference-batch",
                        on_unit=lambda: bar.advance(task), on_group=write_view)
        seconds = totals["time_s"]
        write_cameras_json(tmp / "cameras.json", [c for _, c in chosen], [s for s, _ in chosen])
        manifest.metrics = {"views": len(chosen), "paths_per_s": totals["paths"] / max(seconds, 1e-9),
                            "rays_per_s": totals["rays"] / max(seconds, 1e-9), "render_time_s": round(seconds, 3),
                            "per_view": per_view, "engine": eng.name, "workers": eng.workers}
        result_manifest = manifest.write(tmp)
    return result_manifest
