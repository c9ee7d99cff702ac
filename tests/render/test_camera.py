"""Cameras and pose conventions: projection against OpenCV, rays, look_at, axis flips, quaternions.

Oracles are independent implementations (cv2.projectPoints, cv2.undistortPoints,
scipy.spatial.transform.Rotation) or geometric facts, never the code under test.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from render.camera import Camera, Intrinsics, distort_normalized, undistort_normalized
from render.poses import (
    OPENCV_TO_OPENGL, c2w_to_colmap, colmap_to_c2w, invert_rigid, look_at, opencv_to_opengl,
    opengl_to_opencv, qvec_to_rotmat, rotmat_to_qvec,
)

# moderate distortion, every coefficient non-zero (k1, k2, p1, p2, k3)
DIST = (-0.12, 0.05, 0.0015, -0.001, -0.01)


def _camera(dist=(0.0,) * 5, eye=(2.0, -3.0, 1.5), target=(0.1, 0.2, 0.3)) -> Camera:
    k = Intrinsics(640, 480, 520.0, 515.0, 318.7, 242.2, dist)
    return Camera(k, look_at(eye, target, (0, 0, 1)), "cam")


def _points_in_view(cam: Camera, n: int, seed: int, margin: float = 0.9) -> np.ndarray:
    """(n, 3) world points in front of ``cam`` whose ideal projections fill ``margin`` of the frame."""
    rng = np.random.default_rng(seed)
    k = cam.intrinsics
    u = rng.uniform(k.width * (1 - margin) / 2, k.width * (1 + margin) / 2, n)
    v = rng.uniform(k.height * (1 - margin) / 2, k.height * (1 + margin) / 2, n)
    z = rng.uniform(0.5, 8.0, n)
    pc = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    return pc @ cam.cam_to_world[:3, :3].T + cam.cam_to_world[:3, 3]


def _random_rotations(n: int, seed: int) -> np.ndarray:
    return Rotation.random(n, random_state=seed).as_matrix()


def _half_turns() -> list[np.ndarray]:
    """180-degree rotations: the quaternion's scalar part is 0 (the sign-ambiguous case)."""
    axes = [np.array(a, dtype=float) for a in ([1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3])]
    return [Rotation.from_rotvec(np.pi * a / np.linalg.norm(a)).as_matrix() for a in axes]


# --------------------------------------------------------------------------- projection


@pytest.mark.parametrize("dist", [(0.0,) * 5, DIST], ids=["pinhole", "distorted"])
def test_project_matches_cv2_projectPoints(dist):
    cam = _camera(dist)
    pts = _points_in_view(cam, 500, seed=1)
    uv, z = cam.project(pts)
    w2c = cam.world_to_cam
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    uv_cv, _ = cv2.projectPoints(pts, rvec, w2c[:3, 3], cam.intrinsics.K_opencv, np.array(dist))
    # OpenCV puts pixel centres at integers, we at +0.5
    np.testing.assert_allclose(uv, uv_cv.reshape(-1, 2) + 0.5, atol=0.01, rtol=0)
    assert np.all(z > 0)


def test_K_opencv_is_K_shifted_by_half_pixel():
    k = _camera().intrinsics
    np.testing.assert_array_equal(k.K - k.K_opencv, [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])


def test_distortion_actually_moves_points():
    # guards the parametrized test above against a no-op distortion path
    uv0, _ = _camera().project(_points_in_view(_camera(), 50, seed=2))
    uv1, _ = _camera(DIST).project(_points_in_view(_camera(), 50, seed=2))
    assert np.abs(uv1 - uv0).max() > 5.0


def test_undistort_matches_cv2_undistortPoints():
    k = _camera(DIST).intrinsics
    rng = np.random.default_rng(3)
    px = np.stack([rng.uniform(0, k.width, 400), rng.uniform(0, k.height, 400)], axis=1)
    xy_d = np.stack([(px[:, 0] - k.cx) / k.fx, (px[:, 1] - k.cy) / k.fy], axis=1)
    ours = undistort_normalized(xy_d, k.dist)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    ref = cv2.undistortPoints((px - 0.5).reshape(-1, 1, 2), k.K_opencv, np.array(k.dist), R=None, P=None, criteria=crit)
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-7)
    np.testing.assert_allclose(distort_normalized(ours, k.dist), xy_d, atol=1e-10)


# --------------------------------------------------------------------------- rays


@pytest.mark.parametrize("dist", [(0.0,) * 5, DIST], ids=["pinhole", "distorted"])
def test_pixel_rays_and_project_are_inverses(dist):
    cam = _camera(dist)
    origins, dirs = cam.pixel_rays()  # every pixel centre, row-major
    k = cam.intrinsics
    assert dirs.shape == (k.width * k.height, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(origins, np.broadcast_to(cam.center, origins.shape), atol=0)
    depth = np.random.default_rng(4).uniform(0.5, 10.0, len(dirs))
    uv, z = cam.project(origins + depth[:, None] * dirs)
    jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    np.testing.assert_allclose(uv, np.stack([jj.ravel(), ii.ravel()], axis=1), atol=1e-6)
    assert np.all(z > 0)

    # and the other way: project a world point, cast the ray back through it
    pts = _points_in_view(cam, 300, seed=5)
    uv, _ = cam.project(pts)
    o, d = cam.pixel_rays(uv)
    to_pts = pts - o
    to_pts /= np.linalg.norm(to_pts, axis=1, keepdims=True)
    np.testing.assert_allclose(d, to_pts, atol=1e-9)


def test_principal_point_ray_is_the_optical_axis():
    cam = _camera(DIST)  # distortion is centred at the principal point
    k = cam.intrinsics
    _, d = cam.pixel_rays(np.array([[k.cx, k.cy]]))
    np.testing.assert_allclose(d[0], cam.cam_to_world[:3, 2], atol=1e-12)


# --------------------------------------------------------------------------- look_at


@pytest.mark.parametrize("eye,target,up", [
    ((2.0, -3.0, 1.5), (0.1, 0.2, 0.3), (0, 0, 1)),
    ((0.0, 0.0, -800.0), (0.0, 0.0, 0.0), (0, 1, 0)),  # Cornell-like, +Y up
    ((-1.0, 4.0, -2.0), (3.0, 1.0, 0.0), (0, 0, 1)),  # looking slightly upwards
])
def test_look_at_target_at_principal_point_and_up_is_up(eye, target, up):
    c2w = look_at(eye, target, up)
    R = c2w[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_array_equal(c2w[3], [0, 0, 0, 1])
    np.testing.assert_allclose(c2w[:3, 3], eye)
    cam = Camera(Intrinsics(320, 240, 300.0, 300.0, 161.5, 118.25), c2w)
    uv, z = cam.project(np.array([target]))
    np.testing.assert_allclose(uv[0], [161.5, 118.25], atol=1e-9)
    assert z[0] > 0
    # a point above the target (world up) appears higher in the image: smaller row coordinate
    dist = np.linalg.norm(np.subtract(target, eye))
    above = np.asarray(target, dtype=float) + 0.05 * dist * np.asarray(up, dtype=float)
    uv_up, _ = cam.project(above[None])
    assert uv_up[0, 1] < uv[0, 1] - 1.0
    assert abs(uv_up[0, 0] - uv[0, 0]) < 1e-6  # straight up, no sideways drift
    # and world "right" (forward x up) appears on the right
    right = np.cross(np.subtract(target, eye), up)
    uv_r, _ = cam.project((np.asarray(target) + 0.05 * dist * right / np.linalg.norm(right))[None])
    assert uv_r[0, 0] > uv[0, 0] + 1.0


def test_look_at_rejects_degenerate_input():
    with pytest.raises(ValueError, match="parallel"):
        look_at((0, 0, 5), (0, 0, 0), (0, 0, 1))
    with pytest.raises(ValueError, match="coincide"):
        look_at((1, 2, 3), (1, 2, 3), (0, 0, 1))


# --------------------------------------------------------------------------- OpenCV <-> OpenGL


def test_point_in_front_of_opencv_camera_has_negative_opengl_z():
    c2w = look_at((2.0, -3.0, 1.5), (0.1, 0.2, 0.3), (0, 0, 1))
    c2w_gl = opencv_to_opengl(c2w)
    p = np.array([0.1, 0.2, 0.3, 1.0])  # the target, in front of the camera
    p_cv = invert_rigid(c2w) @ p
    p_gl = invert_rigid(c2w_gl) @ p
    assert p_cv[2] > 0 and p_gl[2] < 0
    np.testing.assert_allclose(p_gl[:3], p_cv[:3] * [1, -1, -1], atol=1e-12)
    # a point above the camera's optical axis (world up) has y < 0 in OpenCV, y > 0 in OpenGL
    q = invert_rigid(c2w_gl) @ np.array([0.1, 0.2, 1.3, 1.0])
    assert q[1] > 0
    # same camera centre, the flip is its own inverse
    np.testing.assert_array_equal(c2w_gl[:3, 3], c2w[:3, 3])
    np.testing.assert_array_equal(opengl_to_opencv(c2w_gl), c2w)
    np.testing.assert_array_equal(OPENCV_TO_OPENGL @ OPENCV_TO_OPENGL, np.eye(4))
    assert np.linalg.det(c2w_gl[:3, :3]) == pytest.approx(1.0)


# --------------------------------------------------------------------------- quaternions


def test_qvec_round_trips_random_and_half_turn_rotations():
    for R in list(_random_rotations(200, seed=6)) + _half_turns():
        q = rotmat_to_qvec(R)
        assert q.shape == (4,)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
        assert q[0] >= 0
        np.testing.assert_allclose(qvec_to_rotmat(q), R, atol=1e-12)
        # scalar-first, and the same rotation scipy reads from (x, y, z, w)
        x, y, z, w = Rotation.from_matrix(R).as_quat()
        ref = np.array([w, x, y, z])
        assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-9


def test_qvec_to_rotmat_matches_scipy_scalar_first():
    q = np.array([0.3, -0.5, 0.2, 0.7])
    q /= np.linalg.norm(q)
    ref = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    np.testing.assert_allclose(qvec_to_rotmat(q), ref, atol=1e-12)
    np.testing.assert_allclose(qvec_to_rotmat(3.0 * q), ref, atol=1e-12)  # normalized inside


def test_colmap_c2w_round_trip():
    rng = np.random.default_rng(7)
    for R in list(_random_rotations(50, seed=8)) + _half_turns():
        c2w = np.eye(4)
        c2w[:3, :3] = R
        c2w[:3, 3] = rng.normal(scale=5.0, size=3)
        q, t = c2w_to_colmap(c2w)
        # COLMAP's t is world-to-camera: the camera centre maps to the origin
        np.testing.assert_allclose(qvec_to_rotmat(q) @ c2w[:3, 3] + t, 0.0, atol=1e-12)
        np.testing.assert_allclose(colmap_to_c2w(q, t), c2w, atol=1e-12)


# --------------------------------------------------------------------------- scaling


@pytest.mark.parametrize("factor", [0.5, 2.0, 0.25, 1.5])
@pytest.mark.parametrize("dist", [(0.0,) * 5, DIST], ids=["pinhole", "distorted"])
def test_scaled_intrinsics_scale_projections_exactly(factor, dist):
    cam = _camera(dist)
    k2 = cam.intrinsics.scaled(factor)
    assert (k2.width, k2.height) == (640 * factor, 480 * factor)
    cam2 = Camera(k2, cam.cam_to_world)
    pts = _points_in_view(cam, 200, seed=9)
    uv, _ = cam.project(pts)
    uv2, _ = cam2.project(pts)
    # continuous coordinates (image corner at 0) scale by the factor; centres follow
    np.testing.assert_allclose(uv2, uv * factor, atol=1e-9)


def test_scaled_intrinsics_with_rounded_size_scale_per_axis():
    cam = _camera()
    k2 = cam.intrinsics.scaled(1 / 3)  # 640 x 480 -> 213 x 160: x does not scale by exactly 1/3
    assert (k2.width, k2.height) == (213, 160)
    sx, sy = 213 / 640, 160 / 480
    uv, _ = cam.project(_points_in_view(cam, 50, seed=10))
    uv2, _ = Camera(k2, cam.cam_to_world).project(_points_in_view(cam, 50, seed=10))
    np.testing.assert_allclose(uv2, uv * [sx, sy], atol=1e-9)
    # the image's outer edges still map to the outer edges
    assert k2.cx / k2.width == pytest.approx(cam.intrinsics.cx / 640, rel=1e-12)


def test_intrinsics_reject_bad_values():
    with pytest.raises(ValueError):
        Intrinsics(0, 10, 1.0, 1.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        Intrinsics(10, 10, -1.0, 1.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        Camera(Intrinsics(10, 10, 1.0, 1.0, 5.0, 5.0), np.full((4, 4), np.nan))
