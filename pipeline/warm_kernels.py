"""Compile the renderers' numba kernels ahead of first use: ``python -m pipeline.warm_kernels``.

`make setup` runs it, so the first render of a fresh checkout loads machine code from numba's
cache instead of compiling on first use (one to two minutes per integrator family on these
2 cores: the compiled volpath, bdpt and sppm kernels are large). The cache folder is keyed by
render/'s sources (render/_kernel_cache.py); a marker in it records that this tree's kernels are
warm, so a second run costs only the digest. Each integrator is warmed by a real render at a
toy size through the CLI, two at a time (numba compiles on one core per process).
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from render._kernel_cache import kernel_cache_dir

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


def main(argv: list[str] | None = None) -> int:
    """Warm the kernels unless the marker says they are; exit 1 naming an integrator whose
    toy render failed (a render bug: set-up should say so, not hide it)."""
    folder = kernel_cache_dir()
    if (folder / MARKER).is_file():
        print(f"warm_kernels: kernels already compiled ({folder})")
        return 0
    print(f"warm_kernels: compiling the renderers' kernels into {folder} (once per source tree)", flush=True)
    with tempfile.TemporaryDirectory(prefix="lumigraph-warm-") as tmp, ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda si: _render(si[0], si[1], Path(tmp)), WARM_RENDERS))
    failed = [(name, err) for name, _, err in results if err is not None]
    for name, seconds, err in results:
        print(f"  {name:<17} {seconds:6.1f} s" + (f"  FAILED: {err}" if err else ""))
    if failed:
        print(f"warm_kernels: {len(failed)} integrator(s) failed to render at a toy size: "
              f"{', '.join(n for n, _ in failed)}", file=sys.stderr)
        return 1
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MARKER).write_text("".join(f"{n} {s:.1f}\n" for n, s, _ in results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
