"""OpenMP's wait policy for torch's intra-op threads: idle threads sleep instead of spinning.

torch (CPU wheels) runs its intra-op parallel regions on libgomp's thread pool. With the default
policy a thread that reaches a barrier first spins until its partner arrives; on 2 cores shared
with other busy processes the partner is often descheduled, so every parallel tensor operation can
wait out a scheduler time slice. Measured on the default scene's fast NeRF stage
(``lumigraph nerf --minutes 1.5``, 2 torch threads, load 4-7, interleaved rounds): 22-24 training
steps with the default policy, 134 and more with ``OMP_WAIT_POLICY=PASSIVE``, 128-177 with one
torch thread. libgomp reads the variable once, when it is loaded (with torch), so it must be in
the environment before the first ``import torch``: :func:`passive_omp_wait` is called by the NeRF
entry points before they import torch, and reports whether it came in time.

No torch import here (that would load libgomp).
"""
from __future__ import annotations

import os

__all__ = ["passive_omp_wait", "openmp_loaded"]

_POLICY: str | None = None   # the policy in effect, as first determined


def openmp_loaded() -> bool:
    """True when an OpenMP runtime (libgomp / libiomp) is mapped into this process (Linux
    /proc/self/maps; False where that file cannot be read)."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            return any("libgomp" in line or "libiomp" in line for line in f)
    except OSError:
        return False


def passive_omp_wait() -> str:
    """Set ``OMP_WAIT_POLICY=PASSIVE`` unless the user set a policy, if OpenMP is not loaded yet.

    Returns the policy in effect: the user's value, ``"PASSIVE"`` (set here in time) or
    ``"default (OpenMP loaded first)"`` when something imported torch before this call (the
    variable would be read by nobody, so it is not set). The first call's answer is kept."""
    global _POLICY
    if _POLICY is None:
        user = os.environ.get("OMP_WAIT_POLICY")
        if user:
            _POLICY = user.upper()
        elif openmp_loaded():
            _POLICY = "default (OpenMP loaded first)"
        else:
            os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
            _POLICY = "PASSIVE"
    return _POLICY
