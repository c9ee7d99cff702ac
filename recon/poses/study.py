"""What pose accuracy costs in time: method x image scale x feature count on one capture.

Each cell runs one estimate (COLMAP with known intrinsics, or ChArUco with known intrinsics on
images resized by the scale) and scores it against the ground truth (COLMAP after the similarity
alignment, ChArUco metric). Feature count applies to COLMAP only (ChArUco rows carry None).
"""
from __future__ import annotations

import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import cv2

from render.camera import Camera

from .align import score_cameras
from .charuco import BoardNotFound, CharucoConfig, estimate_charuco
from .colmap import ColmapConfig, ReconstructionError, estimate_colmap

__all__ = ["STUDY_COLUMNS", "pose_study"]

STUDY_COLUMNS = ("method", "image_scale", "width", "height", "max_features", "wall_time_s", "registered",
                 "views", "rotation_error_deg_mean", "rotation_error_deg_max", "center_error_rel_mean",
                 "reprojection_error_px", "status")


def _row(method, scale, k, features, seconds, cams, truth, reproj, status="ok") -> dict:
    row = {"method": method, "image_scale": scale, "width": k.width, "height": k.height, "max_features": features,
           "wall_time_s": round(seconds, 3), "registered": len(cams), "views": len(truth),
           "rotation_error_deg_mean": None, "rotation_error_deg_max": None, "center_error_rel_mean": None,
           "reprojection_error_px": reproj, "status": status}
    if len(cams) >= 3:
        try:
            _, m, _ = score_cameras(cams, truth, align=method == "colmap")
            row.update({k_: m[k_] for k_ in ("rotation_error_deg_mean", "rotation_error_deg_max",
                                             "center_error_rel_mean")})
        except ValueError as exc:
            row["status"] = f"unscorable: {exc}"
    return row


def pose_study(images: Mapping[str, Path], truth: Sequence[Camera], targets: Mapping | None,
               scales: Sequence[float] = (0.5, 1.0), features: Sequence[int] = (1024, 4096, 8192),
               methods: Sequence[str] = ("charuco", "colmap"), seed: int = 0) -> list[dict]:
    """Rows (dicts with :data:`STUDY_COLUMNS`) of the grid; failed cells keep their time and status.

    images: view name -> image file; truth: ground-truth cameras (camera-to-world, OpenCV axes)
    at the images' resolution; targets: a capture's ``targets.json`` content (ChArUco rows need it).
    """
    by_name = {c.name: c for c in truth}
    k0 = truth[0].intrinsics
    rows = []
    for scale in scales:
        k = k0.scaled(scale)
        if "charuco" in methods and targets:
            t0 = time.perf_counter()
            imgs = {}
            for n, p in images.items():
                img = cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB)
                if scale != 1.0:
                    img = cv2.resize(img, (k.width, k.height), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)
                imgs[n] = img
            try:
                res = estimate_charuco(imgs, targets, k, CharucoConfig())
                cams = [replace(c, intrinsics=k0) for c in res.cameras]
                rows.append(_row("charuco", scale, k, None, time.perf_counter() - t0, cams, by_name,
                                 res.reprojection_error_px))
            except BoardNotFound as exc:
                rows.append(_row("charuco", scale, k, None, time.perf_counter() - t0, [], by_name, None, str(exc)))
        if "colmap" in methods:
            for f in features:
                cfg = ColmapConfig(image_scale=scale, max_features=f, seed=seed)
                t0 = time.perf_counter()
                with tempfile.TemporaryDirectory(prefix="lumigraph-study-") as tmp:
                    try:
                        res = estimate_colmap(images, k0, Path(tmp), cfg)
                        rows.append(_row("colmap", scale, k, f, time.perf_counter() - t0, res.cameras, by_name,
                                         res.reprojection_error_px))
                    except ReconstructionError as exc:
                        rows.append(_row("colmap", scale, k, f, time.perf_counter() - t0, [], by_name, None, str(exc)))
    return rows
