"""Slab-set files: ``slabs.json`` plus one memory-mappable ``.npy`` per array.

A slab set in a folder::

    slabs.json                 format, and per slab: geometry (corners, shape), focal_depth,
                               the file names of its arrays, and the array conventions in words
    <name>.radiance.npy        (Nv, Nu, Nt, Ns, 3) float32 linear RGB (see :mod:`render.slab`)
    <name>.depth.npy           (Nv, Nu, Nt, Ns) float32 distance from the uv plane, 0 = empty (optional)

Arrays are plain NumPy ``.npy`` files so ``np.load(mmap_mode="r")`` maps them without reading.
Large slabs are filled in place: :func:`create_slab_arrays` opens writable memmaps. Every
writer is atomic per file (:func:`render.image_io.atomic_path`) and refuses non-finite values.
"""
from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .image_io import atomic_path
from .slab import LightSlab, SlabGeometry

__all__ = ["SLABS_JSON", "SLABS_FORMAT", "create_slab_arrays", "write_slab_index", "save_slabs", "load_slabs"]

SLABS_JSON = "slabs.json"
SLABS_FORMAT = "lumigraph.slabs/1"

_CONVENTION = {
    "corners": "world corners in the order (0,0), (1,0), (1,1), (0,1); u/s along corner1-corner0, v/t along corner3-corner0",
    "orientation": "forward = e_s x e_t points from the uv plane to the st plane; radiance seen by eye rays along +forward",
    "samples": "sample i of N sits at (i + 0.5) / N (cell centres)",
    "radiance": "(Nv, Nu, Nt, Ns, 3) float32 linear RGB",
    "depth": "(Nv, Nu, Nt, Ns) float32 distance along forward from the uv plane to the first surface, 0 = empty",
}


def _names(geom: SlabGeometry) -> tuple[str, str]:
    if not geom.name or any(ch in geom.name for ch in "/\\ ") or geom.name.startswith("."):
        raise ValueError(f"slab name {geom.name!r} cannot be a file name")
    return f"{geom.name}.radiance.npy", f"{geom.name}.depth.npy"


def create_slab_arrays(folder, geom: SlabGeometry, with_depth: bool = True
                       ) -> tuple[np.memmap, np.memmap | None]:
    """Create zero-filled writable memmaps for a slab's radiance (and depth) in ``folder``.

    The caller fills them and then calls :func:`write_slab_index`; until the index names them,
    the arrays are not part of a slab set (pipeline stages write into an atomic stage folder).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rad_name, depth_name = _names(geom)
    rad = np.lib.format.open_memmap(folder / rad_name, mode="w+", dtype=np.float32, shape=geom.array_shape)
    depth = None
    if with_depth:
        depth = np.lib.format.open_memmap(folder / depth_name, mode="w+", dtype=np.float32, shape=geom.array_shape[:4])
    return rad, depth


def write_slab_index(folder, slabs: Sequence[LightSlab], check: bool = True) -> Path:
    """Write ``slabs.json`` for slabs whose arrays already are in ``folder`` (flushed here).

    ``check`` scans every array for non-finite values (the arrays must never carry NaN/Inf).
    """
    folder = Path(folder)
    entries = []
    names = [s.geometry.name for s in slabs]
    if len(set(names)) != len(names):
        raise ValueError(f"slab names must be unique, got {names}")
    for s in slabs:
        rad_name, depth_name = _names(s.geometry)
        for arr, fname in ((s.radiance, rad_name), (s.depth, depth_name)):
            if arr is None:
                continue
            if isinstance(arr, np.memmap):
                arr.flush()
            if check and not np.all(np.isfinite(arr)):
                raise ValueError(f"{folder / fname}: refusing to write non-finite values")
            if not (folder / fname).is_file():
                raise ValueError(f"{folder / fname}: array file missing (use create_slab_arrays or save_slabs)")
        entries.append({**s.geometry.to_dict(), "focal_depth": s.focal_depth, "radiance": rad_name,
                        "depth": None if s.depth is None else depth_name})
    doc = {"format": SLABS_FORMAT, "convention": _CONVENTION, "slabs": entries}
    out = folder / SLABS_JSON
    with atomic_path(out) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    return out


def save_slabs(folder, slabs: Sequence[LightSlab]) -> Path:
    """Write in-memory slabs (arrays and index) to ``folder``; returns the index path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for s in slabs:
        rad_name, depth_name = _names(s.geometry)
        for arr, fname in ((s.radiance, rad_name), (s.depth, depth_name)):
            if arr is None:
                continue
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{folder / fname}: refusing to write non-finite values")
            with atomic_path(folder / fname) as tmp:
                np.save(tmp, np.ascontiguousarray(arr, dtype=np.float32))
    return write_slab_index(folder, slabs, check=False)


def load_slabs(folder, mmap: bool = True) -> list[LightSlab]:
    """Read a slab set; arrays are memory-mapped read-only when ``mmap``.

    Raises ValueError (one line naming the file or field) on a missing or malformed set.
    """
    folder = Path(folder)
    index = folder / SLABS_JSON
    if not index.is_file():
        raise ValueError(f"{index}: no slab index")
    try:
        doc = json.loads(index.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{index}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    if doc.get("format") != SLABS_FORMAT or not isinstance(doc.get("slabs"), list) or not doc["slabs"]:
        raise ValueError(f"{index}: not a {SLABS_FORMAT} slab set")
    slabs = []
    for i, e in enumerate(doc["slabs"]):
        try:
            geom = SlabGeometry.from_dict(e)
            arrays = []
            for key in ("radiance", "depth"):
                if e.get(key) is None:
                    arrays.append(None)
                    continue
                path = folder / e[key]
                if not path.is_file():
                    raise ValueError(f"{path}: missing slab array")
                arrays.append(np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False))
            slabs.append(LightSlab(geom, arrays[0], arrays[1], e.get("focal_depth")))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{index}: slab {i} malformed ({exc})") from None
    return slabs
