"""A digest of every integrator's output (mean and variance bytes) on small renders of three scenes.

For refactors that must not change behaviour: run it in two trees and compare the lines
(``git worktree add /tmp/old <rev>``, then ``python scripts/render_digests.py`` in each; issue 17's
move was checked this way). Prints ``scene integrator sha1[:12]`` per line.
"""
from __future__ import annotations

import hashlib
import sys
from pathlib import Path

sys.path.insert(0, str(Path.cwd()))  # the tree the command runs in, not this file's

from render.camera import Camera, Intrinsics  # noqa: E402
from render.integrators import RenderSettings, prepare, render  # noqa: E402
from rig.build import build_scene  # noqa: E402
from rig.spec import load_spec  # noqa: E402

CASES = (("cornell", ("direct", "path", "volpath", "bdpt", "sppm", "pssmlt")),
         ("cornell_fog", ("volpath",)), ("glass_caustic", ("path", "bdpt", "sppm")))


def small(cam: Camera, width: int = 24) -> Camera:
    """``cam`` scaled to ``width`` pixels across (same field of view)."""
    k = cam.intrinsics
    s = width / k.width
    return Camera(Intrinsics(width, int(k.height * s), k.fx * s, k.fy * s, k.cx * s, k.cy * s, k.dist),
                  cam.cam_to_world, cam.name)


def main() -> None:
    for name, integrators in CASES:
        rig = build_scene(*load_spec(f"scenes/{name}.yaml"))
        cam = small((rig.cameras.get("scene") or rig.cameras.get("test"))[0])
        prepared = prepare(rig.scene)
        for integ in integrators:
            effects = {"direct", "shadows", "soft_shadows", "specular"} if integ == "direct" else None
            r = render(rig.scene, cam, RenderSettings(integrator=integ, spp=16 if integ == "pssmlt" else 8, seed=3,
                                                      max_depth=4), effects=effects, prepared=prepared)
            print(name, integ, hashlib.sha1(r.mean.tobytes() + r.variance.tobytes()).hexdigest()[:12])


if __name__ == "__main__":
    main()
