"""Pose conventions and converters.

Our poses are camera-to-world 4x4 float64 in OpenCV axes (x right, y down, z forward).
OpenGL / pyrender / nerfstudio use x right, y up, z backward: the two differ by a flip of the
camera's y and z axes (right-multiplying by diag(1, -1, -1, 1)). COLMAP stores world-to-camera
(``cam_from_world``) in OpenCV axes, as a scalar-first unit quaternion plus translation in its
text files. Rotations and rigid transforms to and from COLMAP's go through pycolmap
(``Rotation3d``, ``Rigid3d``), imported on first use (it takes 0.3 s to import).
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "OPENCV_TO_OPENGL", "opencv_to_opengl", "opengl_to_opencv", "invert_rigid",
    "rotmat_to_qvec", "qvec_to_rotmat", "look_at", "c2w_to_colmap", "colmap_to_c2w", "c2w_to_rigid3d",
    "rigid3d_to_c2w",
]

OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])


def opencv_to_opengl(c2w: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world in OpenCV axes -> the same camera in OpenGL axes."""
    return np.asarray(c2w, dtype=np.float64) @ OPENCV_TO_OPENGL


def opengl_to_opencv(c2w_gl: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world in OpenGL axes -> OpenCV axes (the flip is its own inverse)."""
    return np.asarray(c2w_gl, dtype=np.float64) @ OPENCV_TO_OPENGL


def invert_rigid(m: np.ndarray) -> np.ndarray:
    """Inverse of a (4, 4) rigid transform without a general matrix inverse."""
    R, t = m[:3, :3], m[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> (4,) scalar-first unit quaternion (w, x, y, z) with w >= 0, the order of
    COLMAP's ``images.txt``. The conversion is pycolmap's (``Rotation3d``, Eigen's, which stores
    x, y, z, w); only the reordering and the sign choice are ours."""
    import pycolmap

    x, y, z, w = pycolmap.Rotation3d(np.asarray(R, dtype=np.float64)).quat
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(4,) scalar-first quaternion (w, x, y, z; normalized here) -> (3, 3) float64 rotation, via
    pycolmap's ``Rotation3d``."""
    import pycolmap

    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.asarray(pycolmap.Rotation3d(np.array([x, y, z, w])).matrix(), dtype=np.float64)


def c2w_to_rigid3d(c2w: np.ndarray):
    """OpenCV camera-to-world (4, 4) -> pycolmap ``Rigid3d`` cam_from_world (COLMAP's image pose)."""
    import pycolmap

    return pycolmap.Rigid3d(invert_rigid(np.asarray(c2w, dtype=np.float64))[:3, :])


def rigid3d_to_c2w(cam_from_world) -> np.ndarray:
    """pycolmap ``Rigid3d`` cam_from_world -> OpenCV camera-to-world (4, 4) float64."""
    w2c = np.eye(4)
    w2c[:3, :] = np.asarray(cam_from_world.matrix(), dtype=np.float64)
    return invert_rigid(w2c)


def c2w_to_colmap(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV camera-to-world (4, 4) -> COLMAP world-to-camera ``(qvec (4,) w x y z, tvec (3,))``."""
    rigid = c2w_to_rigid3d(c2w)
    return rotmat_to_qvec(rigid.rotation.matrix()), np.asarray(rigid.translation, dtype=np.float64).copy()


def colmap_to_c2w(qvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """COLMAP world-to-camera ``(qvec (4,) w x y z, tvec (3,))`` -> OpenCV camera-to-world (4, 4) float64."""
    w2c = np.eye(4)
    w2c[:3, :3] = qvec_to_rotmat(qvec)
    w2c[:3, 3] = tvec
    return invert_rigid(w2c)


def look_at(eye, target, up) -> np.ndarray:
    """Camera-to-world (4, 4) float64, OpenCV axes, at ``eye`` looking at ``target``.

    ``up`` is the world direction that should appear up in the image (camera -y).
    Raises ValueError when the view direction is parallel to ``up``.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    n = np.linalg.norm(z)
    if n < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    z /= n
    x = np.cross(z, up)  # camera x (right) = forward x up, since camera y points down
    nx = np.linalg.norm(x)
    if nx < 1e-9:
        raise ValueError("look_at: view direction is parallel to the up vector")
    x /= nx
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m
