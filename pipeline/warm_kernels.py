"""Compile the renderers' numba kernels ahead of first use: ``python -m pipeline.warm_kernels``.

`make setup` runs it, so the first render of a fresh checkout loads machine code from numba's
cache instead of compiling on first use (one to two minutes per integrator family on these
2 cores: the compiled volpath, bdpt and sppm kernels are large). The cache folder is keyed by
render/'s sources (render/_kernel_cache.py); a marker in it records that this tree's kernels are
warm, so a second run costs only the digest. Each integrator is warmed by a real render at a
toy size through the CLI, two at a time (numba compiles on one core per process).

The NeRF's held-out march (recon/nerf/march_kernels.py, compiled into the same folder: numba
places it by the environment render/ sets) is warmed too, in process by a toy march, whenever
``--only`` is not given: numba's own index notices an edit to that file, so it is called every time
(loading the cached kernel 1.6 s with numba's import, compiling it 7.2 s, at load 6). Without it the
first ``lumigraph nerf`` after a checkout compiled it inside its ``--minutes`` budget.

``--only path,direct`` warms just those integrators (`make demo`: the default scene's stages use
the path tracer alone, so a fresh clone's demo does not wait for bdpt's or volpath's kernels);
each warmed integrator leaves its own marker (``warm.<integrator>``), the full set the ``warm`` one.

Without ``--only`` it then builds the path tracer's ahead-of-time extension (render.path_aot_build,
15 to 30 s, once per source tree: a process rendering with ``path`` or ``direct`` then imports no
numba). A failed build is reported and ignored (exit status unchanged): the JIT kernels remain;
``LUMIGRAPH_AOT=0`` skips it.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from render._kernel_cache import kernel_cache_dir
from render.path_aot_build import build as build_aot

#: (built-in scene, integrator) rendered at 8 x 6, 1 spp: every integrator of the registry once,
#: each on a scene it accepts (volpath's media need a participating medium; `direct` is refused
#: by every built-in scene's effects, so it renders in process with the effects it reaches)
WARM_RENDERS = (
    ("cornell_fog", "volpath"), ("cornell", "bdpt"), ("cornell", "sppm"), ("cornell", "pssmlt"),
    ("cornell", "path"), ("cornell", "direct"), ("cornell", "irradiance_cache"),
)
_DIRECT_ONLY = """
from rig.build import load_scene
from render.integrators import RenderSettings, render
rig = load_scene({scene!r})
camera = next(c for cams in rig.cameras.values() for c in cams)
render(rig.scene, camera, RenderSettings(integrator="direct", spp=1), effects={{"direct", "soft_shadows"}})
"""
MARKER = "warm"


def _render(scene: str, integrator: str, out: Path) -> tuple[str, float, str | None]:
    cmd = [sys.executable, "-m", "pipeline", "reference", scene, "--views", "scene", "--integrator", integrator,
           "--spp", "1", "--size", "8", "6", "--out", str(out / f"{scene}-{integrator}"), "-q"]
    if integrator == "direct":
        cmd = [sys.executable, "-c", _DIRECT_ONLY.format(scene=scene)]
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    err = None if r.returncode == 0 else (r.stderr.strip().splitlines() or ["(no output)"])[-1]
    return integrator, time.perf_counter() - t, err


def warm_nerf_march() -> float:
    """Compile the NeRF's held-out march (or load it from numba's cache) with a toy march of 4
    rays through a 2^3 grid, in this process; returns the seconds it took. The kernel's argument
    types do not depend on the input (``march`` converts every array), so this is the stage's."""
    import numpy as np

    from recon.nerf.march_kernels import march

    t = time.perf_counter()
    o = np.tile(np.array([[0.0, 0.0, -2.0]], np.float32), (4, 1))
    d = np.tile(np.array([[0.0, 0.0, 1.0]], np.float32), (4, 1))
    march(o, d, np.ones(4, np.float32), np.full(4, 3.0, np.float32), np.zeros(4, np.int64), 0.1,
          np.full(3, -1.0), np.full(3, 1.0), np.ones((2, 2, 2), bool), np.zeros((2, 2, 2), np.int64), 10.0,
          np.zeros((2, 2, 2), np.float32), 0.0, 1.0, 1e-4, 1e-4, threads=1)
    return time.perf_counter() - t


def main(argv: list[str] | None = None) -> int:
    """Warm the kernels unless the markers say they are; exit 1 naming an integrator whose
    toy render failed (a render bug: set-up should say so, not hide it), 2 for an unknown name."""
    parser = argparse.ArgumentParser(prog="python -m pipeline.warm_kernels", description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=None, help="comma-separated integrators to warm (default: all)")
    args = parser.parse_args(argv)
    known = [i for _, i in WARM_RENDERS]
    wanted = known if args.only is None else [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in wanted if n not in known]
    if unknown or not wanted:
        print(f"warm_kernels: --only: unknown integrator {', '.join(unknown) or '(none given)'} "
              f"(known: {', '.join(known)})", file=sys.stderr)
        return 2
    folder = kernel_cache_dir()
    if args.only is None:
        print(f"warm_kernels: nerf march kernel ready ({warm_nerf_march():.1f} s)", flush=True)
    todo = [] if (folder / MARKER).is_file() else [(sc, i) for sc, i in WARM_RENDERS
                                                    if i in wanted and not (folder / f"{MARKER}.{i}").is_file()]
    if not todo:
        print(f"warm_kernels: kernels already compiled ({folder})")
        if args.only is None:
            _build_aot()
        return 0
    print(f"warm_kernels: compiling {', '.join(i for _, i in todo)} kernels into {folder} (once per source tree)",
          flush=True)
    with tempfile.TemporaryDirectory(prefix="lumigraph-warm-") as tmp, ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda si: _render(si[0], si[1], Path(tmp)), todo))
    failed = [(name, err) for name, _, err in results if err is not None]
    for name, seconds, err in results:
        print(f"  {name:<17} {seconds:6.1f} s" + (f"  FAILED: {err}" if err else ""))
    if failed:
        print(f"warm_kernels: {len(failed)} integrator(s) failed to render at a toy size: "
              f"{', '.join(n for n, _ in failed)}", file=sys.stderr)
        return 1
    folder.mkdir(parents=True, exist_ok=True)
    for name, seconds, _ in results:
        (folder / f"{MARKER}.{name}").write_text(f"{name} {seconds:.1f}\n")
    if all((folder / f"{MARKER}.{i}").is_file() for i in known):
        (folder / MARKER).write_text("".join((folder / f"{MARKER}.{i}").read_text() for i in known))
    if args.only is None:
        _build_aot()
    return 0


def _build_aot() -> None:
    """The path tracer's ahead-of-time extension (a no-op when built; skipped with LUMIGRAPH_AOT=0);
    a failure is only reported: the JIT kernels render the same."""
    if os.environ.get("LUMIGRAPH_AOT", "1").strip() == "0":
        return
    try:
        ok = build_aot() == 0
    except Exception as e:  # noqa: BLE001  (set-up goes on with the JIT kernels)
        print(f"path_aot_build: {type(e).__name__}: {e}", file=sys.stderr)
        ok = False
    if not ok:
        print("warm_kernels: the ahead-of-time path kernels were not built; the JIT ones will be used",
              file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
