"""Image I/O: linear OpenEXR (float32), PNG previews (sRGB uint8), and atomic writes.

Every writer writes to a temporary name in the destination folder and renames it when complete,
so an interrupted write never leaves a file that looks finished.
"""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from .color import to_srgb8

_UMASK = os.umask(0)
os.umask(_UMASK)

__all__ = ["atomic_path", "write_exr", "read_exr", "write_png", "read_png", "write_preview"]


@contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; rename it to ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".partial{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; finished files get the usual mode
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _check_finite(image: np.ndarray, path) -> None:
    if not np.all(np.isfinite(image)):
        raise ValueError(f"{path}: refusing to write non-finite values")


def write_exr(path, image: np.ndarray) -> None:
    """Write (H, W), (H, W, 1) or (H, W, 3) float data as a float32 OpenEXR (channels Y or RGB)."""
    a = np.asarray(image, dtype=np.float32)
    _check_finite(a, path)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim == 2:
        channels = {"Y": np.ascontiguousarray(a)}
    elif a.ndim == 3 and a.shape[2] == 3:
        channels = {"RGB": np.ascontiguousarray(a)}
    else:
        raise ValueError(f"write_exr: unsupported shape {a.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, channels) as f:
            f.write(str(tmp))


def read_exr(path) -> np.ndarray:
    """Read an OpenEXR written by :func:`write_exr`: (H, W, 3) or (H, W) float32."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such image")
    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.asarray(ch["RGB"].pixels, dtype=np.float32)
        if "Y" in ch:
            return np.asarray(ch["Y"].pixels, dtype=np.float32)
        if all(c in ch for c in "RGB"):
            return np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
        raise ValueError(f"{path}: no RGB or Y channels (has {sorted(ch)})")


def write_png(path, image: np.ndarray) -> None:
    """Write a uint8 (H, W), (H, W, 3) or (H, W, 4) image as PNG, atomically."""
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise ValueError(f"write_png expects uint8, got {a.dtype}")
    with atomic_path(path) as tmp:
        Image.fromarray(a).save(tmp, format="PNG")


def read_png(path) -> np.ndarray:
    """Read a PNG as uint8 array."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such image")
    return np.asarray(Image.open(path))


def write_preview(path, linear: np.ndarray, exposure: float = 1.0) -> None:
    """Write the sRGB uint8 PNG preview of linear radiance (H, W, 3)."""
    write_png(path, to_srgb8(linear, exposure))
