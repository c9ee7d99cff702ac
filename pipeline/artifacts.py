"""The artifact layout (DESIGN.md), stage manifests and atomic stage folders.

``pipeline`` is the only package that knows where files go::

    artifacts/<scene>/capture/           images/ linear/ depth/ masks/ cameras.json
                                         transforms_{train,test}.json colmap/ targets.json manifest.json
    artifacts/<scene>/poses/<method>/    cameras.json transforms_*.json colmap/ metrics.json manifest.json
    artifacts/<scene>/reference/         linear/ variance/ images/ manifest.json
    artifacts/<scene>/slab/  artifacts/<scene>/nerf/<model>/  artifacts/<scene>/validate/

A stage writes into a hidden sibling folder ``.<name>.partial-*`` and renames it into place only
when complete, so an interrupted stage leaves nothing that looks finished.

``--out`` never deletes what a user put there (:func:`check_out`): a stage replaces only an
absent or empty folder, or a finished folder of its own kind (its ``manifest.json`` names the
stage; for ``poses`` also the failure folder of a failed estimate); anything else (a file, a
folder of the user's files, another stage's folder) is refused with BadInput before any work,
unless the caller passes ``overwrite=True`` (the CLI's ``--overwrite``).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from render.camera_io import view_name_problem
from render.image_io import atomic_path

__all__ = ["BadInput", "DEFAULT_ROOT", "stage_dir", "atomic_stage", "check_out", "check_file_stem", "sha256_file",
           "Manifest", "write_json", "read_json", "read_manifest", "read_stage_manifest", "MANIFEST", "OVERWRITE_HINT"]

DEFAULT_ROOT = Path("artifacts")
MANIFEST = "manifest.json"


class BadInput(ValueError):
    """User input is wrong (missing file, malformed scene, failed reconstruction): exit code 2."""


OVERWRITE_HINT = "pass --overwrite to replace it, or choose another --out"


def check_file_stem(name, where: str) -> str:
    """``name`` if it is a plain file stem (a view name read from an input file), else BadInput
    naming ``where`` (the file and field). The rule is :func:`render.camera_io.view_name_problem`:
    no path separators, no leading '.', no control characters or whitespace, at most 200 bytes,
    so ``folder / f"{name}.exr"`` stays inside ``folder``."""
    problem = view_name_problem(name)
    if problem is not None:
        raise BadInput(f"{where}: {problem}")
    return name


def _failed_poses_folder(folder: Path) -> bool:
    """The failure folder of a failed pose estimate (pipeline.stages.poses): only metrics.json,
    whose status is "failed"."""
    entries = [p.name for p in folder.iterdir()]
    if entries != ["metrics.json"]:
        return False
    try:
        doc = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("status") == "failed"


def check_out(final: Path, stage: str | None, overwrite: bool = False) -> None:
    """BadInput (one line naming ``final``) unless ``final`` may be replaced by ``stage``'s output:
    absent, an empty folder, or a finished folder of the same stage (its manifest's "stage"; with
    ``stage`` None, of any stage), or for ``poses`` a failed estimate's folder. ``overwrite``
    allows anything (the user asked). Called before any work, and again by :func:`atomic_stage`."""
    final = Path(final)
    if overwrite or not (final.exists() or final.is_symlink()):
        return
    if not final.is_dir():
        raise BadInput(f"{final}: exists and is not a folder; refusing to replace it ({OVERWRITE_HINT})")
    try:
        entries = sorted(p.name for p in final.iterdir())
    except OSError as exc:
        raise BadInput(f"{final}: cannot list the output folder ({exc.strerror})") from None
    if not entries:
        return
    kind = None
    if (final / MANIFEST).is_file():
        try:
            doc = json.loads((final / MANIFEST).read_text())
            kind = doc.get("stage") if isinstance(doc, dict) else None
        except (OSError, ValueError):
            kind = None
    if kind is not None and (stage is None or kind == stage):
        return
    if stage == "poses" and _failed_poses_folder(final):
        return
    what = (f"a finished '{kind}' stage folder, not '{stage}'" if isinstance(kind, str)
            else f"not a finished {stage or 'stage'} folder (holds {len(entries)} entries, e.g. {entries[0]!r})")
    raise BadInput(f"{final}: {what}; refusing to replace it ({OVERWRITE_HINT})")


def stage_dir(scene_name: str, stage: str, root: Path = DEFAULT_ROOT) -> Path:
    """Default folder of a stage for a scene, e.g. ``artifacts/turntable/capture``."""
    return Path(root) / scene_name / stage


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def write_json(path: Path, data) -> None:
    """Atomic, deterministic JSON (sorted keys, no NaN allowed)."""
    text = json.dumps(data, indent=2, sort_keys=True, allow_nan=False)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text + "\n")


def read_json(path: Path):
    path = Path(path)
    if not path.is_file():
        raise BadInput(f"{path}: file not found")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise BadInput(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def _remove_orphans(final: Path) -> None:
    """Delete partial folders of ``final`` (and replaced ones, ``.old-<pid>``, of a run killed
    between its two renames) left by processes that no longer run."""
    for kind in (".partial-", ".old-"):
        for folder in final.parent.glob(f".{final.name}{kind}*"):
            pid = folder.name.rsplit(kind, 1)[1].split("-", 1)[0]
            if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
                shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def atomic_stage(final: Path, stage: str | None = None, overwrite: bool = False):
    """Yield a fresh temporary folder; on success replace ``final`` with it, else delete it.

    ``final`` is checked first (:func:`check_out`): only an absent or empty folder or a finished
    ``stage`` folder is replaced, unless ``overwrite``. A killed run leaves its
    ``.<name>.partial-<pid>-*`` folder behind (nothing can clean up after SIGKILL); the next run
    of the stage removes those whose process is gone."""
    final = Path(final)
    check_out(final, stage, overwrite)
    created = [d for d in [final.parent, *final.parent.parents] if not d.exists()]  # deepest first
    final.parent.mkdir(parents=True, exist_ok=True)
    _remove_orphans(final)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.partial-{os.getpid()}-", dir=final.parent))
    try:
        yield tmp
        if final.exists() or final.is_symlink():
            old = final.with_name(f".{final.name}.old-{os.getpid()}")
            os.replace(final, old)
            os.replace(tmp, final)
            if old.is_dir() and not old.is_symlink():
                shutil.rmtree(old, ignore_errors=True)
            else:  # a file (or link) the user asked to overwrite
                old.unlink(missing_ok=True)
        else:
            os.replace(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        if not final.exists():  # failed: the folders made for it go too (when still empty)
            for d in created:
                try:
                    d.rmdir()
                except OSError:
                    break


@dataclass
class Manifest:
    """What a stage did: its params, inputs and outputs with content hashes, wall time, metrics.

    Output paths are relative to the stage folder; input paths are as given.
    """

    stage: str
    params: dict = field(default_factory=dict)
    inputs: dict[str, str] = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    started: float = field(default_factory=time.time)

    def add_input(self, path: Path) -> None:
        path = Path(path)
        if path.is_dir():
            for p in sorted(path.rglob("*")):
                if p.is_file():
                    self.inputs[str(p)] = sha256_file(p)
        else:
            self.inputs[str(path)] = sha256_file(path)

    def write(self, folder: Path) -> dict:
        """Hash every file in ``folder`` and write ``folder/manifest.json``; returns its content."""
        folder = Path(folder)
        outputs = {str(p.relative_to(folder)): sha256_file(p) for p in sorted(folder.rglob("*"))
                   if p.is_file() and p.name != MANIFEST}
        from . import __version__

        data = {"stage": self.stage, "lumigraph": __version__, "params": self.params, "inputs": self.inputs,
                "outputs": outputs, "wall_time_s": round(time.time() - self.started, 3),
                "metrics": self.metrics}
        write_json(folder / MANIFEST, data)
        return data


def read_manifest(folder: Path) -> dict:
    """Read a stage folder's manifest; BadInput if the folder is not a finished stage."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BadInput(f"{folder}: no such folder")
    if not (folder / MANIFEST).is_file():
        raise BadInput(f"{folder}: no {MANIFEST} (not a finished stage folder)")
    doc = read_json(folder / MANIFEST)
    if not isinstance(doc, dict):
        raise BadInput(f"{folder / MANIFEST}: expected a JSON object")
    if not isinstance(doc.get("stage"), str):
        raise BadInput(f"{folder / MANIFEST}: field 'stage' missing or not a string")
    for key in ("params", "inputs", "outputs", "metrics"):
        if not isinstance(doc.get(key, {}), dict):
            raise BadInput(f"{folder / MANIFEST}: field '{key}' is not an object")
    if not isinstance(doc.get("wall_time_s", 0.0), (int, float)) or isinstance(doc.get("wall_time_s"), bool):
        raise BadInput(f"{folder / MANIFEST}: field 'wall_time_s' is not a number")
    return doc


def read_stage_manifest(folder: Path, stage: str) -> dict:
    """:func:`read_manifest` of a folder that must be a finished ``stage`` folder (BadInput
    naming the manifest and its 'stage' field otherwise)."""
    doc = read_manifest(folder)
    if doc["stage"] != stage:
        raise BadInput(f"{Path(folder) / MANIFEST}: field 'stage' is {doc['stage']!r}, expected a {stage!r} folder")
    return doc
