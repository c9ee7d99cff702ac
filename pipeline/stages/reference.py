"""The ``reference`` stage: path-traced renders of a scene's views, each with its variance image.

Layout::

    reference/linear/<view>.exr     mean linear radiance (float32)
    reference/variance/<view>.exr   per-pixel variance of that mean (the render's own error bars)
    reference/images/<view>.png     sRGB preview
    reference/cameras.json          the rendered cameras (split = where the view came from)
    reference/manifest.json         spp, integrator, effects, per-view time and noise

View names match the capture's, so any two stages' images of a view pair up by name.
A view is rendered in fixed batches of samples merged exactly (render.film.merge_results), so
the result does not depend on how the work is split, and the progress bar moves per batch.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from render import pathtracer
from render.camera import Camera, Intrinsics
from render.camera_io import write_cameras_json
from render.film import merge_results
from render.image_io import write_exr, write_preview
from rig.build import RigScene

from ..artifacts import BadInput, Manifest, atomic_stage
from ..progress import progress_bar

__all__ = ["run_reference", "select_views", "resize_camera", "SAMPLE_BATCH"]

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


def run_reference(rig: RigScene, scene_file: Path, out: Path, spp: int = 64, size: tuple[int, int] | None = None,
                  views: str = "test", integrator: str = "auto", seed: int = 0, max_depth: int = 8,
                  quiet: bool = False) -> dict:
    """Render the chosen views with the path tracer into ``out`` atomically; returns the manifest."""
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

    effects = scene_effects(rig.scene)
    prepared = pathtracer.prepare(rig.scene)
    try:
        chosen_integrator = pathtracer.choose_integrator(effects, integrator, prepared.has_delta_lights)
    except ValueError as exc:
        raise BadInput(f"--integrator: {exc}") from None
    settings = replace(settings, integrator=chosen_integrator)
    manifest = Manifest("reference", params={
        "scene": rig.scene.name, "views": views, "spp": spp, "seed": seed, "max_depth": max_depth,
        "integrator_requested": integrator, "integrator": chosen_integrator, "effects": sorted(effects),
        "size": list(size) if size else None, "sample_batch": SAMPLE_BATCH})
    manifest.add_input(scene_file)
    batches = [(a, min(a + SAMPLE_BATCH, spp)) for a in range(0, spp, SAMPLE_BATCH)]
    per_view, paths, rays, seconds = {}, 0, 0, 0.0
    with atomic_stage(out) as tmp, progress_bar(quiet) as bar:
        task = bar.add_task(f"reference {rig.scene.name}", total=len(chosen) * len(batches),
                            info=f"{chosen_integrator}, {spp} spp")
        for split, cam in chosen:
            result = None
            for rng in batches:
                part = pathtracer.render(rig.scene, cam, settings, rng, effects, prepared)
                result = part if result is None else merge_results(result, part)
                bar.advance(task)
            write_exr(tmp / "linear" / f"{cam.name}.exr", result.mean)
            write_exr(tmp / "variance" / f"{cam.name}.exr", result.variance)
            write_preview(tmp / "images" / f"{cam.name}.png", result.mean)
            per_view[cam.name] = {"time_s": round(result.stats["time_s"], 3),
                                  "mean_radiance": float(result.mean.mean()),
                                  "mean_stderr": float(np.sqrt(result.variance).mean())}
            paths += result.stats["paths"]
            rays += result.stats["rays"]
            seconds += result.stats["time_s"]
        write_cameras_json(tmp / "cameras.json", [c for _, c in chosen], [s for s, _ in chosen])
        manifest.metrics = {"views": len(chosen), "paths_per_s": paths / max(seconds, 1e-9),
                            "rays_per_s": rays / max(seconds, 1e-9), "render_time_s": round(seconds, 3),
                            "per_view": per_view}
        result_manifest = manifest.write(tmp)
    return result_manifest
