"""COLMAP in a child process that can be stopped: :func:`estimate_colmap_stoppable`.

COLMAP computes for minutes in C++ threads (feature extraction, matching, mapping) that nothing
in the calling process can stop, and that abort that whole process (a stack dump, exit -6) when
their work folder vanishes under them. Run in a child process instead, the estimate can be
stopped at any moment: the parent waits in short polls (so a signal's Python handler runs at
once), and when it is interrupted it kills the child (SIGKILL) before its ``finally`` removes the
work folder (~0.5 GB at 1000 views). The child is ``python -m recon.poses.colmap_process WORKDIR``,
not multiprocessing's spawn, which re-runs a caller's unguarded main script.

Protocol (all files in the work folder): ``request.pkl`` (the arguments), then the child writes
``response.pkl`` (``("ok", ColmapResult without its reconstruction)`` or ``("error", exception)``)
and the model in ``result/`` (a pycolmap.Reconstruction does not pickle). The child's stderr is
the parent's, so COLMAP's own error lines reach the user as before.
"""
from __future__ import annotations

import pickle
import signal
import subprocess
import sys
import traceback
from collections.abc import Mapping, Sequence
from pathlib import Path

from render.camera import Intrinsics

from .colmap import ColmapConfig, ColmapResult, estimate_colmap
from .pairing import ViewOrder

__all__ = ["estimate_colmap_stoppable"]

#: seconds between the parent's checks on the child (how soon an interrupt is acted on)
POLL_S = 0.2


def estimate_colmap_stoppable(images: Mapping[str, Path], intrinsics: Intrinsics | None, workdir: Path,
                              config: ColmapConfig = ColmapConfig(),
                              order: Sequence[ViewOrder] | None = None,
                              boards: Mapping[str, Mapping] | None = None) -> ColmapResult:
    """:func:`recon.poses.colmap.estimate_colmap` with the same arguments and result, run in a
    child process that is killed if this call is interrupted (KeyboardInterrupt or any exception
    raised by a signal handler while it waits). Re-raises the child's exception (a bug's carries
    the child's traceback as a note); RuntimeError if the child dies without an answer."""
    import pycolmap

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    request, response = workdir / "request.pkl", workdir / "response.pkl"
    request.write_bytes(pickle.dumps((dict(images), intrinsics, workdir, config, None if order is None else list(order),
                                       None if boards is None else {k: dict(v) for k, v in boards.items()})))
    child = subprocess.Popen([sys.executable, "-m", "recon.poses.colmap_process", str(workdir)],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    try:
        while True:
            try:
                code = child.wait(POLL_S)
                break
            except subprocess.TimeoutExpired:
                continue
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    if not response.is_file():
        raise RuntimeError(f"the COLMAP child process died without an answer (exit code {code})")
    status, payload = pickle.loads(response.read_bytes())
    if status == "error":
        raise payload
    payload.reconstruction = pycolmap.Reconstruction(str(workdir / "result"))
    return payload


def _die_with_parent() -> None:
    """Linux: the kernel sends this process SIGKILL when its parent dies (prctl PR_SET_PDEATHSIG),
    so a parent killed outright (SIGKILL, no chance to clean up) leaves no orphan COLMAP writing
    into the partial folder for minutes. Elsewhere a no-op."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def _child(workdir: Path) -> int:
    """The child's side of the protocol (module docstring). Ctrl-C reaches the whole process
    group: the child ignores it and leaves the stopping to its parent; SIGTERM ends it quietly
    (pycolmap's import installs glog's handler, which would print a stack dump first)."""
    import pycolmap  # noqa: F401  (before resetting its SIGTERM handler)

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _die_with_parent()
    images, intrinsics, workdir, config, order, boards = pickle.loads((workdir / "request.pkl").read_bytes())
    try:
        res = estimate_colmap(images, intrinsics, workdir, config, order, boards)
        (workdir / "result").mkdir()
        res.reconstruction.write(str(workdir / "result"))
        res.reconstruction = None
        answer = ("ok", res)
    except Exception as exc:  # handed to the parent, which re-raises it
        exc.add_note(f"in the COLMAP child process:\n{traceback.format_exc()}")
        answer = ("error", exc)
    partial = workdir / "response.pkl.partial"
    partial.write_bytes(pickle.dumps(answer))
    partial.replace(workdir / "response.pkl")  # whole or absent
    return 0


if __name__ == "__main__":
    sys.exit(_child(Path(sys.argv[1])))
