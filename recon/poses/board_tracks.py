"""The calibration board's inner corners as extra tracks for COLMAP's final bundle adjustment.

A lab knows its own board (``targets.json``'s ``board`` definition: squares, lengths, ArUco
dictionary); where it lies is not used (``board_to_world`` is the capture's ground truth). Each
ChArUco corner has an id, so one corner seen in many views is one track without matching, and a
chessboard corner refined by ``cv2.cornerSubPix`` is localised without SIFT's scale- and
foreshortening-dependent error (issue 21: the ring-wide pitch of the 1000-view layout).

Detection (:func:`detect_corners`): ArUco markers and ChArUco corners found on the grey image
(optionally shrunk by ``scale`` first), then every corner refined by ``cv2.cornerSubPix`` on the
full-resolution grey image; views run on a thread pool (OpenCV releases the GIL). The stage runs
it beside COLMAP's mapper (:class:`CornerJob`: threads at a low priority that use the cores the
mapper leaves idle) instead of after it. Tracks (:func:`add_corner_tracks`): each corner id seen in at least two
registered views is triangulated from the mapper's poses (linear, in normalized camera
coordinates, so any COLMAP camera model), observations farther than :data:`CORNER_OUTLIER_PX`
from it dropped, and added once to the model (adding each corner 10 times over-corrected,
session 33). pycolmap refuses to extend an image's ``points2D``, so the model is rebuilt with the
corners appended to each image's keypoints (cameras, rigs, frames, poses and every SIFT track
carried over unchanged).

Pixels: detection in OpenCV's convention (centres at integers), returned in ours (+0.5), which is
COLMAP's.
"""
from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .charuco import detect_board, make_board

__all__ = ["BoardCorners", "CornerJob", "board_definitions", "detect_corners", "add_corner_tracks", "DETECT_SCALE"]

#: markers and corners are detected on the image shrunk by this factor, then refined at full size
#: (a view where the shrunk image shows no corner is detected again at full size). Measured on 28
#: views of the 224-view layout (1280x960; one-off /tmp/s34/hb/probe_detect.py, one thread, load
#: 2.2-2.4): full size 0.080 CPU s a view (0.127 s wall), 1,084 corners, positions identical to the
#: session-33 probe's; shrunk by 0.5: 0.060 CPU s a view but 1,035 corners (5% lost on the low,
#: foreshortened views) and one 6 px off. Full size, then: the cost is small beside SIFT's.
DETECT_SCALE = 1.0
#: cv2.cornerSubPix's half window (pixels at full size) and stopping rule
SUBPIX_HALF_WINDOW = 5
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
#: a refined corner that moved farther than this (full-size px) from the detection is dropped
SUBPIX_MAX_SHIFT_PX = 2.0
#: an observation farther than this (working px) from its triangulated corner is dropped
CORNER_OUTLIER_PX = 2.0
#: an image smaller than this (shorter side, px) is detected at full size only
MIN_SHRUNK_SIDE = 480


@dataclass
class BoardCorners:
    """Per view (file stem): corner keys ``"<board>:<id>"`` and (N, 2) float64 pixel positions in
    our convention (+0.5) at the input resolution; ``seconds``: wall seconds of each view's
    detection (read, detect, refine; threads share the cores); ``cpu_s``: CPU seconds of the whole
    detection (the sum of each view's thread CPU time); ``wall_s``: from start to the last view."""

    views: dict[str, tuple[list[str], np.ndarray]] = field(default_factory=dict)
    seconds: list[float] = field(default_factory=list)
    cpu_s: float = 0.0
    wall_s: float = 0.0


def board_definitions(targets: Mapping) -> dict[str, dict]:
    """``targets.json`` (board name -> ``{"board": definition, "board_to_world": ...}``) -> board
    name -> definition, each checked by :func:`recon.poses.charuco.make_board`. Only the
    definitions: the board's placement is the capture's ground truth. ValueError naming the
    board and field when malformed."""
    out = {}
    for name, target in targets.items():
        if not isinstance(target, Mapping) or not isinstance(target.get("board"), Mapping):
            raise ValueError(f"board {name!r}: field 'board' missing or not an object")
        try:
            make_board(target["board"])
        except ValueError as exc:
            raise ValueError(f"board {name!r}: {exc}") from None
        out[str(name)] = dict(target["board"])
    return out


def _detect_view(path: Path, boards: Mapping[str, object], scale: float) -> tuple[list[str], np.ndarray]:
    """One view's refined corners (keys, (N, 2) +0.5 convention)."""
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if gray is None:
        raise ValueError(f"{path}: unreadable image")
    if scale != 1.0 and min(gray.shape) * scale < MIN_SHRUNK_SIDE:
        scale = 1.0
    small = gray if scale == 1.0 else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    keys, xy = [], []
    for name, board in boards.items():
        _, pts, ids = detect_board(small, board)
        if not len(ids) and scale != 1.0:
            _, pts, ids = detect_board(gray, board)
            pts = (pts + 0.5) * scale - 0.5  # as if found on the shrunk image
        if not len(ids):
            continue
        start = ((pts + 0.5) / scale - 0.5).astype(np.float32)  # OpenCV convention, full size
        ref = cv2.cornerSubPix(gray, start.reshape(-1, 1, 2).copy(), (SUBPIX_HALF_WINDOW, SUBPIX_HALF_WINDOW),
                               (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2).astype(np.float64)
        ok = np.all(np.isfinite(ref), axis=1) & (np.linalg.norm(ref - start, axis=1) <= SUBPIX_MAX_SHIFT_PX)
        keys += [f"{name}:{int(i)}" for i in ids[ok]]
        xy.append(ref[ok] + 0.5)
    return keys, (np.concatenate(xy) if xy else np.zeros((0, 2)))


def detect_corners(images: Mapping[str, Path], boards: Mapping[str, Mapping], threads: int = 1,
                   scale: float = DETECT_SCALE, initializer: Callable[[], None] | None = None,
                   stop: threading.Event | None = None) -> BoardCorners:
    """Every view's ChArUco corners (module docstring). images: view name -> 8-bit image file;
    boards: board name -> definition (:func:`board_definitions`); threads: views detected at
    once; initializer: run first in each worker thread (:class:`CornerJob` lowers their
    priority); stop: when set, the views not yet started are skipped (an abandoned estimate).
    Views where no board is found are left out of ``views``. The result does not depend on the
    threads, their priority or their order."""
    made = {name: make_board(b) for name, b in boards.items()}
    out = BoardCorners()
    t0 = time.perf_counter()

    def one(item):
        name, path = item
        if stop is not None and stop.is_set():
            return name, [], np.zeros((0, 2)), 0.0, 0.0
        t, c = time.perf_counter(), time.thread_time()
        keys, xy = _detect_view(Path(path), made, scale)
        return name, keys, xy, time.perf_counter() - t, time.thread_time() - c

    with ThreadPoolExecutor(max(int(threads), 1), initializer=initializer) as pool:
        for name, keys, xy, seconds, cpu in pool.map(one, images.items()):
            out.seconds.append(seconds)
            out.cpu_s += cpu
            if keys:
                out.views[name] = (keys, xy)
    out.wall_s = time.perf_counter() - t0
    return out


#: the nice value of :class:`CornerJob`'s threads while they run beside the mapper (19: the
#: lowest priority, they take only the CPU time the mapper leaves; Linux gives each thread its own)
BACKGROUND_NICE = 19


def _set_nice(tid: int, value: int) -> bool:
    """Set one thread's nice value (Linux: per thread); False where it is refused (raising the
    priority back needs the privilege) or unsupported."""
    try:
        os.setpriority(os.PRIO_PROCESS, tid, value)
        return True
    except (OSError, AttributeError):
        return False


class CornerJob:
    """:func:`detect_corners` started now on ``threads`` threads at nice :data:`BACKGROUND_NICE`,
    beside whatever the caller runs next (COLMAP's mapper, which leaves part of the cores idle:
    at 1000 views 404 CPU s in 299 s wall on 2 cores, session 34). :meth:`result` waits for it,
    first raising the threads back to the caller's priority (where permitted) so the remaining
    views are not starved; :meth:`cancel` skips the views not yet started. Same corners as
    :func:`detect_corners` called in series (tests/recon/test_poses_board_tracks.py)."""

    def __init__(self, images: Mapping[str, Path], boards: Mapping[str, Mapping], threads: int = 1,
                 scale: float = DETECT_SCALE, nice: int = BACKGROUND_NICE):
        self._lock = threading.Lock()
        self._tids: dict[int, int] = {}  # worker thread id -> its nice value before
        self._foreground = False
        self._nice = nice
        self._stop = threading.Event()
        self.started = time.perf_counter()
        self._runner = ThreadPoolExecutor(1)
        self._future = self._runner.submit(detect_corners, dict(images), boards, threads, scale, self._enter, self._stop)

    def _enter(self) -> None:
        tid = threading.get_native_id()
        with self._lock:
            try:
                before = os.getpriority(os.PRIO_PROCESS, tid)
            except (OSError, AttributeError):
                return
            self._tids[tid] = before
            if not self._foreground:
                _set_nice(tid, max(before, self._nice))

    def result(self) -> BoardCorners:
        """The detection's result once every view is done (re-raises its error)."""
        with self._lock:
            self._foreground = True
            for tid, before in self._tids.items():
                _set_nice(tid, before)
        try:
            return self._future.result()
        finally:
            self._runner.shutdown()

    def cancel(self) -> None:
        """Skip the views not yet started and wait for those running (an abandoned estimate)."""
        self._stop.set()
        self._runner.shutdown(wait=True)


def _triangulate(P: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    """Linear triangulation: P (V, 3, 4) world -> camera, uv (V, 2) normalized coordinates."""
    A = np.concatenate([uv[:, :1] * P[:, 2] - P[:, 0], uv[:, 1:] * P[:, 2] - P[:, 1]])
    X = np.linalg.svd(A)[2][-1]
    if abs(X[3]) < 1e-12:
        return None
    return X[:3] / X[3]


def add_corner_tracks(rec, corners: Mapping[str, tuple[list[str], np.ndarray]],
                      to_working: Callable[[np.ndarray], np.ndarray], min_views: int = 2):
    """A copy of the pycolmap model ``rec`` with the board's corners added as tracks, and its
    figures. corners: view name (file stem) -> (keys, (N, 2) input pixels, +0.5 convention);
    to_working: input pixels -> the model's (working) pixels. Each corner key registered in at
    least ``min_views`` views becomes one 3D point, triangulated from the model's poses;
    observations beyond :data:`CORNER_OUTLIER_PX` of it are dropped (then it is triangulated again).
    Returns ``(model, {"corner_tracks", "corner_observations", "corner_views"}, {key: point3D id})``."""
    import pycolmap

    by_stem = {Path(img.name).stem: image_id for image_id, img in rec.images.items() if img.has_pose}
    obs: dict[str, list[tuple[int, np.ndarray]]] = {}
    for stem, (keys, xy) in corners.items():
        if stem not in by_stem or not len(keys):
            continue
        work = to_working(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
        for key, p in zip(keys, work):
            obs.setdefault(key, []).append((by_stem[stem], p))
    # per image: its camera-frame pose and the corners' normalized coordinates
    pose = {i: np.asarray(rec.images[i].cam_from_world().matrix(), dtype=np.float64) for i in by_stem.values()}
    tracks = []  # (xyz, [(image_id, working xy)])
    for key in sorted(obs):
        lst = obs[key]
        if len(lst) < min_views:
            continue
        ids = [i for i, _ in lst]
        xy = np.array([p for _, p in lst])
        uv = np.array([np.asarray(rec.images[i].camera.cam_from_img(p.reshape(1, 2)), dtype=np.float64).reshape(2)
                       for i, p in lst])
        P = np.stack([pose[i] for i in ids])
        keep = np.ones(len(ids), dtype=bool)
        X = None
        for _ in range(2):
            if keep.sum() < min_views:
                X = None
                break
            X = _triangulate(P[keep], uv[keep])
            if X is None:
                break
            Xc = np.einsum("vij,j->vi", P[:, :, :3], X) + P[:, :, 3]
            front = Xc[:, 2] > 1e-9
            proj = np.array([np.asarray(rec.images[i].camera.img_from_cam(c.reshape(1, 3)), dtype=np.float64).reshape(2)
                             if f else np.full(2, np.inf) for i, c, f in zip(ids, Xc, front)])
            new_keep = np.linalg.norm(proj - xy, axis=1) <= CORNER_OUTLIER_PX
            if np.array_equal(new_keep, keep):
                break
            keep = new_keep
        if X is None or keep.sum() < min_views:
            continue
        tracks.append((key, X, [(ids[j], xy[j]) for j in np.nonzero(keep)[0]]))

    # the model rebuilt with the corners appended to each image's keypoints
    extra: dict[int, list[np.ndarray]] = {}
    new = pycolmap.Reconstruction()
    for cam in rec.cameras.values():
        new.add_camera(cam)
    for rig in rec.rigs.values():
        new.add_rig(rig)
    for fr in rec.frames.values():
        f = pycolmap.Frame()
        f.frame_id, f.rig_id = fr.frame_id, fr.rig_id
        if fr.has_pose:
            f.rig_from_world = fr.rig_from_world
        for d in fr.data_ids:
            f.add_data_id(d)
        new.add_frame(f)
    index: dict[tuple[int, int], int] = {}  # (image_id, track number) -> point2D index
    for t, (_, _, members) in enumerate(tracks):
        for image_id, p in members:
            lst = extra.setdefault(image_id, [])
            index[(image_id, t)] = rec.images[image_id].num_points2D() + len(lst)
            lst.append(p)
    for image_id, img in rec.images.items():
        xy = np.array([p.xy for p in img.points2D], dtype=np.float64).reshape(-1, 2)
        if image_id in extra:
            xy = np.concatenate([xy, np.array(extra[image_id])])
        im = pycolmap.Image(name=img.name, keypoints=xy, camera_id=img.camera_id, image_id=image_id)
        im.frame_id = img.frame_id
        new.add_image(im)
    for point in rec.points3D.values():
        new.add_point3D(point.xyz, point.track, point.color)
    n_obs, point_ids = 0, {}
    for t, (key, X, members) in enumerate(tracks):
        track = pycolmap.Track()
        for image_id, _ in members:
            track.add_element(image_id, index[(image_id, t)])
        point_ids[key] = new.add_point3D(X, track, np.array([255, 0, 255], dtype=np.uint8))
        n_obs += len(members)
    new.update_point_3d_errors()
    return new, {"corner_tracks": len(tracks), "corner_observations": n_obs, "corner_views": len(extra)}, point_ids
