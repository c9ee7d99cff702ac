"""Pinhole cameras, lens distortion, projection and pixel rays.

Conventions (see docs/architecture.md):

* Camera frame is OpenCV: x right, y down, z forward.
* ``cam_to_world`` is a 4x4 float64 camera-to-world matrix in OpenCV axes.
* Pixel (row i, col j) has its centre at continuous image coordinates (j + 0.5, i + 0.5),
  COLMAP's convention. ``cx, cy`` are stored in that convention; OpenCV calls need
  ``cx - 0.5, cy - 0.5`` (:meth:`Intrinsics.K_opencv`).
* Distortion is OpenCV/Brown: ``(k1, k2, p1, p2, k3)``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["Intrinsics", "Camera", "distort_normalized", "undistort_normalized"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels, principal point in the pixel-centre-at-+0.5 convention.

    ``dist`` holds OpenCV's ``(k1, k2, p1, p2, k3)``; all zeros means an ideal pinhole.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist) + (0.0,) * (5 - len(self.dist)))

    @classmethod
    def from_fov(cls, width: int, height: int, fov_y_deg: float) -> "Intrinsics":
        """Square-pixel pinhole with vertical field of view ``fov_y_deg``, centred principal point."""
        fy = 0.5 * height / np.tan(np.radians(fov_y_deg) / 2)
        return cls(width, height, fy, fy, width / 2.0, height / 2.0)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 calibration matrix, pixel centres at +0.5 (COLMAP convention)."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    @property
    def K_opencv(self) -> np.ndarray:
        """(3, 3) float64 calibration matrix for OpenCV calls (pixel centres at integers)."""
        K = self.K
        K[0, 2] -= 0.5
        K[1, 2] -= 0.5
        return K

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    @property
    def fov_y(self) -> float:
        """Vertical field of view in radians (ignoring distortion)."""
        return 2.0 * np.arctan(0.5 * self.height / self.fy)

    def scaled(self, factor: float) -> "Intrinsics":
        """Intrinsics for the image resized by ``factor`` (pixel-centre convention preserved)."""
        w, h = int(round(self.width * factor)), int(round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return replace(self, width=w, height=h, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy)

    def to_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
                "cx": self.cx, "cy": self.cy, "dist": list(self.dist)}

    @classmethod
    def from_dict(cls, d: dict) -> "Intrinsics":
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]),
                   float(d["cx"]), float(d["cy"]), tuple(d.get("dist", (0.0,) * 5)))


def distort_normalized(xy: np.ndarray, dist) -> np.ndarray:
    """Apply OpenCV's Brown model to normalized coordinates.

    xy: (N, 2) float64 undistorted normalized coordinates (x/z, y/z). Returns (N, 2) float64.
    """
    k1, k2, p1, p2, k3 = dist
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def undistort_normalized(xy_d: np.ndarray, dist, iterations: int = 20) -> np.ndarray:
    """Invert :func:`distort_normalized` by fixed-point iteration (as OpenCV's undistortPoints).

    xy_d: (N, 2) float64 distorted normalized coordinates. Returns (N, 2) float64.
    """
    k1, k2, p1, p2, k3 = dist
    xy = xy_d.copy()
    for _ in range(iterations):
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        radial = np.where(np.abs(radial) < 1e-12, 1e-12, radial)  # guard: never divide by 0
        xy = np.stack([(xy_d[:, 0] - dx) / radial, (xy_d[:, 1] - dy) / radial], axis=1)
    return xy


@dataclass(frozen=True)
class Camera:
    """A named calibrated view: intrinsics plus a camera-to-world pose in OpenCV axes."""

    intrinsics: Intrinsics
    cam_to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    name: str = "view"

    def __post_init__(self) -> None:
        m = np.asarray(self.cam_to_world, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise ValueError(f"cam_to_world must be a finite (4, 4) matrix, got shape {m.shape}")
        object.__setattr__(self, "cam_to_world", m)

    @property
    def world_to_cam(self) -> np.ndarray:
        """(4, 4) float64 world-to-camera (rigid inverse)."""
        R, t = self.cam_to_world[:3, :3], self.cam_to_world[:3, 3]
        out = np.eye(4)
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ t
        return out

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 camera centre in world coordinates."""
        return self.cam_to_world[:3, 3].copy()

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points to continuous pixel coordinates (centres at +0.5).

        points_world: (N, 3). Returns ``(uv, z)``: (N, 2) float64 pixel coordinates (x right,
        y down) and (N,) float64 camera-frame depth. Points with z <= 0 get non-finite-free but
        meaningless uv; callers mask with ``z > 0``.
        """
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        pc = p @ self.world_to_cam[:3, :3].T + self.world_to_cam[:3, 3]
        z = pc[:, 2]
        safe_z = np.where(np.abs(z) < 1e-12, 1e-12, z)
        xy = pc[:, :2] / safe_z[:, None]
        if self.intrinsics.has_distortion:
            xy = distort_normalized(xy, self.intrinsics.dist)
        k = self.intrinsics
        uv = np.stack([k.fx * xy[:, 0] + k.cx, k.fy * xy[:, 1] + k.cy], axis=1)
        return uv, z

    def pixel_rays(self, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World-space rays through pixel positions.

        pixels: (N, 2) float64 continuous pixel coordinates (x, y), centres at +0.5; ``None``
        means every pixel centre in row-major order (N = H * W). Returns ``(origins, dirs)``,
        both (N, 3) float64, ``dirs`` unit length. Distortion is inverted exactly, so the ray
        through a distorted pixel is the one a real lens would see.
        """
        k = self.intrinsics
        if pixels is None:
            jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
            pixels = np.stack([jj.ravel(), ii.ravel()], axis=1)
        pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        xy = np.stack([(pixels[:, 0] - k.cx) / k.fx, (pixels[:, 1] - k.cy) / k.fy], axis=1)
        if k.has_distortion:
            xy = undistort_normalized(xy, k.dist)
        d_cam = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
        dirs = d_cam @ self.cam_to_world[:3, :3].T
        origins = np.broadcast_to(self.cam_to_world[:3, 3], dirs.shape).copy()
        return origins, dirs

    def to_dict(self) -> dict:
        return {"name": self.name, "intrinsics": self.intrinsics.to_dict(),
                "cam_to_world": self.cam_to_world.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        return cls(Intrinsics.from_dict(d["intrinsics"]), np.array(d["cam_to_world"], dtype=np.float64), d["name"])
