"""Spp for spp: RMSE of the Sobol and independent samplers on the Cornell box (128 x 128), and of
Mitsuba 3's multijitter and independent samplers on the same scene when ``mitsuba`` is installed.

Figures (bench/results/sampler.json), one run:

* ours (``path``, max_depth 8): for each spp and sampler (``sobol-blocks``, the default; ``sobol``;
  ``independent``), the RMSE of a render (seed 1) against a long reference of our own (seed 1000,
  REF_SPP, the ``sobol`` replicates), and the RMSE against the truth estimated by
  removing the reference's own noise: sqrt(max(MSE - mean var_ref, 0)) (the reference's variance
  image is the replicates', honest under Sobol); the ratio Sobol / independent per spp;
* Mitsuba (``path``, the same scene through bench.bench_media_mitsuba's translation, max_depth
  9 = our 8 bounces): RMSE of its renders against its own long reference (independent sampler at
  REF_SPP, seed 1000, so it shares no pattern with the renders), per spp and sampler, and the ratio multijitter / independent per spp. Each renderer
  is judged against its own reference so the figures measure noise, not the 0.2-0.3% mean
  offset between the two renderers (bench/results/media_mitsuba.json).

``--volpath`` (bench/results/sampler_volpath.json; ``--quick``: sampler_volpath_quick.json): volpath
on scenes/cornell_fog.yaml and scenes/glowing_smoke.yaml at VOL_SIZE^2 (max_depth 8), "sobol-blocks"
against "independent" against a long reference of our own ("sobol" replicates, seed 1000, its
variance subtracted as above): the RMSE at equal spp (seeds 1..VOL_SEEDS, mean of the per-seed
RMSEs), and at equal time: the seconds per spp of each sampler timed in interleaved rounds
at TIME_SPP (wall and CPU), the cost ratio the median of the rounds' CPU ratios (the wall ratios
of a round scatter too much on a shared machine; recorded beside), and the
independent sampler given the spp that costs what "sobol-blocks" costs at the top level (spp x
that ratio). Load averages before and
after are recorded.

Run: ``.venv/bin/python -m bench.bench_sampler`` (``--quick``: fewer spp levels, a shorter reference).
"""
from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import parse_flags, write_result

SIZE = 128
#: volpath's figures: image size, seeds per level, the spp the per-spp cost is timed at
VOL_SIZE = 64
VOL_SEEDS = 2
TIME_SPP = 64


def _cornell():
    from pipeline.stages.reference import resize_camera
    from rig.build import load_scene

    rig = load_scene("cornell")
    return rig.scene, resize_camera(rig.cameras["scene"][0], SIZE, SIZE)


def _ours(scene, cam, spps, ref_spp) -> dict:
    from render.integrators import RenderSettings, prepare, render

    ps = prepare(scene)
    t0 = time.perf_counter()
    # the replicates' sampler for the reference: its variance image (subtracted as the reference's
    # noise) is unbiased without a model; the default's is render.film.blocks_variance's
    ref = render(scene, cam, RenderSettings(integrator="path", spp=ref_spp, seed=1000, sampler="sobol"), prepared=ps)
    ref_s = time.perf_counter() - t0
    ref_mean = ref.mean.astype(np.float64)
    noise = float(ref.variance.astype(np.float64).mean())
    out = {"reference_spp": ref_spp, "reference_s": round(ref_s, 2), "reference_noise_mse": noise, "levels": []}
    for spp in spps:
        row = {"spp": int(spp)}
        for sampler in ("sobol-blocks", "sobol", "independent"):
            t0 = time.perf_counter()
            r = render(scene, cam, RenderSettings(integrator="path", spp=int(spp), seed=1, sampler=sampler), prepared=ps)
            mse = float(np.mean((r.mean.astype(np.float64) - ref_mean) ** 2))
            row[sampler] = {"rmse": np.sqrt(mse), "rmse_truth_est": np.sqrt(max(mse - noise, 0.0)),
                            "mean_variance": float(r.variance.astype(np.float64).mean()),
                            "seconds": round(time.perf_counter() - t0, 3)}
        row["ratio_sobol_to_independent"] = row["sobol"]["rmse_truth_est"] / row["independent"]["rmse_truth_est"]
        row["ratio_sobol_blocks_to_independent"] = (row["sobol-blocks"]["rmse_truth_est"]
                                                    / row["independent"]["rmse_truth_est"])
        out["levels"].append(row)
    return out


def _mitsuba(scene, cam, spps, ref_spp) -> dict:
    from bench.bench_media_mitsuba import _mitsuba as load_mitsuba
    from bench.bench_media_mitsuba import mitsuba_scene

    mi, variant = load_mitsuba()
    if mi is None:
        return {"skipped": "mitsuba is not installed"}
    c2w = np.asarray(cam.cam_to_world, np.float64)
    eye, forward, up = c2w[:3, 3], c2w[:3, 2], -c2w[:3, 1]  # OpenCV axes: z forward, y down
    fov_y = float(np.degrees(2 * np.arctan(cam.intrinsics.height / 2 / cam.intrinsics.fy)))
    out = {"mitsuba_version": mi.__version__, "variant": variant, "reference_spp": ref_spp, "levels": []}
    with tempfile.TemporaryDirectory() as tmp:
        def render(sampler: str, spp: int, seed: int) -> np.ndarray:
            d = mitsuba_scene(mi, scene, eye, eye + forward, up, fov_y, SIZE, spp, 8, False, Path(tmp))
            d["integrator"] = {"type": "path", "max_depth": 9}
            d["sensor"]["sampler"] = {"type": sampler, "sample_count": int(spp)}
            return np.asarray(mi.render(mi.load_dict(d), seed=seed), dtype=np.float64)[..., :3]

        t0 = time.perf_counter()
        ref = render("independent", ref_spp, 1000)  # independent: uncorrelated with either sampler's renders
        out["reference_s"] = round(time.perf_counter() - t0, 2)
        for spp in spps:
            row = {"spp": int(spp)}
            for sampler in ("multijitter", "independent"):
                row[sampler] = {"rmse": float(np.sqrt(np.mean((render(sampler, spp, 1) - ref) ** 2)))}
            row["ratio_multijitter_to_independent"] = row["multijitter"]["rmse"] / row["independent"]["rmse"]
            out["levels"].append(row)
    out["note"] = ("RMSE against Mitsuba's own independent-sampler reference, its noise not removed (no variance "
                   "image): it adds the reference's RMSE (~ the independent level's x sqrt(spp / REF_SPP)) in quadrature")
    return out


def _volpath_scene(name: str, spps: list[int], ref_spp: int, seeds: int, time_repeats: int) -> dict:
    """volpath's figures on built-in scene ``name`` (module docstring)."""
    from pipeline.stages.reference import resize_camera
    from render.integrators import RenderSettings, prepare, render
    from rig.build import load_scene

    rig = load_scene(name)
    scene, cam = rig.scene, resize_camera(rig.cameras["scene"][0], VOL_SIZE, VOL_SIZE)
    ps = prepare(scene)

    def run(sampler: str, spp: int, seed: int):
        t0, c0 = time.perf_counter(), time.process_time()
        r = render(scene, cam, RenderSettings(integrator="volpath", spp=int(spp), seed=seed, sampler=sampler), prepared=ps)
        return r, time.perf_counter() - t0, time.process_time() - c0

    run("independent", 1, 0)  # kernels loaded before anything is timed
    ref, ref_s, _ = run("sobol", ref_spp, 1000)
    ref_mean = ref.mean.astype(np.float64)
    noise = float(ref.variance.astype(np.float64).mean())

    def rmse(r) -> tuple[float, float]:
        mse = float(np.mean((r.mean.astype(np.float64) - ref_mean) ** 2))
        return np.sqrt(mse), np.sqrt(max(mse - noise, 0.0))

    out = {"scene": name, "size": [VOL_SIZE, VOL_SIZE], "reference_spp": ref_spp, "reference_s": round(ref_s, 2),
           "reference_noise_mse": noise, "reference_mean_rgb": ref_mean.mean((0, 1)).tolist(), "equal_spp": []}
    samplers = ("sobol-blocks", "independent")
    for spp in spps:
        row = {"spp": int(spp)}
        for sampler in samplers:
            errs = [rmse(run(sampler, spp, seed)[0]) for seed in range(1, seeds + 1)]
            row[sampler] = {"rmse": float(np.mean([e[0] for e in errs])),
                            "rmse_truth_est": float(np.mean([e[1] for e in errs])),
                            "per_seed_truth_est": [float(e[1]) for e in errs]}
        row["ratio_sobol_blocks_to_independent"] = (row["sobol-blocks"]["rmse_truth_est"]
                                                    / row["independent"]["rmse_truth_est"])
        out["equal_spp"].append(row)
    # seconds per spp, wall and CPU, of renders interleaved in rounds (the machine is shared). The
    # cost ratio is the median of the rounds' CPU ratios (this process's CPU seconds, both render
    # threads): at load 5-6 on 2 cores the rounds' wall ratios scattered 0.4-1.4 (recorded beside)
    times = {s: [] for s in samplers}
    cpu = {s: [] for s in samplers}
    for _ in range(time_repeats):
        for sampler in samplers:
            _, wall, c = run(sampler, TIME_SPP, 7)
            times[sampler].append(wall / TIME_SPP)
            cpu[sampler].append(c / TIME_SPP)
    per_spp = {s: statistics.median(t) for s, t in times.items()}
    rounds = [a / b for a, b in zip(times["sobol-blocks"], times["independent"])]
    cost = statistics.median([a / b for a, b in zip(cpu["sobol-blocks"], cpu["independent"])])
    top = int(spps[-1])
    ind_spp = max(1, int(round(top * cost)))
    errs = [rmse(run("independent", ind_spp, seed)[0])[1] for seed in range(1, seeds + 1)]
    sb = out["equal_spp"][-1]["sobol-blocks"]["rmse_truth_est"]
    out["equal_time"] = {"time_spp": TIME_SPP, "seconds_per_spp": {s: [round(x, 5) for x in t] for s, t in times.items()},
                         "cpu_seconds_per_spp": {s: [round(x, 5) for x in t] for s, t in cpu.items()},
                         "median_seconds_per_spp": per_spp, "round_wall_ratios": rounds,
                         "wall_cost_ratio_median": statistics.median(rounds),
                         "cost_ratio_sobol_blocks_to_independent": cost,
                         "sobol_blocks_spp": top, "independent_spp": ind_spp,
                         "independent_rmse_truth_est": float(np.mean(errs)),
                         "sobol_blocks_rmse_truth_est": sb,
                         "ratio_sobol_blocks_to_independent": sb / float(np.mean(errs))}
    return out


def volpath_main(quick: bool) -> None:
    spps = [16, 64] if quick else [16, 64, 256]
    ref_spp = 256 if quick else 4096
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    scenes = [_volpath_scene(n, spps, ref_spp, 1 if quick else VOL_SEEDS, 1 if quick else 5)
              for n in ("cornell_fog", "glowing_smoke")]
    figures = {"integrator": "volpath", "max_depth": 8, "scenes": scenes, "wall_s": round(time.perf_counter() - t0, 1),
               "load_before": load0, "load_after": os.getloadavg()}
    write_result("sampler_volpath_quick" if quick else "sampler_volpath", figures)


def main(argv: list[str] | None = None) -> None:
    args = parse_flags("bench_sampler", "Sobol against the independent sampler (and Mitsuba's), spp for spp.", argv,
                       {"--quick": "fewer spp levels, a shorter reference",
                        "--volpath": "the volpath study instead (bench/results/sampler_volpath.json)",
                        "--no-mitsuba": "ours alone"})
    quick = args.quick
    if args.volpath:
        volpath_main(quick)
        return
    spps = [16, 64] if quick else [16, 64, 256]
    ref_spp = 256 if quick else 2048
    scene, cam = _cornell()
    figures = {"scene": "cornell", "size": [SIZE, SIZE], "max_depth": 8, "ours": _ours(scene, cam, spps, ref_spp)}
    if not args.no_mitsuba:
        figures["mitsuba"] = _mitsuba(scene, cam, spps, ref_spp)
    write_result("sampler_quick" if quick else "sampler", figures)


if __name__ == "__main__":
    main(sys.argv[1:])
