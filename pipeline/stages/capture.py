"""The ``capture`` stage: render a scene's train and test views into the capture folder.

Layout (DESIGN.md)::

    capture/images/<view>.png     sRGB preview          capture/linear/<view>.exr   linear radiance
    capture/depth/<view>.exr      z-depth (0 = empty)   capture/masks/<view>.png    subject mask
    capture/cameras.json          ground truth, ours    capture/transforms_{train,test}.json
    capture/colmap/               COLMAP text model     capture/targets.json        calibration boards
    capture/manifest.json

One view is one unit of work (pipeline.distributed): rendered (the rasterizer's EGL renderer or
the path tracer's prepared scene built once per process, pipeline.renderers) and put through the
sensor wherever the engine runs it, from the scene shared once; the client writes every file.
A view is a pure function of (scene, camera, view index, seed), so the bytes are the same in
process and on a cluster of any size.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from render.camera_io import write_cameras_json, write_colmap_text, write_transforms_json
from render.image_io import write_exr, write_png, write_preview
from rig.build import RigScene
from rig.capture import (CAPTURE_SPP, CapturedView, CapturePlan, capture_list, check_capture, finish_view,
                         plan_capture, render_ideal, sensor_config)

from ..artifacts import Manifest, atomic_stage, write_json
from ..distributed import ClusterConfig, DaskEngine, LocalEngine, engine, map_units
from ..progress import console, progress_bar
from ..renderers import prepared_scene, raster_pool

__all__ = ["run_capture", "capture_view", "SPLITS"]

SPLITS = ("train", "test")


def capture_view(scene, scene_key: str, plan: CapturePlan, sensor, seed: int, threads: int, gl_threads: int | None,
                 index: int, split: str, cam) -> CapturedView:
    """One unit of work: view ``index`` (``cam`` of ``split``) rendered by this process's renderer
    of the shared scene ``scene_key`` and put through the sensor."""
    if plan.renderer == "raster":
        renderer = raster_pool(scene, scene_key, gl_threads)
    else:
        renderer = prepared_scene(scene, scene_key, threads)
    rgb, depth, mask = render_ideal(scene, plan, cam, renderer, seed, CAPTURE_SPP, threads)
    return finish_view(cam, split, index, seed, sensor, rgb, depth, mask)


def run_capture(rig: RigScene, scene_file: Path, out: Path, seed: int | None = None, quiet: bool = False,
                cluster: ClusterConfig | LocalEngine | DaskEngine | None = None) -> dict:
    """Capture ``rig`` into ``out`` atomically; returns the manifest.

    cluster: where the views run (pipeline.distributed): None (default) in this process; a
    :class:`ClusterConfig` for a local or existing Dask cluster, or an engine already open. The
    output files are the same bytes either way."""
    seed = rig.spec.seed if seed is None else seed
    plan = plan_capture(rig)
    splits = tuple(s for s in SPLITS if s in rig.cameras) or ("scene",)
    manifest = Manifest("capture", params={"scene": rig.scene.name, "seed": seed, "renderer": plan.renderer,
                                           "effects": sorted(plan.effects), "splits": list(splits),
                                           "renderer_reasons": list(plan.reasons)})
    manifest.add_input(scene_file)
    if plan.renderer != "raster" and not quiet:
        console.print(f"capture: '{rig.scene.name}' is path traced, the rasterizer cannot simulate it exactly: "
                      + "; ".join(plan.reasons))
    views = capture_list(rig, splits)
    check_capture(rig, plan)
    n_views = len(views)
    cameras, split_of = [c for _, c in views], [s for s, _ in views]
    with atomic_stage(out) as tmp, engine(cluster, quiet) as eng, progress_bar(quiet) as bar:
        task = bar.add_task(f"capture {rig.scene.name}", total=n_views, info=plan.renderer)

        def write_view(_: int, view: CapturedView) -> None:
            stem = view.camera.name
            write_exr(tmp / "linear" / f"{stem}.exr", view.rgb)
            write_preview(tmp / "images" / f"{stem}.png", view.rgb)
            write_exr(tmp / "depth" / f"{stem}.exr", view.depth)
            write_png(tmp / "masks" / f"{stem}.png", view.mask.astype(np.uint8) * 255)
            bar.advance(task)

        scene = eng.share(rig.scene)
        gl_threads = eng.render_threads if isinstance(eng, DaskEngine) else None  # in process: llvmpipe's default
        sensor = sensor_config(rig)
        units = [(scene.key, plan, sensor, seed, eng.render_threads, gl_threads, i, s, c) for i, (s, c) in enumerate(views)]
        try:
            map_units(eng, capture_view, units, shared=[scene], on_result=write_view, name="capture-view")
        finally:
            eng.release(scene)
        write_cameras_json(tmp / "cameras.json", cameras, split_of)
        write_colmap_text(tmp / "colmap", cameras, [f"{c.name}.png" for c in cameras])
        for split in splits:
            members = [c for c, s in zip(cameras, split_of) if s == split]
            write_transforms_json(tmp / f"transforms_{split}.json", members, [f"images/{c.name}.png" for c in members])
        write_json(tmp / "targets.json", rig.targets)
        manifest.metrics = {"views": n_views, **{f"views_{s}": split_of.count(s) for s in splits},
                            "engine": eng.name, "workers": eng.workers}
        result = manifest.write(tmp)
    return result
