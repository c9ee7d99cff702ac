"""Slab-set files: ``slabs.json`` plus one memory-mappable ``.npy`` per array.

A slab set in a folder::

    slabs.json                 format, and per slab: geometry (corners, shape), focal_depth,
                               the file names of its arrays, and the array conventions in words
    <name>.radiance.npy        (Nv, Nu, Nt, Ns, 3) float32 or float16 linear RGB (see :mod:`render.lightfield.geometry`)
    <name>.depth.npy           (Nv, Nu, Nt, Ns) float32 or float16 distance from the uv plane, 0 = empty (optional)

or, for a vector-quantized slab (:class:`render.lightfield.geometry.VQRadiance`; ``radiance`` is null and
``vq`` names the files)::

    <name>.codes.npy.xz        (Tv, Tu, Tt, Ts) uint16 codewords, a .npy stream compressed by LZMA
                               (the paper's lossless stage; loaded into memory, ~1/6 of the raw codes)
    <name>.depth.npy.xz        the depth as float16, LZMA-compressed (when the encoder rounded it to
                               float16), else <name>.depth.npy as above
    codebook.npy               (K, 2, 2, 2, 2, 3) float16 tiles, shared by the slabs that share it
                               (float32 in memory; encoders round to float16 first)

Arrays are plain NumPy ``.npy`` files so ``np.load(mmap_mode="r")`` maps them without reading.
Large slabs are filled in place: :func:`create_slab_arrays` opens writable memmaps. Every
writer is atomic per file (:func:`render.image_io.atomic_path`) and refuses non-finite values.
"""
from __future__ import annotations

import io
import json
import lzma
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..image_io import atomic_path
from .geometry import SAMPLE_DTYPES, LightSlab, SlabGeometry, VQRadiance

__all__ = ["SLABS_JSON", "SLABS_FORMAT", "create_slab_arrays", "write_slab_index", "save_slabs", "load_slabs",
           "slab_file_bytes"]

SLABS_JSON = "slabs.json"
SLABS_FORMAT = "lumigraph.slabs/1"

_CONVENTION = {
    "corners": "world corners in the order (0,0), (1,0), (1,1), (0,1); u/s along corner1-corner0, v/t along corner3-corner0",
    "orientation": "forward = e_s x e_t points from the uv plane to the st plane; radiance seen by eye rays along +forward",
    "samples": "sample i of N sits at (i + 0.5) / N (cell centres)",
    "radiance": "(Nv, Nu, Nt, Ns, 3) float32 or float16 linear RGB (the .npy header says which)",
    "depth": "(Nv, Nu, Nt, Ns) float32 or float16 distance along forward from the uv plane to the first surface, 0 = empty",
    "vq": "radiance[iv, iu, it, is] = codebook[codes[iv // 2, iu // 2, it // 2, is // 2], iv % 2, iu % 2, it % 2, is % 2]; "
          "codes LZMA-compressed .npy, codebook (K, 2, 2, 2, 2, 3) float16",
}


def _names(geom: SlabGeometry, slab: LightSlab | None = None) -> tuple[str, str]:
    """File names of a slab's radiance and depth arrays; a compressed slab whose depth is exactly
    float16 keeps it as an LZMA-compressed float16 .npy stream."""
    if not geom.name or any(ch in geom.name for ch in "/\\ ") or geom.name.startswith("."):
        raise ValueError(f"slab name {geom.name!r} cannot be a file name")
    if slab is not None and slab.compressed and slab.depth is not None and _is_float16(slab.depth):
        return f"{geom.name}.radiance.npy", f"{geom.name}.depth.npy.xz"
    return f"{geom.name}.radiance.npy", f"{geom.name}.depth.npy"


def _is_float16(a: np.ndarray) -> bool:
    a = np.asarray(a)
    return a.dtype == np.float16 or bool(np.array_equal(a.astype(np.float16).astype(np.float32), a))


def create_slab_arrays(folder, geom: SlabGeometry, with_depth: bool = True, dtype=np.float32
                       ) -> tuple[np.memmap, np.memmap | None]:
    """Create zero-filled writable memmaps for a slab's radiance (and depth) in ``folder``, of
    ``dtype`` (float32 or float16: :data:`render.lightfield.geometry.SAMPLE_DTYPES`).

    The caller fills them and then calls :func:`write_slab_index`; until the index names them,
    the arrays are not part of a slab set (pipeline stages write into an atomic stage folder).
    """
    dtype = np.dtype(dtype)
    if dtype not in SAMPLE_DTYPES:
        raise ValueError(f"slab sample dtype must be float32 or float16, got {dtype}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rad_name, depth_name = _names(geom)
    rad = np.lib.format.open_memmap(folder / rad_name, mode="w+", dtype=dtype, shape=geom.array_shape)
    depth = None
    if with_depth:
        depth = np.lib.format.open_memmap(folder / depth_name, mode="w+", dtype=dtype, shape=geom.array_shape[:4])
    return rad, depth


def _codebook_names(slabs: Sequence[LightSlab]) -> list[str | None]:
    """File name of each VQ slab's codebook: ``codebook.npy`` for the first codebook (and every
    slab sharing its array), ``<name>.codebook.npy`` for any other; None for plain slabs."""
    first, names = None, []
    for s in slabs:
        if not isinstance(s.radiance, VQRadiance):
            names.append(None)
            continue
        cb = s.radiance.codebook
        if first is None:
            first = cb
        names.append("codebook.npy" if cb is first or np.shares_memory(cb, first) else f"{s.geometry.name}.codebook.npy")
    return names


def write_slab_index(folder, slabs: Sequence[LightSlab], check: bool = True) -> Path:
    """Write ``slabs.json`` for slabs whose arrays already are in ``folder`` (flushed here).

    ``check`` scans every array for non-finite values (the arrays must never carry NaN/Inf).
    """
    folder = Path(folder)
    entries = []
    names = [s.geometry.name for s in slabs]
    if len(set(names)) != len(names):
        raise ValueError(f"slab names must be unique, got {names}")
    for s, cb_name in zip(slabs, _codebook_names(slabs)):
        rad_name, depth_name = _names(s.geometry, s)
        vq = None
        if isinstance(s.radiance, VQRadiance):
            vq = {"codes": f"{s.geometry.name}.codes.npy.xz", "codebook": cb_name}
            arrays = ((s.radiance.codebook, cb_name), (s.depth, depth_name))
            files = [vq["codes"], cb_name]
        else:
            arrays = ((s.radiance, rad_name), (s.depth, depth_name))
            files = [rad_name]
        for arr, fname in arrays:
            if arr is None:
                continue
            if isinstance(arr, np.memmap):
                arr.flush()
            if check and not np.all(np.isfinite(arr)):
                raise ValueError(f"{folder / fname}: refusing to write non-finite values")
            files.append(fname)
        for fname in files:
            if not (folder / fname).is_file():
                raise ValueError(f"{folder / fname}: array file missing (use create_slab_arrays or save_slabs)")
        entries.append({**s.geometry.to_dict(), "focal_depth": s.focal_depth, "radiance": None if vq else rad_name,
                        "depth": None if s.depth is None else depth_name, **({"vq": vq} if vq else {})})
    doc = {"format": SLABS_FORMAT, "convention": _CONVENTION, "slabs": entries}
    out = folder / SLABS_JSON
    with atomic_path(out) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    return out


#: LZMA preset of the float16 depth stream (codes keep preset 6: they are 15x smaller)
DEPTH_XZ_PRESET = 1


def _sample_dtype(arr: np.ndarray) -> np.dtype:
    """The dtype a sample array is stored in: its own, float32 or float16."""
    return np.dtype(np.float16) if np.asarray(arr).dtype == np.float16 else np.dtype(np.float32)


def _save_npy(path: Path, arr: np.ndarray, dtype) -> None:
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{path}: refusing to write non-finite values")
    with atomic_path(path) as tmp:
        np.save(tmp, np.ascontiguousarray(arr, dtype=dtype))


def save_slabs(folder, slabs: Sequence[LightSlab]) -> Path:
    """Write in-memory slabs (arrays and index) to ``folder``; returns the index path.

    Vector-quantized slabs are written as LZMA-compressed codes and a float16 codebook (refused
    if the codebook does not round-trip through float16 exactly)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = set()
    for s, cb_name in zip(slabs, _codebook_names(slabs)):
        rad_name, depth_name = _names(s.geometry, s)
        if isinstance(s.radiance, VQRadiance):
            cb = s.radiance.codebook
            if cb_name not in written:
                if not np.array_equal(cb.astype(np.float16).astype(np.float32), cb):
                    raise ValueError(f"{folder / cb_name}: codebook values are not float16 (round them before encoding)")
                _save_npy(folder / cb_name, cb, np.float16)
                written.add(cb_name)
            buf = io.BytesIO()
            np.save(buf, np.ascontiguousarray(s.radiance.codes))
            with atomic_path(folder / f"{s.geometry.name}.codes.npy.xz") as tmp:
                Path(tmp).write_bytes(lzma.compress(buf.getvalue(), preset=6))
        else:
            _save_npy(folder / rad_name, s.radiance, _sample_dtype(s.radiance))
        if s.depth is not None:
            if depth_name.endswith(".xz"):
                if not np.all(np.isfinite(s.depth)):
                    raise ValueError(f"{folder / depth_name}: refusing to write non-finite values")
                buf = io.BytesIO()
                np.save(buf, np.ascontiguousarray(s.depth, dtype=np.float16))
                with atomic_path(folder / depth_name) as tmp:
                    # preset 1: at the pixel footprint preset 6 took ~12 s per 16 MB of depth (the
                    # stage's longest step) for a 1.6x smaller file; preset 1 is ~9x faster
                    Path(tmp).write_bytes(lzma.compress(buf.getvalue(), preset=DEPTH_XZ_PRESET))
            else:
                _save_npy(folder / depth_name, s.depth, _sample_dtype(s.depth))
    return write_slab_index(folder, slabs, check=False)


def slab_file_bytes(folder) -> dict[str, int]:
    """Bytes on disk of a slab set's files by kind: radiance (float32 arrays), codes, codebook, depth."""
    folder = Path(folder)
    out = {"radiance": 0, "codes": 0, "codebook": 0, "depth": 0}
    for p in folder.iterdir():
        for kind, suffix in (("radiance", ".radiance.npy"), ("codes", ".codes.npy.xz"), ("codebook", "codebook.npy"),
                             ("depth", ".depth.npy"), ("depth", ".depth.npy.xz")):
            if p.name.endswith(suffix):
                out[kind] += p.stat().st_size
    return out


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
    slabs, codebooks = [], {}
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
                if path.name.endswith(".xz"):
                    arrays.append(_load_xz(path))  # float16, as stored
                else:
                    arrays.append(np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False))
            if arrays[0] is None:
                arrays[0] = _load_vq(folder, e["vq"], geom, codebooks)
            slabs.append(LightSlab(geom, arrays[0], arrays[1], e.get("focal_depth")))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{index}: slab {i} malformed ({exc})") from None
    return slabs


def _load_vq(folder: Path, vq: dict, geom: SlabGeometry, codebooks: dict) -> VQRadiance:
    """A VQ slab's codes (decompressed into memory) and its codebook (float32, shared by name)."""
    path = folder / vq["codes"]
    cb_path = folder / vq["codebook"]
    for p in (path, cb_path):
        if not p.is_file():
            raise ValueError(f"{p}: missing slab array")
    codes = _load_xz(path)
    if vq["codebook"] not in codebooks:
        cb = np.load(cb_path, allow_pickle=False)
        if cb.dtype != np.float16 or not np.all(np.isfinite(cb)):
            raise ValueError(f"{cb_path}: codebook must be finite float16")
        codebooks[vq["codebook"]] = cb.astype(np.float32)
    try:
        return VQRadiance(codes, codebooks[vq["codebook"]], geom.array_shape)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _load_xz(path: Path) -> np.ndarray:
    """An LZMA-compressed .npy stream, decompressed into memory."""
    try:
        return np.load(io.BytesIO(lzma.decompress(path.read_bytes())), allow_pickle=False)
    except (lzma.LZMAError, ValueError, EOFError) as exc:
        raise ValueError(f"{path}: unreadable compressed array ({type(exc).__name__})") from None
