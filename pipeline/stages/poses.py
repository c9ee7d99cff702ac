"""The ``poses`` stage: cameras estimated from a capture's images, scored against its ground truth.

Layout (DESIGN.md)::

    poses/<method>/cameras.json            estimated cameras (registered views), capture's splits
    poses/<method>/transforms.json         nerfstudio format, every split; file paths point into the capture
    poses/<method>/transforms_{train,test}.json   Blender split files (when the intrinsics fit that convention)
    poses/<method>/colmap/                 COLMAP text model of the same cameras
    poses/<method>/sparse/                 (colmap only) COLMAP's binary model with 3D points
    poses/<method>/metrics.json            scores (see below)   poses/<method>/manifest.json

Methods: ``gt`` (the capture's ground truth, the baseline), ``colmap`` (structure from motion,
:mod:`recon.poses.colmap`, aligned to the ground-truth frame by a similarity on the camera
centres), ``charuco`` (board poses, :mod:`recon.poses.charuco`; metric already, written as
estimated and scored both without and with the alignment, the latter as ``aligned_*``).
Every written camera is in the ground-truth world frame, so later stages use it as is.

``metrics.json`` (flat, for ``dvc metrics``): status ok|failed (+ reason), method,
views_total / views_registered / registered_fraction / unregistered (names),
rotation_error_deg_{mean,median,max}, center_error_rel_{mean,max} (divided by scene_scale, the
median distance of the true camera centres from their centroid), alignment_scale, worst_view,
sequence_rotation_bias (with a capture order: per sequence the mean error rotation in the camera's
axes, :func:`recon.poses.align.sequence_rotation_bias`) and sequence_pitch_spread_deg (the largest
minus the smallest of those pitches over sequences of more than one view),
reprojection_error_px, focal_rel / principal_point_px / distortion_abs_max (intrinsics error),
self_check_folded / self_check_reason / max_azimuth_gap_deg / duplicate_pairs (no ground truth
used), projection_error_px_{max,view_max_mean,mean} and lens_projection_error_px_{max,mean} (the
whole camera and the lens alone against the truth, :func:`recon.poses.projection_error`),
estimate_time_s, wall_time_s; colmap adds points, models, mean_track_length, its
options, the matcher and mapper that ran, pairs matched and {extract,match,map,refine}_time_s
(refine: the part of map after the mapper) with {extract,match,map}_cpu_time_s (CPU seconds),
first_octave (SIFT's, as resolved; COLMAP's SIFT only), extractor (colmap / opencv), board_corners
(whether the board's corners were added as tracks, ColmapConfig.board_corners; then corner_tracks,
corner_observations, corner_views added, corner_detect_views, corner_detect_s_per_view and
corners_time_s / corners_cpu_time_s, outside map's: the detection runs beside the mapper, so
corners_time_s is what the stage waited after it, corners_wait_time_s, plus the tracks' building,
corners_tracks_time_s; corners_detect_time_s is the detection's own span), image_scale (as
resolved: ``auto`` is 0.75 from 500 views on), crop_box
(the input pixels SIFT saw, ``[x0, y0, x1, y1]``, or null for the whole frame), the
calibration (known / self / charuco), camera_model, camera_model_note (terms the views cannot
constrain), lens_steps (each model's residuals), observed_radius_rel (how far from the centre
the features reach; the ``*_covered`` projection maxima are within it), rational_refit_px and,
with ``--calibration charuco``, charuco_calibration_{source,views,rms_px,time_s} (source: the capture's
calibration sequence, ``calibration/``, when it has one, plus its views_total, corners,
detected_rms_px and radius_rel; else the views); charuco adds board_not_visible, corners_{min,mean} and aligned_* scores.

Failure (a method ran but its result is unusable: no model, too few views registered, no board
ever visible, a folded turntable circle, a pose error above the gate). Both promises hold:

* the stage folder is replaced, atomically, by one holding ONLY ``metrics.json`` with
  ``"status": "failed"``, the ``reason`` and every figure measured before the failure. It has
  no ``manifest.json`` and no cameras, so it never looks finished: ``read_manifest`` and every
  later stage reject it ("not a finished stage folder");
* :func:`run_poses` raises :class:`pipeline.artifacts.BadInput` whose one line names the
  reason and the metrics file, so the CLI exits 2.

Bad input (no capture folder, no finished capture's ``manifest.json``, no or a malformed
``cameras.json`` (NaN poses, view names that are not plain file stems), missing / unreadable /
mixed-size images, duplicate views (identical pixels), a view that sees only a uniform
background, a malformed ``capture_order.json``, no ``targets.json`` for ChArUco) raises BadInput
naming the views before anything is written: a failure folder records a method's finding on a
valid capture, never damaged input.

COLMAP pairs views by the capture's shooting order (``capture_order.json``: ring, frame index,
loop; :mod:`recon.poses.pairing`) above ``ColmapConfig.exhaustive_max_images`` views. Its work
folder (database, resized images: ~0.5 GB at 1000 views) lives inside the stage's atomic
partial folder, never in the system's temp folder. COLMAP runs in a child process
(:mod:`recon.poses.colmap_process`): a stopped run (Ctrl-C, or SIGTERM, which the stage turns
into the same KeyboardInterrupt; exit 130) kills it and removes the partial folder with the
work folder; only SIGKILL leaves the ``.<name>.partial-<pid>-*`` folder, which the next run of
the stage removes.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from recon.poses import (BoardNotFound, CharucoConfig, ColmapConfig, ReconstructionError, ViewOrder,
                         estimate_charuco, intrinsics_error, projection_error, score_cameras,
                         sequence_rotation_bias, turntable_self_check)
from recon.poses.board_tracks import board_definitions
from recon.poses.charuco import calibrate_sequence, make_board
from recon.poses.colmap import resolve_first_octave, resolve_image_scale
from recon.poses.colmap_process import estimate_colmap_stoppable
from render.camera import Camera
from render.camera_io import write_blender_transforms_json, write_cameras_json, write_colmap_text

from ..artifacts import BadInput, Manifest, atomic_stage, check_out, write_json
from ..export import relpath, write_nerfstudio_transforms
from ..progress import progress_bar
from .capture import check_capture_folder

__all__ = ["METHODS", "QualityGates", "PosesConfig", "Capture", "load_capture", "estimate_poses", "run_poses",
           "check_poses"]

METHODS = ("gt", "colmap", "charuco")


@dataclass(frozen=True)
class QualityGates:
    """When an estimate counts as failed.

    min_registered_fraction: registered views / all views below this fails.
    max_rotation_error_deg: ground-truth gate on the largest rotation error (a fold or a broken
        model shows as tens of degrees; an accurate one as hundredths).
    max_azimuth_gap_deg: self-check (no ground truth) on the largest empty sector of camera
        azimuths around the turntable axis; see :func:`recon.poses.turntable_self_check`.
    """

    min_registered_fraction: float = 0.9
    max_rotation_error_deg: float = 5.0
    max_azimuth_gap_deg: float = 90.0


#: where COLMAP's intrinsics come from: the capture's (``known``), COLMAP's self-calibration
#: (``self``: ColmapConfig.known_intrinsics False), ChArUco boards through cv2.calibrateCamera
#: (``charuco``, the lab's route: then held fixed), or ``auto`` (``--self-calibrate``'s default):
#: the capture's calibration sequence when it has one that fits its board within
#: :data:`SEQUENCE_TRUSTED_RMS_PX`, else COLMAP's self-calibration
CALIBRATIONS = ("known", "self", "charuco", "auto")

#: ``auto`` keeps a calibration sequence whose final RMS corner residual is at most this (px):
#: on scenes/real_lens.yaml at 1280x960 the sequence fits to 0.045 px and beats COLMAP's
#: self-calibration on every figure (focal 0.001% against 0.17%, principal point 0.20 against
#: 2.6 px); shrunk to 400x300 it fits to 0.18 px and the two are alike (focal 0.22% / 0.29%,
#: principal point 0.96 / 0.70 px); an earlier 21-view sequence there fitted to 0.32 px with
#: its focal 0.43% off
SEQUENCE_TRUSTED_RMS_PX = 0.2


@dataclass(frozen=True)
class PosesConfig:
    """calibration: one of :data:`CALIBRATIONS` (colmap only); ``self`` and ``auto`` must agree
    with ``colmap.known_intrinsics`` being False (``auto`` fixes the sequence's lens when it
    takes it)."""

    colmap: ColmapConfig = field(default_factory=ColmapConfig)
    charuco: CharucoConfig = field(default_factory=CharucoConfig)
    gates: QualityGates = field(default_factory=QualityGates)
    calibration: str = ""

    def __post_init__(self) -> None:
        if not self.calibration:
            object.__setattr__(self, "calibration", "known" if self.colmap.known_intrinsics else "self")
        if self.calibration not in CALIBRATIONS:
            raise ValueError(f"--calibration must be one of {', '.join(CALIBRATIONS)}, got {self.calibration!r}")
        if (self.calibration in ("self", "auto")) == self.colmap.known_intrinsics:
            raise ValueError("calibration 'self' or 'auto' and only they self-calibrate in COLMAP "
                             "(colmap.known_intrinsics False)")


def _sequence_calibration(cap: Capture, metrics: dict):
    """The capture's calibration sequence (``calibration/``, rig.calibration) through
    :func:`recon.poses.charuco.calibrate_sequence`: (intrinsics, figures), or None when the
    capture has no sequence."""
    folder = cap.folder / "calibration"
    if not (folder / "board.json").is_file():
        return None
    try:
        board = json.loads((folder / "board.json").read_text())["board"]
        make_board(board)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BadInput(f"{folder / 'board.json'}: missing or malformed board definition ({exc})") from None
    paths = sorted((folder / "images").glob("*.png"))
    imgs = {}
    for p in paths:
        img = cv2.imread(str(p))
        if img is None:
            raise BadInput(f"{p}: unreadable image")
        imgs[p.stem] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if len({i.shape for i in imgs.values()}) > 1:
        raise BadInput(f"{folder / 'images'}: mixed image sizes in the calibration sequence")
    t0 = time.perf_counter()
    try:
        res = calibrate_sequence(imgs, board)
    except BoardNotFound as exc:
        raise PoseFailure(f"ChArUco calibration: {exc}", metrics) from None
    return res.intrinsics, {"calibration_source": "sequence", "calibration_views": res.views,
                            "calibration_views_total": res.views_total, "calibration_corners": res.corners,
                            "calibration_rms_px": res.rms_px, "calibration_detected_rms_px": res.detected_rms_px,
                            "calibration_radius_rel": res.radius_rel_max,
                            "calibration_time_s": round(time.perf_counter() - t0, 3)}


def _charuco_calibration(cap: Capture, cfg: CharucoConfig, metrics: dict):
    """The lens from the ChArUco board: the capture's calibration sequence when it has one
    (:func:`_sequence_calibration`, the lab's way), else cv2.calibrateCamera over every view's
    ChArUco corners (:func:`recon.poses.calibrate_intrinsics`): the intrinsics (k1 k2 p1 p2,
    k3 fixed at 0) and a dict of the calibration's figures. A capture without boards in at
    least 3 views is a PoseFailure (the calibration the user asked for cannot be made)."""
    sequence = _sequence_calibration(cap, metrics)
    if sequence is not None:
        return sequence
    if not cap.targets:
        raise BadInput(f"{cap.folder / 'targets.json'}: no calibration target in the capture (needed by --calibration charuco)")
    imgs = {n: cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for n, p in cap.images.items()}
    t0 = time.perf_counter()
    try:
        res = estimate_charuco(imgs, cap.targets, None, replace(cfg, calibrate=True, distortion=True))
    except BoardNotFound as exc:
        raise PoseFailure(f"ChArUco calibration: {exc}", metrics) from None
    except ValueError as exc:  # malformed board definition
        raise BadInput(f"{cap.folder / 'targets.json'}: {exc}") from None
    return res.intrinsics, {"calibration_source": "views", "calibration_views": len(res.cameras),
                            "calibration_rms_px": res.calibration_rms_px,
                            "calibration_time_s": round(time.perf_counter() - t0, 3)}


@dataclass
class Capture:
    """A validated capture: ground-truth cameras and splits in file order, image paths by name,
    the calibration targets (empty dict when the capture has no targets.json) and the shooting
    order (None when the capture has no capture_order.json, e.g. one made before it existed)."""

    folder: Path
    cameras: list[Camera]
    splits: list[str]
    images: dict[str, Path]
    targets: dict
    order: list[ViewOrder] | None = None


class PoseFailure(Exception):
    """The method ran but its result is unusable; carries the metrics measured so far."""

    def __init__(self, reason: str, metrics: dict):
        super().__init__(reason)
        self.reason, self.metrics = reason, metrics


def load_capture(folder: Path, need_targets: bool = False) -> Capture:
    """Read and check a capture folder (:func:`pipeline.stages.capture.check_capture_folder`: a finished
    capture, valid cameras.json, every view's PNG of its camera's size); BadInput (one line
    naming the file) on any problem."""
    folder = Path(folder)
    cameras, splits = check_capture_folder(folder, need=("images",))
    images, by_content, blank = {}, {}, []

    def check(c: Camera) -> tuple[Path, bytes, bool] | Path:
        p = folder / "images" / f"{c.name}.png"
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None or img.dtype != np.uint8:
            return p
        return p, hashlib.sha256(img.tobytes()).digest(), _background_only(img)

    # every view read on all cores (OpenCV's decoding and hashlib release the GIL): 24 s serially
    # at 1000 views, the stage's largest part outside COLMAP
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        for c, got in zip(cameras, pool.map(check, cameras)):
            if isinstance(got, Path):
                raise BadInput(f"{got}: unreadable image (not an 8-bit PNG)")
            p, digest, background = got
            images[c.name] = p
            by_content.setdefault(digest, []).append(c.name)
            if background:
                blank.append(c.name)
    duplicates = [names for names in by_content.values() if len(names) > 1]
    if duplicates:
        groups = "; ".join(" = ".join(g) for g in duplicates[:5]) + ("; ..." if len(duplicates) > 5 else "")
        raise BadInput(f"{folder / 'images'}: duplicate views (identical images): {groups}")
    if blank:
        raise BadInput(f"{folder / 'images'}: {len(blank)} view(s) see only a uniform background "
                       f"(nothing to match): {', '.join(blank[:10])}{', ...' if len(blank) > 10 else ''}")
    targets = {}
    t_file = folder / "targets.json"
    if t_file.is_file():
        try:
            targets = json.loads(t_file.read_text())
        except json.JSONDecodeError as exc:
            raise BadInput(f"{t_file}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
        if not isinstance(targets, dict):
            raise BadInput(f"{t_file}: expected an object of boards")
    elif need_targets:
        raise BadInput(f"{t_file}: no calibration targets in the capture (needed by --method charuco)")
    return Capture(folder, cameras, splits, images, targets, _read_order(folder / "capture_order.json", cameras))


#: downsampling factor and contrast (8-bit levels) below which a view counts as background only
BLANK_BLOCK, BLANK_CONTRAST = 8, 16


def _background_only(img: np.ndarray) -> bool:
    """True when ``img`` ((H, W) or (H, W, C) uint8) is one colour up to noise: the range of its
    ``BLANK_BLOCK``-pixel block means is below ``BLANK_CONTRAST`` levels in every channel. Block
    means divide sensor noise by 8 (a 3-level sigma leaves a range under 4 levels over ~20,000
    blocks), while any subject in view spans tens of levels."""
    h, w = img.shape[:2]
    small = cv2.resize(img, (max(w // BLANK_BLOCK, 1), max(h // BLANK_BLOCK, 1)), interpolation=cv2.INTER_AREA)
    small = small.reshape(small.shape[0] * small.shape[1], -1)
    return bool((small.max(axis=0).astype(int) - small.min(axis=0)).max() < BLANK_CONTRAST)


def _read_order(path: Path, cameras: list[Camera]) -> list[ViewOrder] | None:
    """The capture's shooting order (pipeline.stages.capture.capture_order) for ``cameras``;
    None when the file is absent. BadInput, one line naming the file and field, when malformed or
    not covering every view."""
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
        views = [ViewOrder(str(v["name"]), str(v["sequence"]), int(v["frame"]), int(v["frames"]), bool(v["closed"]),
                           int(v["time"])) for v in doc["views"]]
    except json.JSONDecodeError as exc:
        raise BadInput(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise BadInput(f"{path}: field 'views': malformed entry ({str(exc).splitlines()[0]})") from None
    known = {v.name for v in views}
    missing = [c.name for c in cameras if c.name not in known]
    if missing or len(known) != len(views):
        what = f"view {missing[0]!r} missing" if missing else "a view listed twice"
        raise BadInput(f"{path}: field 'views': {what}")
    return views


def check_poses(poses_dir: Path, capture_dir: Path, cameras: list[Camera], splits: list[str]) -> list[Camera]:
    """The estimated cameras of a finished poses folder, checked against the capture they are used
    with (``cameras``/``splits``: the capture's): every view name is one of the capture's, in the
    same split, at the same image size, and the folder was estimated from a capture with these
    very cameras (the hash of the cameras.json its manifest lists as input). BadInput, one line
    naming the file and field, otherwise (e.g. ``--poses`` of another scene)."""
    from ..artifacts import read_stage_manifest, sha256_file
    from .capture import read_cameras

    poses_dir = Path(poses_dir)
    if not poses_dir.is_dir():
        raise BadInput(f"--poses {poses_dir}: no such folder")
    manifest = read_stage_manifest(poses_dir, "poses")
    cam_file = poses_dir / "cameras.json"
    est, est_splits = read_cameras(cam_file)
    truth = {c.name: (c, s) for c, s in zip(cameras, splits)}
    for c, s in zip(est, est_splits):
        if c.name not in truth:
            raise BadInput(f"{cam_file}: field 'name': view {c.name!r} is not in the capture {capture_dir} "
                           "(poses of another scene?)")
        t, ts = truth[c.name]
        if s != ts:
            raise BadInput(f"{cam_file}: field 'split': view {c.name!r} is {s!r} here but {ts!r} in the capture")
        k, kt = c.intrinsics, t.intrinsics
        if (k.width, k.height) != (kt.width, kt.height):
            raise BadInput(f"{cam_file}: field 'intrinsics': view {c.name!r} is {k.width}x{k.height} here but "
                           f"{kt.width}x{kt.height} in the capture")
    want = sha256_file(Path(capture_dir) / "cameras.json")
    used = [h for p, h in manifest.get("inputs", {}).items() if Path(p).name == "cameras.json"]
    if used and want not in used:
        raise BadInput(f"{poses_dir / 'manifest.json'}: field 'inputs': estimated from a capture with other "
                       f"cameras than {Path(capture_dir) / 'cameras.json'} (poses of another capture?)")
    return est


@contextmanager
def _sigterm_interrupts(colmap: bool):
    """SIGTERM raises KeyboardInterrupt (as Ctrl-C does) inside the block, so the stage's
    ``finally`` clauses remove COLMAP's work folder and the partial folder (~0.5 GB at 1000 views)
    instead of the process dying with them on disk. The previous handler is restored on exit; a
    no-op off the main thread (signal handlers can only be set there). ``colmap``: pycolmap is
    imported first, since its import installs glog's failure handler for SIGTERM (a stack dump,
    then death), which would replace ours if it came later."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if colmap:
        import pycolmap  # noqa: F401  (glog's handlers first, ours over them)

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _prefixed(prefix: str, d: dict) -> dict:
    return {f"{prefix}{k}": v for k, v in d.items()}


def estimate_poses(cap: Capture, method: str, config: PosesConfig = PosesConfig(),
                   workdir: Path | None = None) -> tuple[list[Camera], dict, object]:
    """Run one method on a loaded capture and score it.

    workdir: COLMAP's scratch folder (required by colmap; removed when done).
    Returns ``(cameras, metrics, reconstruction)``: registered cameras in the ground-truth
    frame (camera-to-world, OpenCV axes; capture order), the flat metrics dict with
    ``status = "ok"`` and, for COLMAP, the aligned ``pycolmap.Reconstruction`` (else None).
    Raises :class:`PoseFailure` when the result fails a gate or the method finds nothing.
    """
    if method not in METHODS:
        raise BadInput(f"--method: unknown method {method!r} (known: {', '.join(METHODS)})")
    truth = {c.name: c for c in cap.cameras}
    k_true = cap.cameras[0].intrinsics
    metrics: dict = {"method": method, "views_total": len(cap.cameras)}
    rec = None
    t0 = time.perf_counter()
    if method == "gt":
        cams, extra = list(cap.cameras), {"reprojection_error_px": 0.0}
    elif method == "colmap":
        cfg = config.colmap
        metrics.update(known_intrinsics=cfg.known_intrinsics, image_scale=resolve_image_scale(cfg, len(cap.images)),
                       max_features=cfg.max_features, first_octave=resolve_first_octave(cfg, len(cap.images)),
                       calibration=config.calibration)
        if workdir is None:
            raise ValueError("the colmap method needs a work folder")
        k_given = k_true
        if config.calibration == "charuco":  # the lab's route: the board's calibration, held fixed
            k_given, board = _charuco_calibration(cap, config.charuco, metrics)
            metrics.update(_prefixed("charuco_", board))
            cfg = replace(cfg, known_intrinsics=True)
        elif config.calibration == "auto":  # the sequence when it has one and it fits, else COLMAP's
            sequence = _sequence_calibration(cap, metrics)
            if sequence is not None:
                metrics.update(_prefixed("charuco_", sequence[1]))
            if sequence is not None and sequence[1]["calibration_rms_px"] <= SEQUENCE_TRUSTED_RMS_PX:
                k_given = sequence[0]
                cfg = replace(cfg, known_intrinsics=True)
                metrics.update(calibration="charuco", calibration_requested="auto")
            else:
                metrics.update(calibration="self", calibration_requested="auto")
        try:  # the boards' definitions only (where a board lies is the capture's ground truth)
            boards = board_definitions(cap.targets) if cap.targets and cfg.board_corners is not False else None
        except ValueError as exc:
            raise BadInput(f"{cap.folder / 'targets.json'}: {exc}") from None
        try:
            res = estimate_colmap_stoppable(cap.images, k_given, Path(workdir), cfg, cap.order, boards)
        except ReconstructionError as exc:
            metrics.update(views_registered=0, registered_fraction=0.0, unregistered=list(truth))
            raise PoseFailure(str(exc), metrics) from None
        finally:
            shutil.rmtree(workdir, ignore_errors=True)
        cams, rec = res.cameras, res.reconstruction
        extra = {"reprojection_error_px": res.reprojection_error_px, "points": int(len(res.points)),
                 "models": res.num_models, "mean_track_length": res.mean_track_length, "matcher": res.matcher,
                 "mapper": res.mapper, "pairs": res.pairs, "camera_model": res.camera_model,
                 "camera_model_note": res.lens_note, "lens_steps": res.lens_steps,
                 "observed_radius_rel": res.observed_radius_rel, "rational_refit_px": res.rational_refit_px,
                 "crop_box": None if res.crop_box is None else list(res.crop_box), "extractor": res.extractor,
                 "image_scale": res.image_scale,
                 **res.corner_stats,
                 **{f"{step}_time_s": t for step, t in res.times_s.items()}}
    else:
        cfg = config.charuco
        metrics.update(calibrate=cfg.calibrate)
        imgs = {n: cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for n, p in cap.images.items()}
        try:
            res = estimate_charuco(imgs, cap.targets, None if cfg.calibrate else k_true, cfg)
        except BoardNotFound as exc:
            metrics.update(views_registered=0, registered_fraction=0.0, unregistered=list(truth))
            raise PoseFailure(str(exc), metrics) from None
        except ValueError as exc:  # malformed board definition
            raise BadInput(f"{cap.folder / 'targets.json'}: {exc}") from None
        cams = res.cameras
        extra = {"reprojection_error_px": res.reprojection_error_px, "board_not_visible": res.not_visible,
                 "corners_min": int(min(res.corners.values())), "corners_mean": float(np.mean(list(res.corners.values())))}
    metrics["estimate_time_s"] = round(time.perf_counter() - t0, 3)
    names = {c.name for c in cams}
    metrics.update(views_registered=len(cams), registered_fraction=len(cams) / len(truth),
                   unregistered=[n for n in truth if n not in names], **extra)
    gates = config.gates
    if len(cams) < 3:
        raise PoseFailure(f"only {len(cams)} of {len(truth)} views registered", metrics)
    try:
        if method == "charuco":
            _, aligned, _ = score_cameras(cams, truth, align=True)
            metrics.update(_prefixed("aligned_", aligned))
            scored, m, sim = score_cameras(cams, truth, align=False)
        else:
            scored, m, sim = score_cameras(cams, truth, align=method != "gt")
    except ValueError as exc:  # degenerate centres (e.g. all registered views at one pose)
        raise PoseFailure(f"cannot align the estimate to the ground truth: {exc}", metrics) from None
    metrics.update(m)
    if cap.order is not None:  # the error each sequence's views share (issue 21: a ring-wide pitch)
        bias = sequence_rotation_bias(scored, truth, {v.name: v.sequence for v in cap.order})
        metrics["sequence_rotation_bias"] = bias
        pitches = [b["pitch_deg"] for b in bias if b["views"] > 1]
        metrics["sequence_pitch_spread_deg"] = float(max(pitches) - min(pitches)) if pitches else 0.0
    metrics.update(intrinsics_error(scored[0], truth[scored[0].name]))
    metrics.update(projection_error(scored, truth, radius_rel=metrics.get("observed_radius_rel")))
    check = turntable_self_check(scored, gates.max_azimuth_gap_deg)
    metrics.update(self_check_folded=check["folded"], self_check_reason=check["reason"],
                   max_azimuth_gap_deg=check["max_azimuth_gap_deg"], duplicate_pairs=check["duplicate_pairs"])
    reasons = []
    if metrics["registered_fraction"] < gates.min_registered_fraction:
        reasons.append(f"too few views registered: {len(cams)} of {len(truth)} (gate {gates.min_registered_fraction:.0%})")
    if check["folded"]:
        reasons.append(f"folded turntable circle (self-check): {check['reason']}")
    if metrics["rotation_error_deg_max"] > gates.max_rotation_error_deg:
        reasons.append(f"rotation error up to {metrics['rotation_error_deg_max']:.1f} deg against ground truth "
                       f"(gate {gates.max_rotation_error_deg:g} deg, view {metrics['worst_view']}): "
                       "folded or broken reconstruction")
    if reasons:
        raise PoseFailure("; ".join(reasons), metrics)
    if rec is not None:
        import pycolmap

        rec.transform(pycolmap.Sim3d(sim.scale, pycolmap.Rotation3d(sim.R), sim.t))
    metrics["status"] = "ok"
    return scored, metrics, rec


def _write_cameras(folder: Path, cap: Capture, cams: list[Camera], out_final: Path) -> None:
    split_of = dict(zip((c.name for c in cap.cameras), cap.splits))
    write_cameras_json(folder / "cameras.json", cams, [split_of[c.name] for c in cams])
    write_colmap_text(folder / "colmap", cams, [f"{c.name}.png" for c in cams])
    # file paths lead from the finished folder into the capture's images, masks and depth
    rel = {kind: [relpath(cap.folder / kind / f"{c.name}{suffix}", out_final) for c in cams]
           for kind, suffix in (("images", ".png"), ("masks", ".png"), ("depth", ".exr"))}
    have = {kind: all((cap.folder / kind / f"{c.name}{suffix}").is_file() for c in cams)
            for kind, suffix in (("masks", ".png"), ("depth", ".exr"))}
    write_nerfstudio_transforms(folder / "transforms.json", cams, [split_of[c.name] for c in cams], rel["images"],
                                rel["masks"] if have["masks"] else None, rel["depth"] if have["depth"] else None)
    for split in sorted(set(cap.splits)):
        members = [i for i, c in enumerate(cams) if split_of[c.name] == split]
        if members:
            try:  # Blender/TensoRF split files: file paths without extension
                write_blender_transforms_json(folder / f"transforms_{split}.json", [cams[i] for i in members],
                                              [rel["images"][i].removesuffix(".png") for i in members])
            except ValueError:  # estimated intrinsics the convention cannot state: transforms.json holds them
                pass


def run_poses(capture_dir: Path, method: str, out: Path, config: PosesConfig = PosesConfig(),
              quiet: bool = False, overwrite: bool = False) -> dict:
    """Estimate poses of ``capture_dir`` with ``method`` into ``out`` atomically; returns the manifest.

    On failure writes the failure folder described in the module docstring and raises BadInput.
    ``out`` may be absent, empty, a finished poses folder or a failure folder; anything else is
    refused before any work unless ``overwrite`` (:func:`pipeline.artifacts.check_out`).
    """
    if method not in METHODS:
        raise BadInput(f"--method: unknown method {method!r} (known: {', '.join(METHODS)})")
    out = Path(out)
    check_out(out, "poses", overwrite)
    cap = load_capture(capture_dir, need_targets=method == "charuco")
    if method == "colmap" and config.colmap.matcher == "capture_order" and cap.order is None:
        raise BadInput(f"{cap.folder / 'capture_order.json'}: no shooting order in the capture "
                       "(needed by --matcher capture_order; capture it again, or use --matcher exhaustive)")
    params = {"method": method, "capture": str(capture_dir),
              **({"colmap": asdict(config.colmap), "calibration": config.calibration} if method == "colmap"
              else {"charuco": asdict(config.charuco)} if method == "charuco" else {}), "gates": asdict(config.gates)}
    manifest = Manifest("poses", params=params)
    manifest.add_input(cap.folder / "cameras.json")
    manifest.add_input(cap.folder / "images")
    if method == "charuco":
        manifest.add_input(cap.folder / "targets.json")
    failure = None
    # the work folder lives in the partial folder: no COLMAP leftovers outside it (module docstring)
    with _sigterm_interrupts(method == "colmap"), progress_bar(quiet) as bar, atomic_stage(out, "poses", overwrite) as tmp:
        task = bar.add_task(f"poses {method}", total=1, info=f"{len(cap.cameras)} views")
        try:
            cams, metrics, rec = estimate_poses(cap, method, config, workdir=tmp / "colmap-work")
        except PoseFailure as fail:
            failure = fail.reason
            metrics = {**fail.metrics, "status": "failed", "reason": fail.reason,
                       "wall_time_s": round(time.time() - manifest.started, 3)}
            write_json(tmp / "metrics.json", metrics)
        bar.advance(task)
        if failure is None:
            metrics["wall_time_s"] = round(time.time() - manifest.started, 3)
            result = _write_outputs(tmp, cap, cams, rec, metrics, manifest, out)
    if failure is not None:
        raise BadInput(f"poses {method}: {failure} (see {out / 'metrics.json'})")
    return result


def _write_outputs(tmp: Path, cap: Capture, cams: list[Camera], rec, metrics: dict, manifest: Manifest,
                   out: Path) -> dict:
    """The finished folder's files into the partial folder ``tmp``; returns the manifest."""
    _write_cameras(tmp, cap, cams, out)
    if rec is not None:
        (tmp / "sparse").mkdir()
        rec.write(str(tmp / "sparse"))
    write_json(tmp / "metrics.json", metrics)
    manifest.metrics = {k: v for k, v in metrics.items() if isinstance(v, (int, float, str, bool))}
    return manifest.write(tmp)

