"""The ``export`` verb: a capture written as nerfstudio, instant-ngp or COLMAP open it
(:mod:`pipeline.export` holds the formats). One stage folder, atomic, with a manifest::

    export/nerfstudio/    transforms.json images/ masks/ depth/ (16-bit PNG, millimetres)
    export/instant-ngp/   train/ test/ train_linear/ test_linear/ (each: transforms.json images/ depth/)
    export/colmap/        images/ sparse/0/ (binary model with 3D points)
"""
from __future__ import annotations

from pathlib import Path

from ..artifacts import BadInput, Manifest, atomic_stage, check_out
from ..export import EXPORTERS, FORMATS
from ..progress import progress_bar
from .capture import check_capture_folder

__all__ = ["run_export"]


def run_export(capture_dir: Path, fmt: str, out: Path, quiet: bool = False, overwrite: bool = False) -> dict:
    """Export the capture ``capture_dir`` as ``fmt`` (:data:`FORMATS`) into ``out`` atomically.

    BadInput (one line naming the option, file or field), before anything is written, for an
    unknown format, a folder that is not a finished capture (or lacks a view's image, mask, depth
    or linear file) and an ``out`` holding anything but a finished export unless ``overwrite``."""
    if fmt not in FORMATS:
        raise BadInput(f"--format: unknown format {fmt!r} (known: {', '.join(FORMATS)})")
    out = Path(out)
    check_out(out, "export", overwrite)
    need = ("images", "linear", "depth", "masks")
    cams, splits = check_capture_folder(Path(capture_dir), need=need)
    manifest = Manifest("export", params={"format": fmt, "capture": str(capture_dir)})
    manifest.add_input(Path(capture_dir) / "cameras.json")
    writer = EXPORTERS[fmt]
    with atomic_stage(out, "export", overwrite) as tmp, progress_bar(quiet) as bar:
        task = bar.add_task(f"export {fmt}", total=len(cams))
        manifest.metrics = writer(tmp, Path(capture_dir), cams, splits, bar, task)
        result = manifest.write(tmp)
    return result
