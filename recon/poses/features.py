"""SIFT features through OpenCV, written into a COLMAP database in COLMAP's own conventions.

COLMAP's CPU SIFT (VLFeat) doubles the image first (``first_octave = -1``) and costs ~1 s a view
of the default scene's subject box on this machine; at its own size (octave 0) it is ~4x faster
but finds half the features and doubled the rotation error (recon.poses.colmap.resolve_first_octave).
OpenCV's SIFT also doubles the image first (Lowe's scheme) and is several times faster per core;
its descriptors are converted to what COLMAP's matcher expects, so matching, verification and
mapping run unchanged on them.

Conventions at this boundary:

* keypoints: OpenCV puts the centre of pixel (0, 0) at (0, 0); COLMAP (and this project) at
  (0.5, 0.5): ``x + 0.5, y + 0.5``. Stored as COLMAP's 4-column form ``(x, y, scale,
  orientation)``, scale in pixels (OpenCV's ``size / 2``), orientation in radians (OpenCV's degrees).
* descriptors: OpenCV returns 128 floats (L2-normalised, clipped at 0.2, times 512); COLMAP's
  default normalisation is L1-root (RootSIFT: L1-normalise, square root, so the L2 norm is 1),
  stored as ``uint8(min(round(512 d), 255))`` (COLMAP's FeatureDescriptorsToUnsignedByte).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

__all__ = ["opencv_sift", "rootsift_bytes", "extract_opencv_sift"]


def rootsift_bytes(descriptors: np.ndarray) -> np.ndarray:
    """OpenCV SIFT descriptors ``(N, 128)`` float -> COLMAP's L1-root ``(N, 128)`` uint8.

    An all-zero descriptor (no gradient in its window) stays zero instead of dividing by 0."""
    d = np.asarray(descriptors, dtype=np.float64).reshape(-1, 128)
    l1 = d.sum(axis=1, keepdims=True)
    d = np.sqrt(np.divide(d, l1, out=np.zeros_like(d), where=l1 > 0))
    return np.minimum(np.round(512.0 * d), 255).astype(np.uint8)


def opencv_sift(gray: np.ndarray, max_features: int) -> tuple[np.ndarray, np.ndarray]:
    """SIFT on one 8-bit grey image ``(H, W)``: ``(keypoints (N, 4) float32 [x, y, scale,
    orientation] in COLMAP's pixel convention, descriptors (N, 128) uint8 L1-root)``, N <=
    ``max_features`` (the strongest responses kept, as COLMAP does)."""
    # precise upscale: the doubled image's sample x at 2x (the default resize shifts every keypoint
    # by +0.24 px in x and y, tests/recon/test_poses_features.py: a principal point error of 0.01 deg)
    sift = cv2.SIFT_create(nfeatures=max_features, enable_precise_upscale=True)
    kps, desc = sift.detectAndCompute(gray, None)
    if not kps:
        return np.zeros((0, 4), np.float32), np.zeros((0, 128), np.uint8)
    pts = np.array([(k.pt[0] + 0.5, k.pt[1] + 0.5, k.size / 2, np.deg2rad(k.angle)) for k in kps], np.float32)
    return pts, rootsift_bytes(desc)


def extract_opencv_sift(database: Path, image_dir: Path, names: Sequence[str], max_features: int,
                        num_threads: int = 2, box_of: Callable[[np.ndarray], tuple | None] | None = None
                        ) -> list[int]:
    """Extract :func:`opencv_sift` features of ``image_dir/name`` for every image already imported
    into the COLMAP ``database`` (by name), ``num_threads`` images at a time (OpenCV releases the
    GIL), and write keypoints and descriptors. Each image is read once.

    box_of: the view's own box ``(x0, y0, x1, y1)`` from its pixels ``(H, W[, C])`` (e.g.
    :func:`recon.poses.colmap.view_box`): SIFT runs on that crop only and the keypoints are shifted
    back to the whole frame (None from it: the whole frame). Features far enough inside the box are
    those of the whole frame; the frame's dark background has none to lose, only pixels to filter.
    Returns the feature count per image, in ``names`` order. An unreadable image raises
    ValueError naming it.
    """
    import pycolmap

    def one(name: str) -> tuple[np.ndarray, np.ndarray]:
        img = cv2.imread(str(Path(image_dir) / name), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{Path(image_dir) / name}: unreadable image")
        box = box_of(img) if box_of is not None else None
        x0, y0, x1, y1 = box or (0, 0, img.shape[1], img.shape[0])
        img = img[y0:y1, x0:x1]
        if img.dtype != np.uint8:
            img = (img >> 8).astype(np.uint8)  # 16-bit PNG: its high byte
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
        kps, desc = opencv_sift(img, max_features)
        kps[:, 0] += x0
        kps[:, 1] += y0
        return kps, desc

    db = pycolmap.Database.open(str(database))
    counts = []
    try:
        ids = {img.name: img.image_id for img in db.read_all_images()}
        with ThreadPoolExecutor(max(1, num_threads)) as pool:
            for name, (kps, desc) in zip(names, pool.map(one, names)):
                db.write_keypoints(ids[name], kps)
                db.write_descriptors(ids[name], pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT, desc))
                counts.append(len(kps))
    finally:
        db.close()
    return counts
