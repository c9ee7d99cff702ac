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

Run: ``.venv/bin/python -m bench.bench_sampler`` (``--quick``: fewer spp levels, a shorter reference).
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import write_result

SIZE = 128


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


def main(argv: list[str]) -> None:
    quick = "--quick" in argv
    spps = [16, 64] if quick else [16, 64, 256]
    ref_spp = 256 if quick else 2048
    scene, cam = _cornell()
    figures = {"scene": "cornell", "size": [SIZE, SIZE], "max_depth": 8, "ours": _ours(scene, cam, spps, ref_spp)}
    if "--no-mitsuba" not in argv:
        figures["mitsuba"] = _mitsuba(scene, cam, spps, ref_spp)
    write_result("sampler_quick" if quick else "sampler", figures)


if __name__ == "__main__":
    main(sys.argv[1:])
