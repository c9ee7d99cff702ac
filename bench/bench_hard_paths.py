"""Hard light paths: accuracy per unit time of the integrators on a caustic and a fog scene, and
the cost of pruning (effects drive the integrator; media code only runs with media).

Figures (bench/results/hard_paths.json and hard_paths_rmse_time.csv), measured in one run:

* caustic scene (glass ball on a diffuse floor under a small area light, 48 x 48): RMSE against
  a long ``path`` reference for ``path`` (compiled kernels) and ``volpath`` (numpy) at
  increasing spp, with wall times; the same on a fog scene (the floor and ball inside a
  homogeneous scattering fog, ``volpath`` only: path cannot render media) against a long
  ``volpath`` reference. ``sppm`` (render/sppm.py) on the caustic scene too, at passes chosen
  so its wall times span path's (rows' ``spp`` = passes, SPPM_PHOTONS photons per pass): the
  equal-time entry interpolates every integrator's RMSE (log-log) at the longest time all of
  them reached. sppm takes one eye sample per pixel per pass, so its image RMSE here is
  dominated by the edge pixels of the directly visible light (32 passes = 32 samples there
  against path's thousands), not by the caustic. ``bdpt`` and ``pssmlt`` likewise, each at spp
  chosen to span path's times; ``caustic_vs_path_at_equal_time`` divides each run's RMSE by
  path's at the same wall time. The fog scene has only ``volpath``: bdpt, pssmlt and sppm do not
  render media (docs/architecture.md). Plot: hard_paths_rmse_time.svg (log10 RMSE vs time).
* pruning: median render time of the no-media scene with ``path`` (what auto picks), with
  ``volpath`` (what a scene with media would need), and with ``volpath`` given an empty medium
  (media code running for nothing): ratios show what each pruning saves.

Run: ``.venv/bin/python -m bench.bench_hard_paths`` (``--quick`` for a smoke run).
"""
from __future__ import annotations

import csv
import sys
import time

import numpy as np
import trimesh

from bench.common import RESULTS_DIR, median_time, write_result
from render.camera import Camera, Intrinsics
from render.pathtracer import RenderSettings, prepare, render
from render.poses import look_at
from render.scene import Dielectric, Emissive, Lambertian, Medium, Scene, SceneObject


def _quad(z, half, down=False):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]]) if not down else np.array([[0, 2, 1], [0, 3, 2]])
    return trimesh.Trimesh(v, f, process=False)


def caustic_scene(fog: float = 0.0) -> Scene:
    """Glass ball (r 0.5) over a floor of albedo 0.6 under a 0.4 x 0.4 area light at z = 3;
    fog > 0 fills a 6 x 6 x 2.9 box above the floor with sigma_s = fog (albedo 1, g 0.3)."""
    ball = trimesh.creation.icosphere(3, 0.5)
    ball.apply_translation([0, 0, 0.8])
    objs = [SceneObject("floor", _quad(0.0, 3.0), Lambertian(0.6)),
            SceneObject("ball", ball, Dielectric(1.5)),
            SceneObject("light", _quad(3.0, 0.2, down=True), Emissive(np.full(3, 100.0)))]
    media = []
    if fog > 0:
        box = trimesh.creation.box([6.0, 6.0, 2.9])
        box.apply_translation([0, 0, 1.46])
        media = [Medium(box, sigma_s=fog, g=0.3)]
    return Scene("caustic" if fog == 0 else "fog", objs, media=media)


def camera(size: int) -> Camera:
    return Camera(Intrinsics.from_fov(size, size, 45.0),
                  look_at(np.array([0, -3.2, 2.2]), np.array([0, 0, 0.4]), np.array([0, 0, 1.0])), "c")


#: photons per sppm pass in this benchmark (eye-pass noise dominates on this scene: more passes
#: of fewer photons beat fewer passes of many at equal time)
SPPM_PHOTONS = 50_000


def _rmse(a, b):
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


#: spp (sppm: passes) per integrator, chosen so every integrator's wall times overlap path's
SPP_LISTS = {
    "path": ([4, 16, 64], [4, 16, 64, 256, 1024, 4096]),  # compiled: ~100x faster per sample
    "volpath": ([4, 16], [4, 16, 64, 256]),
    "bdpt": ([2, 8], [2, 8, 32, 128]),
    "pssmlt": ([4, 16], [4, 16, 64, 256]),
    "sppm": ([2, 8], [2, 8, 32, 128]),
}
CAUSTIC_INTEGRATORS = ["path", "volpath", "bdpt", "pssmlt", "sppm"]


def _interp_loglog(points, t: float) -> float:
    """RMSE at time t from (time, rmse) points, interpolated in log-log (t within their range)."""
    ts, es = zip(*sorted(points))
    return float(np.exp(np.interp(np.log(t), np.log(ts), np.log(es))))


def _plot(rows: list[dict], path) -> None:
    """log10 RMSE against wall time (log), one line per (scene, integrator), as SVG."""
    from pipeline.report import Series, svg_plot

    series = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for integ in dict.fromkeys(r["integrator"] for r in rows if r["scene"] == scene):
            pts = sorted((r["time_s"], r["rmse"], r["spp"]) for r in rows
                         if r["scene"] == scene and r["integrator"] == integ)
            series.append(Series(f"{scene}: {integ}", [p[0] for p in pts], [float(np.log10(p[1])) for p in pts],
                                 labels=[f"{integ} {p[2]}" for p in pts], line=True, dashed=scene != "caustic"))
    svg = svg_plot(series, "wall time (s)", "log10 RMSE vs long reference",
                   "Hard light paths: RMSE against time (caustic: solid, fog: dashed)", logx=True)
    path.write_text(svg)


def main(quick: bool = False) -> None:
    size = 24 if quick else 48
    ref_spp = 256 if quick else 4096
    caustic_ref_spp = 1024 if quick else 65536
    cam = camera(size)
    rows, figs = [], {}
    t0 = time.perf_counter()
    for scene_name, sc, ref_integ, integs in (("caustic", caustic_scene(), "path", CAUSTIC_INTEGRATORS),
                                              ("fog", caustic_scene(0.4), "volpath", ["volpath"])):
        ps = prepare(sc)
        ts = time.perf_counter()
        rspp = caustic_ref_spp if scene_name == "caustic" else ref_spp
        ref = render(sc, cam, RenderSettings(integrator=ref_integ, spp=rspp, max_depth=8, seed=999), prepared=ps)
        figs[f"{scene_name}_reference"] = {"integrator": ref_integ, "spp": rspp,
                                           "time_s": round(time.perf_counter() - ts, 2)}
        for integ in integs:
            for spp in SPP_LISTS[integ][0 if quick else 1]:
                ts = time.perf_counter()
                r = render(sc, cam, RenderSettings(integrator=integ, spp=spp, max_depth=8, seed=spp,
                                                   photons_per_pass=SPPM_PHOTONS), prepared=ps)
                dt = time.perf_counter() - ts
                rows.append({"scene": scene_name, "integrator": integ, "spp": spp, "time_s": round(dt, 4),
                             "rmse": _rmse(r.mean, ref.mean)})
    # equal-time comparison on the caustic scene: RMSE interpolated in log-log at a common time
    cau = {i: [(r["time_s"], r["rmse"]) for r in rows if r["scene"] == "caustic" and r["integrator"] == i]
           for i in CAUSTIC_INTEGRATORS}
    t_common = min(max(t for t, _ in v) for v in cau.values())
    at = {i: _interp_loglog(v, t_common) if min(t for t, _ in v) <= t_common else None for i, v in cau.items()}
    best = min((i for i in at if at[i] is not None), key=lambda i: at[i])
    figs["caustic_equal_time"] = {"time_s": t_common, "rmse": at, "best": best,
                                  "rmse_ratio_best_over_path": at[best] / at["path"],
                                  **{f"rmse_ratio_{i}_over_path": (at[i] / at["path"] if at[i] else None)
                                     for i in CAUSTIC_INTEGRATORS if i != "path"},
                                  "sppm_photons_per_pass": SPPM_PHOTONS}
    # every integrator against path at its own runs' wall times (path interpolated, within its range)
    t_path = [t for t, _ in cau["path"]]
    figs["caustic_vs_path_at_equal_time"] = [
        {"integrator": r["integrator"], "spp": r["spp"], "time_s": r["time_s"], "rmse": r["rmse"],
         "rmse_path": _interp_loglog(cau["path"], r["time_s"]),
         "rmse_ratio_over_path": r["rmse"] / _interp_loglog(cau["path"], r["time_s"])}
        for r in rows if r["scene"] == "caustic" and r["integrator"] != "path"
        and min(t_path) <= r["time_s"] <= max(t_path)]
    # pruning: no media -> path; volpath with no media; volpath with an empty (sigma 0) medium
    sc = caustic_scene()
    ps = prepare(sc)
    st = RenderSettings(spp=8 if quick else 32, max_depth=8, seed=1)
    empty = caustic_scene()
    empty.media = [Medium(trimesh.creation.box([6.0, 6.0, 2.9]), sigma_s=0.0)]
    pse = prepare(empty)
    reps = 3 if quick else 5
    t_path, _ = median_time(lambda: render(sc, cam, st, prepared=ps), repeats=reps)
    t_vol, _ = median_time(lambda: render(sc, cam, RenderSettings(**{**st.__dict__, "integrator": "volpath"}),
                                          prepared=ps), repeats=reps)
    t_empty, _ = median_time(lambda: render(empty, cam, st, prepared=pse), repeats=reps)
    figs["pruning"] = {"path_s": t_path, "volpath_no_media_s": t_vol, "volpath_empty_medium_s": t_empty,
                       "volpath_over_path": t_vol / t_path, "empty_medium_over_no_media": t_empty / t_vol,
                       "spp": st.spp, "size": size}
    figs["rmse_time"] = rows
    figs["total_s"] = round(time.perf_counter() - t0, 1)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    with open(RESULTS_DIR / "hard_paths_rmse_time.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["scene", "integrator", "spp", "time_s", "rmse"])
        w.writeheader()
        w.writerows(rows)
    _plot(rows, RESULTS_DIR / "hard_paths_rmse_time.svg")
    write_result("hard_paths", figs)


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
