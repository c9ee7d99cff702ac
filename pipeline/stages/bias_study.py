"""``lumigraph study bias``: biased against unbiased, illuminance in a museum hall made into numbers.

The lecture's slide "Biased vs unbiased rendering" says that very few people can tell whether a
render is nearly physically correct. A light meter can. This study measures the irradiance E
(W/m^2 per channel, and its lux-like luminance Y, :mod:`render.sensors`) at a handful of sensor
points of the Cornell box (the "hall": the short block's top under the light, the floor in the open,
the back wall, the green wall, a ceiling corner lit only indirectly; millimetre frame, +Y up) three ways:

* **unbiased** (:func:`render.sensors.unbiased_irradiance`): the reference path tracer from the
  sensor, with a 95% normal confidence interval from the sample variance. A long run (another
  seed) is the reference; a second run, merged at doubling sample counts, is the curve whose
  interval narrows with time.
* **photon mapping** (:func:`render.sensors.photon_irradiance`: sppm's photon passes gathered at
  the sensors, progressive radii): its estimate (mean of K independent groups) at doubling
  passes, its bias falling as the radii shrink.
* **radiance cache** (Ward's irradiance cache, :mod:`render.integrators.irradiance_cache`):
  records of indirect irradiance placed among the first hits of the box's camera (and the
  sensors), interpolated at the sensors, plus direct light by next-event estimation, for error
  bounds a falling towards 0, K seeds each.

Files (in the study folder)::

    sensors.csv        the sensors and the reference: position, normal, E (R, G, B), Y, its 95% CI
    estimates.csv      one row per (estimator, sensor, budget): budget (samples, photons or error
                       bound), wall time (all sensors together), E, Y, the relative error against
                       the reference, the estimator's own 95% interval (Y_lo, Y_hi: the unbiased CI;
                       Student t over photon groups / cache seeds: noise only), inside the reference's
                       CI or not, the own interval holding the reference or not, photon mapping's mean
                       gather radius (mm), the cache's records
    bias_<sensor>.svg  per sensor: each estimator's Y relative to the reference (%) against time,
                       the unbiased 95% band beside the biased estimates
    bias_error.svg     every biased estimate's |error| (%) against time beside the unbiased
                       interval's half-width (%): where a measurement can tell
    summary.json       title, claim, headline (lecture contract, pipeline/stages/lecture.py)

Size: ``--profile quick`` (about a minute on two cores) or ``full``; ``$LUMIGRAPH_BIAS_SIZE=tiny``
(the CLI test's size, seconds) overrides the profile.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from render.integrators import prepare
from render.sensors import LUMINANCE, Sensor, SensorArray, lux_like, photon_irradiance, unbiased_irradiance

from .lecture import size_name as lecture_size_name
from ..artifacts import write_json
from ..io import write_csv
from ..plot import PALETTE, Series, svg_plot, write_svg

__all__ = ["run", "SIZES", "SIZE_ENV", "HALL_SENSORS", "BiasSize", "size_for", "first_inside"]

SIZE_ENV = "LUMIGRAPH_BIAS_SIZE"
LEVEL = 0.95
Z95 = 1.959963984540054  # two-sided 95% normal quantile

#: the hall's sensors (the Cornell box's millimetre frame, +Y up; the light is the quad
#: x 213..343, z 227..332 at y 548.7 emitting downwards)
HALL_SENSORS = (
    Sensor("under_light", (230.0, 165.0, 240.0), (0.0, 1.0, 0.0)),  # the short block's top, wholly lit
    Sensor("floor", (150.0, 0.0, 420.0), (0.0, 1.0, 0.0)),
    Sensor("back_wall", (278.0, 274.0, 559.2), (0.0, 0.0, -1.0)),
    Sensor("green_wall", (0.0, 274.0, 280.0), (1.0, 0.0, 0.0)),
    Sensor("ceiling_corner", (30.0, 548.8, 530.0), (0.0, -1.0, 0.0)),
)


@dataclass(frozen=True)
class BiasSize:
    """How much work each estimator gets.

    reference_samples: unbiased samples per sensor of the reference (seed + 1).
    curve_samples: the unbiased curve's largest sample count (checkpoints double from 256).
    photon_groups, photon_passes, photons_per_pass: photon mapping's K groups of P passes.
    radius_fraction: photon mapping's initial radius as a fraction of the scene's extent.
    error_bounds, record_rays, cache_seeds, cache_grid: the cache's error bounds a, hemisphere
    rays per record, independent caches per bound, camera first hits (grid x grid) it is built on;
    cache_direct_samples: samples per sensor of the direct light added to the cache's indirect.
    max_depth: scattering events (the sensor the first), the same for every estimator.
    """

    name: str
    reference_samples: int
    curve_samples: int
    photon_groups: int
    photon_passes: int
    photons_per_pass: int
    radius_fraction: float
    error_bounds: tuple
    record_rays: int
    cache_seeds: int
    cache_grid: int
    cache_direct_samples: int
    max_depth: int = 8


SIZES = {
    "tiny": BiasSize("tiny", 1 << 14, 1 << 10, 2, 4, 4000, 0.05, (1.0, 0.4), 32, 2, 16, 1 << 10),
    "quick": BiasSize("quick", 1 << 19, 1 << 17, 4, 32, 20000, 0.05, (1.0, 0.6, 0.4, 0.2), 256, 4, 64, 1 << 15),
    "full": BiasSize("full", 1 << 21, 1 << 19, 8, 128, 50000, 0.05, (1.0, 0.6, 0.4, 0.2, 0.1), 512, 6, 96,
                     1 << 18),
}


def size_for(profile: str) -> BiasSize:
    """The profile's size, or the tiny one when ``$LUMIGRAPH_BIAS_SIZE`` is ``tiny`` (any other
    value is refused: BadInput naming the variable)."""
    return SIZES[lecture_size_name(profile, SIZE_ENV)]


def _hall():
    """(scene, the box's camera) of scenes/cornell.yaml."""
    from rig.build import build_scene
    from rig.spec import load_spec

    spec, base = load_spec("cornell")
    rig_scene = build_scene(spec, base)
    return rig_scene.scene, rig_scene.cameras["scene"][0]


def _camera_first_hits(ps, camera, grid: int) -> tuple[np.ndarray, np.ndarray]:
    """First hits of a grid x grid of pixel-centre rays of ``camera`` on non-emitting surfaces:
    (points (M, 3), unit normals turned toward the camera (M, 3)), float64."""
    k = camera.intrinsics
    j, i = np.meshgrid((np.arange(grid) + 0.5) * k.width / grid, (np.arange(grid) + 0.5) * k.height / grid)
    o, d = camera.pixel_rays(np.stack([j.ravel(), i.ravel()], axis=1))
    h = ps.accel.intersect(o, d)
    hit = h.tri >= 0
    tri = h.tri[hit]
    p, ng = ps.geom.point_normal(tri, h.u[hit], h.v[hit])
    keep = ~ps.mats.emits[ps.geom.obj[tri]]
    n = np.where((np.sum(ng * d[hit], axis=1) > 0)[:, None], -ng, ng)
    return p[keep], n[keep]


def t95(groups: int) -> float:
    """Two-sided 95% Student-t quantile for the mean of ``groups`` independent estimates (nan below 2)."""
    from scipy import stats

    return float(stats.t.ppf(0.975, groups - 1)) if groups >= 2 else math.nan


def first_inside(inside: list[bool]) -> int | None:
    """Index of the first entry from which every later entry is True (None: the last is False)."""
    k = None
    for idx in range(len(inside) - 1, -1, -1):
        if not inside[idx]:
            break
        k = idx
    return k


# ------------------------------------------------------------------ the three estimators
def _reference(ps, sensors: SensorArray, size: BiasSize, seed: int):
    return unbiased_irradiance(None, sensors, size.reference_samples, seed=seed + 1, max_depth=size.max_depth,
                               prepared=ps)


def _unbiased_curve(ps, sensors: SensorArray, size: BiasSize, seed: int) -> list[dict]:
    """Doubling sample counts (256 ..) of one unbiased run (disjoint ranges merged): per checkpoint
    samples, cumulative wall time, (N, 4) mean and 95% interval."""
    rows, est, done, t = [], None, 0, 0.0
    target = 256  # smaller counts' intervals (tens of %) would only flatten the figures
    while target <= size.curve_samples:
        part = unbiased_irradiance(None, sensors, target - done, seed=seed, first_sample=done,
                                   max_depth=size.max_depth, prepared=ps)
        t += part.stats["time_s"]
        est = part if est is None else est.merge(part)
        done = target
        lo, hi = est.interval(LEVEL)
        rows.append({"budget": done, "time_s": t, "mean": est.s1 / est.n, "lo": lo, "hi": hi})
        target *= 2
    return rows


def _photon_curve(ps, sensors: SensorArray, size: BiasSize, seed: int) -> tuple[list[dict], float]:
    """Photon mapping at doubling passes: per checkpoint photons emitted (all groups), the
    cumulative time, (N, 4) mean over groups and its 95% Student-t interval across the K groups
    (noise only: the groups share the bias)."""
    radius0 = size.radius_fraction * ps.geom.extent
    est = photon_irradiance(None, sensors, size.photon_passes, size.photons_per_pass, radius0, seed=seed,
                            max_depth=size.max_depth, groups=size.photon_groups, prepared=ps)
    rows = []
    p = 1
    while p <= size.photon_passes:
        mean, se = est.at(p)
        half = t95(size.photon_groups) * se if se is not None else np.full_like(mean, np.nan)
        rows.append({"budget": p * size.photon_groups * size.photons_per_pass, "passes": p,
                     "time_s": float(est.time_s[p - 1]), "mean": mean, "lo": mean - half, "hi": mean + half,
                     "mean_radius": float(est.radius[:, p - 1].mean())})
        p *= 2
    return rows, radius0


def _cache_curve(ps, camera, sensors: SensorArray, size: BiasSize, seed: int) -> list[dict] | None:
    """Ward's irradiance cache at each error bound (largest first), as Ward and Radiance use it:
    records of *indirect* irradiance (render.integrators.irradiance_cache.build_cache with
    cache_direct False), placed among the camera's first hits plus the sensors and interpolated
    at the sensors, plus direct light by the unbiased estimator cut at one bounce (max_depth 1:
    next-event estimation and the cosine lobe, ``cache_direct_samples`` per sensor, computed once).
    ``cache_seeds`` independent caches per bound. Per bound: records, wall time (direct + all
    seeds' caches), (N, 4) mean over seeds and its 95% interval (Student t, K - 1 dof, on the
    caches' spread plus the direct term's variance). None when the cache module is missing."""
    try:
        from render.integrators.irradiance_cache import Options as CacheOptions, build_cache
    except ImportError:
        return None
    direct = unbiased_irradiance(None, sensors, size.cache_direct_samples, seed=seed + 2, max_depth=1, prepared=ps)
    direct_mean, direct_se = direct.s1 / direct.n, direct.standard_error()
    hits_p, hits_n = _camera_first_hits(ps, camera, size.cache_grid)
    points = np.concatenate([hits_p, sensors.points])
    normals = np.concatenate([hits_n, sensors.normals])
    rows = []
    for a in size.error_bounds:
        t0 = time.perf_counter()
        values, records = [], []
        options = CacheOptions(error_bound=a, record_rays=size.record_rays, cache_direct=False)
        for s in range(size.cache_seeds):
            cache = build_cache(ps, points, normals, options, size.max_depth, seed + 100 + s)
            E, served = cache.lookup(sensors.points, sensors.normals)
            if not served.all() or not np.all(np.isfinite(E)):  # build_cache serves every point it is given
                raise RuntimeError(f"irradiance cache: unserved or non-finite irradiance at the sensors "
                                   f"(error bound {a}): a bug in render.integrators.irradiance_cache")
            values.append(np.concatenate([E, lux_like(E)[:, None]], axis=1))
            records.append(len(cache.position))
        v = np.stack(values)
        mean = v.mean(axis=0) + direct_mean
        # the caches' spread (K - 1 dof) dominates the direct term's standard error: Student t on the sum
        var = direct_se ** 2 + (v.var(axis=0, ddof=1) / len(v) if len(v) > 1 else np.nan)
        half = t95(len(v)) * np.sqrt(var)
        rows.append({"budget": a, "time_s": direct.stats["time_s"] + time.perf_counter() - t0, "mean": mean,
                     "lo": mean - half, "hi": mean + half, "records": float(np.mean(records)),
                     "points": int(len(points))})
    return rows


# ------------------------------------------------------------------ tables, figures, headline
def _rows_for(estimator: str, budget_kind: str, curve: list[dict], sensors: SensorArray, ref_mean, ref_lo,
              ref_hi) -> list[dict]:
    out = []
    for c in curve:
        for i, name in enumerate(sensors.names):
            y = float(c["mean"][i, 3])
            out.append({
                "estimator": estimator, "sensor": name, "budget_kind": budget_kind, "budget": c["budget"],
                "time_s": float(c["time_s"]), "E_r": float(c["mean"][i, 0]), "E_g": float(c["mean"][i, 1]),
                "E_b": float(c["mean"][i, 2]), "Y": y, "Y_lo": _finite(c["lo"][i, 3]), "Y_hi": _finite(c["hi"][i, 3]),
                "Y_ref": float(ref_mean[i, 3]), "rel_error_pct": 100.0 * (y / ref_mean[i, 3] - 1.0),
                "inside_ref_ci": bool(ref_lo[i, 3] <= y <= ref_hi[i, 3]),
                "own_ci_holds_ref": _holds(c["lo"][i, 3], c["hi"][i, 3], ref_mean[i, 3]),
                "mean_radius": c.get("mean_radius"), "records": c.get("records")})
    return out


def _holds(lo, hi, value) -> bool | None:
    """Does the interval [lo, hi] contain value (None when the interval is unknown)?"""
    if not (math.isfinite(float(lo)) and math.isfinite(float(hi))):
        return None
    return bool(lo <= value <= hi)


def _finite(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def _pct(v: float, ref: float) -> float:
    return 100.0 * (v / ref - 1.0)


def sensor_plot(name: str, i: int, ref_mean, ref_lo, ref_hi, curves: dict) -> str:
    """Y of sensor i relative to the reference (%) against wall time (s, log): the unbiased
    estimate with its 95% band (dashed), photon mapping and the cache (labelled by budget),
    the reference's 95% CI as dashed lines."""
    ref = ref_mean[i, 3]
    series = []
    unb = curves["unbiased"]
    t = [c["time_s"] for c in unb]
    series.append(Series("unbiased (path)", t, [_pct(c["mean"][i, 3], ref) for c in unb], colour=PALETTE[0], line=True))
    series.append(Series("unbiased 95% CI", t, [_pct(c["hi"][i, 3], ref) for c in unb], colour=PALETTE[0], line=True,
                         dashed=True))
    series.append(Series("unbiased 95% CI (low)", t, [_pct(c["lo"][i, 3], ref) for c in unb], colour=PALETTE[0],
                         line=True, dashed=True))
    pm = curves["photon"]
    series.append(Series("photon mapping", [c["time_s"] for c in pm], [_pct(c["mean"][i, 3], ref) for c in pm],
                         labels=[f"{c['budget']:.2g} ph" for c in pm], colour=PALETTE[1], line=True, annotate=True))
    if curves.get("cache"):
        ca = curves["cache"]
        series.append(Series("irradiance cache", [c["time_s"] for c in ca], [_pct(c["mean"][i, 3], ref) for c in ca],
                             labels=[f"a={c['budget']:g}" for c in ca], colour=PALETTE[2], line=True, annotate=True))
    band = [(_pct(ref_hi[i, 3], ref), "reference +95%"), (_pct(ref_lo[i, 3], ref), "reference -95%")]
    svg = svg_plot(series, "wall time, all sensors (s)", "Y relative to the reference (%)",
                   title=f"{name}: Y = {ref:.4g} W/m^2 (lux-like)", logx=True, hlines=band)
    return svg


def error_plot(sensors: SensorArray, ref_mean, curves: dict) -> str:
    """|Y error| (%) of every biased estimate against wall time (log), one line per (estimator,
    sensor), beside the unbiased 95% half-width (%) of each sensor: below its line, a
    measurement of that cost cannot tell the biased estimate from the truth."""
    series = []
    for i, name in enumerate(sensors.names):
        ref = ref_mean[i, 3]
        unb = curves["unbiased"]
        series.append(Series(f"unbiased CI {name}", [c["time_s"] for c in unb],
                             [100.0 * (c["hi"][i, 3] - c["mean"][i, 3]) / ref for c in unb],
                             colour=PALETTE[i % len(PALETTE)], line=True, dashed=True))
        pm = curves["photon"]
        series.append(Series(f"photon {name}", [c["time_s"] for c in pm],
                             [abs(_pct(c["mean"][i, 3], ref)) for c in pm], colour=PALETTE[i % len(PALETTE)], line=True))
        if curves.get("cache"):
            ca = curves["cache"]
            series.append(Series(f"cache {name}", [c["time_s"] for c in ca],
                                 [abs(_pct(c["mean"][i, 3], ref)) for c in ca], colour=PALETTE[i % len(PALETTE)]))
    return svg_plot(series, "wall time, all sensors (s)", "|Y error| or 95% half-width (%)",
                    title="biased errors against the unbiased error bar", logx=True)


CLAIM = ("The lecture: 'very few people can tell if a render is nearly physically correct'. A light meter "
         "can be asked instead. Irradiance (and its lux-like luminance) at sensor points of the Cornell box by an "
         "unbiased path-traced estimator with a 95% confidence interval, against photon mapping (SPPM's "
         "progressive density estimate) and Ward's irradiance cache: at which budget each biased estimate "
         "lies inside the unbiased interval, how large its error still is at its largest budget, and how "
         "long an unbiased measurement needs to expose that error.")


def _entry(curve: list[dict], i: int, ref_lo, ref_hi, ref_y: float | None = None) -> dict:
    """Where estimate i of a curve enters, and stays inside, the reference's 95% CI (ref_y None),
    or where its own 95% interval starts to hold the reference value ref_y for good."""
    if ref_y is None:
        inside = [bool(ref_lo[i, 3] <= c["mean"][i, 3] <= ref_hi[i, 3]) for c in curve]
    else:
        inside = [bool(_holds(c["lo"][i, 3], c["hi"][i, 3], ref_y)) for c in curve]
    k = first_inside(inside)
    return {"index": k, "budget": None if k is None else curve[k]["budget"],
            "time_s": None if k is None else round(float(curve[k]["time_s"]), 3)}


def exposure_time(unbiased_end: dict, i: int, ref_y: float, error_pct: float) -> float:
    """Wall time (s) after which the unbiased estimator's 95% half-width at sensor i falls below
    |error_pct| (% of ref_y): its half-width scales as 1 / sqrt(time) from the curve's last
    checkpoint ``unbiased_end``. inf for a zero error."""
    half_pct = 100.0 * (unbiased_end["hi"][i, 3] - unbiased_end["mean"][i, 3]) / ref_y
    if error_pct == 0.0:
        return math.inf
    return float(unbiased_end["time_s"] * (half_pct / abs(error_pct)) ** 2)


def headline(sensors: SensorArray, ref, ref_lo, ref_hi, curves: dict) -> tuple[list[dict], dict]:
    """The summary's headline rows (lecture contract) and the flat metrics for the manifest.

    Per biased estimator and sensor: the budget from which its own 95% noise interval holds the
    reference for good (no bias measurable at its own noise; "not within budget" when the last
    does not), the budget from which its estimate stays inside the reference's 95% CI (strict: the
    reference's interval is far narrower), its error at the largest budget with its own noise,
    and how long an unbiased measurement needs for its 95% half-width to fall below that error
    (from then on a light meter can tell)."""
    ref_mean = ref.s1 / ref.n
    rows, metrics = [], {}
    half_ref = 100.0 * (ref_hi[:, 3] - ref_mean[:, 3]) / ref_mean[:, 3]
    rows.append({"figure": "reference: 95% CI half-width of Y (widest sensor)", "value": round(float(half_ref.max()), 4),
                 "unit": "%", "note": f"unbiased, {ref.n} samples per sensor, another seed than the curve"})
    metrics["reference_half_width_pct_max"] = float(half_ref.max())
    unb = curves["unbiased"]
    cover = [bool(c["lo"][i, 3] <= ref_mean[i, 3] <= c["hi"][i, 3]) for c in unb for i in range(len(sensors))]
    rows.append({"figure": "unbiased: 95% CIs along the curve that contain the reference",
                 "value": f"{sum(cover)}/{len(cover)}", "unit": "",
                 "note": "checkpoints x sensors; about 95% expected (checkpoints share samples)"})
    metrics["unbiased_curve_coverage"] = sum(cover) / len(cover)
    for key, label, unit in (("photon", "photon mapping", "photons"), ("cache", "irradiance cache", "error bound")):
        curve = curves.get(key)
        if not curve:
            rows.append({"figure": f"{label}", "value": "not run", "unit": "",
                         "note": "render.integrators.irradiance_cache is missing"})
            continue
        last = curve[-1]
        worst = 0.0
        for i, name in enumerate(sensors.names):
            y_ref = ref_mean[i, 3]
            e = _entry(curve, i, ref_lo, ref_hi, y_ref)
            strict = _entry(curve, i, ref_lo, ref_hi)
            err = _pct(last["mean"][i, 3], y_ref)
            noise = 100.0 * (last["hi"][i, 3] - last["mean"][i, 3]) / y_ref
            t_expose = exposure_time(unb[-1], i, y_ref, err)
            value = "not within budget" if e["budget"] is None else e["budget"]
            if not math.isfinite(noise):
                exposed = f"its own noise unknown (one group); an unbiased measurement's half-width falls below " \
                          f"the error after {t_expose:.2g} s"
            elif abs(err) > noise:
                exposed = f"an unbiased measurement exposes it after {t_expose:.2g} s"
            else:
                exposed = "within its own noise: not a measured bias"
            inside = "never" if strict["budget"] is None else f"from {strict['budget']:g} {unit}"
            rows.append({"figure": f"{label}, {name}: no bias measurable at its own noise from", "value": value,
                         "unit": "" if e["budget"] is None else unit,
                         "note": f"error {err:+.2f}% (own 95% noise +-{noise:.2f}%) at {last['budget']:g} {unit}, "
                                 f"{last['time_s']:.3g} s; inside the reference's 95% CI: {inside}; {exposed}"})
            metrics[f"{key}_{name}_noise_pct"] = noise if math.isfinite(noise) else -1.0
            metrics[f"{key}_{name}_error_pct"] = err
            metrics[f"{key}_{name}_consistent_from"] = -1.0 if e["budget"] is None else float(e["budget"])
            metrics[f"{key}_{name}_inside_ref_ci_from"] = -1.0 if strict["budget"] is None else float(strict["budget"])
            metrics[f"{key}_{name}_exposed_after_s"] = t_expose if math.isfinite(t_expose) else -1.0
            worst = max(worst, abs(err))
        metrics[f"{key}_worst_error_pct"] = worst
    return rows, metrics


def run(out: Path, profile: str = "quick", seed: int = 0, quiet: bool = False) -> dict:
    """Fill ``out`` (the lecture dispatch's temporary folder) with the study; returns the
    manifest's metrics (flat numbers)."""
    from ..progress import progress_bar

    size = size_for(profile)
    out = Path(out)
    t_start = time.perf_counter()
    scene, camera = _hall()
    ps = prepare(scene)
    sensors = SensorArray.of(HALL_SENSORS)
    curves: dict = {}
    with progress_bar(quiet) as bar:
        task = bar.add_task("bias", total=4)
        bar.update(task, info="unbiased reference")
        ref = _reference(ps, sensors, size, seed)
        bar.advance(task)
        bar.update(task, info="unbiased curve")
        curves["unbiased"] = _unbiased_curve(ps, sensors, size, seed)
        bar.advance(task)
        bar.update(task, info="photon mapping")
        curves["photon"], radius0 = _photon_curve(ps, sensors, size, seed)
        bar.advance(task)
        bar.update(task, info="irradiance cache")
        curves["cache"] = _cache_curve(ps, camera, sensors, size, seed)
        bar.advance(task)
    ref_mean = ref.s1 / ref.n
    ref_lo, ref_hi = ref.interval(LEVEL)
    se = ref.standard_error()
    write_csv(out / "sensors.csv", [
        {"sensor": name, "x": float(sensors.points[i, 0]), "y": float(sensors.points[i, 1]),
         "z": float(sensors.points[i, 2]), "nx": float(sensors.normals[i, 0]), "ny": float(sensors.normals[i, 1]),
         "nz": float(sensors.normals[i, 2]), "E_r": float(ref_mean[i, 0]), "E_g": float(ref_mean[i, 1]),
         "E_b": float(ref_mean[i, 2]), "Y": float(ref_mean[i, 3]), "Y_se": float(se[i, 3]),
         "Y_lo": float(ref_lo[i, 3]), "Y_hi": float(ref_hi[i, 3]), "samples": ref.n}
        for i, name in enumerate(sensors.names)],
        ["sensor", "x", "y", "z", "nx", "ny", "nz", "E_r", "E_g", "E_b", "Y", "Y_se", "Y_lo", "Y_hi", "samples"])
    rows = (_rows_for("unbiased", "samples per sensor", curves["unbiased"], sensors, ref_mean, ref_lo, ref_hi)
            + _rows_for("photon", "photons", curves["photon"], sensors, ref_mean, ref_lo, ref_hi))
    if curves["cache"]:
        rows += _rows_for("cache", "error bound", curves["cache"], sensors, ref_mean, ref_lo, ref_hi)
    write_csv(out / "estimates.csv", rows, ["estimator", "sensor", "budget_kind", "budget", "time_s", "E_r", "E_g",
                                            "E_b", "Y", "Y_lo", "Y_hi", "Y_ref", "rel_error_pct", "inside_ref_ci",
                                            "own_ci_holds_ref", "mean_radius", "records"])
    figures = []
    for i, name in enumerate(sensors.names):
        write_svg(out / f"bias_{name}.svg", sensor_plot(name, i, ref_mean, ref_lo, ref_hi, curves))
        figures.append(f"bias_{name}.svg")
    write_svg(out / "bias_error.svg", error_plot(sensors, ref_mean, curves))
    figures.insert(0, "bias_error.svg")
    head, metrics = headline(sensors, ref, ref_lo, ref_hi, curves)
    summary = {
        "study": "bias", "title": "Biased against unbiased: illuminance at sensor points", "claim": CLAIM,
        "headline": head, "figures": figures, "profile": profile, "size": size.name, "seed": seed,
        "level": LEVEL, "luminance_weights": LUMINANCE.tolist(), "max_depth": size.max_depth,
        "photon_initial_radius_mm": radius0, "cache": "run" if curves["cache"] else "missing",
        "sensors": {name: {"position": sensors.points[i].tolist(), "normal": sensors.normals[i].tolist(),
                           "Y": float(ref_mean[i, 3]), "Y_ci": [float(ref_lo[i, 3]), float(ref_hi[i, 3])]}
                    for i, name in enumerate(sensors.names)},
        "wall_s": round(time.perf_counter() - t_start, 2)}
    write_json(out / "summary.json", summary)
    metrics["wall_s"] = summary["wall_s"]
    return metrics
