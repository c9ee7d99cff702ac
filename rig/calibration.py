"""The calibration sequence: the scene's ChArUco board alone, shot close up by the capture's own
camera at several tilts so that it fills the whole frame, as a lab shoots a board before a session.

The turntable views see the board from one distance and a narrow range of tilts, and their
features cover under half of the image's half-diagonal: a lens fitted to them is extrapolated
beyond and its principal point trades against a pitch shared by every view (issue 21). A board
that fills the frame, then sits in each quadrant, frontal and at tilts of 15, 30 and 45 degrees
(:func:`calibration_poses`), constrains focal, principal point and distortion to within 0.85 of
the half-diagonal (Zhang 2000: tilted planar views; at 60 degrees the corners were 0.4-0.6 px off
at 640x480, so the tilts stop at 45). The sequence is rendered
with the capture's intrinsics, lens and sensor (noise, vignetting), the board object alone
under the scene's lights; only the images and the board's definition are written
(``capture/calibration/``): no pose or intrinsic of the sequence is recorded, so nothing of the
truth can enter a calibration made from it.

Poses are camera-to-world (4, 4) float64, OpenCV axes (x right, y down, z forward). The board
frame is OpenCV's (:mod:`rig.build`): origin at the board image's top-left corner, x right, y
down the image, z into the board; the camera looks along the board's +z from its front side.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from render.camera import Camera, Intrinsics, undistort_normalized

from .build import RigScene, build_scene

__all__ = ["calibration_poses", "calibration_rig", "CALIBRATION_SPLIT", "board_overfill_distance"]

#: the split name of the sequence's views (their names: ``calib_<index:03d>``)
CALIBRATION_SPLIT = "calibration"


def _undistorted_half_extent(k: Intrinsics) -> tuple[float, float]:
    """Largest |x|, |y| (normalized, undistorted) over the image border: the half-size of the
    plane rectangle, at unit depth, that a frontal view must see to cover every pixel."""
    t = np.linspace(0.0, 1.0, 65)
    w, h = float(k.width), float(k.height)
    border = np.concatenate([np.column_stack([t * w, np.zeros_like(t)]), np.column_stack([t * w, np.full_like(t, h)]),
                             np.column_stack([np.zeros_like(t), t * h]), np.column_stack([np.full_like(t, w), t * h])])
    xy_d = (border - [k.cx, k.cy]) / [k.fx, k.fy]
    xy = undistort_normalized(xy_d, k.dist) if k.has_distortion else xy_d
    if not np.all(np.isfinite(xy)):
        xy = xy_d  # beyond the model's invertible region: the ideal field of view instead
    return float(np.abs(xy[:, 0]).max()), float(np.abs(xy[:, 1]).max())


def board_overfill_distance(board_size: tuple[float, float], k: Intrinsics, margin: float = 0.85) -> float:
    """Distance (scene units) at which a frontal view of a ``board_size`` (width, height) board,
    aimed at its centre, sees board everywhere in the frame with ``margin`` to spare."""
    x, y = _undistorted_half_extent(k)
    return margin * min(0.5 * board_size[0] / x, 0.5 * board_size[1] / y)


#: where a view puts the board's centre, as fractions of the image's half-extent (x right, y down):
#: the four quadrants, so that the board reaches each corner of the frame
_QUADRANTS = ((-0.45, -0.45), (0.45, -0.45), (0.45, 0.45), (-0.45, 0.45))


def _rotation_taking(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) rotation taking unit vector ``a`` to unit vector ``b`` (Rodrigues; a != -b)."""
    v, c = np.cross(a, b), float(a @ b)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def calibration_poses(board_to_world: np.ndarray, board_size: tuple[float, float], k: Intrinsics,
                      tilts_deg: tuple[float, ...] = (15.0, 30.0, 45.0), azimuths: int = 12,
                      spread: float = 2.0) -> list[np.ndarray]:
    """Camera-to-world poses of the sequence, as a lab moves a board in front of a camera:

    1. one frontal view from :func:`board_overfill_distance`: board in every pixel;
    2. four frontal views from ``spread`` times as far, the board's centre in each quadrant
       of the image (:data:`_QUADRANTS`) so that its outer corners reach the frame's corners;
    3. for each tilt of ``tilts_deg``, ``azimuths`` views tilted about axes at equal steps in
       the board plane, from that distance too, the board's centre in the quadrants in turn.

    board_to_world: (4, 4) board frame -> world. board_size: (width, height) in scene units.
    The image's x axis follows the board's x (no roll). Returns ``5 + len(tilts_deg) * azimuths``
    (4, 4) float64 poses.
    """
    b2w = np.asarray(board_to_world, dtype=np.float64)
    centre = np.array([0.5 * board_size[0], 0.5 * board_size[1], 0.0])
    d_fill = board_overfill_distance(board_size, k)
    half = _undistorted_half_extent(k)
    views = [(np.array([0.0, 0.0, 1.0]), d_fill, (0.0, 0.0))]  # (forward in the board frame, distance, placement)
    views += [(np.array([0.0, 0.0, 1.0]), spread * d_fill, q) for q in _QUADRANTS]
    for j, tilt in enumerate(tilts_deg):
        t = np.radians(tilt)
        for i in range(azimuths):
            phi = 2 * np.pi * (i + 0.5 * j) / azimuths
            # forward tilted by ``t`` towards (cos phi, sin phi) in the board plane
            forward = np.array([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])
            views.append((forward, spread * d_fill, _QUADRANTS[(i + j) % 4]))
    poses = []
    for z, d, (qx, qy) in views:
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        x /= np.linalg.norm(x)
        aimed = np.column_stack([x, np.cross(z, x), z])  # camera axes in the board frame, centre on the axis
        # turn the camera about its centre so the board's centre is seen at the placement
        seen = np.array([qx * half[0], qy * half[1], 1.0])
        turn = _rotation_taking(seen / np.linalg.norm(seen), np.array([0.0, 0.0, 1.0]))
        c2b = np.eye(4)
        c2b[:3, :3] = aimed @ turn
        c2b[:3, 3] = centre - d * z
        poses.append(b2w @ c2b)
    return poses


def calibration_rig(rig: RigScene) -> RigScene | None:
    """The calibration sequence's scene: the spec's ``calibration.board`` object alone under the
    scene's lights, with :func:`calibration_poses` for the capture's intrinsics (those of its
    first view) as its one split :data:`CALIBRATION_SPLIT` (cameras ``calib_000`` ...), or None
    when the spec asks for no sequence."""
    cal = rig.spec.calibration
    if cal is None:
        return None
    intrinsics = next(cams[0].intrinsics for cams in rig.cameras.values() if cams)
    board_object = next(o for o in rig.spec.objects if o.name == cal.board)  # the spec checked it is a board
    material = rig.spec.materials[board_object.material]
    spec = rig.spec.model_copy(update={"objects": [board_object], "materials": {board_object.material: material},
                                       "textures": {material.texture: rig.spec.textures[material.texture]}})
    board_rig = build_scene(spec, Path("."))  # a charuco texture is drawn, never read from a file
    target = board_rig.targets[cal.board]
    b = target["board"]
    size = (b["squares"][0] * b["square_length"], b["squares"][1] * b["square_length"])
    poses = calibration_poses(np.asarray(target["board_to_world"]), size, intrinsics, tuple(cal.tilts_deg),
                              cal.azimuths)
    cams = [Camera(intrinsics, p, f"calib_{i:03d}") for i, p in enumerate(poses)]
    return RigScene(spec, board_rig.scene, {CALIBRATION_SPLIT: cams}, {cal.board: target})
