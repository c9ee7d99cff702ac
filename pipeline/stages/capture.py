"""The ``capture`` stage: render a scene's train and test views into the capture folder.

Layout (DESIGN.md)::

    capture/images/<view>.png     sRGB preview          capture/linear/<view>.exr   linear radiance
    capture/depth/<view>.exr      z-depth (0 = empty)   capture/masks/<view>.png    subject mask
    capture/cameras.json          ground truth, ours    capture/transforms.json     nerfstudio, every split
    capture/transforms_{train,test}.json   Blender/TensoRF split files (file paths without extension)
    capture/colmap/               COLMAP text model     capture/targets.json        calibration boards
    capture/capture_order.json    shooting order (sequence, frame, loop)    capture/manifest.json
    capture/calibration/images/calib_<i>.png, capture/calibration/board.json   the calibration
                                  sequence, when the scene asks for one (rig.calibration): images
                                  and the board's definition only, no pose

Depth EXRs hold z-depth in channel ``Z``. ``transforms.json`` follows nerfstudio's format with the
splits, masks and depth (:func:`pipeline.export.write_nerfstudio_transforms`);
``lumigraph export`` writes the folders that need other files (pipeline/export.py).

One view is one unit of work (pipeline.distributed): rendered (the rasterizer's EGL renderer or
the path tracer's prepared scene built once per process, pipeline.renderers) and put through the
sensor wherever the engine runs it, from the scene shared once; the client writes every file.
A view is a pure function of (scene, camera, view index, seed), so the bytes are the same in
process and on a cluster of any size.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from render.camera import Camera
from render.camera_io import read_cameras_json, write_blender_transforms_json, write_cameras_json, write_colmap_text
from render.image_io import exr_size, png_size, write_depth_exr, write_exr, write_png, write_preview
from rig.build import RigScene
from rig.spec import view_sequences
from rig.capture import (CAPTURE_SPP, CapturedView, CapturePlan, capture_list, check_capture, finish_view,
                         plan_capture, render_ideal, sensor_config)

from ..artifacts import BadInput, Manifest, atomic_stage, check_out, read_stage_manifest, write_json
from ..export import write_nerfstudio_transforms
from ..distributed import ClusterConfig, DaskEngine, LocalEngine, engine, map_units
from ..progress import console, progress_bar
from ..renderers import prepared_scene, raster_pool

__all__ = ["run_capture", "capture_view", "check_capture_folder", "read_cameras", "SPLITS", "VIEW_FILES"]

SPLITS = ("train", "test")
#: a view's files in a capture folder: kind -> (sub-folder, suffix)
VIEW_FILES = {"images": ("images", ".png"), "linear": ("linear", ".exr"), "depth": ("depth", ".exr"),
              "masks": ("masks", ".png")}


def read_cameras(path: Path) -> tuple[list[Camera], list[str]]:
    """A stage input's ``cameras.json`` (:func:`render.camera_io.read_cameras_json`: view names
    are plain file stems, poses rigid and finite, intrinsics finite): ``(cameras, splits)``;
    BadInput, one line naming the file and field, on any problem."""
    path = Path(path)
    if not path.is_file():
        raise BadInput(f"{path}: no camera file (cameras.json missing)")
    try:
        return read_cameras_json(path)
    except (ValueError, FileNotFoundError) as exc:
        raise BadInput(str(exc).splitlines()[0]) from None


def check_capture_folder(folder: Path, need: tuple[str, ...] = ("images", "linear")) -> tuple[list[Camera], list[str]]:
    """Check a capture folder before a later stage reads it; returns its ``(cameras, splits)``.

    A finished capture stage (``manifest.json`` whose stage is "capture"), a valid ``cameras.json``
    and, for every view, the files of the kinds in ``need`` (:data:`VIEW_FILES`); every view file
    present of any kind must be a readable image (its header) of the view's size, all views one
    size. Headers only: decoding stays with the reader. BadInput, one line naming the file (and
    field), on the first problem."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BadInput(f"{folder}: no such capture folder")
    read_stage_manifest(folder, "capture")
    cameras, splits = read_cameras(folder / "cameras.json")
    first = None
    for cam in cameras:
        k = cam.intrinsics
        for kind, (sub, suffix) in VIEW_FILES.items():
            p = folder / sub / f"{cam.name}{suffix}"
            if not p.is_file():
                if kind in need:
                    raise BadInput(f"{p}: image missing for view {cam.name!r}")
                continue
            try:
                w, h = png_size(p) if suffix == ".png" else exr_size(p)
            except ValueError as exc:
                reason = str(exc).splitlines()[0].replace(f"{p}: ", "", 1)
                raise BadInput(f"{p}: unreadable image: {reason}") from None
            if first is None:
                first = (p, w, h)
            elif (w, h) != first[1:]:
                raise BadInput(f"{p}: image is {w}x{h} but {first[0].relative_to(folder)} is "
                               f"{first[1]}x{first[2]} (mixed image sizes)")
            if (w, h) != (k.width, k.height):
                raise BadInput(f"{p}: image is {w}x{h} but cameras.json says {k.width}x{k.height} for view {cam.name!r}")
    return cameras, splits


def capture_order(rig: RigScene, splits: tuple[str, ...]) -> dict:
    """``capture_order.json``: the order the rig shot the views in (:func:`rig.spec.view_sequences`:
    sequence, frame index within it, closed loop), plus ``time``, the view's index in the whole
    capture. Pose estimation pairs views by it, as a video's frame order, never by file name."""
    views, time = [], 0
    for split in splits:
        names = [c.name for c in rig.cameras.get(split, [])]
        for name, seq in zip(names, view_sequences(getattr(rig.spec.cameras, split), split), strict=True):
            views.append({"name": name, "split": split, **seq, "time": time})
            time += 1
    return {"views": views}


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


def _capture_calibration(rig: RigScene, eng, gl_threads: int | None, seed: int, first_index: int, tmp: Path,
                         bar) -> int:
    """Render the scene's calibration sequence (:func:`rig.calibration.calibration_rig`), if it asks
    for one, into ``tmp/calibration``: PNG previews (what a lab's calibration tool reads) and
    ``board.json`` ({"board": the board's definition}). Its views draw sensor noise after the
    capture's own (indices from ``first_index``), so the capture's views keep their bytes. Returns
    the number of views (0: no sequence)."""
    from rig.calibration import CALIBRATION_SPLIT, calibration_rig

    cal = calibration_rig(rig)
    if cal is None:
        return 0
    cams = cal.cameras[CALIBRATION_SPLIT]
    plan = plan_capture(cal)
    check_capture(cal, plan)
    task = bar.add_task("calibration sequence", total=len(cams), info=plan.renderer)

    def write_view(_: int, view: CapturedView) -> None:
        write_preview(tmp / "calibration" / "images" / f"{view.camera.name}.png", view.rgb)
        bar.advance(task)

    scene = eng.share(cal.scene)
    units = [(scene.key, plan, sensor_config(cal), seed, eng.render_threads, gl_threads, first_index + i,
              CALIBRATION_SPLIT, c) for i, c in enumerate(cams)]
    try:
        map_units(eng, capture_view, units, shared=[scene], on_result=write_view, name="capture-calibration")
    finally:
        eng.release(scene)
    write_json(tmp / "calibration" / "board.json", {"board": next(iter(cal.targets.values()))["board"]})
    return len(cams)


def run_capture(rig: RigScene, scene_file: Path, out: Path, seed: int | None = None, quiet: bool = False,
                cluster: ClusterConfig | LocalEngine | DaskEngine | None = None, overwrite: bool = False) -> dict:
    """Capture ``rig`` into ``out`` atomically; returns the manifest.

    ``out`` may be absent, empty or a finished capture folder; anything else is refused
    (BadInput, before any work) unless ``overwrite`` (:func:`pipeline.artifacts.check_out`).

    cluster: where the views run (pipeline.distributed): None (default) in this process; a
    :class:`ClusterConfig` for a local or existing Dask cluster, or an engine already open. The
    output files are the same bytes either way."""
    check_out(out, "capture", overwrite)
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
    with atomic_stage(out, "capture", overwrite) as tmp, engine(cluster, quiet) as eng, progress_bar(quiet) as bar:
        task = bar.add_task(f"capture {rig.scene.name}", total=n_views, info=plan.renderer)

        def write_view(_: int, view: CapturedView) -> None:
            stem = view.camera.name
            write_exr(tmp / "linear" / f"{stem}.exr", view.rgb)
            write_preview(tmp / "images" / f"{stem}.png", view.rgb)
            write_depth_exr(tmp / "depth" / f"{stem}.exr", view.depth)
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
        names = [c.name for c in cameras]
        write_nerfstudio_transforms(tmp / "transforms.json", cameras, split_of, [f"images/{n}.png" for n in names],
                                    [f"masks/{n}.png" for n in names], [f"depth/{n}.exr" for n in names])
        for split in splits:
            members = [c for c, s in zip(cameras, split_of) if s == split]
            try:  # Blender/TensoRF split files: file paths without extension, camera_angle_x
                write_blender_transforms_json(tmp / f"transforms_{split}.json", members,
                                              [f"images/{c.name}" for c in members])
            except ValueError as exc:  # intrinsics the convention cannot state: transforms.json holds them
                manifest.params.setdefault("blender_split_files", str(exc).split(": ", 1)[-1])
        write_json(tmp / "targets.json", rig.targets)
        write_json(tmp / "capture_order.json", capture_order(rig, splits))
        calibration_views = _capture_calibration(rig, eng, gl_threads, seed, n_views, tmp, bar)
        manifest.metrics = {"views": n_views, **{f"views_{s}": split_of.count(s) for s in splits},
                            "engine": eng.name, "workers": eng.workers,
                            **({"calibration_views": calibration_views} if calibration_views else {})}
        result = manifest.write(tmp)
    return result
