"""``lumigraph study caching``: does caching light paths pay? (issue 19, part 2; the lecture's
slides "LDD+E - variance control: ... OR cache results" and "the plenoptic function as a cache").

Ward's irradiance cache (:mod:`render.integrators.irradiance_cache`: records of indirect
irradiance at the first diffuse vertex, interpolated within the error bound a; direct light per
sample) against the unbiased path tracer, on the Cornell box and on the turntable (its spec
restricts the effects to direct light and shadows, so interreflection is switched on here: without
it there is nothing to cache). Per scene, at the profile's size::

    a long path-traced reference (``ref_spp`` samples: two independent halves, seeds 10^6 + seed
        and 10^6 + seed + 1), noise floor from its variance image
    path at 1, 2, 4, ... spp: time and RMSE against the reference (the equal-time curve)
    the cache at each error bound a (one cache from all ``cache_spp`` samples, ``record_rays`` rays
        per record): time split into record creation (tracing the records' rays), lookup
        (placement coverage tests and interpolation) and direct light; RMSE; and path at the
        same wall time (spp = the cache's seconds / path's seconds per spp), rendered and scored
    the bias at "infinite" samples: the cache with ``bias_rays`` rays per record and ``bias_spp``
        samples in GROUPS independent caches, split in two halves c1, c2 of whole groups, against
        the reference's two halves r1, r2: bias^2 = mean over pixels of (c1 - r1)(c2 - r2), whose
        expectation is exactly the squared bias (all four independent; clipped at 0 for bias_rms),
        with its standard error over pixels; "resolved" when above 2 standard errors (the errors
        are heavy-tailed: an outlier record spreads over its neighbours' pixels)

Every RMSE is over the pixels that see no emitter (reference radiance below EMITTER_CUT).

Files written into the study folder::

    caching_rmse.csv          every render: scene, method, a, spp, records, seconds (and split), RMSE
    caching_equal_time.csv    per scene and a: the cache's RMSE, path's at the same seconds, their ratio
    caching_bias.csv          per scene and a: RMSE, noise, bias at many record rays, image-mean bias
    rmse_vs_time_<scene>.svg  path's RMSE against seconds (line) and the cache's points (labelled a)
    bias_vs_error_bound.svg   the bias at many record rays against a, per scene
    time_split.svg            seconds in record creation and in lookups against a, per scene
    images_<scene>.png        reference | path at equal time | cache (middle a), side by side
    summary.json              the lecture contract's front page (title, claim, headline, figures)

Profiles: ``quick`` (96 x 96 Cornell, 64 x 48 turntable; about two minutes on 2 cores) and
``full`` (192 x 192, 160 x 120; more samples, record rays and error bounds). The environment variable
``LUMIGRAPH_CACHING_SIZE=tiny`` shrinks everything to seconds (16 x 16): for tests of the files
and the contract only; the summary records the size used. Timings are wall clock on a shared
machine: the ratios, not the seconds, are the result.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .lecture import size_name as lecture_size_name
from ..artifacts import write_json
from ..io import write_csv
from ..plot import PALETTE, Series, svg_plot, write_svg

__all__ = ["SIZE_ENV", "SIZES", "StudySize", "size_name", "run"]

#: environment variable selecting the tests' ``tiny`` size instead of the profile's
SIZE_ENV = "LUMIGRAPH_CACHING_SIZE"
#: the scenes and the effects each is rendered with (None: the scene's own)
SCENES = {"cornell": None, "turntable": ("direct", "shadows", "interreflection")}


@dataclass(frozen=True)
class StudySize:
    """The sizes of one profile. sizes: scene -> (width, height); ref_spp: the reference's
    samples; path_spp: the equal-time curve's sample counts; cache_spp: samples of the timed cache
    renders (direct light per sample, one lookup each); error_bounds: the a values; record_rays:
    rays per record in the timed runs; bias_rays / bias_spp: the "infinite samples" runs."""

    name: str
    sizes: dict
    ref_spp: int
    path_spp: tuple
    cache_spp: int
    error_bounds: tuple
    record_rays: int
    bias_rays: int
    bias_spp: int


SIZES = {
    "tiny": StudySize("tiny", {"cornell": (16, 16), "turntable": (16, 12)}, 64, (1, 4, 16), 4, (0.3, 0.8), 16, 64, 16),
    "quick": StudySize("quick", {"cornell": (96, 96), "turntable": (64, 48)}, 512, (1, 2, 4, 8, 16, 32, 64), 64,
                       (0.3, 0.6, 1.0), 128, 256, 256),
    "full": StudySize("full", {"cornell": (192, 192), "turntable": (160, 120)}, 2048,
                      (1, 2, 4, 8, 16, 32, 64, 128, 256), 128, (0.2, 0.4, 0.7, 1.0), 256, 512, 512),
}


def size_name(profile: str) -> str:
    """The size to run: the profile's, or ``tiny`` when ``$LUMIGRAPH_CACHING_SIZE`` says so (any
    other value of it is refused: BadInput naming the variable)."""
    return lecture_size_name(profile, SIZE_ENV)


CLAIM = ("Caching results is the other way to control the variance of LDD+E paths (the slide's 'OR cache "
         "results'): Ward's irradiance cache traces many rays at sparse records and interpolates their indirect "
         "irradiance within an error bound a, trading noise for bias. Tested here against a long path-traced "
         "reference, at equal wall time with unbiased path tracing: caching can pay only where indirect light "
         "is a large part of the noise and records are far fewer than pixels (large images, large a); where "
         "records approach the pixel count (small images, small a) their rays cost what path tracing's would, "
         "and where direct light or anti-aliasing dominates the noise (the turntable's spot lights and "
         "textures) the cache, which leaves direct light per sample, cannot beat path. Its bias does not fall "
         "with more record rays, only as a goes to 0, where the cache is the path tracer again.")


#: pixels whose reference radiance reaches this in some channel see an emitter (the Cornell light's
#: is (17, 12, 4); lit surfaces stay below 1): they are left out of every RMSE, since their
#: anti-aliasing noise (a sample sees 17 or 0.5) is the same for every method and would swamp the rest
EMITTER_CUT = 1.0


@dataclass
class _Image:
    """A mean image (H, W, 3) and the variance of that mean (H, W, 3)."""

    mean: np.ndarray
    variance: np.ndarray


def _rmse(img: np.ndarray, ref: np.ndarray, keep: np.ndarray) -> float:
    """RMSE over the pixels ``keep`` (H, W) bool, all channels."""
    d = img.astype(np.float64)[keep] - ref.astype(np.float64)[keep]
    return float(np.sqrt(np.mean(d ** 2)))


def _scene_and_camera(name: str, size: tuple[int, int]):
    """(scene, camera resized to ``size``, effects) of built-in scene ``name``: its first test
    view (the scene camera when it has none)."""
    from rig.build import build_scene
    from rig.spec import load_spec
    from render.effects import scene_effects

    from .reference import resize_camera

    spec, base = load_spec(name)
    rig = build_scene(spec, base)
    split = "test" if rig.cameras.get("test") else "scene"
    cam = resize_camera(rig.cameras[split][0], *size)
    effects = frozenset(SCENES[name]) if SCENES[name] is not None else frozenset(scene_effects(rig.scene))
    return rig.scene, cam, effects


def _study_scene(name: str, size: StudySize, seed: int, out: Path, on_step) -> dict:
    """Every measurement of one scene (module docstring): {rows, equal_time, bias, images}."""
    from render.image_io import write_exr
    from render.film import merge_results
    from render.integrators import RenderSettings, prepare, render
    from render.integrators.irradiance_cache import Options, render_cache

    scene, cam, effects = _scene_and_camera(name, size.sizes[name])
    ps = prepare(scene)
    ref_seed = 1_000_000 + seed
    t0 = time.perf_counter()
    # two independent halves (two seeds: halves of one Sobol render are stratified together, hence
    # correlated); the reference is their mean, and the bias test pairs each with half the cache
    ref_halves = [render(scene, cam, RenderSettings(integrator="path", spp=size.ref_spp // 2, seed=ref_seed + i),
                         effects=effects, prepared=ps) for i in (0, 1)]
    ref = _Image(0.5 * (ref_halves[0].mean + ref_halves[1].mean), 0.25 * (ref_halves[0].variance + ref_halves[1].variance))
    ref_s = time.perf_counter() - t0
    write_exr(out / "scratch" / f"reference_{name}.exr", ref.mean)
    keep = ref.mean.max(axis=2) < EMITTER_CUT
    ref_noise = float(np.sqrt(np.mean(ref.variance.astype(np.float64)[keep])))
    on_step(f"{name}: reference")
    rows = [{"scene": name, "method": "reference", "spp": size.ref_spp, "time_s": ref_s,
             "rmse": 0.0, "noise_rms": ref_noise}]
    # path: the equal-time curve (the first render also warms the kernels' caches)
    render(scene, cam, RenderSettings(integrator="path", spp=1, seed=seed), effects=effects, prepared=ps)
    curve = []
    for spp in size.path_spp:
        t0 = time.perf_counter()
        p = render(scene, cam, RenderSettings(integrator="path", spp=spp, seed=seed), effects=effects, prepared=ps)
        dt = time.perf_counter() - t0
        curve.append((spp, dt, _rmse(p.mean, ref.mean, keep)))
        rows.append({"scene": name, "method": "path", "spp": spp, "time_s": dt, "rmse": curve[-1][2]})
    on_step(f"{name}: path curve")
    # seconds per spp from the largest run (the least start-up per sample)
    s_per_spp = curve[-1][1] / curve[-1][0]
    equal, images = [], {"reference": ref.mean}
    middle = size.error_bounds[len(size.error_bounds) // 2]
    st = RenderSettings(integrator="irradiance_cache", spp=size.cache_spp, seed=seed)
    render_cache(scene, cam, RenderSettings(integrator="irradiance_cache", spp=1, seed=seed),
                 Options(error_bound=1.0, record_rays=4), (0, 1), effects, ps, groups=1)  # compile / warm
    for a in size.error_bounds:
        opts = Options(error_bound=a, record_rays=size.record_rays)
        t0 = time.perf_counter()
        c = render_cache(scene, cam, st, opts, (0, size.cache_spp), effects, ps, groups=1)
        dt = time.perf_counter() - t0
        rm = _rmse(c.mean, ref.mean, keep)
        s = c.stats
        rows.append({"scene": name, "method": "irradiance_cache", "error_bound": a, "record_rays": size.record_rays,
                     "spp": size.cache_spp, "records": s["records"], "time_s": dt, "create_s": s["create_s"],
                     "lookup_s": s["lookup_s"], "direct_s": s["direct_s"], "rmse": rm})
        spp_eq = max(1, int(round(dt / s_per_spp)))
        t1 = time.perf_counter()
        p = render(scene, cam, RenderSettings(integrator="path", spp=spp_eq, seed=seed + 1), effects=effects,
                   prepared=ps)
        dt_p = time.perf_counter() - t1
        rp = _rmse(p.mean, ref.mean, keep)
        equal.append({"scene": name, "error_bound": a, "records": s["records"], "pixels": int(c.mean.shape[0] * c.mean.shape[1]),
                      "cache_s": dt, "create_s": s["create_s"], "lookup_s": s["lookup_s"], "direct_s": s["direct_s"],
                      "cache_rmse": rm, "path_spp": spp_eq, "path_s": dt_p, "path_rmse": rp,
                      "path_over_cache": rp / max(rm, 1e-300), "pays": bool(rm < rp),
                      "ref_noise_rms": ref_noise})
        if a == middle:
            images["path_equal_time"], images["cache"] = p.mean, c.mean
        on_step(f"{name}: cache a={a:g}")
    # the bias at "infinite" samples: many record rays; two independent halves of the cache's
    # groups (c1, c2) against the reference's two halves (r1, r2): E[(c1 - r1)(c2 - r2)] = bias^2
    # exactly (all four independent), where mean (c - r)^2 minus variance estimates is at the
    # mercy of heavy-tailed pixels (measured: the variance images overstate the spread between
    # seeds 3x on the Cornell box at 64 spp, for path as for the cache)
    bias = []
    stb = RenderSettings(integrator="irradiance_cache", spp=size.bias_spp, seed=seed + 2)
    h = size.bias_spp // 2
    r1, r2 = (r.mean.astype(np.float64)[keep] for r in ref_halves)
    for a in size.error_bounds:
        opts = Options(error_bound=a, record_rays=size.bias_rays)
        c1, c2 = (render_cache(scene, cam, stb, opts, rng, effects, ps) for rng in ((0, h), (h, size.bias_spp)))
        c = merge_results(c1, c2)
        d = (c.mean.astype(np.float64) - ref.mean.astype(np.float64))[keep]
        mse = float(np.mean(d ** 2))
        products = (c1.mean.astype(np.float64)[keep] - r1) * (c2.mean.astype(np.float64)[keep] - r2)
        cross = float(np.mean(products))
        # its standard error over pixels (an underestimate: a record's error spreads over its neighbours)
        cross_se = float(np.std(products, ddof=1) / math.sqrt(products.size))
        noise2 = float(np.mean(c.variance.astype(np.float64)[keep] + ref.variance.astype(np.float64)[keep]))
        bias.append({"scene": name, "error_bound": a, "record_rays": size.bias_rays, "spp": size.bias_spp,
                     "groups": c.stats["groups"], "records": c.stats["records"], "rmse": math.sqrt(mse),
                     "noise_rms": math.sqrt(noise2), "bias_squared": cross, "bias_squared_se": cross_se,
                     "bias_resolved": bool(cross > 2.0 * cross_se), "bias_rms": math.sqrt(max(0.0, cross)),
                     "mean_rel_bias": float(d.mean() / max(float(ref.mean[keep].mean()), 1e-300)),
                     "time_s": c.stats["time_s"]})
        on_step(f"{name}: bias a={a:g}")
    return {"rows": rows, "equal_time": equal, "bias": bias, "images": images, "curve": curve,
            "ref_noise": ref_noise, "pixels_scored": int(keep.sum())}


def _rmse_plot(name: str, part: dict) -> str:
    curve = part["curve"]
    series = [Series("path (spp)", [c[1] for c in curve], [c[2] for c in curve], [f"{c[0]} spp" for c in curve],
                     PALETTE[0], line=True),
              Series("irradiance cache (a)", [e["cache_s"] for e in part["equal_time"]],
                     [e["cache_rmse"] for e in part["equal_time"]],
                     [f"a={e['error_bound']:g}" for e in part["equal_time"]], PALETTE[1], annotate=True)]
    return svg_plot(series, "wall seconds", "RMSE against the reference", f"{name}: RMSE against time", logx=True,
                    hlines=[(part["ref_noise"], "reference noise")])


def _bias_plot(parts: dict) -> str:
    series = []
    for i, (name, part) in enumerate(parts.items()):
        b = part["bias"]
        series.append(Series(f"{name}: bias", [r["error_bound"] for r in b], [r["bias_rms"] for r in b],
                             [f"{r['records']} records" for r in b], PALETTE[2 * i], line=True))
        series.append(Series(f"{name}: noise", [r["error_bound"] for r in b], [r["noise_rms"] for r in b],
                             colour=PALETTE[2 * i + 1], line=True, dashed=True))
    return svg_plot(series, "error bound a", "RMS over pixels", "bias at many record rays, and the remaining noise",
                    logx=True)


def _time_plot(parts: dict) -> str:
    series = []
    for i, (name, part) in enumerate(parts.items()):
        e = part["equal_time"]
        series.append(Series(f"{name}: record creation", [r["error_bound"] for r in e], [r["create_s"] for r in e],
                             [f"{r['records']} records" for r in e], PALETTE[2 * i], line=True))
        series.append(Series(f"{name}: lookups", [r["error_bound"] for r in e], [r["lookup_s"] for r in e],
                             colour=PALETTE[2 * i + 1], line=True, dashed=True))
    return svg_plot(series, "error bound a", "wall seconds", "where the cache's time goes", logx=True)


def _image_strip(images: dict) -> np.ndarray:
    """reference | path at equal time | cache, with a 2-pixel white gap: (H, 3W + 4, 3)."""
    ims = [images[k] for k in ("reference", "path_equal_time", "cache") if k in images]
    gap = np.ones((ims[0].shape[0], 2, 3), np.float32)
    parts = []
    for i, im in enumerate(ims):
        parts += ([gap] if i else []) + [im.astype(np.float32)]
    return np.concatenate(parts, axis=1)


def _headline(parts: dict) -> list[dict]:
    rows = []
    for name, part in parts.items():
        eq = part["equal_time"]
        best = max(eq, key=lambda r: r["path_over_cache"])
        worst = min(eq, key=lambda r: r["path_over_cache"])
        rows.append({"figure": f"{name}: path RMSE / cache RMSE at equal time (best a)",
                     "value": round(best["path_over_cache"], 3), "unit": "ratio (> 1: caching pays)",
                     "note": (f"a = {best['error_bound']:g}: {best['records']} records for {best['pixels']} pixels, "
                              f"{best['cache_s']:.2f} s; caching {'pays' if best['pays'] else 'does not pay'} "
                              f"(worst a = {worst['error_bound']:g}: ratio {worst['path_over_cache']:.2f})")})
        b = part["bias"]
        unresolved = [f"{r['error_bound']:g}" for r in b if not r["bias_resolved"]]
        rows.append({"figure": f"{name}: bias at many record rays (smallest / largest a)",
                     "value": f"{b[0]['bias_rms']:.4g} / {b[-1]['bias_rms']:.4g}", "unit": "RMS radiance",
                     "note": (f"a = {b[0]['error_bound']:g} / {b[-1]['error_bound']:g}, {b[0]['record_rays']} rays "
                              f"per record, {b[0]['spp']} spp; image-mean bias {100 * b[0]['mean_rel_bias']:+.2f}% / "
                              f"{100 * b[-1]['mean_rel_bias']:+.2f}%; remaining noise {b[0]['noise_rms']:.3g}"
                              + (f"; not resolved (bias^2 estimate within 2 standard errors of 0, heavy-tailed: "
                                 f"a record's outlier spreads over its neighbours) at a = {', '.join(unresolved)}"
                                 if unresolved else ""))})
        share = [r["create_s"] / max(r["create_s"] + r["lookup_s"], 1e-12) for r in eq]
        rows.append({"figure": f"{name}: record creation's share of the cache's time (per a)",
                     "value": " / ".join(f"{100 * s:.0f}%" for s in share), "unit": "%",
                     "note": "the rest: placement's coverage tests and the interpolation (lookups); a = "
                             + ", ".join(f"{r['error_bound']:g}" for r in eq)})
    return rows


FIGURES = ["rmse_vs_time_cornell.svg", "rmse_vs_time_turntable.svg", "images_cornell.png", "images_turntable.png",
           "bias_vs_error_bound.svg", "time_split.svg"]


def run(out: Path, profile: str = "quick", seed: int = 0, quiet: bool = False) -> dict:
    """Fill ``out`` (the lecture dispatch's temporary folder) with the study (module docstring);
    returns the manifest's metrics (flat numbers)."""
    from render.image_io import write_preview

    from ..progress import progress_bar

    name = size_name(profile)
    size = SIZES[name]
    out = Path(out)
    t0 = time.perf_counter()
    parts = {}
    steps = len(SCENES) * (2 + 2 * len(size.error_bounds))
    with progress_bar(quiet) as bar:
        task = bar.add_task("caching", total=steps, info="")

        def on_step(label: str) -> None:
            bar.update(task, advance=1, info=label)

        for scene in SCENES:
            parts[scene] = _study_scene(scene, size, seed, out, on_step)
    rows = [r for p in parts.values() for r in p["rows"]]
    write_csv(out / "caching_rmse.csv", rows, ["scene", "method", "error_bound", "record_rays", "spp", "records",
                                               "time_s", "create_s", "lookup_s", "direct_s", "rmse", "noise_rms"])
    equal = [r for p in parts.values() for r in p["equal_time"]]
    write_csv(out / "caching_equal_time.csv", equal, list(equal[0].keys()))
    bias = [r for p in parts.values() for r in p["bias"]]
    write_csv(out / "caching_bias.csv", bias, list(bias[0].keys()))
    for scene, part in parts.items():
        write_svg(out / f"rmse_vs_time_{scene}.svg", _rmse_plot(scene, part))
        write_preview(out / f"images_{scene}.png", _image_strip(part["images"]))
    write_svg(out / "bias_vs_error_bound.svg", _bias_plot(parts))
    write_svg(out / "time_split.svg", _time_plot(parts))
    summary = {"study": "caching", "title": "Caching light paths: Ward's irradiance cache against path tracing",
               "claim": CLAIM, "headline": _headline(parts), "figures": FIGURES, "profile": profile,
               "size": name, "seed": seed, "equal_time": equal, "bias": bias,
               "sizes": {k: list(v) for k, v in size.sizes.items()}, "reference_spp": size.ref_spp,
               "record_rays": size.record_rays, "bias_record_rays": size.bias_rays,
               "wall_s": round(time.perf_counter() - t0, 2)}
    write_json(out / "summary.json", summary)
    metrics = {"size": name, "wall_s": summary["wall_s"]}
    for r in equal:
        key = f"{r['scene']}_a{r['error_bound']:g}"
        metrics[f"{key}_path_over_cache"] = round(r["path_over_cache"], 4)
        metrics[f"{key}_records"] = r["records"]
    for r in bias:
        metrics[f"{r['scene']}_a{r['error_bound']:g}_bias_rms"] = round(r["bias_rms"], 6)
    return metrics
