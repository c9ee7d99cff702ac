"""Path tracer throughput and the cost of accuracy, on the Cornell box at 256 x 256.

Figures (bench/results/pathtracer.json), all measured in the same run (shared, noisy machines:
medians and ratios matter, not absolute numbers):

* bare embreex first-hit rays/s on the Cornell box (jittered camera rays, float32 arrays
  prepared beforehand, split over the same number of threads as the renderer), timed in
  rounds interleaved with the renders below (same machine load), and the load average;
* ``path`` and ``direct`` paths/s and rays/s (camera, extension and shadow rays) and their
  ratio to bare Embree (goal: the whole path tracer at >= 0.5 of bare Embree's rays/s);
* ``direct`` vs ``path`` time on a one-bounce scene (one convex object under an area light);
* an RMSE-vs-time curve of progressive ``path`` renders against a high-spp render
  (bench/results/pathtracer_rmse_time.csv and .png).

Run: ``.venv/bin/python -m bench.bench_pathtracer`` (``--quick`` for a smoke run).
"""
from __future__ import annotations

import csv
import importlib.util
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import trimesh

import embreex.mesh_construction as emesh
import embreex.rtcore_scene as escene

from bench.common import RESULTS_DIR, parse_flags, write_result
from render.camera import Camera, Intrinsics
from render.metrics import rmse
from render.film import RenderResult
from render.integrators import RenderSettings, prepare, refine, render
from render.poses import look_at
from render.scene import Emissive, Lambertian, Scene, SceneObject

THREADS = 2
ROOT = Path(__file__).resolve().parent.parent


def _cornell_module():
    """The programmatic Cornell box of the render tests (tests/render/cornell_box.py)."""
    spec = importlib.util.spec_from_file_location("lumigraph_cornell_box", ROOT / "tests" / "render" / "cornell_box.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def bare_embree_runner(scene: Scene, camera: Camera, passes: int, threads: int):
    """Bare embreex first-hit queries: one triangle soup, prebuilt float32 camera rays split over
    ``threads`` threads. Returns (run() -> None, rays per run, closer)."""
    tris = np.concatenate([np.asarray(o.mesh.vertices, np.float32)[np.asarray(o.mesh.faces)] for o in scene.objects])
    es = escene.EmbreeScene()
    emesh.TriangleMesh(es, np.ascontiguousarray(tris))
    k = camera.intrinsics
    rng = np.random.default_rng(0)
    jj, ii = np.meshgrid(np.arange(k.width), np.arange(k.height))
    px = np.stack([jj.ravel(), ii.ravel()], 1).astype(np.float64)
    px = np.concatenate([px + rng.random(px.shape) for _ in range(passes)])
    o, d = camera.pixel_rays(px)
    o, d = np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)
    bounds = np.linspace(0, len(o), threads + 1).astype(int)
    chunks = [(o[a:b], d[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    ex = ThreadPoolExecutor(threads)

    def run():
        list(ex.map(lambda c: es.run(c[0], c[1], output=True), chunks))

    return run, len(o), ex.shutdown


def interleaved(runs: dict, repeats: int) -> dict:
    """Time each of ``runs`` (name -> fn) once per round, round-robin, after one warm-up round:
    the bare baseline and the renders see the same machine load. Returns name -> (median wall
    seconds, minimum CPU seconds over all threads)."""
    wall = {k: [] for k in runs}
    cpu = {k: [] for k in runs}
    for r in range(repeats + 1):
        for k, fn in runs.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            if r:
                wall[k].append(time.perf_counter() - t0)
                cpu[k].append(time.process_time() - c0)
    return {k: (float(np.median(wall[k])), float(np.min(cpu[k]))) for k in runs}


def _figures(res: RenderResult, wall: float, cpu: float) -> dict:
    st = res.stats
    return {"seconds": wall, "cpu_seconds": cpu, "paths": st["paths"], "rays": st["rays"],
            "paths_per_s": st["paths"] / wall, "rays_per_s": st["rays"] / wall,
            "paths_per_cpu_s": st["paths"] / cpu, "rays_per_cpu_s": st["rays"] / cpu,
            "rays_per_path": st["rays"] / st["paths"]}


def one_bounce_scene() -> tuple[Scene, Camera]:
    """A convex diffuse ball under a downward area light, black background (no path has more
    than one bounce, so `direct` is lossless)."""
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    v = np.array([[-0.6, -0.6, 1.5], [0.6, -0.6, 1.5], [0.6, 0.6, 1.5], [-0.6, 0.6, 1.5]])
    light = trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)  # normal -z
    sc = Scene("one_bounce", [SceneObject("ball", ball, Lambertian([0.8, 0.6, 0.4])),
                              SceneObject("light", light, Emissive([4, 4, 4]))])
    cam = Camera(Intrinsics.from_fov(256, 256, 30.0), look_at([0, -3.0, 1.0], [0, 0, 0], [0, 0, 1]), "v")
    return sc, cam


def _throughput(scene, camera, settings, effects=None, prepared=None, repeats=5) -> dict:
    """Median wall time and minimum CPU time over the repeats (all threads; the minimum is the
    least disturbed by other jobs on a shared machine)."""
    res = {}

    def run():
        res["r"] = render(scene, camera, settings, effects=effects, prepared=prepared)

    (t, c), = interleaved({"r": run}, repeats).values()
    return _figures(res["r"], t, c)


def rmse_time_curve(scene, camera, prepared, ref_spp: int, max_spp: int, seed: int = 77) -> tuple[list[dict], dict]:
    """Progressive `path` renders at 2, 4, 8, ... spp (each refining the last) against a
    `ref_spp` render with another seed; returns the curve rows and the reference's own figures."""
    t0 = time.perf_counter()
    ref = render(scene, camera, RenderSettings(integrator="path", spp=ref_spp, seed=seed + 1), prepared=prepared)
    ref_time = time.perf_counter() - t0
    ref_floor = float(np.sqrt(np.mean(ref.variance)))  # the reference's own RMS standard error
    rows = []
    settings = RenderSettings(integrator="path", spp=2, seed=seed)
    t0 = time.perf_counter()
    cur = render(scene, camera, settings, prepared=prepared)
    spp = 2
    while True:
        elapsed = time.perf_counter() - t0
        err = rmse(cur.mean, ref.mean)
        predicted = float(np.sqrt(np.mean(cur.variance) + np.mean(ref.variance)))
        rows.append({"spp": spp, "seconds": elapsed, "rmse": err, "predicted_rmse": predicted})
        print(f"  spp {spp:5d}  {elapsed:7.2f} s  RMSE {err:.5f}  (predicted from variance {predicted:.5f})", flush=True)
        if spp >= max_spp:
            break
        cur = refine(cur, scene, camera, settings, spp, prepared=prepared)
        spp *= 2
    return rows, {"ref_spp": ref_spp, "ref_seconds": ref_time, "ref_rms_stderr": ref_floor}


def plot_loglog(path: Path, xs, ys, title: str, xlabel: str, ylabel: str, extra=None) -> None:
    """A minimal log-log line plot written with PIL (matplotlib is not a dependency)."""
    from PIL import Image, ImageDraw

    w, h, m = 640, 420, 60
    img = Image.new("RGB", (w, h), "white")
    dr = ImageDraw.Draw(img)
    series = [(np.asarray(xs, float), np.asarray(ys, float), (200, 40, 40))]
    if extra is not None:
        series.append((np.asarray(extra[0], float), np.asarray(extra[1], float), (120, 120, 120)))
    allx = np.concatenate([s[0] for s in series])
    ally = np.concatenate([s[1] for s in series])
    lx0, lx1 = np.floor(np.log10(allx.min())), np.ceil(np.log10(allx.max()))
    ly0, ly1 = np.floor(np.log10(ally.min())), np.ceil(np.log10(ally.max()))
    lx1, ly1 = max(lx1, lx0 + 1), max(ly1, ly0 + 1)

    def tx(x):
        return m + (np.log10(x) - lx0) / (lx1 - lx0) * (w - 2 * m)

    def ty(y):
        return h - m - (np.log10(y) - ly0) / (ly1 - ly0) * (h - 2 * m)

    dr.rectangle([m, m, w - m, h - m], outline="black")
    for e in range(int(lx0), int(lx1) + 1):
        x = tx(10.0 ** e)
        dr.line([x, m, x, h - m], fill=(225, 225, 225))
        dr.text((x - 12, h - m + 6), f"1e{e}", fill="black")
    for e in range(int(ly0), int(ly1) + 1):
        y = ty(10.0 ** e)
        dr.line([m, y, w - m, y], fill=(225, 225, 225))
        dr.text((6, y - 6), f"1e{e}", fill="black")
    for sx, sy, col in series:
        pts = [(tx(a), ty(b)) for a, b in zip(sx, sy)]
        dr.line(pts, fill=col, width=2)
        for x, y in pts:
            dr.ellipse([x - 3, y - 3, x + 3, y + 3], outline=col)
    dr.text((m, 20), title, fill="black")
    dr.text((w // 2 - 40, h - 25), xlabel, fill="black")
    dr.text((m + 6, m + 6), ylabel + "  (red: measured, grey: predicted from variance)", fill="black")
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)


def main(argv: list[str] | None = None) -> dict:
    quick = parse_flags("bench_pathtracer", "Path tracer throughput and noise on the Cornell box (256 x 256).", argv,
                        {"--quick": "1 spp per timing instead of 4"}).quick
    cb = _cornell_module()
    scene = cb.cornell_scene()
    cam = cb.cornell_camera(256, 256)
    ps = prepare(scene, threads=THREADS)
    spp = 1 if quick else 4
    figures: dict = {"scene": "cornell", "resolution": [256, 256], "threads": THREADS, "spp_per_timing": spp}

    repeats = 3 if quick else 9
    figures["load_average_start"] = os.getloadavg()
    bare_run, n_bare, bare_close = bare_embree_runner(scene, cam, passes=spp, threads=THREADS)
    res = {}
    settings = {"path": (RenderSettings(integrator="path", spp=spp), None),
                "direct": (RenderSettings(integrator="direct", spp=spp), {"direct", "soft_shadows"})}

    def renderer(k):
        def run():
            res[k] = render(scene, cam, settings[k][0], effects=settings[k][1], prepared=ps)
        return run

    timing = interleaved({"bare": bare_run, "path": renderer("path"), "direct": renderer("direct")}, repeats)
    bare_close()
    figures["load_average_end"] = os.getloadavg()
    figures["repeats"] = repeats
    figures["embree_called_directly"] = ps.accel.direct is not None
    bt, bc = timing["bare"]
    bare, bare_cpu = n_bare / bt, n_bare / bc
    figures["bare_embree"] = {"first_hit_rays_per_s": bare, "first_hit_rays_per_cpu_s": bare_cpu, "rays": n_bare,
                              "seconds": bt, "cpu_seconds": bc}
    print(f"load average {figures['load_average_start'][0]:.1f} -> {figures['load_average_end'][0]:.1f} "
          f"(2 cores); medians of {repeats} interleaved rounds", flush=True)
    print(f"bare embreex first hit: {bare / 1e6:.2f} M rays/s ({bare_cpu / 1e6:.2f} M per CPU second)", flush=True)
    for k in ("path", "direct"):
        figures[k] = _figures(res[k], *timing[k])
        figures[k]["rays_per_s_over_bare_embree"] = figures[k]["rays_per_s"] / bare
        figures[k]["rays_per_cpu_s_over_bare_embree"] = figures[k]["rays_per_cpu_s"] / bare_cpu
        print(f"{k:6s}: {figures[k]['paths_per_s'] / 1e3:.0f} k paths/s, {figures[k]['rays_per_s'] / 1e6:.2f} M rays/s "
              f"({figures[k]['rays_per_s_over_bare_embree']:.2f} x bare Embree; per CPU second "
              f"{figures[k]['rays_per_cpu_s_over_bare_embree']:.2f} x)", flush=True)

    sc1, cam1 = one_bounce_scene()
    ps1 = prepare(sc1, threads=THREADS)
    ob = {"direct_mis": _throughput(sc1, cam1, RenderSettings(integrator="direct", spp=spp), prepared=ps1),
          "direct_light_only": _throughput(sc1, cam1, RenderSettings(integrator="direct", spp=spp, strategy="light"),
                                           prepared=ps1),
          "path": _throughput(sc1, cam1, RenderSettings(integrator="path", spp=spp), prepared=ps1)}
    for k in ("direct_mis", "direct_light_only"):
        ob[f"path_over_{k}_time"] = ob["path"]["seconds"] / ob[k]["seconds"]
        ob[f"path_over_{k}_cpu_time"] = ob["path"]["cpu_seconds"] / ob[k]["cpu_seconds"]
    figures["one_bounce"] = ob
    print(f"one-bounce scene: path / direct(MIS) wall {ob['path_over_direct_mis_time']:.2f}, "
          f"cpu {ob['path_over_direct_mis_cpu_time']:.2f}; path / direct(light only) wall "
          f"{ob['path_over_direct_light_only_time']:.2f}, cpu {ob['path_over_direct_light_only_cpu_time']:.2f}", flush=True)

    res = 64 if quick else 128
    cam_c = cb.cornell_camera(res, res)
    rows, ref = rmse_time_curve(scene, cam_c, ps, ref_spp=64 if quick else 1024, max_spp=8 if quick else 128)
    csv_path = RESULTS_DIR / "pathtracer_rmse_time.csv"
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    with open(csv_path, "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    png_path = RESULTS_DIR / "pathtracer_rmse_time.png"
    plot_loglog(png_path, [r["seconds"] for r in rows], [r["rmse"] for r in rows],
                f"Cornell box {res}x{res}, path: RMSE vs time (ref {ref['ref_spp']} spp)", "seconds", "RMSE",
                extra=([r["seconds"] for r in rows], [r["predicted_rmse"] for r in rows]))
    figures["rmse_vs_time"] = {"resolution": [res, res], **ref, "curve": rows,
                               "csv": str(csv_path.relative_to(ROOT)), "png": str(png_path.relative_to(ROOT))}
    write_result("pathtracer", figures)
    for p in (ps, ps1):
        p.accel.close()
    return figures


if __name__ == "__main__":
    main(sys.argv[1:])
