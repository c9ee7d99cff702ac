"""A tiny synthetic capture for NeRF tests: a coloured cube of fog rendered *exactly* by the
voxel integrator of recon.nerf.volume, seen by 8 train and 2 test cameras on a ring (32x24 pixels).

The folder has the capture layout the NeRF reads: linear/<view>.exr, cameras.json (splits),
manifest.json. Building it takes well under a second.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pipeline.artifacts import Manifest
from render.camera import Camera, Intrinsics
from render.camera_io import write_cameras_json
from render.image_io import write_exr
from render.poses import look_at
from recon.nerf.volume import VoxelField, render_voxels_exact

SIZE = (32, 24)
# The fast model shrunk for tests: small grids and batches, occupancy updates from step 30.
FAST_SMALL = (("res_init", 16), ("res_final", 40), ("occ_res", 16), ("steps_per_side", 96),
              ("n_comp_app", 12), ("points_per_batch", 8192), ("max_rays", 1024), ("occ_start", 30),
              ("occ_every", 30))


def tiny_field() -> VoxelField:
    """A 0.3-wide cube of density 40 / unit whose colour varies smoothly with position."""
    n = 12
    lo, hi = (-0.15, -0.15, -0.15), (0.15, 0.15, 0.15)
    u = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    X, Y, Z = torch.meshgrid(u, u, u, indexing="ij")
    rgb = torch.stack([0.2 + 0.6 * X, 0.2 + 0.6 * Y, 0.8 - 0.6 * Z], dim=-1)
    return VoxelField(torch.full((n, n, n), 40.0, dtype=torch.float64), rgb, lo, hi)


def tiny_cameras() -> tuple[list[Camera], list[str]]:
    k = Intrinsics.from_fov(*SIZE, 40.0)
    cams, splits = [], []
    for i in range(10):
        az = 2 * np.pi * i / 10
        el = np.radians(30 if i % 2 else 15)
        eye = 1.2 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(Camera(k, look_at(eye, np.zeros(3), np.array([0.0, 0.0, 1.0])), f"view_{i:03d}"))
        splits.append("test" if i in (3, 8) else "train")
    return cams, splits


def render_exact(cam: Camera) -> np.ndarray:
    o, d = cam.pixel_rays()
    out = render_voxels_exact(tiny_field(), torch.from_numpy(o), torch.from_numpy(d), background=0.0)
    k = cam.intrinsics
    return out.rgb.numpy().reshape(k.height, k.width, 3).astype(np.float32)


def make_tiny_capture(folder: Path) -> Path:
    folder = Path(folder)
    cams, splits = tiny_cameras()
    for c in cams:
        write_exr(folder / "linear" / f"{c.name}.exr", render_exact(c))
    write_cameras_json(folder / "cameras.json", cams, splits)
    Manifest("capture", params={"scene": "tiny-fog"}).write(folder)
    return folder
