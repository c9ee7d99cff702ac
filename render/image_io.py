"""Image I/O: linear OpenEXR (float32), PNG previews (sRGB uint8), and atomic writes.

Every writer writes to a temporary name in the destination folder and renames it when complete,
so an interrupted write never leaves a file that looks finished.
"""
from __future__ import annotations

import os
import sys
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from .color import to_srgb8

_UMASK = os.umask(0)
os.umask(_UMASK)

__all__ = ["atomic_path", "write_exr", "write_depth_exr", "read_exr", "exr_size", "write_png", "read_png", "png_size",
           "write_preview", "DEPTH_CHANNEL", "SINGLE_CHANNELS"]

#: the channel a depth image is written in: OpenEXR's standard name for depth (Blender, Nuke, pbrt and
#: the depth tools look for it); ``Y`` means luminance
DEPTH_CHANNEL = "Z"
#: single-channel names the reader accepts, in order of preference: ``Z`` (depth, written since issue
#: 18), ``Y`` (luminance: every other single-channel image, and depth written before issue 18)
SINGLE_CHANNELS = ("Z", "Y")

#: one native-output redirection at a time: file descriptors are process-wide
_NATIVE_OUTPUT_LOCK = threading.Lock()


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


def write_exr(path, image: np.ndarray, channel: str = "Y") -> None:
    """Write (H, W), (H, W, 1) or (H, W, 3) float data as a float32 OpenEXR: RGB for three
    channels, else the one channel named ``channel`` (``Y``, luminance, by default; depth goes
    through :func:`write_depth_exr`, channel ``Z``)."""
    if channel not in SINGLE_CHANNELS:
        raise ValueError(f"write_exr: single channel must be one of {SINGLE_CHANNELS}, got {channel!r}")
    a = np.asarray(image, dtype=np.float32)
    _check_finite(a, path)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim == 2:
        channels = {channel: np.ascontiguousarray(a)}
    elif a.ndim == 3 and a.shape[2] == 3:
        channels = {"RGB": np.ascontiguousarray(a)}
    else:
        raise ValueError(f"write_exr: unsupported shape {a.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, channels) as f:
            f.write(str(tmp))


def write_depth_exr(path, depth: np.ndarray) -> None:
    """Write a (H, W) float z-depth image (metres along the optical axis, 0 where nothing was hit)
    as a float32 OpenEXR in channel ``Z`` (:data:`DEPTH_CHANNEL`)."""
    write_exr(path, depth, channel=DEPTH_CHANNEL)


@contextmanager
def _native_output_captured():
    """Collect what native libraries print on file descriptors 1 and 2 during the block.

    OpenEXR's C/C++ core reports a corrupt file on stdout and stderr itself before raising, which
    would put extra lines before our one-line error. Yields ``{fd: bytes}`` filled when the block
    ends; the caller decides whether to re-emit (success: warnings are kept) or drop them (the
    failure becomes one exception naming the file). Serialised by a lock: descriptors are
    process-wide, and two interleaved redirections would leave one restored to the other's sink."""
    captured: dict[int, bytes] = {}
    with _NATIVE_OUTPUT_LOCK:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (AttributeError, ValueError, OSError):
                pass
        saved = {fd: os.dup(fd) for fd in (1, 2)}
        sinks = {fd: tempfile.TemporaryFile() for fd in (1, 2)}
        try:
            for fd, sink in sinks.items():
                os.dup2(sink.fileno(), fd)
            yield captured
        finally:
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
            for fd, sink in sinks.items():
                sink.seek(0)
                captured[fd] = sink.read()
                sink.close()


def _reemit(captured: dict[int, bytes]) -> None:
    for fd, text in captured.items():
        if text:
            os.write(fd, text)


def _native_reason(captured: dict[int, bytes], path: Path, exc: Exception) -> str:
    """The first line OpenEXR printed (its own path prefix removed), else the exception's."""
    for fd in (2, 1):
        for line in captured.get(fd, b"").decode("utf-8", "replace").splitlines():
            line = line.strip().removeprefix(f"{path}:").strip()
            if line:
                return line
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _read_openexr(path, read, **open_kw):
    """``read(f)`` on the opened OpenEXR file ``path``. FileNotFoundError when absent; ValueError,
    one line naming the file, when OpenEXR cannot read it: what its native core prints about a
    corrupt file goes into that line instead of the terminal (kept and re-emitted on success)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such image")
    error = None
    with _native_output_captured() as captured:
        try:
            with OpenEXR.File(str(path), **open_kw) as f:
                result = read(f)
        except Exception as exc:  # OpenEXR raises assorted types (RuntimeError, ValueError, ...) on corrupt files
            error = exc
    if error is not None:
        raise ValueError(f"{path}: unreadable EXR image ({_native_reason(captured, path, error)})") from None
    _reemit(captured)
    return result


def _exr_pixels(f) -> np.ndarray:
    ch = f.channels()
    if "RGB" in ch:
        return np.asarray(ch["RGB"].pixels, dtype=np.float32)
    for name in SINGLE_CHANNELS:
        if name in ch:
            return np.asarray(ch[name].pixels, dtype=np.float32)
    if all(c in ch for c in "RGB"):
        return np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
    raise ValueError(f"no RGB, Z or Y channels (has {sorted(ch)})")


def read_exr(path) -> np.ndarray:
    """Read an OpenEXR written by :func:`write_exr`: (H, W, 3) or (H, W) float32.

    Single-channel images are read from ``Z`` (depth) or ``Y`` (luminance; depth written before
    issue 18 used it). FileNotFoundError when absent; ValueError, one line naming the file, when
    the file is not a readable OpenEXR image (truncated, corrupt, no RGB, Z or Y channels). Nothing is printed: what
    OpenEXR's native core prints about a corrupt file goes into that line instead."""
    return _read_openexr(path, _exr_pixels)


def exr_size(path) -> tuple[int, int]:
    """(width, height) of an OpenEXR image from its header alone (ValueError naming the file when
    the header is unreadable)."""
    (x0, y0), (x1, y1) = _read_openexr(path, lambda f: f.header()["dataWindow"], header_only=True)
    return int(x1 - x0 + 1), int(y1 - y0 + 1)


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


def png_size(path) -> tuple[int, int]:
    """(width, height) of a PNG from its header (ValueError naming the file when it is not a PNG)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such image")
    try:
        with Image.open(path) as im:
            if im.format != "PNG":
                raise ValueError(f"a {im.format} image")
            return int(im.width), int(im.height)
    except (OSError, ValueError, SyntaxError) as exc:  # PIL.UnidentifiedImageError is an OSError
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"{path}: not a readable PNG image ({reason.replace(str(path), 'file')})") from None


def write_preview(path, linear: np.ndarray, exposure: float = 1.0) -> None:
    """Write the sRGB uint8 PNG preview of linear radiance (H, W, 3)."""
    write_png(path, to_srgb8(linear, exposure))
