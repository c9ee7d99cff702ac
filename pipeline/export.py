"""Captures in the formats the field's tools open unchanged: nerfstudio, instant-ngp, COLMAP.

Two layers:

* :func:`write_nerfstudio_transforms` writes the ``transforms.json`` a capture (and a poses
  folder) carries: nerfstudio's format (``nerfstudio/data/dataparsers/nerfstudio_dataparser.py``,
  v1.1.5) with ``train_filenames`` / ``val_filenames`` / ``test_filenames`` (val = test: the
  held-out views), per-frame ``mask_path`` and ``depth_file_path``, ``applied_transform`` (identity:
  the poses are in the scene's own world frame, nothing was applied) and the depth unit. One file
  for every split, so nerfstudio normalises train and eval poses together.
* ``lumigraph export CAPTURE --format F`` (:func:`pipeline.stages.export.run_export`) writes what a shared folder cannot
  serve, into its own stage folder (atomic, with a manifest):

  - ``nerfstudio``: images, masks and 16-bit PNG depth in millimetres (nerfstudio's default
    ``depth_unit_scale_factor`` 1e-3; OpenCV builds without OpenEXR cannot read the EXR depth),
    with that ``transforms.json``;
  - ``instant-ngp``: one folder per split (``train/``, ``test/``: instant-ngp given a folder loads
    every json with ``frames`` in it, so the held-out views must live apart), sRGB PNGs with
    ``dynamic_mask_<name>.png`` beside them, 16-bit depth PNGs with ``integer_depth_scale``, and
    ``aabb_scale``, ``scale`` and ``offset`` that put the subject in the unit cube; plus
    ``train_linear/`` and ``test_linear/`` over the linear EXR radiance (instant-ngp reads EXR
    natively, as HDR; it applies dynamic masks to 8-bit images only);
  - ``colmap``: ``images/`` and a binary model in ``sparse/0`` (COLMAP's layout, what its GUI's
    File > Import model opens) with 3D points from the ground-truth depth, written by pycolmap.

Conventions: our cameras are OpenCV camera-to-world; transforms files are OpenGL
camera-to-world in the scene's world frame (:mod:`render.camera_io`). Depth is z-depth along the
optical axis in scene units (metres), 0 where nothing was hit.
"""
from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np
from PIL import Image

from render.camera import Camera
from render.camera_io import ColmapPoints, write_colmap_model, write_transforms_json
from render.image_io import read_exr, read_png

from .artifacts import BadInput

__all__ = ["FORMATS", "EXPORTERS", "write_nerfstudio_transforms", "ngp_framing", "depth_points", "relpath",
           "NGP_DEPTH_MAX_M", "NS_DEPTH_UNIT_M"]

FORMATS = ("nerfstudio", "instant-ngp", "colmap")
#: instant-ngp's depth PNGs: metres per integer step is chosen so this depth fits 16 bits
NGP_DEPTH_MAX_M = 16.0
#: nerfstudio's default depth_unit_scale_factor: its 16-bit depth PNGs are in millimetres
NS_DEPTH_UNIT_M = 1e-3
#: the subject's bounding box fills 1 / FRAMING_MARGIN of instant-ngp's unit cube
FRAMING_MARGIN = 1.1
#: nerfstudio's applied_transform when nothing was applied (3x4; it assumes a COLMAP axis swap otherwise
#: whenever colmap/sparse/0 exists beside the json)
_IDENTITY_3x4 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
_CONVENTION = {
    "transform_matrix": "camera-to-world, OpenGL camera axes (x right, y up, z backward) = OpenCV's with y and z "
                        "flipped; world frame is the scene's own (turntable scenes: +Z up, metres)",
    "pixel_centers": "pixel (row i, col j) has its centre at (j + 0.5, i + 0.5); cx, cy given in it",
    "depth": "z-depth along the optical axis (not ray length), 0 where nothing was hit",
    "masks": "subject masks: 255 on the subject, 0 elsewhere (nerfstudio ignores pixels where the mask is 0)",
}


def _splits_of(names: list[str], splits: list[str]) -> dict[str, list[str]]:
    return {s: [n for n, t in zip(names, splits) if t == s] for s in dict.fromkeys(splits)}


def write_nerfstudio_transforms(path: Path, cameras: list[Camera], splits: list[str], image_paths: list[str],
                                mask_paths: list[str] | None, depth_paths: list[str] | None,
                                depth_unit_m: float = 1.0) -> None:
    """Write nerfstudio's ``transforms.json`` over every view (see the module docstring).

    cameras/splits: N cameras and their split labels; image/mask/depth paths: N paths relative to
    ``path``'s folder (masks and depth may be None). ``depth_unit_m``: metres per stored depth unit
    (1 for the capture's EXRs, 1e-3 for millimetre PNGs); recorded as ``depth_unit_scale_factor``,
    the name of nerfstudio's option that must be given this value (it does not read it from the file)."""
    extras = [{} for _ in cameras]
    for key, paths in (("mask_path", mask_paths), ("depth_file_path", depth_paths)):
        if paths is not None:
            for e, p in zip(extras, paths):
                e[key] = p
    extra: dict = {"applied_transform": _IDENTITY_3x4, "depth_unit_scale_factor": depth_unit_m,
                   "lumigraph_convention": _CONVENTION}
    by_split = _splits_of(image_paths, splits)
    if by_split.get("train") and by_split.get("test"):
        # val = test: nerfstudio evaluates during training on "val" and with ns-eval on "test"
        extra.update(train_filenames=by_split["train"], val_filenames=by_split["test"],
                     test_filenames=by_split["test"])
    write_transforms_json(path, cameras, image_paths, extras, extra)


# --------------------------------------------------------------------------- geometry from depth


def depth_points(cam: Camera, depth: np.ndarray, stride: int = 1, mask: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """World points of a z-depth image: ``(xyz (M, 3) float64, pixel (M, 2) float64)``.

    depth: (H, W) z-depth of ``cam`` (0 = nothing hit); every ``stride``-th pixel centre in both
    directions (and, with ``mask`` (H, W) bool, only where it is set) with depth > 0. The point is
    ``C + z * d / d_z`` for the pixel's ray ``d`` (distortion inverted by :meth:`Camera.pixel_rays`)."""
    k = cam.intrinsics
    ii, jj = np.mgrid[0:k.height:stride, 0:k.width:stride]
    z = depth[ii, jj]
    keep = z > 0
    if mask is not None:
        keep &= mask[ii, jj]
    pix = np.stack([jj[keep] + 0.5, ii[keep] + 0.5], axis=1).astype(np.float64)
    origins, dirs = cam.pixel_rays(pix)
    d_cam_z = dirs @ cam.cam_to_world[:3, 2]  # the ray's component along the optical axis
    xyz = origins + dirs * (z[keep].astype(np.float64) / d_cam_z)[:, None]
    return xyz, pix


def ngp_framing(cameras: list[Camera], depths: list[np.ndarray], masks: list[np.ndarray]) -> dict:
    """instant-ngp's ``scale``, ``offset`` and ``aabb_scale`` for a capture.

    instant-ngp maps a NeRF-frame position p to ``p * scale + offset`` (then cycles the axes,
    ``nerf_matrix_to_ngp``) and trains inside the unit cube, enlarged ``aabb_scale`` times around
    its centre. scale = 1 / (FRAMING_MARGIN x the subject's largest bounding-box side, from the
    depth of its masked pixels, 0.5 and 99.5 percentiles per axis) and offset = 0.5 - scale * (the box centre) put the subject in the unit cube
    centred at 0.5; aabb_scale is the smallest power of two (1..128) whose cube holds every
    surface seen (all depth points), so the board and turntable are inside the trained volume."""
    subject, seen = [], []
    for cam, depth, mask in zip(cameras, depths, masks):
        stride = max(1, cam.intrinsics.width // 160)  # ~160 x 120 samples per view bound the box well
        subject.append(depth_points(cam, depth, stride, mask)[0])
        seen.append(depth_points(cam, depth, stride)[0])
    sub = np.concatenate(subject)
    if len(sub) == 0:
        raise BadInput("export: no subject pixel with depth in any view (masks empty?): cannot frame the subject")
    # robust bounds: mask-edge pixels carry depth of what lies behind the subject's silhouette
    lo, hi = np.percentile(sub, 0.5, axis=0), np.percentile(sub, 99.5, axis=0)
    scale = 1.0 / (FRAMING_MARGIN * max(float(np.max(hi - lo)), 1e-9))
    centre = (lo + hi) / 2
    offset = 0.5 - scale * centre
    allp = np.concatenate(seen) * scale + offset
    reach = float(np.max(np.abs(allp - 0.5))) * 2  # cube side, in unit cubes, that holds every surface
    aabb_scale = int(min(128, 2 ** max(0, math.ceil(math.log2(max(reach, 1.0))))))
    return {"scale": scale, "offset": offset.tolist(), "aabb_scale": aabb_scale,
            "subject_box": [lo.tolist(), hi.tolist()]}


def _triangulated_points(cameras: list[Camera], depths: list[np.ndarray], images: list[np.ndarray],
                         stride: int, tolerance_rel: float = 0.01) -> ColmapPoints:
    """3D points from the ground-truth depth with COLMAP tracks: every ``stride``-th pixel of each
    view with depth becomes a point, observed in every view where it projects inside the image in
    front of the camera and that view's own depth there agrees within ``tolerance_rel`` (so
    occluded views are left out). Colours from the source view's sRGB preview."""
    xyz_all, rgb_all, obs_point, obs_image, obs_xy = [], [], [], [], []
    base = 0
    for src, (cam, depth, img) in enumerate(zip(cameras, depths, images)):
        xyz, pix = depth_points(cam, depth, stride)
        if not len(xyz):
            continue
        ij = np.floor(pix).astype(int)
        rgb_all.append(img[ij[:, 1], ij[:, 0], :3])
        xyz_all.append(xyz)
        ids = np.arange(base, base + len(xyz))
        for dst, (c2, d2) in enumerate(zip(cameras, depths)):
            if dst == src:
                seen, uv = np.ones(len(xyz), bool), pix
            else:
                uv, z = c2.project(xyz)
                k = c2.intrinsics
                inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < k.width) & (uv[:, 1] >= 0) & (uv[:, 1] < k.height)
                seen = inside.copy()
                col = np.clip(np.floor(uv[:, 0]).astype(int), 0, k.width - 1)
                row = np.clip(np.floor(uv[:, 1]).astype(int), 0, k.height - 1)
                seen[inside] = np.abs(d2[row[inside], col[inside]] - z[inside]) <= tolerance_rel * z[inside]
            obs_point.append(ids[seen])
            obs_image.append(np.full(int(seen.sum()), dst))
            obs_xy.append(uv[seen])
        base += len(xyz)
    if not xyz_all:
        raise BadInput("export: no pixel with depth in any view: no 3D points for the COLMAP model")
    return ColmapPoints(np.concatenate(xyz_all), np.concatenate(rgb_all).astype(np.uint8),
                        np.concatenate(obs_point), np.concatenate(obs_image), np.concatenate(obs_xy))


# --------------------------------------------------------------------------- the export stage


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)


def _write_u16(path: Path, values: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(values.astype(np.uint16)).save(path, format="PNG")


def _quantise(depth: np.ndarray, unit_m: float, what: Path) -> np.ndarray:
    q = np.rint(depth / unit_m)
    if q.max(initial=0) > 65535:
        raise BadInput(f"{what}: depth {float(depth.max()):.3f} m does not fit 16 bits at {unit_m:g} m per step")
    return q


def _export_nerfstudio(tmp: Path, cap: Path, cams: list[Camera], splits: list[str], bar, task) -> dict:
    names = [c.name for c in cams]
    for n in names:
        _copy(cap / "images" / f"{n}.png", tmp / "images" / f"{n}.png")
        _copy(cap / "masks" / f"{n}.png", tmp / "masks" / f"{n}.png")
        _write_u16(tmp / "depth" / f"{n}.png", _quantise(read_exr(cap / "depth" / f"{n}.exr"), NS_DEPTH_UNIT_M,
                                                         cap / "depth" / f"{n}.exr"))
        bar.advance(task)
    write_nerfstudio_transforms(tmp / "transforms.json", cams, splits, [f"images/{n}.png" for n in names],
                                [f"masks/{n}.png" for n in names], [f"depth/{n}.png" for n in names],
                                depth_unit_m=NS_DEPTH_UNIT_M)
    return {"views": len(names), "depth_unit_m": NS_DEPTH_UNIT_M}


def _export_instant_ngp(tmp: Path, cap: Path, cams: list[Camera], splits: list[str], bar, task) -> dict:
    depths = [read_exr(cap / "depth" / f"{c.name}.exr") for c in cams]
    masks = [read_png(cap / "masks" / f"{c.name}.png") > 0 for c in cams]
    framing = ngp_framing(cams, depths, masks)
    unit = NGP_DEPTH_MAX_M / 65535
    top = {"aabb_scale": framing["aabb_scale"], "scale": framing["scale"], "offset": framing["offset"],
           "integer_depth_scale": unit, "lumigraph_convention": {
               **_CONVENTION, "framing": "scale and offset put the subject's bounding box "
               f"{framing['subject_box']} (metres) in the unit cube; aabb_scale holds every surface seen",
               "dynamic_mask": "dynamic_mask_<name>.png marks the pixels instant-ngp ignores: everything but the "
               "subject (the capture's mask inverted)",
               "depth": f"depth/<name>.png: 16-bit, z-depth in metres = value * integer_depth_scale ({unit:.6g})"}}
    for split in dict.fromkeys(splits):
        members = [(c, d, m) for c, d, m, s in zip(cams, depths, masks, splits) if s == split]
        for linear in (False, True):
            folder = tmp / (f"{split}_linear" if linear else split)
            paths, extras = [], []
            for c, d, m in members:
                if linear:
                    _copy(cap / "linear" / f"{c.name}.exr", folder / "images" / f"{c.name}.exr")
                    paths.append(f"images/{c.name}.exr")
                else:
                    _copy(cap / "images" / f"{c.name}.png", folder / "images" / f"{c.name}.png")
                    Image.fromarray(np.where(m, 0, 255).astype(np.uint8)).save(
                        folder / "images" / f"dynamic_mask_{c.name}.png", format="PNG")
                    paths.append(f"images/{c.name}.png")
                _write_u16(folder / "depth" / f"{c.name}.png", _quantise(d, unit, cap / "depth" / f"{c.name}.exr"))
                extras.append({"depth_path": f"depth/{c.name}.png"})
            write_transforms_json(folder / "transforms.json", [c for c, _, _ in members], paths, extras, top)
        bar.advance(task, len(members))
    return {"views": len(cams), "aabb_scale": framing["aabb_scale"], "scale": framing["scale"],
            "integer_depth_scale": unit}


def _export_colmap(tmp: Path, cap: Path, cams: list[Camera], splits: list[str], bar, task) -> dict:
    names = [c.name for c in cams]
    for n in names:
        _copy(cap / "images" / f"{n}.png", tmp / "images" / f"{n}.png")
    depths = [read_exr(cap / "depth" / f"{n}.exr") for n in names]
    images = [read_png(cap / "images" / f"{n}.png") for n in names]
    stride = max(1, cams[0].intrinsics.width // 64)  # ~64 x 48 points per view: enough to see the scene
    points = _triangulated_points(cams, depths, images, stride)
    write_colmap_model(tmp / "sparse" / "0", cams, [f"{n}.png" for n in names], points, binary=True)
    bar.advance(task, len(names))
    track = np.bincount(points.obs_point)
    return {"views": len(names), "points3D": int(len(points.xyz)), "mean_track_length": float(track.mean())}


def relpath(target: Path, start: Path) -> str:
    """``target`` relative to the folder ``start`` (both resolved), with forward slashes."""
    return Path(os.path.relpath(Path(target).resolve(), Path(start).resolve())).as_posix()


#: format -> writer(tmp folder, capture folder, cameras, splits, progress bar, task) -> metrics
EXPORTERS = {"nerfstudio": _export_nerfstudio, "instant-ngp": _export_instant_ngp, "colmap": _export_colmap}
