"""Loaded scenes cached on disk, so a command that renders a scene it has loaded before skips the
schema: importing pydantic and building the spec's models costs ~0.15 s of the ~0.3 s a
one-sample ``lumigraph reference`` needs (bench/bench_startup.py).

An entry is the pickled :class:`rig.rig_scene.RigScene` (its spec kept as the file's bytes and
validated only if read), keyed by

* the scene file's resolved path and the SHA-256 of its bytes,
* the sources of rig/ and render/ (any edit starts new entries), Python's and numpy's versions,

and checked on every hit against the size and modification time of each file the spec names
(textures, density grids; for an image bundled with scikit-image, its ``skimage.data`` module;
for a ChArUco board, the ``cv2`` package that drew it). A scene that names a mesh file is not cached: trimesh may read files
the mesh names in turn (an OBJ's materials), which the key could not see. Only a scene that loaded
without error is stored, so every refusal of bad input happens as before.

Where: ``$LUMIGRAPH_CACHE_DIR/scenes`` (default ``$XDG_CACHE_HOME/lumigraph`` or
``~/.cache/lumigraph``), a folder of this user's that nobody else can write (else the cache is
not used: an entry is a pickle); at most :data:`MAX_ENTRIES` entries of at most
:data:`MAX_ENTRY_BYTES` each, the least recently used removed first. ``LUMIGRAPH_SCENE_CACHE=0``
turns it off. The cache holds only copies: removing the folder loses nothing.
"""
from __future__ import annotations

import hashlib
import os
import pickle
import stat
import sys
import tempfile
from pathlib import Path

from .rig_scene import RigScene
from .scene_file import file_stamp, read_spec_bytes, recording_reads, resolve_scene_path

__all__ = ["load_scene", "cache_dir", "MAX_ENTRIES", "MAX_ENTRY_BYTES"]

MAX_ENTRIES = 64
MAX_ENTRY_BYTES = 64 * 1024 * 1024
_RIG = Path(__file__).resolve().parent
_FORMAT = 1


def cache_dir() -> Path | None:
    """The folder entries live in, or None when the cache is off (``LUMIGRAPH_SCENE_CACHE=0``)."""
    if os.environ.get("LUMIGRAPH_SCENE_CACHE", "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    base = os.environ.get("LUMIGRAPH_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "lumigraph")
    return Path(base) / "scenes"


def _private(folder: Path) -> bool:
    """The folder is this user's and nobody else can write to it (pickles are code)."""
    try:
        st = folder.stat()
    except OSError:
        return False
    return stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and not st.st_mode & 0o022


def _key(path: Path, raw: bytes) -> str:
    import numpy as np

    from render._kernel_cache import render_digest, sources_digest

    h = hashlib.sha256()
    for part in (str(_FORMAT), str(path), hashlib.sha256(raw).hexdigest(), sources_digest(_RIG), render_digest(),
                 sys.version, np.__version__):
        h.update(part.encode("utf-8", "surrogateescape") + b"\0")
    return h.hexdigest()[:32]


def _read(entry: Path) -> RigScene | None:
    """The entry's scene if it is whole and every file it read is unchanged, else None."""
    try:
        with open(entry, "rb") as f:
            record = pickle.load(f)
        if record.get("format") != _FORMAT or not isinstance(record.get("rig"), RigScene):
            return None
        if any(file_stamp(Path(p)) != tuple(s) for p, s in record["reads"]):
            return None
        os.utime(entry)  # least recently used goes first
        return record["rig"]
    except Exception:  # a truncated, foreign or unreadable entry is a miss, never an error
        return None


def _write(folder: Path, entry: Path, rig: RigScene, reads: list[tuple[Path, str, tuple[int, int] | None]]) -> None:
    stamps = [(str(p.resolve()), stamp) for p, _, stamp in reads]  # absolute: a hit may come from another folder
    if any(s is None for _, s in stamps):
        return
    data = pickle.dumps({"format": _FORMAT, "reads": stamps, "rig": rig}, protocol=pickle.HIGHEST_PROTOCOL)
    if len(data) > MAX_ENTRY_BYTES:
        return
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=".pkl")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, entry)
    except BaseException:
        os.unlink(tmp)
        raise
    entries = sorted(folder.glob("*.pkl"), key=lambda p: p.stat().st_mtime_ns)
    for old in entries[:-MAX_ENTRIES]:
        old.unlink(missing_ok=True)


def load_scene(scene: str | Path) -> RigScene:
    """:func:`rig.build.load_scene` through the cache: the same scene (SpecError on bad input)."""
    path = resolve_scene_path(scene)
    folder = cache_dir()
    if folder is not None:
        try:
            folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        except OSError:
            folder = None
    if folder is None or not _private(folder):
        from .build import load_scene as load_uncached

        return load_uncached(scene)
    raw = read_spec_bytes(path)
    resolved = path.resolve()  # the entry's spec source: a hit may come from another working folder
    entry = folder / f"{_key(resolved, raw)}.pkl"
    rig = _read(entry) if entry.is_file() else None
    if rig is not None:
        return rig
    from .build import load_scene as load_uncached

    with recording_reads() as reads:
        rig = load_uncached(path, raw)
    if not any(field.endswith("mesh.file") for _, field, _ in reads):
        cached = RigScene(None, rig.scene, rig.cameras, rig.targets, spec_source=(resolved, raw))
        try:
            _write(folder, entry, cached, reads)
        except OSError:  # a full disk or a read-only cache costs the next run time, nothing else
            pass
    return rig
