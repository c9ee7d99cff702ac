"""The measured Cornell box built programmatically (REFERENCES.md; millimetres, +Y up).

Quads from the Cornell Program of Computer Graphics data; the light is lowered from the ceiling
to y = 548.7 and emits downwards only; Tungsten's RGB albedos and light radiance (17, 12, 4).
Camera at (278, 273, -800) looking along +z, up +y, vfov 2 atan(12.5 / 35) = 39.3077 degrees.
"""
from __future__ import annotations

import numpy as np
import trimesh

from render.camera import Camera, Intrinsics
from render.poses import look_at
from render.scene import Emissive, Lambertian, Scene, SceneObject

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
LIGHT_RADIANCE = (17.0, 12.0, 4.0)
VFOV_DEG = float(np.degrees(2 * np.arctan(12.5 / 35.0)))

_Q = {
    "floor": [[552.8, 0, 0], [0, 0, 0], [0, 0, 559.2], [549.6, 0, 559.2]],
    "ceiling": [[556.0, 548.8, 0], [556.0, 548.8, 559.2], [0, 548.8, 559.2], [0, 548.8, 0]],
    "back": [[549.6, 0, 559.2], [0, 0, 559.2], [0, 548.8, 559.2], [556.0, 548.8, 559.2]],
    "right_green": [[0, 0, 559.2], [0, 0, 0], [0, 548.8, 0], [0, 548.8, 559.2]],
    "left_red": [[552.8, 0, 0], [549.6, 0, 559.2], [556.0, 548.8, 559.2], [556.0, 548.8, 0]],
    "light": [[343.0, 548.7, 227.0], [343.0, 548.7, 332.0], [213.0, 548.7, 332.0], [213.0, 548.7, 227.0]],
}
_SHORT = [
    [[130, 165, 65], [82, 165, 225], [240, 165, 272], [290, 165, 114]],
    [[290, 0, 114], [290, 165, 114], [240, 165, 272], [240, 0, 272]],
    [[130, 0, 65], [130, 165, 65], [290, 165, 114], [290, 0, 114]],
    [[82, 0, 225], [82, 165, 225], [130, 165, 65], [130, 0, 65]],
    [[240, 0, 272], [240, 165, 272], [82, 165, 225], [82, 0, 225]],
]
_TALL = [
    [[423, 330, 247], [265, 330, 296], [314, 330, 456], [472, 330, 406]],
    [[423, 0, 247], [423, 330, 247], [472, 330, 406], [472, 0, 406]],
    [[472, 0, 406], [472, 330, 406], [314, 330, 456], [314, 0, 456]],
    [[314, 0, 456], [314, 330, 456], [265, 330, 296], [265, 0, 296]],
    [[265, 0, 296], [265, 330, 296], [423, 330, 247], [423, 0, 247]],
]


def quads_mesh(quads) -> trimesh.Trimesh:
    """Triangulate quads (Q, 4, 3) as (0, 1, 2), (0, 2, 3), keeping their winding."""
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 3)
    v = q.reshape(-1, 3)
    base = 4 * np.arange(len(q))[:, None]
    f = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
    return trimesh.Trimesh(v, f, process=False)


def cornell_scene() -> Scene:
    objs = []
    for name, col in (("floor", WHITE), ("ceiling", WHITE), ("back", WHITE),
                      ("right_green", GREEN), ("left_red", RED)):
        objs.append(SceneObject(name, quads_mesh([_Q[name]]), Lambertian(col)))
    objs.append(SceneObject("short_block", quads_mesh(_SHORT), Lambertian(WHITE)))
    objs.append(SceneObject("tall_block", quads_mesh(_TALL), Lambertian(WHITE)))
    light = quads_mesh([_Q["light"]])
    if light.face_normals[0, 1] > 0:  # emit downwards only
        light.invert()
    objs.append(SceneObject("light", light, Emissive(LIGHT_RADIANCE)))
    return Scene("cornell", objs, up=np.array([0.0, 1.0, 0.0]))


def cornell_camera(width: int = 256, height: int = 256) -> Camera:
    eye = np.array([278.0, 273.0, -800.0])
    c2w = look_at(eye, eye + [0, 0, 1.0], [0, 1.0, 0])
    return Camera(Intrinsics.from_fov(width, height, VFOV_DEG), c2w, "cornell")
