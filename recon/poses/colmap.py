"""Structure from motion with COLMAP (pycolmap): SIFT features, matching, incremental mapping, CPU.

Two modes (:class:`ColmapConfig.known_intrinsics`):

* known intrinsics: one camera with the given calibration (PINHOLE ``fx fy cx cy``, OPENCV /
  FULL_OPENCV when it has distortion); bundle adjustment keeps it fixed, only poses and points move;
* self-calibration (:func:`calibrate_lens`): the mapper runs on one SIMPLE_RADIAL camera
  (``f cx cy k1``) from COLMAP's focal guess (1.2 x the larger image side), focal and k1 refined,
  the principal point at the centre; then the principal point is freed and the lens model
  climbs SIMPLE_RADIAL -> RADIAL -> OPENCV (-> FULL_OPENCV when asked), one model at a time,
  each bundle adjusted from the previous solution: the order COLMAP users refine in (focal,
  then k1, then the rest). ``auto`` keeps the richest model the views constrain.

Why an OPENCV camera from the start registered 2 of 56 views (issue 21): see :data:`OPENCV_FROM_START`.

COLMAP and we put pixel centres at +0.5, so intrinsics pass to and from COLMAP unchanged.
Images can be resized by ``image_scale`` first (intrinsics scaled with them); the returned
cameras always have the input resolution's intrinsics. Poses come back in COLMAP's arbitrary
similarity frame: align them with :func:`recon.poses.align.umeyama` before comparing.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from render.camera import Camera, Intrinsics
from render.camera_io import colmap_camera

from .features import extract_opencv_sift
from .pairing import ViewOrder, capture_order_pairs, doubling_offsets

__all__ = ["ColmapConfig", "ColmapResult", "ReconstructionError", "estimate_colmap"]


class ReconstructionError(ValueError):
    """Structure from motion produced no usable model (one line: what failed)."""


@dataclass(frozen=True)
class ColmapConfig:
    """Options that matter for accuracy and time; the defaults give the figures in the report.

    known_intrinsics: the given calibration held fixed (True: PINHOLE, or OPENCV / FULL_OPENCV
        when it has distortion) or self-calibration (False; see ``camera_model``).
    camera_model: self-calibration's lens model: ``auto`` or one of :data:`CAMERA_MODELS`. The
        mapper runs on SIMPLE_RADIAL (focal and k1 refined); :func:`calibrate_lens` then frees the
        principal point and climbs one model at a time to the one asked for, or with ``auto`` to
        the richest the views constrain (a likelihood-ratio test per step).
    image_scale: resize factor applied before feature extraction (1 = capture resolution); None
        (auto): :func:`resolve_image_scale` (1, or :data:`LARGE_IMAGE_SCALE` from
        ``large_min_images`` views on).
    large_min_images: the view count from which ``image_scale`` None stands for
        :data:`LARGE_IMAGE_SCALE`.
    max_features: SIFT features per image.
    first_octave: SIFT's first octave: -1 doubles the image first (COLMAP's default: finer
        features, 4x the pixels to filter), 0 starts at the image's own size (~4x faster, twice
        the rotation error); None (auto): -1 (:func:`resolve_first_octave`, the measurement).
        COLMAP's extractor only (OpenCV's SIFT always doubles the image first).
    extractor: whose SIFT: ``colmap`` (COLMAP's CPU SIFT, VLFeat), ``opencv`` (OpenCV's SIFT,
        descriptors converted to COLMAP's, :mod:`recon.poses.features`), or ``auto``
        (:func:`resolve_extractor`: opencv from ``global_min_images`` images on).
    matcher: ``exhaustive`` (every pair), ``capture_order`` (the shooting order's pairs,
        :mod:`recon.poses.pairing`: neighbours within each ring with loop closure, same-phase
        links between rings; needs the order), ``sequential`` (neighbours in name order, loop
        detection off), or ``auto``: exhaustive up to ``exhaustive_max_images`` images, then
        capture_order when the order is known, else sequential.
    sequential_overlap: neighbours matched ahead per image by the sequential and capture-order
        matchers (the capture-order window).
    pair_offsets: the capture-order matcher's steps within a sequence: ``consecutive`` (the next
        ``sequential_overlap`` frames) or ``doubling`` (1, 2, 4, .. up to ``sequential_overlap``:
        4 pairs per view instead of 12 at the default overlap; :func:`recon.poses.pairing.doubling_offsets`).
    link_window: half-width of the capture-order links between sequences (frames either side of
        the same phase).
    mapper: ``incremental`` (COLMAP's incremental mapper), ``global`` (COLMAP 4's global mapper,
        GLOMAP: rotation averaging, global positioning, one bundle adjustment), or ``auto``:
        global from ``global_min_images`` images on.

    Why ``auto`` switches at 150 images (measured; rotation error mean after alignment):

    * 20 views, 400x300 (tests/recon/conftest.py's small capture; ``lumigraph poses CAPTURE
      --method colmap --matcher M --mapper P``): exhaustive + incremental 190 pairs, 0.113 deg;
      capture_order + incremental 110 pairs, 0.119 deg; capture_order + global 110 pairs,
      0.131 deg; all 20/20.
    * 56 views, the default scene (issue 21's figures, same stage): exhaustive + incremental
      1540 pairs, 0.018 deg; the global mapper on the same matches 0.019 deg, mapping 9 s
      instead of 14; capture_order + incremental 700 pairs, 0.0196 deg, 56/56
      (``python -m bench.bench_poses --views 56 --configs capture_order+incremental``).
    * 224 views, rings of 96 + 96 and 32 held out (``python -m bench.bench_poses --views 224
      --configs capture_order+global``): 3168 pairs (exhaustive: 24,976), 224/224, 0.024 deg
      (issue 21: name-order sequential + incremental 0.029 deg); with the subject's box, doubling
      steps (1,376 pairs), no retriangulation and 10 final iterations: 0.021 deg, extract 123 s,
      match 45 s, map 121 s on the quiet machine (473 / 278 / 311-455 s at load 7-9; the
      earlier defaults 1253 / 458 / 880 s at load 7-11).
    * 1000 views (issue 21): the incremental mapper on 8,977 sequential pairs was stopped after
      77 minutes, still mapping; the global mapper on the same matches registered 1000/1000 at
      0.029 deg in 11.3 minutes. The two full train rings of the 1000-view layout (640 views,
      320 each at 20 and 35 deg; OpenCV SIFT, doubling pairs, 3,520; /tmp probe at load 4-11):
      640/640 at 0.051 deg mean after the 10 final iterations (map 342 CPU s), tracks capped at
      300 a view 0.059 deg (168 CPU s): above the 0.03 goal either way.
    * The ring-wide pitch (session 30; rings of 160 at 20 and 35 deg + 8 held out, 328 views,
      OpenCV SIFT, 1,824 doubling pairs; /tmp probes at load 5-8, one run each;
      :func:`recon.poses.align.sequence_rotation_bias`): 328/328 at 0.0326 deg mean (0.082 max),
      the 20-deg ring pitched +0.018 deg, the 35-deg ring -0.003 (per-view scatter 0.017-0.028).
      Not the cause: the alignment (a rotation-only fit gives 0.0322; it differs from the centre
      fit by 0.007 deg), convergence (bundle adjustment started at the TRUE poses returns to the
      same pitch, +0.018, and the truth's cost is higher: 45,864 against 45,639), the links (link
      window 3, 2,528 pairs: 0.0335, pitch +0.023), the mapper's 100-view track limit
      (``track_max_num_views_per_track`` unlimited: 0.0337), retriangulation (0.0381, 154 CPU s
      against 130), threads (2: identical result) or one bundle-adjustment round instead of 3
      (identical, 0.0326). The features are: the same tracks with their observations replaced by
      true projections plus Gaussian noise of the same rms (0.38 px) give 0.012 deg mean, ring
      pitches within 0.002 and per-view scatter 0.009 deg; the real residuals (observed minus
      true projection, 0.87 px rms with their outliers) shuffled among the observations give
      0.0096 deg, no ring pitch: their structure, not their size or tails, costs the accuracy;
      shuffled only within each view, 0.0094 deg, and they hold no field over the image (mean
      radial residual within 0.006 px at every radius, a fitted k1 of 5e-5): the harmful part is
      each point's error changing smoothly with the viewing direction along its track.
      The real SIFT positions carry no
      per-view or per-ring mean offset against the truth (per-view means at the 0.013-0.021 px
      noise floor), so their error is structured per point and viewing direction, and the mean
      error is set by it, not by the geometry; open: which feature error (texture filtering of
      the obliquely seen board, SIFT's localisation under foreshortening).
    * Which observations carry it (session 33; 224 views, the stage's global-mapper model before
      its 10 final iterations, then those iterations on a changed set of tracks, image
      measurements only; one-off /tmp/s33/hb/probe_ba.py, load 8-15): all tracks 0.0196 deg mean
      (0.073 max), ring pitches +0.0074 / +0.0008 deg (held-out ring +0.0040). Only the
      observations of SIFT keypoints up to 1.9 px scale (OpenCV's size / 2; the median, 51% of
      them): 0.0177 (0.066 max), pitches +0.0025 / +0.0052 / +0.0036 (30 iterations: the same);
      only those above 1.9 px: 0.0577 (0.125 max); only those up to 1.3 px (27%): 0.0329 (0.091
      max): the larger keypoints hold most of the error, but the smallest alone are too few.
      The ChArUco board's inner corners (``detect_board``, cornerSubPix, one track per corner id
      across the views, triangulated from the mapper's poses: 58 tracks, 8,613 observations, 4%
      of the SIFT ones) added before the final iterations: 0.0167 (0.055 max), pitches +0.0022 /
      -0.0001 / +0.0010; each corner added 10 times over-corrects (0.0170, pitches -0.0083 /
      -0.0020 / -0.0073). Both together (scale up to 1.9 px, the corners once): 0.0151 (0.050
      max), pitches -0.0029 / +0.0038 / 0.0000, the final iterations on 10,219 points instead of
      17,347. At 1000 views (LAYOUTS[1000], the stage's final model of the end-to-end run in
      bench_poses_scale.json, 0.0433 deg; 10 more iterations, load 3.4-4.2): with the corners
      (58 tracks, 38,335 observations, every view) 0.0256 deg mean (0.066 max), pitches +0.0044
      (20 deg) / -0.0157 (35) / -0.0152 (50) / -0.0058 (held out) against +0.047 / +0.001 /
      -0.011 / +0.023; without them 0.0432 (0.140 max): the corners, not the iterations. In the
      stage since session 34: ``board_corners`` below (:mod:`recon.poses.board_tracks`; pycolmap
      refuses to extend an image's points2D, so the model is rebuilt with the corners appended
      to each image's keypoints instead of the probe's text-model round trip). The detection,
      513 s for 1000 views in that probe (one thread, load ~12), measures 0.080 CPU s a view at
      1280x960 (28 views, load ~2; ``board_tracks.DETECT_SCALE``).
    * The stage with the corners (session 34; 224 views, ``bench_poses --views 224 --configs C
      --add``, one config a process at load 1.8-4.6, so CPU seconds): ``auto`` 0.0166 deg mean
      (0.055 max; 58 tracks, 8,537 observations, corners 16 CPU s), ``auto+nocorners`` 0.0196
      (0.073), extract / match / map 77 / 68 / 101 and 78 / 71 / 88 CPU s. Cutting SIFT's cost
      with the corners on: ``image_scale`` 0.75 185 CPU s instead of 245 at 0.0219 deg (without
      the corners 0.0270), 0.85 215 s at 0.0186; 0.5 113 s
      at 0.0391; ``max_features`` 1024 163 s at 0.0325, 1536 185 s at 0.0405 (the cap binds below
      OpenCV's ~1,800 a view; which features survive it moves the ring pitch). Defaults kept.

    * The stage's own wall time (session 35; ``bench_poses --views N --add``, quiet runs): the
      board's corners detected beside the mapper instead of after it (:class:`recon.poses.board_tracks.CornerJob`,
      threads at nice 19 in the mapper's idle share; the same cameras bit for bit at 224 views with
      one thread), the capture read and the working copies written on all cores, the copies
      without PNG row filters, and ``image_scale`` 0.75 from 500 views on
      (:func:`resolve_image_scale`): 1000 views 1000/1000 at 0.0286 deg in 531.8 s wall (extract
      / match / map / corners 109 / 132 / 268 / 4.7 s; load 0.05-1.8, up to 5.5 in 5-s samples);
      earlier quiet runs on the way 602.6 s (final iterations on 2 threads) and 618.1 s (PNG row
      filters; its mapper 261 s against 188 s on the same inputs: quiet runs vary by tens of
      seconds); session 34 at scale 0.75: 615.9 s, 35 s of it the corners after the mapper, now
      3-5 s. 224 views 136.5-175.9 s wall, 0.0166 deg.
      Not kept: the final bundle adjustment on 2 threads (61.8 s against 49.3 on one at 1000 views),
      one round of the global mapper's bundle adjustment (``global_ba_rounds`` 1: ~5% of the
      mapper at 224 views), COLMAP's brute-force CPU matcher (>7x slower at 224 views).

    Below 150 views exhaustive matching and the incremental mapper stay the most accurate at a
    cost that is still small; above, pairs must grow linearly and only the global mapper
    finishes. ``bench/results/bench_poses_scale.json`` holds the stage's own figures at 56 / 224
    / 1000 views.
    global_tracks_per_view: the global mapper keeps tracks until every view has this many (the
        longest first; 0 = every track): fewer points in global positioning and its bundle
        adjustment.
    global_retriangulate: the global mapper's retriangulation and second bundle adjustment after
        the first (False, the default, skips them: see :func:`resolve_final_ba_iterations`).
    global_ba_rounds: rounds of the global mapper's bundle adjustment (COLMAP's
        ``ba_num_iterations``, 3 by default; each round filters the tracks and adjusts again).
    final_ba_iterations: iterations of one extra global bundle adjustment with tight tolerances
        after mapping (0 skips it); None (auto): :func:`resolve_final_ba_iterations`.
    crop_to_subject: extract features from the views' common box around the subject
        (:func:`subject_box`: the background is dark; found from the images themselves, no pose
        involved) instead of the whole frame; the intrinsics follow the crop (principal point
        shifted, or with self-calibration a box centred on the image so the mapper's centred
        principal point stays right). Same features on the subject, fewer pixels to filter.
        None (auto): with known intrinsics only; self-calibration keeps the whole frame, as its
        lens figures were measured (a centred box on ``scenes/real_lens.yaml`` keeps 68% of the
        frame; not measured).
    board_corners: the calibration board's inner corners as extra tracks before the final bundle
        adjustment (:mod:`recon.poses.board_tracks`: ChArUco detection and cornerSubPix, one track
        per corner id, triangulated from the mapper's poses; only the board's definition is used,
        never where it lies). None (auto): on when the board definitions are given (the stage
        passes the capture's ``targets.json`` boards), the intrinsics are known and a final bundle
        adjustment runs; True: also with self-calibration (before the lens ladder); False, or no
        board: the path without them, unchanged. Measured: see "Which observations carry it" above
        (224 views 0.0196 -> 0.0167 deg, 1000 views 0.0433 -> 0.0256).
    seed: COLMAP's RANSAC seeds (two-view verification, mapper, triangulation) and its global PRNG.
    num_threads: threads of feature extraction and matching (-1 = all cores); the result does not
        depend on it. COLMAP numbers images in the order its extraction threads finish, and the
        mapper breaks ties by image id, so two runs registered the views in different orders
        (and once folded the model): the images are imported in name order before extraction, so
        their ids are fixed. Incremental mapping and bundle adjustment run on one thread, since
        Ceres sums residuals in scheduling order on more.
    global_threads: threads of the global mapper (rotation averaging, global positioning and its
        bundle adjustment; the final bundle adjustment stays on one thread). 2 departs from
        scheduling-independence by rounding only: measured at 224 views (rings of 96 + 96, 32 held
        out, 1280x960, the stage's defaults on one database; /tmp probe at load 6-8), two threads
        against one moved no rotation by more than 3.2e-13 deg and no centre by more than 1.3e-13
        (scene units), 224/224 at 0.01956 deg mean either way, and the global mapper took 177 s
        wall instead of 295 (positioning 128 s instead of 211, its bundle adjustment 42 instead of
        68; CPU 97 s against 108). 1 gives bit-identical runs.
    """

    known_intrinsics: bool = True
    image_scale: float | None = None
    large_min_images: int = 500
    max_features: int = 8192
    first_octave: int | None = None
    extractor: Literal["auto", "colmap", "opencv"] = "auto"
    matcher: Literal["auto", "exhaustive", "capture_order", "sequential"] = "auto"
    exhaustive_max_images: int = 150
    sequential_overlap: int = 12
    pair_offsets: Literal["consecutive", "doubling"] = "doubling"
    link_window: int = 1
    mapper: Literal["auto", "incremental", "global"] = "auto"
    global_min_images: int = 150
    global_tracks_per_view: int = 0
    global_retriangulate: bool = False
    global_ba_rounds: int = 3
    camera_model: str = "auto"
    final_ba_iterations: int | None = None
    crop_to_subject: bool | None = None
    board_corners: bool | None = None
    seed: int = 0
    num_threads: int = -1
    global_threads: int = 2

    def __post_init__(self) -> None:
        if self.image_scale is not None and not 0.05 <= self.image_scale <= 4.0:
            raise ValueError(f"image_scale must be in [0.05, 4], got {self.image_scale}")
        if self.first_octave is not None and self.first_octave not in (-1, 0, 1):
            raise ValueError(f"first_octave must be -1, 0 or 1, got {self.first_octave}")
        if self.max_features < 64:
            raise ValueError(f"max_features must be >= 64, got {self.max_features}")
        if self.extractor not in ("auto", "colmap", "opencv"):
            raise ValueError(f"extractor must be auto, colmap or opencv, got {self.extractor!r}")
        if self.matcher not in ("auto", "exhaustive", "capture_order", "sequential"):
            raise ValueError(f"matcher must be auto, exhaustive, capture_order or sequential, got {self.matcher!r}")
        if self.mapper not in ("auto", "incremental", "global"):
            raise ValueError(f"mapper must be auto, incremental or global, got {self.mapper!r}")
        if self.pair_offsets not in ("consecutive", "doubling"):
            raise ValueError(f"pair_offsets must be consecutive or doubling, got {self.pair_offsets!r}")
        if self.sequential_overlap < 1 or self.link_window < 0:
            raise ValueError("sequential_overlap must be >= 1 and link_window >= 0")
        if self.large_min_images < 2:
            raise ValueError(f"large_min_images must be >= 2, got {self.large_min_images}")
        if self.global_ba_rounds < 1:
            raise ValueError(f"global_ba_rounds must be >= 1, got {self.global_ba_rounds}")
        if self.global_threads < 1:
            raise ValueError(f"global_threads must be >= 1, got {self.global_threads}")
        if self.camera_model != "auto" and self.camera_model not in CAMERA_MODELS:
            raise ValueError(f"camera_model must be auto, {', '.join(CAMERA_MODELS)}, got {self.camera_model!r}")


@dataclass
class ColmapResult:
    """Registered cameras (input-resolution intrinsics, COLMAP's frame, camera-to-world OpenCV
    axes, named by image stem), the names COLMAP could not register, and model statistics.

    camera_model: the COLMAP model estimated (PINHOLE / OPENCV / FULL_OPENCV for known
    intrinsics); lens_steps / lens_note: :func:`calibrate_lens`'s per-model fits and note
    (self-calibration only); rational_refit_px: see :func:`rational_refit_px` (input pixels);
    observed_radius_rel: the 99th percentile of the observed keypoints' distance from the image
    centre over the half-diagonal (1 = the corners): where the lens is measured, not extrapolated.
    points: (P, 3) float64 sparse points in COLMAP's frame. reprojection_error_px is the mean
    over all observations, in input-resolution pixels. matcher/mapper: what ran (``auto``
    resolved), extractor: whose SIFT ran (``colmap`` or ``opencv``); pairs: image pairs matched; times_s: wall seconds of ``extract``, ``match``,
    ``map`` (the mapper and the final bundle adjustment) and ``refine`` (the part of ``map``
    after the mapper: final bundle adjustment, or the lens ladder when self-calibrating), and
    ``extract_cpu`` / ``match_cpu`` / ``map_cpu``: CPU seconds of this process's threads in each.
    crop_box: ``(x0, y0, x1, y1)`` input pixels the features were extracted from (the views'
    common box, :func:`subject_box`), None for the whole frame (or when the OpenCV extractor
    cropped each view to its own box, :func:`view_box`). corner_stats: the board corners' figures
    (``board_corners`` False when they were not used, :func:`resolve_board_corners`; else
    ``corner_tracks`` / ``corner_observations`` / ``corner_views`` added and the detection's
    ``corner_detect_views`` / ``corner_detect_s_per_view`` (median wall), with ``times_s``'s
    ``corners`` / ``corners_cpu``, which ``map`` does not count: the detection runs beside the
    mapper (:class:`recon.poses.board_tracks.CornerJob`), so ``corners`` is the wall the stage
    waited for it after the mapper (``corners_wait``) plus the tracks' building
    (``corners_tracks``), and ``corners_detect`` the detection's own wall span; ``corners_cpu``
    the detection's thread CPU seconds plus the tracks'). image_scale: the scale the images were
    resized by (``auto`` resolved, :func:`resolve_image_scale`).
    """

    cameras: list[Camera]
    unregistered: list[str]
    reprojection_error_px: float
    points: np.ndarray
    num_models: int
    mean_track_length: float
    reconstruction: object = field(repr=False)  # pycolmap.Reconstruction, in COLMAP's frame
    matcher: str = ""
    mapper: str = ""
    pairs: int = 0
    times_s: dict = field(default_factory=dict)
    camera_model: str = ""
    lens_steps: list = field(default_factory=list)
    lens_note: str = ""
    rational_refit_px: float = 0.0
    observed_radius_rel: float = 0.0
    crop_box: tuple[int, int, int, int] | None = None
    extractor: str = ""
    corner_stats: dict = field(default_factory=dict)
    image_scale: float = 1.0


#: a pixel belongs to the subject when its brightest channel exceeds this (8-bit) after averaging
#: over SUBJECT_CELL x SUBJECT_CELL blocks (the average tames sensor noise on the black background)
SUBJECT_LEVEL = 12
SUBJECT_CELL = 8
#: pixels kept around the subject's box (SIFT's support region at the box edge)
SUBJECT_MARGIN = 32
#: a box covering more of the frame than this is not worth a crop (every view re-encoded)
CROP_MAX_AREA = 0.8


def _bright_extent(img: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """One image's bright blocks (module constants): their extent ``(lo, hi)`` as ``(2,)`` float
    arrays ``[x, y]`` in input pixels (hi exclusive), None when nothing is bright."""
    height, width = img.shape[:2]
    bright = img if img.ndim == 2 else img[..., :3].max(axis=2)
    cells = cv2.resize(bright, (max(width // SUBJECT_CELL, 1), max(height // SUBJECT_CELL, 1)),
                       interpolation=cv2.INTER_AREA)
    ys, xs = np.nonzero(cells > SUBJECT_LEVEL * (257 if img.dtype == np.uint16 else 1))
    if not len(xs):
        return None
    return (np.array([xs.min() * width / cells.shape[1], ys.min() * height / cells.shape[0]]),
            np.array([(xs.max() + 1) * width / cells.shape[1], (ys.max() + 1) * height / cells.shape[0]]))


def _grown(lo: np.ndarray, hi: np.ndarray, width: int, height: int) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)``: the extent grown by SUBJECT_MARGIN, clipped to the frame."""
    x0, y0 = (int(max(np.floor(v) - SUBJECT_MARGIN, 0)) for v in lo)
    return x0, y0, int(min(np.ceil(hi[0]) + SUBJECT_MARGIN, width)), int(min(np.ceil(hi[1]) + SUBJECT_MARGIN, height))


def view_box(img: np.ndarray) -> tuple[int, int, int, int] | None:
    """One view's own subject box ``(x0, y0, x1, y1)`` (as :func:`subject_box` for that view
    alone, never None for a size reason), None when nothing is bright. img: ``(H, W[, C])``."""
    extent = _bright_extent(img)
    return None if extent is None else _grown(*extent, img.shape[1], img.shape[0])


def subject_box(images: Sequence[Path], centred: bool = False) -> tuple[int, int, int, int] | None:
    """The box ``(x0, y0, x1, y1)`` (input pixels, x1/y1 exclusive) holding every view's subject:
    the union over views of the blocks brighter than :data:`SUBJECT_LEVEL` (mean over
    :data:`SUBJECT_CELL`-pixel blocks, brightest channel), grown by :data:`SUBJECT_MARGIN` and
    clipped to the frame. ``centred``: the box made symmetric about the frame's centre (the larger
    margin kept on both sides). None when the box covers more than :data:`CROP_MAX_AREA` of the
    frame or nothing is bright (then the whole frame is used). Reads only the images."""
    lo = np.array([np.inf, np.inf])
    hi = np.array([-np.inf, -np.inf])
    width = height = 0
    for path in images:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ReconstructionError(f"{path}: unreadable image")
        height, width = img.shape[:2]
        extent = _bright_extent(img)
        if extent is not None:
            lo, hi = np.minimum(lo, extent[0]), np.maximum(hi, extent[1])
    if not np.all(np.isfinite(lo)):
        return None
    x0, y0, x1, y1 = _grown(lo, hi, width, height)
    if centred:
        mx, my = min(x0, width - x1), min(y0, height - y1)
        x0, x1, y0, y1 = mx, width - mx, my, height - my
    if (x1 - x0) * (y1 - y0) > CROP_MAX_AREA * width * height:
        return None
    return x0, y0, x1, y1


#: the working copies' PNG options: zlib level 1 without PNG's row filters (lossless all the same).
#: Measured on 40 views of the 1000-view layout at 960x720 (one-off, quiet): 9.1 ms a write and
#: 4.9 ms a read, 143 KB, against 25.3 / 7.1 ms and 126 KB with the default filters; at 1000
#: views the preparation took 26 s wall (51 CPU s) on 2 threads with them
PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1] + ([cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
                                               if hasattr(cv2, "IMWRITE_PNG_FILTER") else [])


def _prepare_images(images: Mapping[str, Path], scale: float, folder: Path,
                    box: tuple[int, int, int, int] | None = None, threads: int = 1) -> list[str]:
    """Copy (scale 1, no box) or crop to ``box`` (x0, y0, x1, y1) and resize (INTER_AREA down,
    INTER_CUBIC up) every image into ``folder``; PNGs written fast (:data:`PNG_FAST`).
    ``threads`` images at a time (OpenCV's read, resize and write release the GIL: at 1000 views
    and scale 0.75 this ran serially, 160 s of extraction's wall against 261 CPU s on 2 cores)."""
    folder.mkdir(parents=True, exist_ok=True)

    def one(item: tuple[str, Path]) -> str:
        stem, path = item
        name = f"{stem}{Path(path).suffix.lower() or '.png'}"
        if scale == 1.0 and box is None:
            shutil.copyfile(path, folder / name)
            return name
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ReconstructionError(f"{path}: unreadable image")
        if box is not None:
            x0, y0, x1, y1 = box
            img = img[y0:y1, x0:x1]
        h, w = img.shape[:2]
        if scale != 1.0:
            size = (int(round(w * scale)), int(round(h * scale)))  # as Intrinsics.scaled
            interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
            img = cv2.resize(img, size, interpolation=interp)
        cv2.imwrite(str(folder / name), img, PNG_FAST)
        return name

    with ThreadPoolExecutor(max(int(threads), 1)) as pool:
        return list(pool.map(one, images.items()))


def _image_size(path: Path) -> tuple[int, int]:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ReconstructionError(f"{path}: unreadable image")
    return img.shape[1], img.shape[0]


def _camera_from_colmap(cam, scale_back: float | tuple[float, float], width: int, height: int,
                        offset: tuple[float, float] = (0.0, 0.0)) -> Intrinsics:
    """A pycolmap PINHOLE / SIMPLE_RADIAL / RADIAL / OPENCV / FULL_OPENCV camera -> our Intrinsics
    at the input resolution: working pixels times ``scale_back`` (one factor, or x and y), plus
    ``offset`` (the crop's top-left corner in input pixels). FULL_OPENCV's rational denominator (k4..k6) has no place in our
    five-term Brown lens: it is refitted by :func:`_brown_from_rational` (its deviation is
    reported by :func:`rational_refit_px`)."""
    p = np.asarray(cam.params, dtype=np.float64)
    if cam.model_name == "SIMPLE_RADIAL":
        f, cx, cy, k1 = p
        fx = fy = f
        dist = (k1, 0.0, 0.0, 0.0, 0.0)
    elif cam.model_name == "RADIAL":
        f, cx, cy, k1, k2 = p
        fx = fy = f
        dist = (k1, k2, 0.0, 0.0, 0.0)
    elif cam.model_name == "PINHOLE":
        fx, fy, cx, cy = p
        dist = (0.0,) * 5
    elif cam.model_name == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
        dist = (k1, k2, p1, p2, 0.0)
    elif cam.model_name == "FULL_OPENCV":
        fx, fy, cx, cy = p[:4]
        dist = _brown_from_rational(p, cam.width, cam.height)[0]
    else:  # pragma: no cover - we only create these models
        raise ReconstructionError(f"unexpected COLMAP camera model {cam.model_name}")
    bx, by = (scale_back, scale_back) if np.isscalar(scale_back) else scale_back
    return Intrinsics(width, height, fx * bx, fy * by, cx * bx + offset[0], cy * by + offset[1], dist)


def _brown_from_rational(p: np.ndarray, width: float, height: float) -> tuple[tuple, float]:
    """FULL_OPENCV params ``fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6`` -> the five-term Brown lens
    ``(k1, k2, p1, p2, k3)`` nearest it over the image (linear least squares on a 33 x 25 grid of
    normalized points spanning the image), and the largest distance between the two projections
    there in pixels. Exact (0 px) when k4 = k5 = k6 = 0."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6 = (float(v) for v in p)
    if k4 == k5 == k6 == 0.0:
        return (k1, k2, p1, p2, k3), 0.0
    u, v = np.meshgrid(np.linspace(0, width, 33), np.linspace(0, height, 25))
    x, y = ((u - cx) / fx).ravel(), ((v - cy) / fy).ravel()  # undistorted directions near the image
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3) / (1 + k4 * r2 + k5 * r2 ** 2 + k6 * r2 ** 3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    # Brown: xd - x = x (k1 r2 + k2 r4 + k3 r6) + 2 p1 x y + p2 (r2 + 2 x^2), likewise y: linear in the terms
    A = np.concatenate([np.stack([x * r2, x * r2 ** 2, 2 * x * y, r2 + 2 * x * x, x * r2 ** 3], 1),
                        np.stack([y * r2, y * r2 ** 2, r2 + 2 * y * y, 2 * x * y, y * r2 ** 3], 1)]) * [fx, fx, fx, fx, fx]
    A[len(x):] *= fy / fx
    b = np.concatenate([(xd - x) * fx, (yd - y) * fy])
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    dev = np.abs(A @ sol - b).reshape(2, -1)
    return (float(sol[0]), float(sol[1]), float(sol[2]), float(sol[3]), float(sol[4])), float(np.hypot(*dev).max())


def rational_refit_px(cam) -> float:
    """How far (px, largest over the image) the Brown lens written for a FULL_OPENCV camera
    projects from the camera itself (0 for every other model)."""
    if cam.model_name != "FULL_OPENCV":
        return 0.0
    return _brown_from_rational(np.asarray(cam.params, dtype=np.float64), cam.width, cam.height)[1]


def _observed_radius(rec, scale_back: tuple[float, float] = (1.0, 1.0), offset: tuple[float, float] = (0.0, 0.0),
                     size: tuple[int, int] | None = None) -> float:
    """99th percentile of the triangulated keypoints' distance from the input image's centre, over
    its half-diagonal (1 at the corners); working pixels map to input ones as in
    :func:`_camera_from_colmap`, ``size`` is the input (width, height) (default: the camera's)."""
    cam = next(iter(rec.cameras.values()))
    xy = _observations(rec)[2] * scale_back + offset
    if not len(xy):
        return 0.0
    width, height = size or (cam.width, cam.height)
    r = np.linalg.norm(xy - [width / 2, height / 2], axis=1) / (0.5 * np.hypot(width, height))
    return float(np.percentile(r, 99))


def _diagnose(db: Path) -> str:
    """Why the mapper found nothing, from the feature database: too few features, or matched
    pairs that show no camera motion (COLMAP's WATERMARK / PANORAMIC / PLANAR_OR_PANORAMIC
    two-view geometries: content that stays put in the image, e.g. a static background)."""
    import pycolmap

    database = pycolmap.Database.open(str(db))
    try:
        n_img = max(database.num_images(), 1)
        per_image = database.num_keypoints() / n_img
        _, geoms = database.read_two_view_geometries()
    finally:
        database.close()
    cfg = pycolmap.TwoViewGeometryConfiguration
    static = {int(cfg.WATERMARK), int(cfg.PANORAMIC), int(cfg.PLANAR_OR_PANORAMIC)}
    moving = {int(cfg.CALIBRATED), int(cfg.UNCALIBRATED), int(cfg.PLANAR)}
    n_static = sum(int(g.config) in static for g in geoms)
    n_moving = sum(int(g.config) in moving for g in geoms)
    if per_image < 100 or n_static + n_moving == 0:
        return f"{per_image:.0f} features per image, {n_moving} verified pairs (textureless subject?)"
    if n_static > n_moving:
        return (f"{n_static} of {n_static + n_moving} matched pairs show no camera motion "
                "(static content in view: a background that does not turn with the object?)")
    return f"{n_moving} verified pairs but no initial pair could be triangulated"


def estimate_colmap(images: Mapping[str, Path], intrinsics: Intrinsics | None, workdir: Path,
                    config: ColmapConfig = ColmapConfig(), order: Sequence[ViewOrder] | None = None,
                    boards: Mapping[str, Mapping] | None = None) -> ColmapResult:
    """Run feature extraction, matching and mapping on ``images``.

    images: view name (file stem) -> image file (8-bit PNG/JPEG), all one size.
    intrinsics: the true calibration at the images' resolution; required when
        ``config.known_intrinsics``, else ignored. workdir: an empty scratch folder (database,
        resized images, raw models). order: the views' shooting order (the capture's
        ``capture_order.json``), needed by the capture_order matcher; views it lacks are refused.
        boards: the calibration boards' definitions (board name -> ``targets.json``'s ``board``
        dict, :func:`recon.poses.board_tracks.board_definitions`) for ``config.board_corners``.
        Returns a :class:`ColmapResult` for the largest model.
    Raises :class:`ReconstructionError` when COLMAP builds no model (e.g. a textureless
    object: no features survive matching, the mapper returns nothing).
    """
    import pycolmap

    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = max(level, 2)  # COLMAP's INFO/WARNING chatter off; errors stay
    try:
        return _estimate(images, intrinsics, workdir, config, order, boards)
    finally:
        pycolmap.logging.minloglevel = level


def resolve_matcher(config: ColmapConfig, n_images: int, have_order: bool) -> str:
    """The matcher ``auto`` stands for (ColmapConfig.matcher)."""
    if config.matcher != "auto":
        return config.matcher
    if n_images <= config.exhaustive_max_images:
        return "exhaustive"
    return "capture_order" if have_order else "sequential"


def resolve_mapper(config: ColmapConfig, n_images: int) -> str:
    """The mapper ``auto`` stands for (ColmapConfig.mapper)."""
    if config.mapper != "auto":
        return config.mapper
    return "global" if n_images >= config.global_min_images else "incremental"


#: the image scale ``image_scale`` None stands for from ``large_min_images`` views on
LARGE_IMAGE_SCALE = 0.75


def resolve_image_scale(config: ColmapConfig, n_images: int) -> float:
    """The image scale ``None`` stands for (ColmapConfig.image_scale): 1 below
    ``config.large_min_images`` views, :data:`LARGE_IMAGE_SCALE` from there on. Measured with the
    board corners (``bench_poses --views N --configs auto,auto+scale0.75``, one config a process):
    224 views 0.0166 deg mean at scale 1 against 0.0219 at 0.75 (245 -> 185 CPU s), where the
    stage takes ~4.5 minutes either way, so full scale stays; 1000 views (quiet, session 34)
    0.0249 deg in 711.6 s wall at scale 1 against 0.0286 deg in 615.9 s at 0.75 (CPU 1139 ->
    945 s): at full scale the 10-minute goal is out of reach on 2 cores (the CPU seconds alone,
    perfectly shared, take 570 s), at 0.75 it is within reach and the rotation error stays under
    0.03. The switch at 500 views is a choice between the two measured counts (near their
    geometric mean, 473); no count between them was measured."""
    if config.image_scale is not None:
        return config.image_scale
    return LARGE_IMAGE_SCALE if n_images >= config.large_min_images else 1.0


def resolve_first_octave(config: ColmapConfig, n_images: int) -> int:
    """SIFT's first octave ``None`` stands for (ColmapConfig.first_octave): -1 (the image doubled
    first, COLMAP's default) at every view count. Measured (bench_poses --views 224, 1280x960,
    capture_order + global, two runs side by side on the shared machine): octave 0 extracts 2.7x
    faster (463 s against 1253 s; 1,100 features per image) but doubles the rotation error, 0.049
    deg mean at 224 views (octave -1: 0.024) and 0.042 at 56 (0.020), above the 0.03 goal."""
    if config.first_octave is not None:
        return config.first_octave
    return -1


def resolve_extractor(config: ColmapConfig, n_images: int) -> str:
    """The SIFT ``auto`` stands for (ColmapConfig.extractor): COLMAP's below ``global_min_images``
    images (the 56-view figures were measured with it), OpenCV's from there on. Measured at 224
    views (rings of 96 + 96, 32 held out, 1280x960; doubling capture-order pairs, 1,376; global
    mapper, 10 final iterations; /tmp probe at load 7-11, so CPU seconds): OpenCV's SIFT on each
    view's own box, 1,829 features a view (COLMAP's: ~2,400), 0.27 CPU s a view read and extracted
    on a 28-view sample (COLMAP's ~1.1: 0.55 s wall a view on 2 quiet cores), 224/224 at 0.0189
    deg mean (0.061 max; COLMAP's SIFT 0.0211, 0.048), the map 108 CPU s."""
    if config.extractor != "auto":
        return config.extractor
    return "opencv" if n_images >= config.global_min_images else "colmap"


def resolve_final_ba_iterations(config: ColmapConfig, mapper: str) -> int:
    """The final bundle adjustment's iterations ``None`` stands for: 100 after the incremental
    mapper (as before), 10 after the global mapper, whose own retriangulation is skipped by default.
    Measured at 224 views (rings of 96 + 96, 32 held out, 1280x960; the subject's box, doubling
    capture-order pairs, 1,376 pairs; one database, mapper variants in one run at load 7-9,
    /tmp probe): the global mapper without retriangulation 285 s, 0.0261 deg mean (0.062 max),
    then 10 tight iterations 26 s, 0.0211 deg (0.048 max); with tracks capped at 300 per view 60 s
    but 0.037 deg (0.031 after the 10 iterations). The earlier default (retriangulation and 100
    iterations) mapped the same layout in 880 s at 0.024 deg (final bundle adjustment 329 s;
    full frame, 3,168 pairs, an earlier run at load 7-11)."""
    if config.final_ba_iterations is not None:
        return config.final_ba_iterations
    return 10 if mapper == "global" else 100


def resolve_board_corners(config: ColmapConfig, have_boards: bool, mapper: str) -> bool:
    """Whether the board's corners become tracks (ColmapConfig.board_corners): never without a
    board definition; ``None`` (auto): with known intrinsics and a final bundle adjustment."""
    if not have_boards or config.board_corners is False:
        return False
    if config.board_corners:
        return True
    return config.known_intrinsics and resolve_final_ba_iterations(config, mapper) > 0


def _map(config: ColmapConfig, mapper: str, db: Path, image_dir: Path, workdir: Path, n_images: int):
    """COLMAP's mapper on the matched database: {model index: pycolmap.Reconstruction}."""
    import pycolmap

    fixed = config.known_intrinsics
    if mapper == "global":
        with _info_lines_dropped(workdir / "mapper.log"):
            return pycolmap.global_mapping(db, image_dir, workdir / "sparse", options=_global_options(config, n_images))
    opts = pycolmap.IncrementalPipelineOptions()
    opts.random_seed = config.seed
    opts.mapper.random_seed = config.seed
    opts.triangulation.random_seed = config.seed
    opts.num_threads = 1  # scheduling-independent (see ColmapConfig)
    opts.mapper.num_threads = 1
    opts.min_model_size = min(10, n_images)
    opts.ba_refine_focal_length = not fixed
    opts.ba_refine_extra_params = not fixed
    opts.ba_refine_principal_point = False  # freed after mapping (calibrate_lens)
    opts.mapper.abs_pose_refine_focal_length = not fixed
    opts.mapper.abs_pose_refine_extra_params = not fixed
    return pycolmap.incremental_mapping(db, image_dir, workdir / "sparse", options=opts)


def _estimate(images: Mapping[str, Path], intrinsics: Intrinsics | None, workdir: Path,
              config: ColmapConfig, order: Sequence[ViewOrder] | None,
              boards: Mapping[str, Mapping] | None = None) -> ColmapResult:
    import pycolmap

    if len(images) < 2:
        raise ReconstructionError(f"structure from motion needs at least 2 images, got {len(images)}")
    if len({hashlib.sha256(Path(p).read_bytes()).digest() for p in images.values()}) == 1:
        raise ReconstructionError(f"all {len(images)} images are identical: no camera motion to reconstruct from")
    if config.known_intrinsics and intrinsics is None:
        raise ValueError("known_intrinsics needs the intrinsics")
    matcher = resolve_matcher(config, len(images), order is not None)
    mapper = resolve_mapper(config, len(images))
    if matcher == "capture_order":
        if order is None:
            raise ValueError("the capture_order matcher needs the capture order")
        known = {v.name for v in order}
        missing = [n for n in images if n not in known]
        if missing:
            raise ValueError(f"capture order lacks {len(missing)} view(s), e.g. {missing[0]!r}")
    workdir = Path(workdir)
    image_dir, db = workdir / "images", workdir / "database.db"
    times: dict[str, float] = {}
    # CPU seconds beside wall seconds: on a shared machine the wall time follows the load, the
    # CPU time (every thread of this process) much less
    t0, c0 = time.perf_counter(), time.process_time()
    first = next(iter(images.values()))
    width, height = _image_size(Path(first))
    crop = config.known_intrinsics if config.crop_to_subject is None else config.crop_to_subject
    extractor = resolve_extractor(config, len(images))
    image_scale = resolve_image_scale(config, len(images))
    threads = (os.cpu_count() or 1) if config.num_threads < 1 else config.num_threads
    # OpenCV's extraction crops each view to its own box as it reads it (one read, no re-encoded
    # copy); COLMAP's reads files, so those are cropped to the views' common box first
    box = subject_box(list(images.values()), centred=not config.known_intrinsics) if crop and extractor == "colmap" else None
    x0, y0, x1, y1 = box or (0, 0, width, height)
    names = _prepare_images(images, image_scale, image_dir, box, threads)
    sw, sh = _image_size(image_dir / names[0])
    scale_back = ((x1 - x0) / sw, (y1 - y0) / sh)  # working pixel -> input pixel, after the crop's offset
    offset = (float(x0), float(y0))

    reader = pycolmap.ImageReaderOptions()
    if config.known_intrinsics:
        sx, sy = 1 / scale_back[0], 1 / scale_back[1]
        working = replace(intrinsics, width=sw, height=sh, fx=intrinsics.fx * sx, fy=intrinsics.fy * sy,
                          cx=(intrinsics.cx - x0) * sx, cy=(intrinsics.cy - y0) * sy)
        reader.camera_model, params = colmap_camera(working)
        reader.camera_params = ",".join(repr(float(v)) for v in params)
    else:
        reader.camera_model = "SIMPLE_RADIAL"
    pycolmap.set_random_seed(config.seed)
    # image ids in name order, whatever order the extraction threads finish in (see ColmapConfig)
    pycolmap.Database.open(db).close()  # import_images needs the database file to exist
    pycolmap.import_images(db, image_dir, camera_mode=pycolmap.CameraMode.SINGLE, image_names=names, options=reader)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = config.num_threads
    extraction.sift.max_num_features = config.max_features
    extraction.sift.first_octave = resolve_first_octave(config, len(names))
    extraction.use_gpu = False
    if extractor == "opencv":
        extract_opencv_sift(db, image_dir, names, config.max_features, threads, view_box if crop else None)
    else:
        pycolmap.extract_features(db, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)

    times["extract"] = time.perf_counter() - t0
    times["extract_cpu"] = time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.num_threads
    matching.use_gpu = False
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = config.seed
    if matcher == "capture_order":
        suffix = {Path(n).stem: Path(n).suffix for n in names}
        wanted = [v for v in order if v.name in suffix]
        offsets = doubling_offsets(config.sequential_overlap) if config.pair_offsets == "doubling" else None
        pairs = capture_order_pairs(wanted, config.sequential_overlap, config.link_window, offsets)
        pair_file = workdir / "pairs.txt"
        with open(pair_file, "w") as f:
            f.writelines(f"{a}{suffix[a]} {b}{suffix[b]}\n" for a, b in pairs)
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = str(pair_file)
        pycolmap.match_image_pairs(db, matching_options=matching, pairing_options=pairing,
                                   verification_options=verification, device=pycolmap.Device.cpu)
    elif matcher == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = config.sequential_overlap
        pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_exhaustive(db, matching_options=matching, verification_options=verification,
                                  device=pycolmap.Device.cpu)
    if matcher == "capture_order":
        n_pairs = len(pairs)
    elif matcher == "exhaustive":
        n_pairs = len(names) * (len(names) - 1) // 2
    else:
        database = pycolmap.Database.open(str(db))
        try:
            n_pairs = int(database.num_matched_image_pairs())
        finally:
            database.close()
    times["match"] = time.perf_counter() - t0
    times["match_cpu"] = time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()

    fixed = config.known_intrinsics
    (workdir / "sparse").mkdir(exist_ok=True)
    # the board's corners are detected beside the mapper, on threads at the lowest priority (the
    # mapper leaves part of the 2 cores idle); they are needed only after it
    corner_job = None
    if resolve_board_corners(config, bool(boards), mapper):
        from .board_tracks import CornerJob

        corner_job = CornerJob(images, boards, threads)
    try:
        models = _map(config, mapper, db, image_dir, workdir, len(names))
    except BaseException:
        if corner_job is not None:
            corner_job.cancel()
        raise
    models = {i: m for i, m in (models or {}).items() if m.num_reg_images() > 0}
    if not models:
        if corner_job is not None:
            corner_job.cancel()
        raise ReconstructionError(f"COLMAP built no model from {len(names)} images: {_diagnose(db)}")
    rec = max(models.values(), key=lambda m: m.num_reg_images())

    corner_stats: dict = {"board_corners": False}
    corner_s = corner_cpu = 0.0
    if corner_job is not None:
        from .board_tracks import add_corner_tracks

        # corners: the wall the stage waited for the detection plus the tracks' building;
        # corners_cpu: the detection's thread CPU (also inside map_cpu's process total) plus the tracks'
        tc = time.perf_counter()
        found = corner_job.result()
        waited = time.perf_counter() - tc
        sb, off = np.asarray(scale_back, dtype=np.float64), np.asarray(offset, dtype=np.float64)
        tt, ct = time.perf_counter(), time.process_time()
        rec, added, _ = add_corner_tracks(rec, found.views, lambda xy: (xy - off) / sb)
        track_s = time.perf_counter() - tt
        corner_s = time.perf_counter() - tc
        corner_cpu = found.cpu_s + (time.process_time() - ct)
        corner_stats = {"board_corners": True, **added, "corner_detect_views": len(found.views),
                        "corner_detect_s_per_view": round(float(np.median(found.seconds)), 4)}
        times["corners"], times["corners_cpu"] = corner_s, corner_cpu
        times["corners_detect"], times["corners_wait"], times["corners_tracks"] = found.wall_s, waited, track_s
    lens_steps, lens_note = [], ""
    t_refine = time.perf_counter()
    if not fixed:
        rec, lens_steps, lens_note = calibrate_lens(rec, workdir, config.camera_model,
                                                    100 if config.final_ba_iterations is None else max(config.final_ba_iterations, 1))
    elif resolve_final_ba_iterations(config, mapper) > 0:
        # one thread: on 2 (session 35, 1000 views at scale 0.75, quiet) the 10 iterations took
        # 61.8 s wall against 49.3 s on one (session 34, same config): SuiteSparse's factorisation is
        # serial, and the second thread only contends
        _bundle_adjust(rec, workdir, resolve_final_ba_iterations(config, mapper), False, False, False)

    times["map"] = time.perf_counter() - t0 - corner_s
    times["map_cpu"] = time.process_time() - c0 - corner_cpu
    times["refine"] = time.perf_counter() - t_refine  # of map: the final bundle adjustment / lens ladder
    cameras, registered = [], set()
    for img in rec.images.values():
        if not img.has_pose:
            continue
        stem = Path(img.name).stem
        w2c = np.eye(4)
        w2c[:3, :] = np.asarray(img.cam_from_world().matrix(), dtype=np.float64)
        c2w = np.eye(4)
        c2w[:3, :3] = w2c[:3, :3].T
        c2w[:3, 3] = -w2c[:3, :3].T @ w2c[:3, 3]
        cameras.append(Camera(_camera_from_colmap(img.camera, scale_back, width, height, offset), c2w, stem))
        registered.add(stem)
    order = {n: i for i, n in enumerate(images)}
    cameras.sort(key=lambda c: order[c.name])
    points = np.array([p.xyz for p in rec.points3D.values()], dtype=np.float64).reshape(-1, 3)
    err = float(rec.compute_mean_reprojection_error()) * float(np.mean(scale_back)) if len(points) else 0.0
    return ColmapResult(cameras=cameras, unregistered=[n for n in images if n not in registered],
                        reprojection_error_px=err if np.isfinite(err) else 0.0, points=points,
                        num_models=len(models), mean_track_length=float(rec.compute_mean_track_length())
                        if len(points) else 0.0, reconstruction=rec, matcher=matcher, mapper=mapper,
                        pairs=n_pairs, times_s={k: round(v, 3) for k, v in times.items()},
                        camera_model=next(iter(rec.cameras.values())).model_name, lens_steps=lens_steps,
                        lens_note=lens_note, rational_refit_px=rational_refit_px(next(iter(rec.cameras.values())))
                        * float(np.mean(scale_back)),
                        observed_radius_rel=_observed_radius(rec, scale_back, offset, (width, height)),
                        crop_box=box, extractor=extractor, corner_stats=corner_stats, image_scale=image_scale)


@contextmanager
def _info_lines_dropped(log: Path):
    """Run the block with file descriptor 2 sent to ``log``, then pass on all but glog's INFO
    lines. pycolmap.bundle_adjustment logs its heading and timer at INFO whatever
    ``pycolmap.logging.minloglevel`` says, and a CLI's bad-input exit must print one line."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(log, "wb") as f:
            os.dup2(f.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)
    for line in log.read_text(errors="replace").splitlines():
        if line and not line.startswith("I"):
            print(line, file=sys.stderr)


def _global_options(config: ColmapConfig, n_images: int):
    """COLMAP's global mapper (GLOMAP) seeded, on ``config.global_threads`` threads (2 differs
    from 1 by rounding only, ColmapConfig), intrinsics refined only when self-calibrating."""
    import pycolmap

    opts = pycolmap.GlobalPipelineOptions()
    opts.random_seed = config.seed
    opts.num_threads = config.global_threads
    opts.min_model_size = min(10, n_images)
    m = opts.mapper
    m.random_seed = config.seed
    m.num_threads = config.global_threads
    m.rotation_averaging.random_seed = config.seed
    m.global_positioning.random_seed = config.seed
    m.global_positioning.use_gpu = False
    if config.global_tracks_per_view > 0:
        m.track_required_tracks_per_view = config.global_tracks_per_view
    m.skip_retriangulation = not config.global_retriangulate
    m.ba_num_iterations = config.global_ba_rounds
    fixed = config.known_intrinsics
    ba = m.bundle_adjustment
    ba.refine_focal_length = not fixed
    ba.refine_extra_params = not fixed
    ba.refine_principal_point = False  # freed after mapping (calibrate_lens)
    ba.ceres.use_gpu = False
    ba.ceres.solver_options.num_threads = config.global_threads
    return opts


# --------------------------------------------------------------------------- self-calibration

#: the camera models self-calibration climbs through, simplest first (COLMAP's names and parameter
#: orders: SIMPLE_RADIAL f cx cy k1; RADIAL f cx cy k1 k2; OPENCV fx fy cx cy k1 k2 p1 p2;
#: FULL_OPENCV adds k3 k4 k5 k6, the rational model's numerator k3 and denominator k4..k6)
CAMERA_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
#: Why an OPENCV camera from the start failed (issue 21: "registered 2 of 56 views"), measured on
#: scenes/real_lens.yaml (56 views, 1280x960, the stage's matches; /tmp scripts, load ~17): the
#: incremental mapper with OPENCV from COLMAP's focal guess (1.2 x 1280 = 1536 px, 16% above the
#: true 1319) and all four distortion terms free from the first bundle adjustment built two models
#: it gave up on, of 2 and 10 images, before a third reached 56/56, in 1338 s against 251 s for
#: SIMPLE_RADIAL on the same matches; that OPENCV camera ended with k2 = -0.32 (true 0.03) and the
#: principal point still pinned. Focal, k1, k2 and the tangential terms trade against each other
#: while few views are registered, so early models drift and stall (the issue's 2 views match the
#: first abandoned model; that earlier run itself was not repeated). Hence the order here: map with SIMPLE_RADIAL (focal and k1), then free the
#: principal point, then one model at a time (calibrate_lens).
OPENCV_FROM_START = "map SIMPLE_RADIAL, then climb (calibrate_lens)"
#: the richest model ``auto`` tries: FULL_OPENCV's rational denominator k4..k6 trades against
#: k1..k3 wherever the features do not reach the image's rim (on a turntable they stay near the
#: centre), so its fits extrapolate wildly, and cameras.json's five-term Brown lens cannot hold
#: it (it is written as its nearest Brown lens, :func:`rational_refit_px`); it runs only when asked
AUTO_TOP_MODEL = "OPENCV"
#: parameters each model estimates (the principal point counted, as it is refined)
MODEL_PARAMS = {"SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12}


def _promote(camera, model: str) -> None:
    """Turn a pycolmap camera into the next richer ``model`` in place, the new terms at 0 (the
    projection is unchanged): SIMPLE_RADIAL -> RADIAL -> OPENCV -> FULL_OPENCV."""
    import pycolmap

    p = [float(v) for v in camera.params]
    current = camera.model_name
    if (current, model) == ("SIMPLE_RADIAL", "RADIAL"):
        new = p + [0.0]
    elif (current, model) == ("RADIAL", "OPENCV"):
        f, cx, cy, k1, k2 = p
        new = [f, f, cx, cy, k1, k2, 0.0, 0.0]
    elif (current, model) == ("OPENCV", "FULL_OPENCV"):
        new = p + [0.0] * 4
    else:
        raise ValueError(f"cannot promote a {current} camera to {model}")
    camera.model = getattr(pycolmap.CameraModelId, model)
    camera.params = new


def _observations(rec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every observation of a triangulated point: (M,) image ids, (M,) point ids, (M, 2) pixels,
    (M,) the keypoint's index in its image."""
    image_ids, point_ids, xy, index = [], [], [], []
    for image_id, img in rec.images.items():
        if not img.has_pose:
            continue
        for i, p in enumerate(img.points2D):
            if p.has_point3D():
                image_ids.append(image_id)
                point_ids.append(p.point3D_id)
                xy.append(p.xy)
                index.append(i)
    return (np.asarray(image_ids), np.asarray(point_ids), np.asarray(xy, dtype=np.float64).reshape(-1, 2),
            np.asarray(index))


def _residuals(rec, obs) -> np.ndarray:
    """(M, 2) reprojection residuals (pixels at the working scale) of the observations ``obs``
    (:func:`_observations`) in ``rec``; an observation whose point is gone or behind its camera
    gets a residual of 1e3 px, a deliberate large value (it no longer fits)."""
    image_ids, point_ids, xy = obs[:3]
    res = np.full(xy.shape, 1e3)
    for image_id in np.unique(image_ids):
        img = rec.images[int(image_id)]
        sel = np.nonzero(image_ids == image_id)[0]
        alive = [i for i in sel if rec.exists_point3D(int(point_ids[i]))]
        if not alive:
            continue
        X = np.array([rec.points3D[int(point_ids[i])].xyz for i in alive])
        pose = np.asarray(img.cam_from_world().matrix(), dtype=np.float64)
        Xc = X @ pose[:, :3].T + pose[:, 3]
        front = Xc[:, 2] > 1e-9
        uv = np.asarray(img.camera.img_from_cam(np.where(front[:, None], Xc, [0.0, 0.0, 1.0])), dtype=np.float64)
        ok = front & np.all(np.isfinite(uv), axis=1)
        rows = np.asarray(alive)[ok]
        res[rows] = uv[ok] - xy[rows]
    return res


def _bundle_adjust(rec, workdir: Path, iterations: int, refine_focal: bool, refine_principal_point: bool,
                   refine_extra: bool, threads: int = 1) -> None:
    """One global bundle adjustment of ``rec`` in place: Cauchy loss, tight tolerances, ``threads``
    threads (1: scheduling-independent); glog's INFO lines dropped."""
    import pycolmap

    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = refine_focal
    ba.refine_extra_params = refine_extra
    ba.refine_principal_point = refine_principal_point
    ba.print_summary = False
    ba.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    so = ba.ceres.solver_options
    so.max_num_iterations = iterations
    so.function_tolerance, so.gradient_tolerance, so.parameter_tolerance = 1e-12, 1e-12, 1e-12
    so.num_threads = threads
    with _info_lines_dropped(workdir / "ba.log"):
        pycolmap.bundle_adjustment(rec, ba)


#: a richer camera model is kept when it lowers the sum of squared residuals by more than the
#: chi-square quantile of its extra parameters at this significance (residual variance from the
#: richer model); see :func:`calibrate_lens`
MODEL_TEST_ALPHA = 1e-3
#: inlier residual bound (working-scale px) for the model test: robust BA leaves outliers that
#: would dominate a sum of squares
MODEL_TEST_INLIER_PX = 2.0
#: fraction of the observations, the farthest from the image centre, held out to test whether a
#: model's lens extrapolates beyond the features it was fitted to
HOLDOUT_FRACTION = 0.1


def _radius(obs, rec) -> np.ndarray:
    cam = next(iter(rec.cameras.values()))
    return np.linalg.norm(obs[2] - [cam.width / 2, cam.height / 2], axis=1)


def _fit_ladder(rec, workdir: Path, top: str, iterations: int) -> list[tuple[str, object]]:
    """[(model, reconstruction)] from SIMPLE_RADIAL with its principal point freed up to ``top``,
    each model bundle adjusted from the previous one's solution (``rec`` is not changed)."""
    import pycolmap

    cur = pycolmap.Reconstruction(rec)
    _bundle_adjust(cur, workdir, iterations, True, True, True)
    fits = [("SIMPLE_RADIAL", cur)]
    for name in CAMERA_MODELS[1:CAMERA_MODELS.index(top) + 1]:
        nxt = pycolmap.Reconstruction(fits[-1][1])
        _promote(next(iter(nxt.cameras.values())), name)
        _bundle_adjust(nxt, workdir, iterations, True, True, True)
        fits.append((name, nxt))
    return fits


def calibrate_lens(rec, workdir: Path, model: str, iterations: int = 100) -> tuple[object, list[dict], str]:
    """Self-calibrate the lens of a mapped reconstruction's one camera, COLMAP users' order:
    (the mapper refined the focal length and k1 of a SIMPLE_RADIAL camera), then the principal
    point is freed, then one model at a time is added (RADIAL's k2, OPENCV's fx != fy and
    tangential p1 p2, FULL_OPENCV's k3..k6), each started from the previous model's solution with
    its new terms at 0 and bundle adjusted with every intrinsic free.

    rec: pycolmap.Reconstruction with one SIMPLE_RADIAL camera (not changed). model: a name of
    :data:`CAMERA_MODELS`, or ``auto``: climb the ladder up to :data:`AUTO_TOP_MODEL` and keep a
    richer model only when both (a) it significantly lowers the squared residuals of the same
    observations (likelihood-ratio test: the drop over the richer model's residual variance
    exceeds the chi-square quantile at :data:`MODEL_TEST_ALPHA` of the added parameters; inliers
    within :data:`MODEL_TEST_INLIER_PX` of the simpler model) and (b) refitted without the
    outermost :data:`HOLDOUT_FRACTION` of the observations, it predicts those held-out ones better
    than the simpler model does: a term that only bends the lens where no feature was seen
    fails (b).
    Returns ``(reconstruction, steps, note)``: the chosen model's reconstruction, one dict per
    model tried (model, rms_px, holdout_rms_px, observations, chosen) and a one-line note naming
    the terms the views could not constrain (empty when every tried term was kept).
    """
    import pycolmap
    from scipy.stats import chi2

    if model != "auto" and model not in CAMERA_MODELS:
        raise ValueError(f"camera_model must be auto or one of {', '.join(CAMERA_MODELS)}, got {model!r}")
    if len(rec.cameras) != 1 or next(iter(rec.cameras.values())).model_name != "SIMPLE_RADIAL":
        raise ValueError("calibrate_lens needs one SIMPLE_RADIAL camera")
    top = AUTO_TOP_MODEL if model == "auto" else model
    fits = _fit_ladder(rec, workdir, top, iterations)
    obs = _observations(fits[0][1])
    residuals = [_residuals(r, obs) for _, r in fits]
    inlier = np.linalg.norm(residuals[0], axis=1) <= MODEL_TEST_INLIER_PX
    sse = [float(np.sum(r[inlier] ** 2)) for r in residuals]
    n = 2 * int(inlier.sum())
    holdout_sse = [np.nan] * len(fits)
    if model == "auto" and len(fits) > 1:
        # the same rim observations deleted from the mapped model, the ladder refitted, the rim predicted
        radius = _radius(obs, rec)
        rim = radius > np.quantile(radius, 1 - HOLDOUT_FRACTION)
        inner = pycolmap.Reconstruction(rec)
        for image_id, index in zip(obs[0][rim], obs[3][rim]):
            if inner.images[int(image_id)].points2D[int(index)].has_point3D():
                inner.delete_observation(int(image_id), int(index))
        held = tuple(o[rim] for o in obs)
        held_res = [_residuals(r, held) for _, r in _fit_ladder(inner, workdir, top, iterations)]
        ok = np.all([np.linalg.norm(r, axis=1) < 1e3 for r in held_res], axis=0)
        ok &= np.linalg.norm(held_res[0], axis=1) <= 4 * MODEL_TEST_INLIER_PX  # rim outliers of the simplest
        holdout_sse = [float(np.sum(r[ok] ** 2)) for r in held_res]
        n_held = int(ok.sum())
    chosen = len(fits) - 1
    if model == "auto":
        chosen = 0
        for i in range(1, len(fits)):
            extra = MODEL_PARAMS[fits[i][0]] - MODEL_PARAMS[fits[chosen][0]]
            variance = sse[i] / max(n - MODEL_PARAMS[fits[i][0]], 1)
            significant = (sse[chosen] - sse[i]) / variance > chi2.ppf(1 - MODEL_TEST_ALPHA, extra)
            if significant and holdout_sse[i] < holdout_sse[chosen]:
                chosen = i
    steps = [{"model": name, "rms_px": float(np.sqrt(sse[i] / max(n, 1))), "observations": n // 2,
              "holdout_rms_px": (float(np.sqrt(holdout_sse[i] / max(n_held, 1))) if np.isfinite(holdout_sse[i])
                                 else None), "chosen": i == chosen} for i, (name, _) in enumerate(fits)]
    note = ""
    if model == "auto" and chosen < len(fits) - 1:
        rejected = [name for name, _ in fits[chosen + 1:]]
        note = (f"the views cannot constrain {', '.join(rejected)} beyond {fits[chosen][0]} (not significant at "
                f"alpha {MODEL_TEST_ALPHA:g}, or no better on the outermost {HOLDOUT_FRACTION:.0%} of the features "
                f"when fitted without them): kept {fits[chosen][0]}")
    elif model != "auto" and len(fits) > 1:
        extra = MODEL_PARAMS[fits[-1][0]] - MODEL_PARAMS[fits[-2][0]]
        variance = sse[-1] / max(n - MODEL_PARAMS[fits[-1][0]], 1)
        if not (sse[-2] - sse[-1]) / variance > chi2.ppf(1 - MODEL_TEST_ALPHA, extra):
            note = (f"the views cannot constrain {model}'s terms beyond {fits[-2][0]} (no significant drop in "
                    f"squared residuals, alpha {MODEL_TEST_ALPHA:g}): {model} kept as asked, its extra terms are noise")
    return fits[chosen][1], steps, note
