"""Reading and writing the stages' files: checked EXR images, CSV tables, error images.

Every reader raises :class:`pipeline.artifacts.BadInput` with one line naming the file (the CLI
turns it into exit 2); every writer is atomic (:func:`render.image_io.atomic_path`), so an
interrupted write never leaves a file that looks finished.
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from render.color import to_srgb8
from render.image_io import atomic_path, read_exr

from .artifacts import BadInput

__all__ = ["read_image", "write_csv", "error_image"]


def read_image(path: Path, shape: tuple[int, ...] | None = None, grey_to_rgb: bool = False,
               shape_of: str = "") -> np.ndarray:
    """A linear EXR image as float32, (H, W) or (H, W, C), checked: BadInput naming ``path`` when
    it is missing, unreadable, not of ``shape`` (when given) or holds a non-finite pixel.

    grey_to_rgb: a single-channel image is repeated to ``shape``'s channel count when ``shape`` is
    (H, W, C) (a model may render grey); shape_of: says in the error whose shape ``shape`` is."""
    path = Path(path)
    if not path.is_file():
        raise BadInput(f"{path}: file not found")
    try:
        a = read_exr(path)
    except ValueError as exc:  # read_exr names the file and OpenEXR's reason
        raise BadInput(str(exc).splitlines()[0]) from None
    if grey_to_rgb and a.ndim == 2 and shape is not None and len(shape) == 3:
        a = np.repeat(a[..., None], shape[2], axis=2)
    if shape is not None and a.shape != tuple(shape):
        raise BadInput(f"{path}: shape {a.shape}, expected {tuple(shape)}" + (f" ({shape_of})" if shape_of else ""))
    if not np.all(np.isfinite(a)):
        raise BadInput(f"{path}: non-finite pixels")
    return a


def write_csv(path: Path, rows: list[dict], columns: list[str] | tuple[str, ...], float_format: str = ".6g") -> None:
    """A CSV table with a header of ``columns`` and one line per row (keys beyond ``columns``
    ignored, missing values and None empty), floats formatted by ``float_format`` (None: repr,
    every digit kept), written atomically with Unix line ends."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if r.get(k) is None
                    else (format(r[k], float_format) if float_format and isinstance(r[k], float) else r[k])
                    for k in columns})
    with atomic_path(Path(path)) as tmp:
        Path(tmp).write_text(buf.getvalue())


def error_image(render: np.ndarray, ref: np.ndarray, gain: float) -> np.ndarray:
    """(H, W, 3) uint8 grey sRGB preview of |render - ref| averaged over RGB, times ``gain``;
    render and ref are (H, W, 3) linear images."""
    err = np.abs(render.astype(np.float32) - ref).mean(axis=2, keepdims=True)
    return to_srgb8(np.repeat(err, 3, axis=2), gain)
