"""The ``capture`` stage: render a scene's train and test views into the capture folder.

Layout (DESIGN.md)::

    capture/images/<view>.png     sRGB preview          capture/linear/<view>.exr   linear radiance
    capture/depth/<view>.exr      z-depth (0 = empty)   capture/masks/<view>.png    subject mask
    capture/cameras.json          ground truth, ours    capture/transforms_{train,test}.json
    capture/colmap/               COLMAP text model     capture/targets.json        calibration boards
    capture/manifest.json
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from render.camera_io import write_cameras_json, write_colmap_text, write_transforms_json
from render.image_io import write_exr, write_png, write_preview
from rig.build import RigScene
from rig.capture import capture_views, plan_capture

from ..artifacts import Manifest, atomic_stage, write_json
from ..progress import console, progress_bar

__all__ = ["run_capture", "SPLITS"]

SPLITS = ("train", "test")


def run_capture(rig: RigScene, scene_file: Path, out: Path, seed: int | None = None, quiet: bool = False) -> dict:
    """Capture ``rig`` into ``out`` atomically; returns the manifest."""
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
    n_views = sum(len(rig.cameras[s]) for s in splits)
    cameras, split_of = [], []
    with atomic_stage(out) as tmp, progress_bar(quiet) as bar:
        task = bar.add_task(f"capture {rig.scene.name}", total=n_views, info=plan.renderer)
        for view in capture_views(rig, seed, splits):
            stem = view.camera.name
            write_exr(tmp / "linear" / f"{stem}.exr", view.rgb)
            write_preview(tmp / "images" / f"{stem}.png", view.rgb)
            write_exr(tmp / "depth" / f"{stem}.exr", view.depth)
            write_png(tmp / "masks" / f"{stem}.png", view.mask.astype(np.uint8) * 255)
            cameras.append(view.camera)
            split_of.append(view.split)
            bar.advance(task)
        write_cameras_json(tmp / "cameras.json", cameras, split_of)
        write_colmap_text(tmp / "colmap", cameras, [f"{c.name}.png" for c in cameras])
        for split in splits:
            members = [c for c, s in zip(cameras, split_of) if s == split]
            write_transforms_json(tmp / f"transforms_{split}.json", members, [f"images/{c.name}.png" for c in members])
        write_json(tmp / "targets.json", rig.targets)
        manifest.metrics = {"views": n_views, **{f"views_{s}": split_of.count(s) for s in splits}}
        result = manifest.write(tmp)
    return result
