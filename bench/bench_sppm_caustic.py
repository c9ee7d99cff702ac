"""The compiled ``sppm`` against ``path`` at equal time on the glass caustic (scenes/glass_caustic.yaml's
0.4 m source; bench_hard_paths' scene, camera and caustic region, 48 x 48).

Figures (bench/results/sppm_caustic.json), measured in one run against one long ``path``
reference (its own noise RMSE recorded; it is in every RMSE below, in quadrature):

* ``rows``: wall time and RMSE (whole image, caustic region, rest) of ``path`` at spp 4 .. 4096
  and of ``sppm`` at 2 .. 2048 passes for each photons-per-pass setting in PHOTONS (None: the
  pixel count, sppm's default; 50000: bench_hard_paths' SPPM_PHOTONS).
* ``equal_time``: per sppm setting, the RMSEs log-log interpolated at the longest time both it
  and path reached, and their ratios over path's (the issue's goal: the caustic region's ratio
  of the best strategy at most 0.5); ``vs_path_at_equal_time``: each sppm run's RMSEs over
  path's interpolated at that run's own wall time (path's range only).

The reference (``path``, REFERENCE_SPP) is cached in bench/results/ (its mean and variance, keyed
by size and spp; delete the file to re-render it): ``noise_rmse`` and ``noise_rmse_caustic``
are its own noise over the image and the caustic region.

SPPM is consistent, not unbiased: its RMSE holds the blur bias of its radii (which falls with
passes) as well as noise. Run: ``.venv/bin/python -m bench.bench_sppm_caustic`` (``--quick``:
24 x 24, short lists).
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

from bench.bench_hard_paths import _interp_loglog, _rmse, camera, caustic_region, caustic_scene
from bench.common import RESULTS_DIR, parse_flags, write_result
from render.integrators import RenderSettings, prepare, render

#: photons per pass compared (None: the pixel count, sppm's default) and their pass lists (full runs)
PHOTONS = {1_000: [8, 32, 128, 512, 2048], None: [2, 8, 32, 128, 512, 2048], 10_000: [2, 8, 32, 128, 512, 1024],
           50_000: [2, 8, 32, 128, 512]}
QUICK_PASSES = [2, 8, 32]
PATH_SPP = ([4, 16, 64], [4, 16, 64, 256, 1024, 4096])
REFERENCE_SPP = (1024, 32768)


def _reference(sc, cam, ps, spp: int):
    """(mean, variance) (H, W, 3) float64 of a ``path`` render of spp samples, cached on disk."""
    k = cam.intrinsics
    cache = RESULTS_DIR / f"sppm_caustic_reference_{k.width}x{k.height}_{spp}.npz"
    if cache.exists():
        z = np.load(cache)
        return z["mean"], z["variance"]
    ref = render(sc, cam, RenderSettings(integrator="path", spp=spp, max_depth=8, seed=999), prepared=ps)
    mean, var = ref.mean.astype(np.float64), ref.variance.astype(np.float64)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    np.savez(cache, mean=mean, variance=var)
    return mean, var


def main(argv: list[str] | None = None) -> None:
    quick = parse_flags('bench_sppm_caustic', 'The compiled sppm on the glass caustic against path at equal time.', argv, {"--quick": "a smoke run: smaller sizes and sample counts"}).quick
    load0 = os.getloadavg()
    cam = camera(24 if quick else 48)
    sc = caustic_scene()
    ps = prepare(sc)
    region = caustic_region(ps, cam)
    ts = time.perf_counter()
    ref_spp = REFERENCE_SPP[0 if quick else 1]
    ref_mean, ref_var = _reference(sc, cam, ps, ref_spp)
    figs = {"reference": {"render": f"path {ref_spp} spp", "time_s": round(time.perf_counter() - ts, 2),
                          "noise_rmse": float(ref_var.mean() ** 0.5),
                          "noise_rmse_caustic": float(ref_var[region].mean() ** 0.5),
                          "caustic_region_pixels": int(region.sum()),
                          "size": [cam.intrinsics.width, cam.intrinsics.height]}}
    rows = []
    runs = [("path", None, spp) for spp in PATH_SPP[0 if quick else 1]]
    runs += [("sppm", ph, n) for ph, lst in PHOTONS.items() for n in (QUICK_PASSES if quick else lst)]
    render(sc, cam, RenderSettings(integrator="sppm", spp=2, max_depth=8, seed=1), prepared=ps)  # kernels loaded
    for integ, photons, spp in runs:
        ts = time.perf_counter()
        r = render(sc, cam, RenderSettings(integrator=integ, spp=spp, max_depth=8, seed=spp,
                                           photons_per_pass=photons), prepared=ps)
        dt = time.perf_counter() - ts
        rows.append({"integrator": integ if integ == "path" else f"sppm_{photons or 'pixels'}", "spp": spp,
                     "time_s": round(dt, 4), "rmse": _rmse(r.mean, ref_mean),
                     "rmse_caustic": _rmse(r.mean, ref_mean, region), "rmse_rest": _rmse(r.mean, ref_mean, ~region)})
    path_rows = [r for r in rows if r["integrator"] == "path"]
    equal = {}
    for name in dict.fromkeys(r["integrator"] for r in rows if r["integrator"] != "path"):
        mine = [r for r in rows if r["integrator"] == name]
        t = min(max(r["time_s"] for r in mine), max(r["time_s"] for r in path_rows))
        if t < max(min(r["time_s"] for r in mine), min(r["time_s"] for r in path_rows)):
            continue  # no common time span
        entry = {"time_s": t}
        for key in ("rmse", "rmse_caustic", "rmse_rest"):
            a = _interp_loglog([(r["time_s"], r[key]) for r in mine], t)
            b = _interp_loglog([(r["time_s"], r[key]) for r in path_rows], t)
            entry.update({f"{key}_sppm": a, f"{key}_path": b, f"{key}_ratio_over_path": a / b})
        equal[name] = entry
    t_path = [r["time_s"] for r in path_rows]
    per_run = [{"integrator": r["integrator"], "spp": r["spp"], "time_s": r["time_s"],
                **{f"{key}_ratio_over_path": r[key] / _interp_loglog([(p["time_s"], p[key]) for p in path_rows],
                                                                     r["time_s"])
                   for key in ("rmse", "rmse_caustic", "rmse_rest")}}
               for r in rows if r["integrator"] != "path" and min(t_path) <= r["time_s"] <= max(t_path)]
    figs.update(equal_time=equal, vs_path_at_equal_time=per_run, rows=rows, load_average_before_after=[list(load0), list(os.getloadavg())])
    write_result("sppm_caustic_quick" if quick else "sppm_caustic", figs)


if __name__ == "__main__":
    main(sys.argv[1:])
