"""Hard light paths: accuracy per unit time of the integrators on a caustic and a fog scene, and
the cost of pruning (effects drive the integrator; media code only runs with media).

Figures (bench/results/hard_paths.json and hard_paths_rmse_time.csv), measured in one run:

* caustic scenes (glass ball on a diffuse floor under a square area light at 3 m, 48 x 48):
  ``caustic_small`` under the issue's small source (0.1 m, SMALL_SOURCE), against the per-pixel
  inverse-variance combination of long ``bdpt`` and ``path`` renders (:func:`combined_reference`),
  and ``caustic`` under scenes/glass_caustic.yaml's 0.4 m source, against a long ``path``
  render (both sources emit the same power). Each row's RMSE is over the whole image, the
  caustic region (:func:`caustic_region`) and the rest. Each of ``path`` (compiled
  kernels), ``volpath``, ``bdpt``, ``pssmlt`` (compiled chains) and ``sppm`` (rows' ``spp`` = passes of
  SPPM_PHOTONS photons, the pixel count) runs at spp chosen so its wall times span path's; ``<scene>_equal_time``
  interpolates every integrator's RMSE (log-log) at the longest time all of them reached, and
  ``<scene>_vs_path_at_equal_time`` divides each run's RMSE by path's at that run's own wall
  time. ``<scene>_reference.noise_rmse`` is the reference's own noise, included in every RMSE.
  The fog scene (the same floor and ball inside a homogeneous scattering fog) has ``volpath``
  only: bdpt, pssmlt and sppm do not render media (docs/architecture.md). Plot:
  hard_paths_rmse_time.svg (log10 RMSE vs time).
* which strategy wins where (``source_size_sweep``): for sources of side 1.6, 0.8, 0.4, 0.2, 0.1
  and 0.05 m at equal power, bdpt's and pssmlt's predicted RMSE at equal time over path's,
  sqrt(t v / (t_path v_path)) from each render's own variance estimate, over the image and over
  the caustic region (auto's SMALL_SOURCE_SR comes from here). Path finds a caustic only
  when a BSDF-sampled ray leaving the floor through the ball hits the source, so its variance
  there grows as the source's solid angle shrinks; bdpt's light subpaths do not care.
* pruning: median render time of the no-media scene with ``path`` (named: auto picks bdpt for
  this 0.4 m source since its small-source threshold moved to 0.058 sr), with ``volpath`` (what a
  scene with media would need), and with auto given an empty medium (volpath, media code running
  for nothing): ratios show what each pruning saves.

* samples per second (``samples_per_s``, :func:`samples_per_second`): path against the compiled
  volpath with and without media, and volpath's numpy reference; compiled sppm (passes x pixels
  per second at its default photons per pass, the pixel count), its photons per second at
  SPPM_PHOTONS_PER_S per pass, and its numpy reference.

Run: ``.venv/bin/python -m bench.bench_hard_paths`` (``--quick`` for a smoke run;
``--samples-per-s`` for the samples-per-second section alone; ``--sweep`` for the source-size
sweep alone, with the solid angle where bdpt stops winning: hard_paths_source_sweep.json).
"""
from __future__ import annotations

import csv
import os
import sys
import time

import numpy as np
import trimesh

from bench.common import RESULTS_DIR, median_time, parse_flags, write_result
from render.camera import Camera, Intrinsics
from render.integrators import RenderSettings, prepare, render
from render.poses import look_at
from render.scene import Dielectric, Emissive, Lambertian, Medium, Scene, SceneObject


def _quad(z, half, down=False):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]]) if not down else np.array([[0, 2, 1], [0, 3, 2]])
    return trimesh.Trimesh(v, f, process=False)


def caustic_scene(fog: float = 0.0, light_half: float = 0.2) -> Scene:
    """Glass ball (r 0.5) over a floor of albedo 0.6 under a square area light at z = 3 of side
    2 light_half and radiance 100 (0.2 / light_half)^2 (the same power at every size: 0.2 is
    scenes/glass_caustic.yaml's 0.4 m source); fog > 0 fills a 6 x 6 x 2.9 box above the floor
    with sigma_s = fog (albedo 1, g 0.3)."""
    ball = trimesh.creation.icosphere(3, 0.5)
    ball.apply_translation([0, 0, 0.8])
    Le = 100.0 * (0.2 / light_half) ** 2
    objs = [SceneObject("floor", _quad(0.0, 3.0), Lambertian(0.6)),
            SceneObject("ball", ball, Dielectric(1.5)),
            SceneObject("light", _quad(3.0, light_half, down=True), Emissive(np.full(3, Le)))]
    media = []
    if fog > 0:
        box = trimesh.creation.box([6.0, 6.0, 2.9])
        box.apply_translation([0, 0, 1.46])
        media = [Medium(box, sigma_s=fog, g=0.3)]
    return Scene("caustic" if fog == 0 else "fog", objs, media=media)


def camera(size: int) -> Camera:
    return Camera(Intrinsics.from_fov(size, size, 45.0),
                  look_at(np.array([0, -3.2, 2.2]), np.array([0, 0, 0.4]), np.array([0, 0, 1.0])), "c")


#: photons per sppm pass in this benchmark: None, the pixel count (sppm's default). Eye-pass noise
#: dominates on this scene, so more passes of fewer photons beat fewer of many at equal time: with
#: the compiled sppm at 48 x 48 (bench/bench_sppm_caustic.py) the caustic region's RMSE at equal
#: time was 0.45x path's with the pixel count (2304), 0.92x with 50000
SPPM_PHOTONS = None
#: photons per pass of the photons-per-second figure (samples_per_second)
SPPM_PHOTONS_PER_S = 50_000


def _rmse(a, b, mask=None):
    """RMSE over all pixels, or over the (H, W) bool ``mask``'s."""
    e2 = ((a.astype(np.float64) - b.astype(np.float64)) ** 2).mean(axis=-1)
    return float(np.sqrt(e2.mean() if mask is None else e2[mask].mean()))


def caustic_region(ps, cam: Camera, radius: float = 0.3) -> np.ndarray:
    """(H, W) bool: pixels whose first hit is the floor within ``radius`` of the spot under the
    ball, where the caustic lies (the rest of the image: the ball, its highlights and the floor
    lit directly). ps: the scene's :class:`render.integrators.PreparedScene`."""
    o, d = cam.pixel_rays()
    h = ps.accel.intersect(o, d)
    p = o + np.where(np.isfinite(h.t), h.t, 0.0)[:, None] * d
    k = cam.intrinsics
    floor = (h.tri >= 0) & (ps.geom.obj[np.maximum(h.tri, 0)] == 0)
    return (floor & (np.hypot(p[:, 0], p[:, 1]) < radius)).reshape(k.height, k.width)


def combined_reference(results) -> tuple[np.ndarray, float]:
    """Per-pixel inverse-variance combination of independent unbiased renders: (mean (H, W, 3),
    noise RMSE). Path and bdpt fail in different pixels (path in the caustic, bdpt in the
    light's sub-pixel highlights on the ball, which only its s = 0 strategy reaches, at about 30x
    path's cost per sample), so together they make a reference neither makes alone in the time."""
    w = [1.0 / (r.variance.astype(np.float64) + 1e-12) for r in results]
    mean = sum(wi * r.mean.astype(np.float64) for wi, r in zip(w, results)) / sum(w)
    return mean, float(np.sqrt(np.mean(1.0 / sum(w))))


#: spp (sppm: passes) per integrator, chosen so every integrator's wall times overlap path's
SPP_LISTS = {
    "path": ([4, 16, 64], [4, 16, 64, 256, 1024, 4096]),  # compiled: ~100x faster per sample
    "volpath": ([4, 16, 64], [4, 16, 64, 256, 1024, 4096]),  # compiled too
    "bdpt": ([4, 16, 64], [4, 16, 64, 256, 1024, 2048]),  # compiled: about 2x path's cost per sample
    "pssmlt": ([4, 16], [4, 16, 64, 256, 1024]),  # compiled chains: ~4x path's cost per mutation
    "sppm": ([2, 8, 32], [2, 8, 32, 128, 512, 2048]),  # compiled: passes of SPPM_PHOTONS photons
}
CAUSTIC_INTEGRATORS = ["path", "volpath", "bdpt", "pssmlt", "sppm"]


def _interp_loglog(points, t: float) -> float:
    """RMSE at time t from (time, rmse) points, interpolated in log-log (t within their range)."""
    ts, es = zip(*sorted(points))
    return float(np.exp(np.interp(np.log(t), np.log(ts), np.log(es))))


def _plot(rows: list[dict], path) -> None:
    """log10 RMSE against wall time (log), one line per (scene, integrator), as SVG."""
    from pipeline.plot import Series, svg_plot

    series = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for integ in dict.fromkeys(r["integrator"] for r in rows if r["scene"] == scene):
            pts = sorted((r["time_s"], r["rmse"], r["spp"]) for r in rows
                         if r["scene"] == scene and r["integrator"] == integ)
            series.append(Series(f"{scene}: {integ}", [p[0] for p in pts], [float(np.log10(p[1])) for p in pts],
                                 labels=[f"{integ} {p[2]}" for p in pts], line=True, dashed=scene == "fog"))
    svg = svg_plot(series, "wall time (s)", "log10 RMSE vs long reference",
                   "Hard light paths: RMSE against time (caustics: solid, fog: dashed)", logx=True)
    path.write_text(svg)


#: the issue's "small source": a 0.1 m square at 3 m (0.2: the yaml's 0.4 m source)
SMALL_SOURCE = 0.05
#: light half-sizes of the source-size sweep (same power at each size): with bdpt compiled it wins
#: glass_caustic.yaml's 0.4 m source too, so the sweep reaches up to sources where path wins again
SWEEP_HALVES = (0.8, 0.4, 0.2, 0.1, 0.05, 0.025)
#: spp per integrator in the sweep (full, quick): predicted equal-time RMSE from variance x time
SWEEP_SPP = {"path": (4096, 64), "bdpt": (2048, 32), "pssmlt": (128, 8)}


def _equal_time(rows: list[dict], scene: str) -> tuple[dict, list[dict]]:
    """RMSE of every caustic integrator interpolated (log-log) at the longest time all reached,
    over the whole image, the caustic region and the rest; and each run's image RMSE over
    path's at that run's own wall time (path within its range)."""
    def series(i, key):
        return [(r["time_s"], r[key]) for r in rows if r["scene"] == scene and r["integrator"] == i]

    t_common = min(max(t for t, _ in series(i, "rmse")) for i in CAUSTIC_INTEGRATORS)
    summary = {"time_s": t_common}
    for key in ("rmse", "rmse_caustic", "rmse_rest"):
        at = {i: _interp_loglog(series(i, key), t_common) if min(t for t, _ in series(i, key)) <= t_common else None
              for i in CAUSTIC_INTEGRATORS}
        summary[key] = at
        summary[f"{key}_ratio_over_path"] = {i: (at[i] / at["path"] if at[i] else None)
                                             for i in CAUSTIC_INTEGRATORS if i != "path"}
    at = summary["rmse"]
    best = min((i for i in at if at[i] is not None), key=lambda i: at[i])
    summary.update(best=best, rmse_ratio_best_over_path=at[best] / at["path"],
                   sppm_photons_per_pass=SPPM_PHOTONS or "pixel count")
    path_pts = series("path", "rmse")
    t_path = [t for t, _ in path_pts]
    per_run = [{"integrator": r["integrator"], "spp": r["spp"], "time_s": r["time_s"], "rmse": r["rmse"],
                "rmse_path": _interp_loglog(path_pts, r["time_s"]),
                "rmse_ratio_over_path": r["rmse"] / _interp_loglog(path_pts, r["time_s"])}
               for r in rows if r["scene"] == scene and r["integrator"] != "path"
               and min(t_path) <= r["time_s"] <= max(t_path)]
    return summary, per_run


def crossover_solid_angle(sweep: list[dict], integrator: str = "bdpt") -> float | None:
    """The emitter solid angle (sr) below which ``integrator``'s predicted whole-image RMSE at equal
    time beats path's: the geometric mean of the two neighbouring sweep sizes where the ratio
    crosses 1 (the sweep's sizes sorted by solid angle; the largest size where it still wins), or
    None when it wins at none of them; +inf when it wins at every size."""
    rows = sorted(sweep, key=lambda r: r["emitter_solid_angle_sr"])
    wins = [r[f"{integrator}_rmse_ratio_over_path_at_equal_time"] < 1.0 for r in rows]
    if not wins[0]:
        return None
    for k in range(1, len(rows)):
        if not wins[k]:
            return float(np.sqrt(rows[k - 1]["emitter_solid_angle_sr"] * rows[k]["emitter_solid_angle_sr"]))
    return float("inf")


def _source_sweep(cam: Camera, quick: bool) -> list[dict]:
    """Which strategy wins where: per source size, each unbiased integrator's predicted RMSE at
    equal time relative to path's, sqrt(t v / (t_path v_path)), with v the mean variance of the
    pixel means over the image and over the caustic region (an estimator's own variance: no
    reference needed). Heavy tails (the light's sub-pixel highlight on the ball) make v at low
    spp an underestimate, hence the spp."""
    out = []
    for half in SWEEP_HALVES:
        sc = caustic_scene(light_half=half)
        ps = prepare(sc)
        region = caustic_region(ps, cam)
        cost = {}
        for integ, (spp_full, spp_quick) in SWEEP_SPP.items():
            ts = time.perf_counter()
            r = render(sc, cam, RenderSettings(integrator=integ, spp=spp_quick if quick else spp_full, max_depth=8,
                                               seed=7), prepared=ps)
            dt = time.perf_counter() - ts
            v = r.variance.astype(np.float64).mean(axis=-1)
            cost[integ] = (dt, float(v.mean()), float(v[region].mean()), r.spp)
        tp, vp, vpc, _ = cost["path"]
        out.append({"light_side_m": 2 * half, "light_radiance": 100.0 * (0.2 / half) ** 2,
                    "emitter_solid_angle_sr": ps.emitter_solid_angle,
                    **{f"{i}_time_s": round(c[0], 4) for i, c in cost.items()},
                    **{f"{i}_spp": c[3] for i, c in cost.items()},
                    **{f"{i}_mean_variance": c[1] for i, c in cost.items()},
                    **{f"{i}_rmse_ratio_over_path_at_equal_time": float(np.sqrt(c[0] * c[1] / (tp * vp)))
                       for i, c in cost.items() if i != "path"},
                    **{f"{i}_caustic_rmse_ratio_over_path_at_equal_time": float(np.sqrt(c[0] * c[2] / (tp * vpc)))
                       for i, c in cost.items() if i != "path"}})
    return out


def samples_per_second(cam: Camera, quick: bool) -> dict:
    """Camera samples (paths) per second, measured in one run (median of repeats) so the ratios
    hold on a loaded machine: ``path`` and compiled ``volpath`` on the caustic scene (no media),
    compiled ``volpath`` on the fog scene (path cannot render media: its row is the same scene
    without the fog), and the numpy reference of volpath on both (the compiled kernels' speed-up).
    Rays per second (every Embree query) too: a fog path has several times more segments. pssmlt
    on the caustic scene: its samples are the paths that contribute to its image, the mutations
    (proposals) and the bootstrap's uniform paths (splatted since the bootstrap became one of its
    sampling techniques: render.integrators.pssmlt's estimator), over the whole run's time
    (``caustic_pssmlt_samples_per_s``; ``caustic_pssmlt_mutations_per_s`` counts the mutations
    alone, the figure before the bootstrap contributed); its marginal rate (the extra mutations
    of a 4x spp run over its extra time: the cost beyond the bootstrap), and its path sampler
    alone, compiled and numpy; compiled bdpt on the caustic scene. Every
    integrator of a scene is timed in turn within each repeat (interleaved; medians, and the
    per-repeat ratios to path). The issue's goal: each compiled integrator within 2x of path's
    samples/s. Load average recorded before and after."""
    import os

    from render.integrators.volpath import render_volpath

    load0 = os.getloadavg()
    spp, reps = (8, 3) if quick else (64, 15)  # 40-90 ms renders: 5 repeats left the ratios +-10%
    k = cam.intrinsics
    out = {"spp": spp, "size": [k.width, k.height], "repeats": reps}
    for scene_name, sc in (("caustic", caustic_scene()), ("fog", caustic_scene(0.4))):
        ps = prepare(sc)
        numpy_settings = RenderSettings(integrator="volpath", spp=max(spp // 8, 1), max_depth=8, seed=1)
        runs = {"volpath": lambda: render(sc, cam, RenderSettings(integrator="volpath", spp=spp, max_depth=8, seed=1),
                                          prepared=ps),
                "volpath_numpy": lambda: render_volpath(sc, cam, numpy_settings, prepared=ps, numpy_reference=True)}
        if scene_name == "caustic":
            runs["path"] = lambda: render(sc, cam, RenderSettings(integrator="path", spp=spp, max_depth=8, seed=1),
                                          prepared=ps)
            runs["pssmlt"] = lambda: render(sc, cam, RenderSettings(integrator="pssmlt", spp=spp, max_depth=8, seed=1),
                                            prepared=ps)
            # pssmlt's path sampler alone, on one step of a group's chains and on a bootstrap chunk
            from render.integrators.pssmlt import GROUP_CHAINS, primary_dims, sample_paths, sample_paths_numpy

            for rows in (GROUP_CHAINS, 1 << 15):
                U = np.random.default_rng(0).random((rows, primary_dims(8)))
                for sampler in (sample_paths, sample_paths_numpy):
                    t, _ = median_time(lambda: sampler(ps, cam, U, 8), repeats=reps)
                    out[f"pssmlt_{sampler.__name__}_{rows}_rows_per_s"] = rows / t
            # sppm: spp passes of (pixel count) photons each, a sample = one pixel's eye path of a pass
            runs["sppm"] = lambda: render(sc, cam, RenderSettings(integrator="sppm", spp=spp, max_depth=8, seed=1),
                                          prepared=ps)
        if scene_name == "caustic":
            runs["bdpt"] = lambda: render(sc, cam, RenderSettings(integrator="bdpt", spp=spp, max_depth=8, seed=1),
                                          prepared=ps)
            # pssmlt's per-mutation rate beyond its fixed bootstrap (GROUP_BOOTSTRAP x 16 paths): 4x the mutations
            runs["pssmlt_4x"] = lambda: render(sc, cam, RenderSettings(integrator="pssmlt", spp=4 * spp, max_depth=8,
                                                                       seed=1), prepared=ps)
        times = {name: [] for name in runs}
        warm = {name: fn() for name, fn in runs.items()}  # compiled code loaded, workspaces warm
        for _ in range(reps):  # interleaved: a load spike hits every integrator alike
            for name, fn in runs.items():
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)
        out[f"{scene_name}_times_s"] = times
        for name, ts in times.items():
            t = float(np.median(ts))
            n = k.width * k.height * {"volpath_numpy": max(spp // 8, 1), "pssmlt_4x": 4 * spp}.get(name, spp)
            if name.startswith("pssmlt"):  # its samples: mutations and the bootstrap's paths (both splatted)
                out[f"{scene_name}_{name}_mutations_per_s"] = n / t
                out[f"{scene_name}_{name}_bootstrap_paths"] = int(warm[name].stats["bootstrap"])
                n += int(warm[name].stats["bootstrap"])
            out[f"{scene_name}_{name}_samples_per_s"] = n / t
            if name not in ("volpath_numpy", "pssmlt", "pssmlt_4x"):  # Embree queries per second (pssmlt counts none)
                out[f"{scene_name}_{name}_rays_per_s"] = runs[name]().stats["rays"] / t
    path_sps = out["caustic_path_samples_per_s"]
    out["caustic_path_over_volpath"] = path_sps / out["caustic_volpath_samples_per_s"]
    out["caustic_path_over_pssmlt"] = path_sps / out["caustic_pssmlt_samples_per_s"]
    out["caustic_path_over_pssmlt_mutations_only"] = path_sps / out["caustic_pssmlt_mutations_per_s"]
    out["caustic_path_over_bdpt"] = path_sps / out["caustic_bdpt_samples_per_s"]
    n_path = spp * k.width * k.height
    n_pssmlt = n_path + out["caustic_pssmlt_bootstrap_paths"]
    out["caustic_path_over_pssmlt_per_repeat"] = [  # samples/s ratios: contributing paths over the same times
        (n_path / tp) / (n_pssmlt / tm)
        for tp, tm in zip(out["caustic_times_s"]["path"], out["caustic_times_s"]["pssmlt"])]
    out["caustic_path_over_bdpt_per_repeat"] = [
        tb / tp for tp, tb in zip(out["caustic_times_s"]["path"], out["caustic_times_s"]["bdpt"])]
    # the mutations beyond the bootstrap: 3 spp x W x H more mutations in the 4x run's extra time
    extra_t = float(np.median(out["caustic_times_s"]["pssmlt_4x"]) - np.median(out["caustic_times_s"]["pssmlt"]))
    out["caustic_pssmlt_marginal_mutations_per_s"] = 3 * spp * k.width * k.height / extra_t if extra_t > 0 else None
    out["caustic_path_over_pssmlt_marginal"] = (path_sps / out["caustic_pssmlt_marginal_mutations_per_s"]
                                                if extra_t > 0 else None)
    out["fog_volpath_vs_path_without_fog"] = path_sps / out["fog_volpath_samples_per_s"]
    out["fog_volpath_rays_per_sample"] = out["fog_volpath_rays_per_s"] / out["fog_volpath_samples_per_s"]
    out["caustic_path_rays_per_sample"] = out["caustic_path_rays_per_s"] / path_sps
    out["fog_volpath_rays_per_s_vs_path"] = out["caustic_path_rays_per_s"] / out["fog_volpath_rays_per_s"]
    for scene_name in ("caustic", "fog"):
        out[f"{scene_name}_volpath_compiled_over_numpy"] = (out[f"{scene_name}_volpath_samples_per_s"]
                                                            / out[f"{scene_name}_volpath_numpy_samples_per_s"])
    out["caustic_path_over_sppm"] = path_sps / out["caustic_sppm_samples_per_s"]
    out.update(_sppm_photons_per_second(cam, spp, reps))
    out["load_average_before_after"] = [list(load0), list(os.getloadavg())]
    return out


def _sppm_photons_per_second(cam: Camera, spp: int, reps: int) -> dict:
    """sppm on the caustic scene at SPPM_PHOTONS_PER_S photons per pass: photons per second of the
    compiled render (spp passes) and of its numpy reference (spp / 8 passes), and their ratio."""
    from render.integrators.sppm import render_sppm_numpy

    sc = caustic_scene()
    ps = prepare(sc)
    n_numpy = max(spp // 8, 1)
    t, _ = median_time(lambda: render(sc, cam, RenderSettings(integrator="sppm", spp=spp, max_depth=8, seed=1,
                                                              photons_per_pass=SPPM_PHOTONS_PER_S), prepared=ps),
                       repeats=reps)
    t_numpy, _ = median_time(lambda: render_sppm_numpy(sc, cam, n_numpy, SPPM_PHOTONS_PER_S, max_depth=8, seed=1,
                                                       prepared=ps), repeats=max(reps // 2, 1))
    out = {"caustic_sppm_photons_per_pass": SPPM_PHOTONS_PER_S,
           "caustic_sppm_photons_per_s": spp * SPPM_PHOTONS_PER_S / t,
           "caustic_sppm_numpy_photons_per_s": n_numpy * SPPM_PHOTONS_PER_S / t_numpy}
    out["caustic_sppm_compiled_over_numpy"] = out["caustic_sppm_photons_per_s"] / out["caustic_sppm_numpy_photons_per_s"]
    return out


def main(argv: list[str] | None = None) -> None:
    args = parse_flags("bench_hard_paths", "Hard light paths (caustics, fog) at equal time, integrator by integrator.", argv,
                       {"--quick": "a smoke run: smaller sizes and sample counts",
                        "--samples-per-s": "only the samples/s section (bench/results/hard_paths_samples_per_s.json)",
                        "--sweep": "only the source-size sweep, auto's crossover (hard_paths_source_sweep.json)"})
    quick = args.quick
    if args.samples_per_s:
        write_result("hard_paths_samples_per_s", samples_per_second(camera(24 if quick else 48), quick))
        return
    if args.sweep:
        load_before = os.getloadavg()
        t0 = time.perf_counter()
        sweep = _source_sweep(camera(24 if quick else 48), quick)
        write_result("hard_paths_source_sweep", {"load_average_before": load_before, "load_average_after": os.getloadavg(),
                                                 "total_s": round(time.perf_counter() - t0, 1),
                                                 "crossover_sr": crossover_solid_angle(sweep), "sweep": sweep})
        return
    size = 24 if quick else 48
    cam = camera(size)
    rows, figs = [], {}
    t0 = time.perf_counter()
    # (name, scene, reference renders as (integrator, spp), integrators compared)
    small_ref = [("bdpt", 256 if quick else 4096), ("path", 4096 if quick else 65536)]
    setups = (("caustic_small", caustic_scene(light_half=SMALL_SOURCE), small_ref, CAUSTIC_INTEGRATORS),
              ("caustic", caustic_scene(), [("path", 1024 if quick else 65536)], CAUSTIC_INTEGRATORS),
              ("fog", caustic_scene(0.4), [("volpath", 256 if quick else 4096)], ["volpath"]))
    for scene_name, sc, ref_runs, integs in setups:
        ps = prepare(sc)
        region = caustic_region(ps, cam)
        ts = time.perf_counter()
        refs = [render(sc, cam, RenderSettings(integrator=i, spp=n, max_depth=8, seed=999 + k), prepared=ps)
                for k, (i, n) in enumerate(ref_runs)]
        ref_mean, noise = combined_reference(refs)
        # the reference's own noise: every RMSE below includes it (in quadrature)
        figs[f"{scene_name}_reference"] = {"renders": [f"{i} {n} spp" for i, n in ref_runs],
                                           "time_s": round(time.perf_counter() - ts, 2), "noise_rmse": noise,
                                           "caustic_region_pixels": int(region.sum())}
        for integ in integs:
            for spp in SPP_LISTS[integ][0 if quick else 1]:
                ts = time.perf_counter()
                # photons_per_pass is sppm's option alone (the others refuse it)
                photons = SPPM_PHOTONS if integ == "sppm" else None
                r = render(sc, cam, RenderSettings(integrator=integ, spp=spp, max_depth=8, seed=spp,
                                                   photons_per_pass=photons), prepared=ps)
                dt = time.perf_counter() - ts
                rows.append({"scene": scene_name, "integrator": integ, "spp": spp, "time_s": round(dt, 4),
                             "rmse": _rmse(r.mean, ref_mean), "rmse_caustic": _rmse(r.mean, ref_mean, region),
                             "rmse_rest": _rmse(r.mean, ref_mean, ~region)})
    for scene_name in ("caustic_small", "caustic"):
        figs[f"{scene_name}_equal_time"], figs[f"{scene_name}_vs_path_at_equal_time"] = _equal_time(rows, scene_name)
    figs["source_size_sweep"] = _source_sweep(cam, quick)
    # pruning: no media -> path; volpath with no media; volpath with an empty (sigma 0) medium
    sc = caustic_scene()
    ps = prepare(sc)
    st = RenderSettings(spp=8 if quick else 32, max_depth=8, seed=1)
    empty = caustic_scene()
    empty.media = [Medium(trimesh.creation.box([6.0, 6.0, 2.9]), sigma_s=0.0)]
    pse = prepare(empty)
    reps = 3 if quick else 5
    t_path, _ = median_time(lambda: render(sc, cam, RenderSettings(**{**st.__dict__, "integrator": "path"}),
                                           prepared=ps), repeats=reps)
    t_vol, _ = median_time(lambda: render(sc, cam, RenderSettings(**{**st.__dict__, "integrator": "volpath"}),
                                          prepared=ps), repeats=reps)
    t_empty, _ = median_time(lambda: render(empty, cam, st, prepared=pse), repeats=reps)
    figs["pruning"] = {"path_s": t_path, "volpath_no_media_s": t_vol, "volpath_empty_medium_s": t_empty,
                       "volpath_over_path": t_vol / t_path, "empty_medium_over_no_media": t_empty / t_vol,
                       "spp": st.spp, "size": size}
    figs["samples_per_s"] = samples_per_second(cam, quick)
    figs["rmse_time"] = rows
    figs["total_s"] = round(time.perf_counter() - t0, 1)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    with open(RESULTS_DIR / "hard_paths_rmse_time.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["scene", "integrator", "spp", "time_s", "rmse", "rmse_caustic",
                                           "rmse_rest"])
        w.writeheader()
        w.writerows(rows)
    _plot(rows, RESULTS_DIR / "hard_paths_rmse_time.svg")
    write_result("hard_paths", figs)


if __name__ == "__main__":
    main(sys.argv[1:])
