"""Capture benchmark: rig.raster.RasterRenderer against bare pyrender on the same scene and run.

Scene: a textured box on a cylinder turntable with a textured top, two shadowed spot lights,
48 views around it at 256x256. Timed per full frame:

* ``ours``: RasterRenderer.render (radiance pass, float MSAA resolve, rgb + depth + mask).
  Shadow maps are drawn once per scene (lights and geometry are static), not per view.
* ``ours_shadow_maps_per_frame``: the same plus redrawing both shadow maps every view: the
  like-for-like comparison with pyrender, which redraws them on every render call.
* ``pyrender``: stock OffscreenRenderer.render, default shader, RenderFlags.SHADOWS_SPOT,
  uint8 colour + depth read-back.
* ``ours_no_shadows`` and ``pyrender_no_shadows``: both without shadows, which isolates the
  cost of our pipeline (float MRT targets, resolve, read-back, decoding) from the shadow
  implementations (pyrender filters 36 shadow-map texels per light and fragment, we use the
  hardware's bilinear comparison).

Run: ``.venv/bin/python -m bench.bench_capture``; writes bench/results/capture.json.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np
import trimesh

from bench.common import median_time, parse_flags, write_result
from render.camera import Camera, Intrinsics
from render.poses import look_at
from render.scene import Lambertian, Scene, SceneObject, SpotLight
from rig.raster import RasterRenderer  # sets PYOPENGL_PLATFORM=egl before pyrender loads

import pyrender  # noqa: E402  (after rig.raster: EGL platform)

SIZE = 256
N_VIEWS = 48
REPEATS = 5


def _texture(seed: int, n: int = 256) -> np.ndarray:
    """(n, n, 3) uint8 sRGB: a checkerboard with noise, so every texel differs."""
    rng = np.random.default_rng(seed)
    checker = ((np.arange(n)[:, None] // 32 + np.arange(n)[None] // 32) % 2).astype(np.float64)
    base = 60 + 140 * checker[..., None] * rng.uniform(0.5, 1.0, 3)
    return np.clip(base + rng.normal(0, 12, (n, n, 3)), 0, 255).astype(np.uint8)


def _textured_box(lo, hi) -> trimesh.Trimesh:
    """Box with 4 vertices per face so each face maps the whole texture (u right, v up)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    verts, faces, uvs = [], [], []
    for normal in np.vstack([np.eye(3), -np.eye(3)]):
        a = int(np.argmax(np.abs(normal)))
        side = hi if normal[a] > 0 else lo
        u_ax, v_ax = [i for i in range(3) if i != a]
        quad = []
        for su, sv in ((0, 0), (1, 0), (1, 1), (0, 1)):
            p = side.copy()
            p[u_ax] = (lo, hi)[su][u_ax]
            p[v_ax] = (lo, hi)[sv][v_ax]
            quad.append(p)
        quad = np.array(quad)
        n0 = len(verts)
        tri = [[n0, n0 + 1, n0 + 2], [n0, n0 + 2, n0 + 3]]
        if np.cross(quad[1] - quad[0], quad[2] - quad[0]) @ normal < 0:  # outward winding
            tri = [[n0, n0 + 2, n0 + 1], [n0, n0 + 3, n0 + 2]]
        verts.extend(quad)
        faces.extend(tri)
        uvs.extend([[0, 0], [1, 0], [1, 1], [0, 1]])
    return trimesh.Trimesh(np.array(verts), np.array(faces),
                           visual=trimesh.visual.TextureVisuals(uv=np.array(uvs, float)), process=False)


def _disk(radius: float, z: float, sections: int = 64) -> trimesh.Trimesh:
    """Disk facing +z with planar uv over its bounding square."""
    ang = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    rim = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.full(sections, z)], 1)
    verts = np.vstack([[0.0, 0.0, z], rim])
    faces = np.stack([np.zeros(sections, int), 1 + np.arange(sections), 1 + (np.arange(sections) + 1) % sections], 1)
    uv = verts[:, :2] / (2 * radius) + 0.5
    return trimesh.Trimesh(verts, faces, visual=trimesh.visual.TextureVisuals(uv=uv), process=False)


def capture_scene() -> Scene:
    """The benchmark's turntable scene (+Z up, turntable axis through the origin)."""
    table = trimesh.creation.cylinder(radius=0.6, height=0.1, sections=64)
    table.apply_translation([0, 0, 0.05])
    objects = [
        SceneObject("turntable", table, Lambertian([0.35, 0.35, 0.35])),
        SceneObject("turntable_top", _disk(0.6, 0.1005), Lambertian([1.0, 1.0, 1.0], texture=_texture(1))),
        SceneObject("box", _textured_box([-0.2, -0.2, 0.1], [0.2, 0.2, 0.5]),
                    Lambertian([0.9, 0.9, 0.9], texture=_texture(2)), is_subject=True),
    ]
    target = np.array([0.0, 0.0, 0.25])
    lights = []
    for pos, I in (([1.6, -1.0, 2.0], 8.0), ([-1.2, 1.5, 1.7], 5.0)):
        pos = np.array(pos)
        lights.append(SpotLight(pos, target - pos, [I] * 3, np.radians(20), np.radians(35)))
    return Scene("capture_bench", objects, lights=lights, background=[0.02, 0.02, 0.02])


def capture_cameras(n: int = N_VIEWS, size: int = SIZE) -> list[Camera]:
    """n views on two rings (elevations 20 and 40 degrees) around the turntable."""
    k = Intrinsics.from_fov(size, size, 40.0)
    cams = []
    for i in range(n):
        az = 2 * np.pi * i / n
        el = np.radians(20.0 if i % 2 == 0 else 40.0)
        eye = 2.2 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]) + [0, 0, 0.25]
        cams.append(Camera(k, look_at(eye, [0, 0, 0.25], [0, 0, 1]), name=f"view_{i:03d}"))
    return cams


def _bare_pyrender_scene(scene: Scene) -> tuple[pyrender.Scene, pyrender.Node]:
    """The same geometry (unindexed, face normals, uv) with pyrender's stock materials and lights."""
    ps = pyrender.Scene(bg_color=np.append(scene.background, 1.0), ambient_light=np.zeros(3))
    for o in scene.objects:
        m = o.mesh
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=np.append(o.material.albedo, 1.0),
                                                 metallicFactor=0.0, roughnessFactor=1.0, doubleSided=True)
        texcoords = None
        if o.material.texture is not None:
            mat.baseColorTexture = pyrender.Texture(source=o.material.texture, source_channels="RGB")
            texcoords = o.uv[m.faces].reshape(-1, 2)
        ps.add(pyrender.Mesh([pyrender.Primitive(positions=m.vertices[m.faces].reshape(-1, 3),
                                                 normals=np.repeat(m.face_normals, 3, axis=0),
                                                 texcoord_0=texcoords, material=mat)]))
    for light in scene.lights:
        pose = look_at(light.position, light.position + light.direction, [0, 0, 1]) @ np.diag([1.0, -1, -1, 1])
        ps.add(pyrender.SpotLight(color=np.ones(3), intensity=float(light.intensity[0]),
                                  innerConeAngle=light.inner_angle, outerConeAngle=light.outer_angle), pose=pose)
    k = capture_cameras(1)[0].intrinsics
    cam_node = ps.add(pyrender.IntrinsicsCamera(k.fx, k.fy, k.cx, k.cy, znear=0.1, zfar=10.0))
    return ps, cam_node


def pipeline_vs_bare(repeats: int = 3) -> dict:
    """The whole capture stage (render + EXR/PNG/depth/mask writes + camera files + manifest) on
    the default turntable scene at 256x256, against bare pyrender rendering the same views."""
    import tempfile
    from pathlib import Path

    from pipeline.stages.capture import run_capture
    from pipeline.stages.reference import resize_camera
    from rig.build import load_scene
    from rig.spec import resolve_scene_path

    rig = load_scene("turntable")
    rig.cameras = {s: [resize_camera(c, SIZE, SIZE) for c in cams] for s, cams in rig.cameras.items()}
    views = [c for cams in rig.cameras.values() for c in cams]
    bare = pyrender.OffscreenRenderer(SIZE, SIZE)
    ps, cam_node = _bare_pyrender_scene(rig.scene)
    k = views[0].intrinsics
    ps.set_pose(cam_node, np.eye(4))
    cam_node.camera = pyrender.IntrinsicsCamera(k.fx, k.fy, k.cx, k.cy, znear=0.05, zfar=10.0)
    gl_poses = [c.cam_to_world @ np.diag([1.0, -1, -1, 1]) for c in views]

    def run_bare():
        for pose in gl_poses:
            ps.set_pose(cam_node, pose)
            bare.render(ps, flags=pyrender.RenderFlags.SHADOWS_SPOT)

    with tempfile.TemporaryDirectory() as tmp:
        def run_stage():
            run_capture(rig, resolve_scene_path("turntable"), Path(tmp) / "capture", quiet=True)

        times = {"capture_stage": [], "pyrender": []}
        run_stage(), run_bare()  # warm-up
        for _ in range(repeats):
            times["capture_stage"].append(median_time(run_stage, repeats=1, warmup=0)[0])
            times["pyrender"].append(median_time(run_bare, repeats=1, warmup=0)[0])
    bare.delete()
    fps = {k: len(views) / float(np.median(v)) for k, v in times.items()}
    return {"scene": "turntable (default), 256x256", "views": len(views),
            "frames_per_s": {k: round(v, 2) for k, v in fps.items()},
            "time_ratio_stage_over_pyrender": round(fps["pyrender"] / fps["capture_stage"], 3),
            "seconds_per_repeat": {k: [round(x, 3) for x in v] for k, v in times.items()}}


def main(argv: list[str] | None = None) -> None:
    parse_flags("bench_capture", "The capture stage against bare pyrender.", argv, {})
    stage = pipeline_vs_bare()
    scene, cams = capture_scene(), capture_cameras()
    gl_poses = [c.cam_to_world @ np.diag([1.0, -1, -1, 1]) for c in cams]  # render.poses.opencv_to_opengl

    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    ours = RasterRenderer(scene, SIZE, SIZE)
    setup_ours = time.perf_counter() - t0

    def run_ours():
        for c in cams:
            ours.render(c)

    def run_ours_shadows():
        for c in cams:
            ours.render_shadow_maps()
            ours.render(c)

    ours_unshadowed = RasterRenderer(scene, SIZE, SIZE, shadows=False)

    def run_ours_unshadowed():
        for c in cams:
            ours_unshadowed.render(c)

    bare = pyrender.OffscreenRenderer(SIZE, SIZE)
    ps, cam_node = _bare_pyrender_scene(scene)

    def run_bare(flags=pyrender.RenderFlags.SHADOWS_SPOT):
        for pose in gl_poses:
            ps.set_pose(cam_node, pose)
            bare.render(ps, flags=flags)

    # interleave the variants repeat by repeat so drifting load on the shared cores hits all alike
    fns = {"ours": run_ours, "ours_shadow_maps_per_frame": run_ours_shadows, "pyrender": run_bare,
           "ours_no_shadows": run_ours_unshadowed,
           "pyrender_no_shadows": lambda: run_bare(pyrender.RenderFlags.NONE)}
    times = {name: [] for name in fns}
    for fn in fns.values():
        fn()  # warm-up: shader compilation, first uploads
    for _ in range(REPEATS):
        for name, fn in fns.items():
            times[name].append(median_time(fn, repeats=1, warmup=0)[0])
    ours.close()
    ours_unshadowed.close()
    bare.delete()  # last: pyrender's EGL teardown terminates the display every context shares

    fps = {name: N_VIEWS / float(np.median(t)) for name, t in times.items()}
    write_result("capture", {
        "scene": "textured box on a textured cylinder turntable, 2 shadowed spot lights",
        "size": [SIZE, SIZE], "views": N_VIEWS, "repeats": REPEATS,
        "frames_per_s": {k: round(v, 2) for k, v in fps.items()},
        "overhead_ratio": round(fps["pyrender"] / fps["ours"], 3),  # ours' time per frame / pyrender's
        "overhead_ratio_shadow_maps_per_frame": round(fps["pyrender"] / fps["ours_shadow_maps_per_frame"], 3),
        "overhead_ratio_no_shadows": round(fps["pyrender_no_shadows"] / fps["ours_no_shadows"], 3),
        "seconds_per_repeat": {k: [round(x, 4) for x in v] for k, v in times.items()},
        "setup_s_ours": round(setup_ours, 3),
        "load_avg_1min_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "capture_stage_vs_bare_pyrender": stage,
        "notes": "ours: float32 RGBA32F+RG32F 4x MSAA, rgb+depth+mask; pyrender: RGBA8 4x MSAA, uint8 rgb + depth. "
                 "Shadow maps 2048^2 for both.",
    })


if __name__ == "__main__":
    main(sys.argv[1:])
