"""Build the path tracer's ahead-of-time extension (:mod:`render.path_aot`): ``python -m render.path_aot_build``.

`make setup` runs it after warming numba's cache (pipeline/warm_kernels.py); it takes 15 to 30 s.
Three steps, each its own process:

1. record: tiny renders with the JIT kernels (``path`` under each sampler and strategy, on two
   threads, and ``direct``) on a scene of three quads and a point light; each exported kernel's
   dispatcher must then hold exactly one signature, which is what path.py and render.accel pass
   it (pickled numba types). Nothing is written by hand, so a kernel's new argument changes the
   export with it.
2. compile: numba.pycc exports those signatures of the kernels' Python functions, plus
   ``key_<key>`` (:func:`render.path_aot.build_key`), with the JIT kernels' flags that change
   code (``error_model="numpy"``; the wrappers release the GIL as ``nogil`` does), for the host
   CPU. It runs with an empty numba cache: pycc cannot link callees numba loaded from its cache.
3. the folder built under a temporary name is renamed into place (:func:`render.path_aot.extension_dir`).

Exit 0 when built (or already there), 1 when a step failed: callers keep the JIT kernels then.
"""
from __future__ import annotations

import argparse
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .path_aot import KERNELS, MODULE, build_key, extension_dir

#: the pickled {kernel: (argument types, return type)} exported, beside the extension
SIGNATURES = "signatures.pkl"
_ROOT = Path(__file__).resolve().parents[1]


def _tiny_scene():
    """A floor, a wall, a mirror, an area light and a point light, and a 6 x 5 camera."""
    import numpy as np

    from .camera import Camera, Intrinsics
    from .poses import look_at
    from .scene import Emissive, Lambertian, Mirror, PointLight, Scene, SceneObject, TriangleMesh

    def quad(corners):
        return TriangleMesh(np.asarray(corners, float), [[0, 1, 2], [0, 2, 3]])

    objects = [SceneObject("floor", quad([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]]), Lambertian(0.7)),
               SceneObject("wall", quad([[-2, 2, 0], [2, 2, 0], [2, 2, 3], [-2, 2, 3]]), Lambertian(0.5)),
               SceneObject("mirror", quad([[2, -2, 0], [2, 2, 0], [2, 2, 3], [2, -2, 3]]), Mirror()),
               SceneObject("light", quad([[-0.5, -0.5, 2.5], [-0.5, 0.5, 2.5], [0.5, 0.5, 2.5], [0.5, -0.5, 2.5]]),
                           Emissive(5.0))]
    scene = Scene("aot", objects, [PointLight(np.array([0.0, 0.0, 1.5]), 2.0)])
    camera = Camera(Intrinsics.from_fov(6, 5, 50.0), look_at([0, -5, 1.5], [0, 0, 1], [0, 0, 1]))
    return scene, camera


def record(out: Path) -> None:
    """Step 1 (JIT, numba's warm cache): render, then pickle {kernel: (argument types, return type)}."""
    from .integrators import RenderSettings, render
    from .path_aot import jit_kernels

    scene, camera = _tiny_scene()
    fx = {"direct", "soft_shadows", "shadows", "specular"}  # no caustics: a point light through a mirror
    for integrator, threads, opts in (("path", 2, {"sampler": "sobol-blocks"}), ("path", 1, {"sampler": "sobol"}),
                                      ("path", 1, {"sampler": "independent", "strategy": "light"}),
                                      ("path", 1, {"sampler": "sobol", "strategy": "bsdf"}),
                                      ("direct", 1, {"sampler": "sobol"})):
        settings = RenderSettings(integrator=integrator, spp=4, threads=threads, batch_paths=64, **opts)
        render(scene, camera, settings, effects=fx if integrator == "direct" else fx | {"interreflection"})
    jit = jit_kernels()
    sigs = {}
    for name in KERNELS:
        disp = getattr(jit, name)
        if len(disp.signatures) != 1:
            raise RuntimeError(f"{name}: {len(disp.signatures)} signatures after the renders (need exactly 1)")
        sig = disp.signatures[0]
        sigs[name] = (tuple(sig), disp.overloads[sig].signature.return_type)
    out.write_bytes(pickle.dumps(sigs))


def compile_extension(sigs_file: Path, key: str, out_dir: Path, cpu: str = "host") -> None:
    """Step 2 (an empty numba cache): pycc-compile the recorded signatures into out_dir."""
    from numba.core import compiler as ncompiler
    from numba.pycc import CC
    import numba.pycc.compiler as pycc_compiler

    from .path_aot import jit_kernels

    class KernelFlags(ncompiler.Flags):
        """The JIT kernels' flags that change code (``_JIT`` of path_kernels: error_model numpy,
        nogil); pycc builds its Flags() when it compiles the exports."""

        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.error_model = "numpy"
            self.release_gil = True

    pycc_compiler.Flags = KernelFlags
    from numba import types

    sigs = pickle.loads(sigs_file.read_bytes())
    jit = jit_kernels()
    cc = CC(MODULE)
    cc.output_dir = str(out_dir)
    cc.target_cpu = cpu
    cc.verbose = False
    for name in KERNELS:
        args, ret = sigs[name]
        cc.export(name, ret(*args))(getattr(jit, name).py_func)
    cc.export("key_" + key, types.int64())(lambda: 0)  # its presence is the check
    cc.compile()


def build(force: bool = False, cpu: str = "host", quiet: bool = False) -> int:
    """Build this tree's extension unless it is there (``force``: anyway); 0 on success."""
    key = build_key()
    final = extension_dir(key)
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    if not force and any(final.glob(MODULE + ".*")):
        say(f"path_aot_build: extension already built ({final})")
        return 0
    final.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=final.parent))
    try:
        sigs = work / "signatures.pkl"
        env = {**os.environ, "LUMIGRAPH_AOT": "0"}
        steps = ((["--record", str(sigs)], env),
                 (["--compile", str(sigs), "--key", key, "--out", str(work / "ext"), "--cpu", cpu],
                  {**env, "NUMBA_CACHE_DIR": str(work / "numba"), "LUMIGRAPH_NUMBA_CACHE_BASE": str(work / "numba")}))
        for args, step_env in steps:
            r = subprocess.run([sys.executable, "-m", "render.path_aot_build", *args], cwd=_ROOT, env=step_env,
                               capture_output=True, text=True)
            if r.returncode != 0:
                last = (r.stderr.strip().splitlines() or ["(no output)"])[-1]
                print(f"path_aot_build: {args[0][2:]} failed: {last}", file=sys.stderr)
                return 1
        built = work / "ext"
        if not any(built.glob(MODULE + ".*")):
            print("path_aot_build: pycc wrote no extension", file=sys.stderr)
            return 1
        os.rename(sigs, built / SIGNATURES)  # what was exported (tests compare it with the dispatchers)
        if final.exists():  # --force: the old one out of the way first (a reader sees old or new)
            old = final.with_name(f".{final.name}-old-{os.getpid()}")
            os.rename(final, old)
            shutil.rmtree(old, ignore_errors=True)
        os.rename(built, final)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    say(f"path_aot_build: built {final} in {time.perf_counter() - t0:.1f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m render.path_aot_build", description=__doc__.splitlines()[0])
    parser.add_argument("--force", action="store_true", help="rebuild even when the extension is there")
    parser.add_argument("--cpu", default="host", help="LLVM target CPU (default: host)")
    parser.add_argument("--record", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--compile", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--key", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.record is not None:
        record(args.record)
        return 0
    if args.compile is not None:
        compile_extension(args.compile, args.key, args.out, args.cpu)
        return 0
    return build(force=args.force, cpu=args.cpu)


if __name__ == "__main__":
    sys.exit(main())
