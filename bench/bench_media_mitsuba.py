"""Scattering media against an independent renderer: our ``volpath`` vs Mitsuba 3's ``volpath``.

Figures (bench/results/media_mitsuba.json), measured in one run:

* ``closed_form_ray``: single scattering (ours: max_depth 1; Mitsuba: max_depth 2) along the
  camera ray of tests/render/test_media_single_scatter.py, 14.4 mm under the fog box's top in
  the Cornell geometry, against that test's closed form (scipy quadrature), with g = 0.5: ours,
  Mitsuba as the issue set it up (the light's shape has a black diffuse BSDF) and Mitsuba with a
  ``null`` BSDF on the light's shape. This is the ray that decides the fog-box discrepancy.
* ``cornell``: the fog-filled Cornell box of scenes/cornell_fog.yaml without the gold ball, 64 x
  64, per channel image means and ratios ours / Mitsuba, for the scene's fog with g = 0.5 and
  g = 0, pure absorption (sigma_s = 0) and no medium (the two controls), each with standard
  errors (ours: its variance image; Mitsuba: the spread of SEEDS independent renders) and z.
  ``mitsuba`` uses the null-BSDF light; ``mitsuba_opaque_light`` is the issue's setup.

Why the light's BSDF matters in Mitsuba (3.9.1): its ``volpath`` traces a shadow ray through a
null interface by re-spawning it off the surface (an offset of (1 + max|p|) * 8.9e-5 along the
normal: 0.05 mm at the Cornell box's millimetre coordinates) but counts only the distance to the
interface against the distance left, which ends 8.9e-4 * distance short of the light. A
shadow ray leaving the fog box's top (4.3 mm under the light) thus ends up to one offset above
the light's plane, i.e. past the light, whenever the vertex lies less than (1 + max|p|) / 10 =
55 mm below the light's plane (the offset over the sine of the ray's elevation exceeds the
margin): the ray reaches the light's own surface, whose black diffuse BSDF blocks it. Medium
vertices (and wall points) in that layer lose their direct light: on the closed-form ray (18.7 mm
below the light) Mitsuba returns 34-39% of the in-scattered light (what its phase samples find);
rays 50 and 60 mm below the light give 3% and 100% of the closed form (measured while
diagnosing); with a null-BSDF light it matches. A null BSDF lets such
rays through (the light stays an emitter; they end at most two offsets, < 0.1 mm, past its
plane, short of the ceiling). What passes through the light reaches the ceiling's patch behind
it, made black in Mitsuba's scene (:func:`_black_behind_lights`) because our emitters absorb.

Equivalence of the two scenes: the same triangles (our meshes written as OBJ, face normals), the
same pinhole camera (vertical fov 39.3077 degrees, 64 x 64, box pixel filter), RGB radiance and
albedos (Mitsuba's ``*_rgb`` variant: no spectral upsampling), Lambertian walls (two-sided, as
ours), a one-sided emitter, the fog as a ``homogeneous`` medium (sigma_t = sigma_a + sigma_s,
albedo sigma_s / sigma_t, per millimetre) inside a ``cube`` with a ``null`` BSDF (index-matched),
Henyey-Greenstein g with the same meaning (Mitsuba's wi points away from the vertex, hence its
1 + g^2 + 2 g cos), and the same path length: ours counts scattering events (max_depth), Mitsuba
counts vertices (max_depth + 1). Russian roulette differs (unbiased in both).

Run: ``.venv/bin/python -m bench.bench_media_mitsuba`` (``--quick`` for a smoke run). Needs
``pip install mitsuba`` (the ``bench`` extra); skips cleanly without it. The ``llvm_ad_rgb``
variant needs LLVM >= 19 (Debian's libllvm19; DRJIT_LIBLLVM_PATH is pointed at it when found),
otherwise ``scalar_rgb`` is used.
"""
from __future__ import annotations

import glob
import importlib.util
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from bench.common import parse_flags, write_result
from render.camera import Camera, Intrinsics
from render.integrators import RenderSettings, prepare
from render.poses import look_at
from render.scene import Emissive, Lambertian, Medium, Scene, SceneObject
from render.integrators.volpath import render_volpath

ROOT = Path(__file__).resolve().parent.parent
SIZE = 64
#: independent Mitsuba renders per configuration (their spread gives Mitsuba's standard error)
SEEDS = 8


def _load_closed_form():
    """The closed forms live with their test (tests/render/test_media_single_scatter.py)."""
    spec = importlib.util.spec_from_file_location("single_scatter", ROOT / "tests/render/test_media_single_scatter.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _mitsuba():
    """Import mitsuba with a working variant, or None. LLVM < 19 aborts the process inside
    drjit (not an exception), so the LLVM variant is chosen only when libLLVM 19+ is found."""
    if importlib.util.find_spec("mitsuba") is None:
        return None, None
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        found = []
        for path in glob.glob("/usr/lib/*/libLLVM*.so*"):
            m = re.match(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
            if m and int(m.group(1)) >= 19:
                found.append((int(m.group(1)), path))
        if found:
            os.environ["DRJIT_LIBLLVM_PATH"] = max(found)[1]
    import mitsuba as mi

    variant = "llvm_ad_rgb" if "DRJIT_LIBLLVM_PATH" in os.environ else "scalar_rgb"
    try:
        mi.set_variant(variant)
    except Exception:  # noqa: BLE001 - any failure to load the JIT backend: use the scalar one
        variant = "scalar_rgb"
        mi.set_variant(variant)
    return mi, variant


def cornell_fog(mode: str, g: float) -> Scene:
    """scenes/cornell_fog.yaml without the gold ball. mode: "fog" (its medium, with g),
    "absorb" (sigma_s = 0) or "none" (no medium)."""
    from rig.build import load_scene

    sc = load_scene("cornell_fog").scene
    objs = [o for o in sc.objects if o.name != "gold_ball"]
    med = sc.media[0]
    media = {"fog": [Medium(med.bounds, med.sigma_a, med.sigma_s, g=g)],
             "absorb": [Medium(med.bounds, med.sigma_a, np.zeros(3), g=g)], "none": []}[mode]
    return Scene(f"cornell_{mode}", objs, media=media)


def cornell_camera() -> Camera:
    from rig.build import load_scene

    c2w = load_scene("cornell_fog").cameras["scene"][0].cam_to_world
    return Camera(Intrinsics.from_fov(SIZE, SIZE, 39.3077), c2w, "cornell")


def mitsuba_scene(mi, scene: Scene, eye, target, up, fov_deg: float, size: int, spp: int, max_depth: int,
                  null_light: bool, tmp: Path) -> dict:
    """Mitsuba scene dict equivalent to ours (see the module docstring). max_depth: ours."""
    T = mi.ScalarTransform4f
    d = {"type": "scene",
         "integrator": {"type": "volpath", "max_depth": max_depth + 1},
         "sensor": {"type": "perspective", "fov": fov_deg, "fov_axis": "y",
                    "to_world": T().look_at(origin=list(map(float, eye)), target=list(map(float, target)),
                                            up=list(map(float, up))),
                    "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                             "pixel_format": "rgb"},
                    "sampler": {"type": "independent", "sample_count": spp}}}
    objects = _black_behind_lights(scene.objects) if null_light else list(scene.objects)
    for i, o in enumerate(objects):
        path = tmp / f"{i}_{o.name}.obj"
        lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in o.mesh.vertices]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in o.mesh.faces]
        path.write_text("\n".join(lines) + "\n")
        shape = {"type": "obj", "filename": str(path), "face_normals": True}
        if isinstance(o.material, Emissive):
            if o.material.two_sided:
                raise ValueError("a two-sided emitter has no Mitsuba area-light equivalent here")
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": o.material.radiance.tolist()}}
            black = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
            shape["bsdf"] = {"type": "null"} if null_light else black
        else:
            shape["bsdf"] = {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {
                "type": "rgb", "value": np.broadcast_to(o.material.albedo, (3,)).astype(float).tolist()}}}
        d[f"shape_{i}"] = shape
    for i, m in enumerate(scene.media):
        lo, hi = m.bounds.bounds
        if len(m.bounds.faces) != 12 or not np.isclose(m.bounds.volume, np.prod(hi - lo)):
            raise ValueError("only axis-aligned box media are translated")
        st = m.sigma_a + m.sigma_s
        d[f"medium_{i}"] = {
            "type": "cube", "to_world": T().translate(((lo + hi) / 2).tolist()).scale(((hi - lo) / 2).tolist()),
            "bsdf": {"type": "null"},
            "interior": {"type": "homogeneous", "sigma_t": {"type": "rgb", "value": st.tolist()},
                         "albedo": {"type": "rgb", "value": np.where(st > 0, m.sigma_s / np.maximum(st, 1e-300),
                                                                     0.0).tolist()},
                         "scale": 1.0, "phase": {"type": "hg", "g": float(m.g)}}}
    return d


def _black_behind_lights(objects) -> list:
    """The objects with every axis-aligned quad lying just behind a light (within 1 unit, facing
    it, e.g. the Cornell ceiling 0.1 mm above its light) split so that the part behind the light's
    footprint is black. With a null-BSDF light (see the module docstring) that part is reached
    only through the light, where ours absorbs: black keeps the scenes equivalent (a white
    ceiling there adds +0.6% without media and +2% in g = 0 fog, measured)."""
    lights = [o for o in objects if isinstance(o.material, Emissive)]
    out = []
    for o in objects:
        lo, hi = o.mesh.bounds
        flat = np.nonzero(hi - lo < 1e-9)[0]
        behind = None
        if len(flat) == 1 and len(o.mesh.faces) == 2 and isinstance(o.material, Lambertian):
            ax = flat[0]
            for light in lights:
                llo, lhi = light.mesh.bounds
                gap = (lo[ax] - llo[ax]) * -light.mesh.face_normals[0][ax]
                inside = np.all(np.delete((llo >= lo) & (lhi <= hi), ax))
                if lhi[ax] - llo[ax] < 1e-9 and 0 < gap < 1.0 and inside:
                    behind = (ax, llo, lhi)
        if behind is None:
            out.append(o)
            continue
        ax, llo, lhi = behind
        u, v = [k for k in range(3) if k != ax]
        us, vs = [lo[u], llo[u], lhi[u], hi[u]], [lo[v], llo[v], lhi[v], hi[v]]
        for a in range(3):
            for b in range(3):
                q = np.zeros((4, 3))
                q[:, ax] = lo[ax]
                q[:, u] = [us[a], us[a + 1], us[a + 1], us[a]]
                q[:, v] = [vs[b], vs[b], vs[b + 1], vs[b + 1]]
                if us[a + 1] - us[a] > 0 and vs[b + 1] - vs[b] > 0:
                    mat = Lambertian(0.0) if (a, b) == (1, 1) else o.material
                    out.append(SceneObject(f"{o.name}_{a}{b}", trimesh.Trimesh(q, [[0, 1, 2], [0, 2, 3]],
                                                                               process=False), mat))
    return out


def _mitsuba_mean(mi, scene_dict: dict, seeds: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(image mean (3,), its standard error (3,) from the seeds' spread, seconds)."""
    t0 = time.perf_counter()
    sc = mi.load_dict(scene_dict)
    means = np.array([np.asarray(mi.render(sc, seed=17 + k), dtype=np.float64)[..., :3].reshape(-1, 3).mean(0)
                      for k in range(seeds)])
    return means.mean(0), means.std(0, ddof=1) / np.sqrt(seeds), time.perf_counter() - t0


def _ours_mean(scene: Scene, cam: Camera, spp: int, max_depth: int, seed: int):
    """(image mean (3,), standard error (3,) from the variance image, seconds)."""
    t0 = time.perf_counter()
    r = render_volpath(scene, cam, RenderSettings(integrator="volpath", spp=spp, max_depth=max_depth, seed=seed),
                       prepared=prepare(scene))
    m = r.mean.reshape(-1, 3).astype(np.float64)
    se = np.sqrt(r.variance.reshape(-1, 3).astype(np.float64).sum(0)) / len(m)
    return m.mean(0), se, time.perf_counter() - t0


def _ratio(a, sa, b, sb) -> dict:
    """ours / Mitsuba per channel, its standard error (first order) and the z of the difference."""
    r = a / b
    return {"ratio": r.tolist(), "ratio_se": (r * np.sqrt((sa / a) ** 2 + (sb / b) ** 2)).tolist(),
            "z": ((a - b) / np.sqrt(sa ** 2 + sb ** 2)).tolist()}


def closed_form_ray(mi, cf, tmp: Path, quick: bool) -> dict:
    """Single scattering along the test's ray: closed form, ours, Mitsuba (both light BSDFs)."""
    scene = cf._scene(0.5, "area")
    expected = cf.single_scatter_area(0.5) * cf.LIGHT_LE
    spp = 20_000 if quick else 200_000
    cam = Camera(Intrinsics.from_fov(2, 2, 0.001), look_at(cf.RAY_O, cf.RAY_O + cf.RAY_D, np.array([0, 1.0, 0])))
    t0 = time.perf_counter()
    r = render_volpath(scene, cam, RenderSettings(integrator="volpath", spp=spp, max_depth=1, roulette=False, seed=5))
    ours = r.mean.reshape(-1, 3).astype(np.float64).mean(0)
    ours_se = np.sqrt(r.variance.reshape(-1, 3).astype(np.float64).sum(0)) / 4
    out = {"ray_origin_mm": cf.RAY_O.tolist(), "ray_direction": cf.RAY_D.tolist(), "g": 0.5,
           "closed_form": expected.tolist(), "ours": ours.tolist(), "ours_se": ours_se.tolist(),
           "ours_over_closed_form": (ours / expected).tolist(), "ours_z": ((ours - expected) / ours_se).tolist(),
           "ours_spp": spp, "ours_s": round(time.perf_counter() - t0, 2)}
    for key, null_light in (("mitsuba_opaque_light", False), ("mitsuba", True)):
        d = mitsuba_scene(mi, scene, cf.RAY_O, cf.RAY_O + cf.RAY_D, [0, 1, 0], 0.001, 2, spp // SEEDS, 1,
                          null_light, tmp)
        m, se, dt = _mitsuba_mean(mi, d, SEEDS)
        out[key] = {"mean": m.tolist(), "se": se.tolist(), "over_closed_form": (m / expected).tolist(),
                    "z": ((m - expected) / np.maximum(se, 1e-300)).tolist(), "s": round(dt, 2)}
    return out


def main(argv: list[str] | None = None) -> None:
    quick = parse_flags('bench_media_mitsuba', 'Participating media against Mitsuba 3.', argv, {"--quick": "a smoke run: smaller sizes and sample counts"}).quick
    mi, variant = _mitsuba()
    if mi is None:
        print("bench_media_mitsuba: skipped (mitsuba is not installed: pip install -e '.[bench]')")
        return
    cf = _load_closed_form()
    t_start = time.perf_counter()
    figs: dict = {"mitsuba_version": mi.__version__, "mitsuba_variant": variant}
    spp_ours, spp_mi = (32, 64) if quick else (1024, 1024)
    max_depth = 16
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        figs["closed_form_ray"] = closed_form_ray(mi, cf, tmp, quick)
        cam = cornell_camera()
        eye = cam.cam_to_world[:3, 3]
        target = eye + cam.cam_to_world[:3, 2]
        up = -cam.cam_to_world[:3, 1]  # OpenCV camera: y points down the image
        rows = {}
        for name, mode, g in (("fog_g0.5", "fog", 0.5), ("fog_g0", "fog", 0.0), ("absorb", "absorb", 0.5),
                              ("no_medium", "none", 0.5)):
            scene = cornell_fog(mode, g)
            ours, ours_se, t_ours = _ours_mean(scene, cam, spp_ours, max_depth, seed=11)
            row = {"ours": ours.tolist(), "ours_se": ours_se.tolist(), "ours_s": round(t_ours, 1)}
            for key, null_light in (("mitsuba", True), ("mitsuba_opaque_light", False)):
                d = mitsuba_scene(mi, scene, eye, target, up, 39.3077, SIZE, spp_mi // SEEDS, max_depth,
                                  null_light, tmp)
                m, se, dt = _mitsuba_mean(mi, d, SEEDS)
                row[key] = {"mean": m.tolist(), "se": se.tolist(), "s": round(dt, 1),
                            "ours_over": _ratio(ours, ours_se, m, se)}
            rows[name] = row
            print(name, "ours / mitsuba", np.round(row["mitsuba"]["ours_over"]["ratio"], 4),
                  "ours / mitsuba (opaque light)", np.round(row["mitsuba_opaque_light"]["ours_over"]["ratio"], 4),
                  flush=True)
    figs["cornell"] = {"size": SIZE, "max_depth_ours": max_depth, "max_depth_mitsuba": max_depth + 1,
                       "spp_ours": spp_ours, "spp_mitsuba": spp_mi, "mitsuba_seeds": SEEDS, **rows}
    figs["total_s"] = round(time.perf_counter() - t_start, 1)
    write_result("media_mitsuba", figs)


if __name__ == "__main__":
    main(sys.argv[1:])
