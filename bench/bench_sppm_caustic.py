"""The compiled ``sppm`` against ``path`` at equal time on the glass caustic (scenes/glass_caustic.yaml's
0.4 m source; bench_hard_paths' scene, camera and caustic region, 48 x 48).

Figures (bench/results/sppm_caustic.json), measured in one run against one long ``path``
reference (its own noise RMSE recorded; it is in every RMSE below, in quadrature):

* ``rows``: wall time and RMSE (whole image, caustic region, rest) of ``path`` at spp 4 .. 4096
  and of ``sppm`` at 2 .. 512 passes for each photons-per-pass setting in PHOTONS (None: the
  pixel count, sppm's default; 50000: bench_hard_paths' SPPM_PHOTONS).
* ``equal_time``: per sppm setting, the RMSEs log-log interpolated at the longest time both it
  and path reached, and their ratios over path's (the issue's goal: the caustic region's ratio
  of the best strategy at most 0.5).

SPPM is consistent, not unbiased: its RMSE holds the blur bias of its radii (which falls with
passes) as well as noise. Run: ``.venv/bin/python -m bench.bench_sppm_caustic`` (``--quick``:
24 x 24, short lists).
"""
from __future__ import annotations

import os
import sys
import time

from bench.bench_hard_paths import _interp_loglog, _rmse, camera, caustic_region, caustic_scene
from bench.common import write_result
from render.integrators import RenderSettings, prepare, render

#: photons per pass compared (None: the pixel count, sppm's default)
PHOTONS = (None, 10_000, 50_000)
PATH_SPP = ([4, 16, 64], [4, 16, 64, 256, 1024, 4096])
SPPM_PASSES = ([2, 8, 32], [2, 8, 32, 128, 512])


def main(quick: bool = False) -> None:
    load0 = os.getloadavg()
    cam = camera(24 if quick else 48)
    sc = caustic_scene()
    ps = prepare(sc)
    region = caustic_region(ps, cam)
    ts = time.perf_counter()
    ref_spp = 1024 if quick else 32768
    ref = render(sc, cam, RenderSettings(integrator="path", spp=ref_spp, max_depth=8, seed=999), prepared=ps)
    ref_mean = ref.mean
    noise = float(ref.variance.astype(float).mean() ** 0.5)
    figs = {"reference": {"render": f"path {ref_spp} spp", "time_s": round(time.perf_counter() - ts, 2),
                          "noise_rmse": noise, "caustic_region_pixels": int(region.sum()),
                          "size": [cam.intrinsics.width, cam.intrinsics.height]}}
    rows = []
    runs = [("path", None, spp) for spp in PATH_SPP[0 if quick else 1]]
    runs += [("sppm", ph, n) for ph in PHOTONS for n in SPPM_PASSES[0 if quick else 1]]
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
    figs.update(equal_time=equal, rows=rows, load_average_before_after=[list(load0), list(os.getloadavg())])
    write_result("sppm_caustic_quick" if quick else "sppm_caustic", figs)


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
