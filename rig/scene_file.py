"""What a scene file is before its schema: its error type, the built-in scenes' folder, and how a
name or path names a file. Standard library only, so the scene cache (:mod:`rig.scene_cache`)
can find a file and refuse a bad name without importing the schema (pydantic) or YAML.
:mod:`rig.spec` re-exports all of it."""
from __future__ import annotations

import unicodedata
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

__all__ = ["SpecError", "SCENES_DIR", "MAX_SPEC_BYTES", "resolve_scene_path", "read_spec_bytes", "recording_reads", "note_read"]

SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"
#: size of a spec file
MAX_SPEC_BYTES = 4 * 1024 * 1024


class SpecError(ValueError):
    """A scene spec is malformed; the message is one line naming the file and field.

    Characters that could break the line or fool a terminal (controls, line separators,
    surrogates) are shown as escapes, whatever the spec put in a name.
    """

    def __init__(self, message: str):
        super().__init__(_printable(str(message)))


def _printable(text: str) -> str:
    return "".join(c if unicodedata.category(c)[0] != "C" and c not in "\u2028\u2029"
                   else c.encode("unicode_escape", "backslashreplace").decode("ascii") for c in text)


def resolve_scene_path(scene: str | Path) -> Path:
    """A built-in scene name (``scenes/<name>.yaml``) or a path to a YAML file."""
    p = Path(scene)
    try:
        if p.suffix in (".yaml", ".yml") or p.exists():
            if not p.is_file():
                raise SpecError(f"{p}: scene file not found")
            return p
        builtin = SCENES_DIR / f"{scene}.yaml"
        found = builtin.is_file()
    except (OSError, ValueError) as exc:  # a name too long, a NUL byte, a permission
        if isinstance(exc, SpecError):
            raise
        raise SpecError(f"{scene}: not a readable scene file ({type(exc).__name__})") from None
    if not found:
        known = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.yaml")))
        raise SpecError(f"{scene}: not a scene file nor a built-in scene (built-in: {known})")
    return builtin


def read_spec_bytes(path: Path) -> bytes:
    """The bytes of the spec file ``path``, or SpecError (one line) for one too large to read."""
    try:
        size = path.stat().st_size
        if size > MAX_SPEC_BYTES:
            raise SpecError(f"{path}: the spec file is {size} bytes, at most {MAX_SPEC_BYTES}")
        with open(path, "rb") as f:
            raw = f.read(MAX_SPEC_BYTES + 1)
    except OSError as exc:
        raise SpecError(f"{path}: cannot read the scene file ({exc.strerror or type(exc).__name__})") from None
    if len(raw) > MAX_SPEC_BYTES:  # a file that grew, or one whose size the filesystem does not report
        raise SpecError(f"{path}: the spec file is larger than {MAX_SPEC_BYTES} bytes")
    return raw


#: the files a scene build read (path, spec field, (mtime_ns, size) or None), while
#: :func:`recording_reads` is active
_reads: ContextVar[list[tuple[Path, str, tuple[int, int] | None]] | None] = ContextVar("lumigraph_scene_reads",
                                                                                      default=None)


def file_stamp(path: Path) -> tuple[int, int] | None:
    """(mtime_ns, size) of ``path``, or None when it cannot be read."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


@contextmanager
def recording_reads():
    """Collect every file a spec names (:func:`rig.spec.resolve_file`) while the block runs: the
    scene cache keys an entry by them. Yields the list of (path, field, stamp) it fills, each
    stamp taken before the file is read (a file edited during the build then misses next time)."""
    reads: list[tuple[Path, str, tuple[int, int] | None]] = []
    token = _reads.set(reads)
    try:
        yield reads
    finally:
        _reads.reset(token)


def note_read(path: Path, field: str) -> None:
    """Record that a spec's ``field`` named ``path`` (a no-op unless :func:`recording_reads` is active)."""
    reads = _reads.get()
    if reads is not None:
        reads.append((path, field, file_stamp(path)))
