"""The compiled ``bdpt`` against ``path``: samples per second, and the glass caustic at equal time.

Figures (bench/results/bdpt_compiled.json), measured in one run, with the machine and its load
average (on shared cores every time is inflated: quote the ratios, measured side by side):

* ``samples_per_s``: path and bdpt at 128 samples (passes) per pixel, max depth 8, the reference
  stage's 2 threads, interleaved over 5 repeats (medians), on bench_hard_paths' caustic scenes
  (scenes/glass_caustic.yaml's 0.4 m source and the issue's 0.1 m one, 48 x 48) and the Cornell
  box (64 x 64, interreflection: long subpaths at both ends, so the most joins per sample).
  ``path_over_bdpt`` is the ratio of their samples/s (issue 16's goal: at most 2).
* ``caustic_equal_time``: scenes/glass_caustic.yaml as it stands (0.4 m source, 48 x 48): each
  integrator at three sample counts (bdpt at half of path's, about equal times), RMSE against
  the inverse-variance combination of path at 32768 spp and bdpt at 8192 (its noise reported,
  overall and in the caustic region), over the image, the caustic region
  (bench_hard_paths.caustic_region) and the rest; each interpolated in log-log at the longest
  time both reached (issue 16's goal: bdpt's caustic RMSE at most 0.5x path's).

Run: ``.venv/bin/python -m bench.bench_bdpt_compiled`` (``--quick``: tiny sample counts, a smoke run).
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

from bench.bench_hard_paths import (SMALL_SOURCE, _interp_loglog, _rmse, camera, caustic_region, caustic_scene,
                                    combined_reference)
from bench.common import parse_flags, write_result
from render.integrators import RenderSettings, prepare, render


def _cornell():
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "render"))
    from cornell_box import cornell_camera, cornell_scene  # the measured Cornell box of the tests

    return cornell_scene(), cornell_camera(64, 64)


def samples_per_s(quick: bool) -> dict:
    """path and bdpt interleaved per scene: samples/s (medians of the repeats) and their ratio."""
    spp, repeats = (8, 2) if quick else (128, 5)
    scenes = {"caustic_0.4m": (caustic_scene(), camera(48)),
              f"caustic_{2 * SMALL_SOURCE:g}m": (caustic_scene(light_half=SMALL_SOURCE), camera(48)),
              "cornell_64": _cornell()}
    out = {"spp": spp, "max_depth": 8, "threads": 2, "repeats": repeats}
    for name, (sc, cam) in scenes.items():
        ps = prepare(sc)
        for integ in ("path", "bdpt"):  # compiled code loaded, workspaces warm
            render(sc, cam, RenderSettings(integrator=integ, spp=2, max_depth=8, seed=1), prepared=ps)
        times = {"path": [], "bdpt": []}
        npix = cam.intrinsics.width * cam.intrinsics.height
        for rep in range(repeats):
            for integ in times:
                t0 = time.perf_counter()
                render(sc, cam, RenderSettings(integrator=integ, spp=spp, max_depth=8, seed=rep), prepared=ps)
                times[integ].append(time.perf_counter() - t0)
        med = {i: float(np.median(v)) for i, v in times.items()}
        out[name] = {"times_s": times, "samples_per_s": {i: spp * npix / med[i] for i in med},
                     "path_over_bdpt": med["bdpt"] / med["path"],
                     "path_over_bdpt_per_repeat": [b / p for p, b in zip(times["path"], times["bdpt"])]}
    return out


def caustic_equal_time(quick: bool) -> dict:
    """RMSE of path and bdpt at equal time on the yaml's 0.4 m source (image, caustic region, rest)."""
    sc, cam = caustic_scene(), camera(24 if quick else 48)
    ps = prepare(sc)
    region = caustic_region(ps, cam)
    for integ in ("path", "bdpt"):
        render(sc, cam, RenderSettings(integrator=integ, spp=2, max_depth=8, seed=1), prepared=ps)
    t0 = time.perf_counter()
    ref_runs = [("path", 1024), ("bdpt", 256)] if quick else [("path", 32768), ("bdpt", 8192)]
    refs = [render(sc, cam, RenderSettings(integrator=i, spp=n, max_depth=8, seed=999 + k), prepared=ps)
            for k, (i, n) in enumerate(ref_runs)]
    ref, noise = combined_reference(refs)
    inv_var = sum(1.0 / (r.variance.astype(np.float64) + 1e-12) for r in refs)
    out = {"reference": {"renders": [f"{i} {n}" for i, n in ref_runs], "time_s": time.perf_counter() - t0,
                         "noise_rmse": noise, "noise_rmse_caustic": float(np.sqrt(np.mean(1.0 / inv_var[region]))),
                         "caustic_pixels": int(region.sum())}}
    rows = []
    for spp_path in ((8, 32) if quick else (64, 256, 1024)):
        for integ, spp in (("path", spp_path), ("bdpt", spp_path // 2)):
            t0 = time.perf_counter()
            r = render(sc, cam, RenderSettings(integrator=integ, spp=spp, max_depth=8, seed=spp + 7), prepared=ps)
            rows.append({"integrator": integ, "spp": spp, "time_s": time.perf_counter() - t0,
                         "rmse": _rmse(r.mean, ref), "rmse_caustic": _rmse(r.mean, ref, region),
                         "rmse_rest": _rmse(r.mean, ref, ~region)})
    series = lambda i, key: [(r["time_s"], r[key]) for r in rows if r["integrator"] == i]  # noqa: E731
    t_eq = min(max(t for t, _ in series(i, "rmse")) for i in ("path", "bdpt"))
    out.update(rows=rows, equal_time_s=t_eq)
    for key in ("rmse", "rmse_caustic", "rmse_rest"):
        p, b = _interp_loglog(series("path", key), t_eq), _interp_loglog(series("bdpt", key), t_eq)
        out[f"{key}_at_equal_time"] = {"path": p, "bdpt": b, "bdpt_over_path": b / p}
    return out


def main(argv: list[str] | None = None) -> None:
    quick = parse_flags('bench_bdpt_compiled', 'The compiled bdpt against path on the caustic scenes at equal time.', argv, {"--quick": "a smoke run: smaller sizes and sample counts"}).quick
    load0 = os.getloadavg()
    figs = {"samples_per_s": samples_per_s(quick), "caustic_equal_time": caustic_equal_time(quick)}
    figs["load_average"] = {"start": load0, "end": os.getloadavg()}
    write_result("bdpt_compiled", figs)


if __name__ == "__main__":
    main(sys.argv[1:])
