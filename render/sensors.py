"""Irradiance sensors: illuminance at points of a scene, unbiased (with a confidence interval) or by photons.

A *sensor* is a point x with a unit normal n (the side it faces). It measures the irradiance

    E(x, n) = \\int_{H(n)} L_i(x, w) cos(w, n) dw        (W/m^2 per linear RGB channel)

in the scene's light units (:mod:`render.scene`: radiance in W/(m^2 sr), so E in W/m^2 when
lengths are metres; the same numbers in any length unit since solid angle has none). The
*lux-like* scalar is the luminance weighting of E, ``E @ LUMINANCE`` (Rec. 709 Y weights of
linear RGB): photometric illuminance in lux would be 683 lm/W times it for sources whose RGB
triple stood for spectra; we report the W/m^2 number and call it lux-like. Sensors are virtual:
they occlude nothing and see no emission of their own.

Two estimators of the same quantity, each a thin driver over an existing renderer:

* :func:`unbiased_irradiance`: the reference path tracer's compiled kernels
  (:mod:`render.integrators.path_kernels`). Each sensor enters the wavefront as the first vertex
  of its paths, shaded as a white (albedo 1) Lambertian surface: next-event estimation (one
  light sample, MIS against the cosine lobe for area lights; delta lights always sampled) plus
  a cosine-weighted BSDF ray continued by the unbiased path tracer (NEE + MIS at every diffuse
  vertex, Russian roulette). Such a surface leaves radiance E / pi, so each path's radiance times
  pi is an unbiased, independent sample of E. Sample moments give the variance and a normal
  confidence interval (:meth:`IrradianceEstimate.interval`); disjoint sample ranges merge
  exactly (:meth:`IrradianceEstimate.merge`).
* :func:`photon_irradiance`: stochastic progressive photon mapping at the sensors, with the
  photon passes of :mod:`render.integrators.sppm` (:func:`render.integrators.sppm.photon_pass_at`):
  direct light by next-event estimation (unbiased), indirect light by the density estimate
  sum(Phi) / (pi R^2 P N_e) over photons stored at every diffuse hit but the first, the radius
  R of each sensor shrinking per pass by SPPM's rule (alpha = 2/3). Consistent, not unbiased:
  its bias falls with passes. K independent groups (as sppm renders) give a noise estimate.

Max depth counts scattering events with the sensor as the first one (vertex 0), exactly as a
white Lambertian surface at the sensor would be counted by a camera render of that depth.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .integrators.path import kernel_scene_of, path_config
from .integrators.path_kernels import F_DELTA, LAMBERT, KernelScene
from .integrators.wavefront import continue_paths, new_state
from .integrators.prepared import PreparedScene, prepare
from .integrators.sppm import ALPHA, direct_at, photon_pass_at
from .sampling import path_keys
from .scene import Scene

__all__ = ["LUMINANCE", "Sensor", "SensorArray", "IrradianceEstimate", "PhotonEstimate", "lux_like",
           "unbiased_irradiance", "photon_irradiance"]

#: Rec. 709 / sRGB luminance weights of linear RGB (Y = LUMINANCE @ rgb)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def lux_like(E: np.ndarray) -> np.ndarray:
    """Luminance-weighted irradiance: (..., 3) float64 E per channel -> (...,) float64 (W/m^2, Y)."""
    return np.asarray(E, np.float64) @ LUMINANCE


@dataclass(frozen=True)
class Sensor:
    """One illuminance sensor: ``position`` (3,) float64 world point, ``normal`` (3,) unit float64
    (the hemisphere it measures), ``name`` for tables."""

    name: str
    position: tuple[float, float, float]
    normal: tuple[float, float, float]


@dataclass(frozen=True)
class SensorArray:
    """Sensors as arrays: ``names`` (N,) str, ``points`` (N, 3) float64, ``normals`` (N, 3) unit float64."""

    names: tuple[str, ...]
    points: np.ndarray
    normals: np.ndarray

    @classmethod
    def of(cls, sensors) -> "SensorArray":
        """From :class:`Sensor` objects; ValueError naming the sensor when a value is not finite
        or a normal has (near) zero length. Normals are normalized."""
        sensors = list(sensors)
        if not sensors:
            raise ValueError("sensors: at least one sensor is needed")
        p = np.array([s.position for s in sensors], np.float64).reshape(-1, 3)
        n = np.array([s.normal for s in sensors], np.float64).reshape(-1, 3)
        length = np.linalg.norm(n, axis=1)
        for s, pi, ni, li in zip(sensors, p, n, length):
            if not (np.all(np.isfinite(pi)) and np.all(np.isfinite(ni)) and li > 1e-12):
                raise ValueError(f"sensor {s.name!r}: position and normal must be finite, normal non-zero")
        return cls(tuple(s.name for s in sensors), p, n / length[:, None])

    def __len__(self) -> int:
        return len(self.names)


# ------------------------------------------------------------------ unbiased
@dataclass
class IrradianceEstimate:
    """Sample moments of an unbiased irradiance estimate at N sensors.

    s1, s2: (N, 4) float64 sums of the samples and of their squares, columns R, G, B and the
    lux-like Y (kept as its own column so its variance includes the channels' covariance).
    n: samples per sensor. stats: time_s, rays, paths (additive). Merging disjoint sample
    ranges adds everything (:meth:`merge`): the result is the estimate of the union.
    """

    s1: np.ndarray
    s2: np.ndarray
    n: int
    stats: dict = field(default_factory=dict)

    @property
    def mean(self) -> np.ndarray:
        """(N, 3) float64 irradiance per channel."""
        return self.s1[:, :3] / self.n

    @property
    def lux(self) -> np.ndarray:
        """(N,) float64 lux-like irradiance (:func:`lux_like` of the mean)."""
        return self.s1[:, 3] / self.n

    def variance(self) -> np.ndarray:
        """(N, 4) float64 unbiased sample variance of one sample (R, G, B, Y); needs n >= 2."""
        if self.n < 2:
            raise ValueError("sensors: a variance needs at least 2 samples")
        return np.maximum(self.s2 - self.s1 * self.s1 / self.n, 0.0) / (self.n - 1)

    def standard_error(self) -> np.ndarray:
        """(N, 4) float64 standard error of the mean (R, G, B, Y)."""
        return np.sqrt(self.variance() / self.n)

    def interval(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Two-sided normal (CLT) confidence interval of the mean at ``level``: (lo, hi), each
        (N, 4) float64 (R, G, B, Y). Coverage is asymptotic; tests/render/test_sensors.py checks it."""
        if not 0.0 < level < 1.0:
            raise ValueError(f"sensors: level must lie in (0, 1), got {level}")
        half = stats.norm.ppf(0.5 + level / 2.0) * self.standard_error()
        m = self.s1 / self.n
        return m - half, m + half

    def merge(self, other: "IrradianceEstimate") -> "IrradianceEstimate":
        """The estimate of both (disjoint) sample ranges."""
        st = {k: self.stats.get(k, 0) + other.stats.get(k, 0) for k in self.stats.keys() | other.stats.keys()}
        return IrradianceEstimate(self.s1 + other.s1, self.s2 + other.s2, self.n + other.n, st)


def _sensor_kernel_scene(ks: KernelScene, sensors: SensorArray) -> tuple[KernelScene, int]:
    """``ks`` with one degenerate triangle per sensor (vertex = the sensor point, normal = its
    normal) of a new white Lambertian object, absent from every BVH: the kernels shade it when
    handed its primitive id, nothing can hit it. Returns (scene, primitive id of sensor 0)."""
    n, t0, m = len(sensors), len(ks.tri), len(ks.kind)
    rows = np.zeros((n, 12))
    rows[:, 0:3] = sensors.points
    rows[:, 9:12] = sensors.normals
    ext = ks._replace(
        tri=np.ascontiguousarray(np.vstack([ks.tri, rows])),
        tri_obj=np.concatenate([ks.tri_obj, np.full(n, m, np.int64)]),
        uv=np.concatenate([ks.uv, np.zeros((n, 3, 2))]),
        kind=np.append(ks.kind, np.int64(LAMBERT)),
        albedo=np.vstack([ks.albedo, np.ones((1, 3))]),
        ior=np.append(ks.ior, 1.0),
        Le=np.vstack([ks.Le, np.zeros((1, 3))]),
        emits=np.append(ks.emits, False),
        two_sided=np.append(ks.two_sided, True),
        tex=np.vstack([ks.tex, np.zeros((1, 3), np.int64)]),
        tri_pdf_area=np.concatenate([ks.tri_pdf_area, np.zeros(n)]),
        ids=np.concatenate([ks.ids, t0 + np.arange(n, dtype=np.int64)]),
    )
    return ext, len(ks.ids)


def _trace_sensor_paths(ps: PreparedScene, ks: KernelScene, cfg, sensor_prim0: int, sensors: SensorArray,
                        which: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, int]:
    """Radiance leaving the white sensor vertices: one path per entry of ``which`` ((P,) sensor
    indices) with RNG keys ``keys`` (P,) uint64. Returns ((P, 3) float64, rays traced).

    Depth 0 is the sensor itself (a 'hit' handed to shade_bounce, seen head-on along -n); each
    later depth is one Embree query for the live paths, one compiled shading pass and one
    occlusion query for the shadow rays: the driver loop of render.integrators.path."""
    p = len(which)
    cur = new_state(p)
    cur[0][:] = np.arange(p)
    cur[1][:] = keys
    cur[2][:] = 1.0
    cur[3][:] = 0.0
    cur[4][:] = F_DELTA
    cur[6][:] = -sensors.normals[which]  # seen head-on: the shading normal is the sensor's
    hits = ((sensor_prim0 + which).astype(np.int32), np.ones(p, np.float32), np.zeros(p, np.float32),
            np.zeros(p, np.float32))
    L = np.zeros((p, 3))
    rays = continue_paths(ps.accel, ks, cfg, cur, hits, 0, L)
    return L, rays


def unbiased_irradiance(scene: Scene | None, sensors: SensorArray, samples: int, seed: int = 0, max_depth: int = 8,
                        first_sample: int = 0, *, prepared: PreparedScene | None = None, roulette: bool = True,
                        rr_depth: int = 3, batch_paths: int = 1 << 17) -> IrradianceEstimate:
    """Unbiased irradiance at ``sensors``: ``samples`` independent paths per sensor, sample
    indices [first_sample, first_sample + samples) (module docstring for the estimator).

    scene: the scene (or None with ``prepared``). max_depth: scattering events, the sensor being
    the first. The path tracer's defaults otherwise (MIS with the power heuristic, roulette from
    vertex rr_depth). RNG: the path tracer's independent sampler, a hash keyed by (seed, sensor
    index, sample index) (i.i.d. samples, so the variance is the sample variance), so
    estimates of disjoint ranges merge into exactly the estimate of their union. Returns an
    :class:`IrradianceEstimate` (E = pi x the white sensor's radiance, per sample).
    """
    t_start = time.perf_counter()
    samples, first_sample, max_depth = int(samples), int(first_sample), int(max_depth)
    if samples < 1 or first_sample < 0 or max_depth < 0:
        raise ValueError("sensors: samples must be >= 1, first_sample and max_depth >= 0")
    ps = prepared if prepared is not None else prepare(scene)
    if ps.mats.has_glossy:
        raise ValueError("sensors: the unbiased estimator runs the path kernels, which cannot shade GGX materials")
    # independent hash uniforms (not the Sobol sampler): the samples must be i.i.d. for the
    # sample variance and the interval to mean what they say
    cfg = path_config(ps, max_depth, "mis", "power", roulette, rr_depth, direct=False, caustics=True,
                      sampler="independent")
    ks, prim0 = _sensor_kernel_scene(kernel_scene_of(ps), sensors)
    n_sensors = len(sensors)
    total = samples * n_sensors
    s1, s2 = np.zeros((n_sensors, 4)), np.zeros((n_sensors, 4))
    rays = 0
    for start in range(0, total, batch_paths):
        flat = np.arange(start, min(start + batch_paths, total), dtype=np.int64)
        which, sample = flat % n_sensors, first_sample + flat // n_sensors
        keys = path_keys(seed, which, sample)
        L, r = _trace_sensor_paths(ps, ks, cfg, prim0, sensors, which, keys)
        rays += r
        E = np.pi * L
        x = np.concatenate([E, lux_like(E)[:, None]], axis=1)
        for c in range(4):
            s1[:, c] += np.bincount(which, weights=x[:, c], minlength=n_sensors)
            s2[:, c] += np.bincount(which, weights=x[:, c] * x[:, c], minlength=n_sensors)
    if not (np.all(np.isfinite(s1)) and np.all(np.isfinite(s2))):
        raise FloatingPointError("sensors: non-finite irradiance sample (a bug: please report)")
    st = {"time_s": time.perf_counter() - t_start, "rays": int(rays), "paths": int(total)}
    return IrradianceEstimate(s1, s2, samples, st)


# ------------------------------------------------------------------ photon mapping
@dataclass
class PhotonEstimate:
    """Progressive photon-mapped irradiance at N sensors, K independent groups of P passes.

    trace: (K, P, N, 3) float64 each group's estimate after each pass (direct + photon density).
    radius: (K, P, N) float64 each sensor's gather radius after each pass. time_s: (P,) float64
    wall time of the first p passes of all groups together (cumulative). photons_per_pass:
    photons emitted per pass and group. stats: rays, time_s.
    """

    trace: np.ndarray
    radius: np.ndarray
    time_s: np.ndarray
    photons_per_pass: int
    stats: dict = field(default_factory=dict)

    @property
    def mean(self) -> np.ndarray:
        """(N, 3) float64 final estimate: the mean of the groups' last passes."""
        return self.trace[:, -1].mean(axis=0)

    def at(self, passes: int) -> tuple[np.ndarray, np.ndarray | None]:
        """After ``passes`` passes of every group: ((N, 4) mean R, G, B, Y over groups, (N, 4)
        standard error across groups (noise only, not the bias all groups share) or None for one group)."""
        x = self.trace[:, int(passes) - 1]
        x = np.concatenate([x, lux_like(x)[..., None]], axis=-1)
        k = x.shape[0]
        se = np.std(x, axis=0, ddof=1) / np.sqrt(k) if k > 1 else None
        return x.mean(axis=0), se


def photon_irradiance(scene: Scene | None, sensors: SensorArray, passes: int, photons_per_pass: int,
                      initial_radius: float, seed: int = 0, max_depth: int = 8, groups: int = 1, *,
                      prepared: PreparedScene | None = None, alpha: float = ALPHA) -> PhotonEstimate:
    """Irradiance at ``sensors`` by stochastic progressive photon mapping (module docstring).

    passes: passes per group; photons_per_pass: photons emitted per pass; initial_radius: every
    sensor's starting gather radius (scene units, > 0); groups: independent progressive runs
    (group g draws passes [g passes, (g + 1) passes) of the seed's streams, as sppm's groups).
    Per pass and sensor with M photons found: N' = N + alpha M, R' = R sqrt(N' / (N + M)),
    tau' = (tau + Phi) (R' / R)^2; estimate = mean direct + tau / (p N_e pi R^2).
    """
    t_start = time.perf_counter()
    passes, photons_per_pass, groups, max_depth = int(passes), int(photons_per_pass), int(groups), int(max_depth)
    if passes < 1 or photons_per_pass < 1 or groups < 1 or max_depth < 0:
        raise ValueError("sensors: passes, photons_per_pass and groups must be >= 1, max_depth >= 0")
    if not (np.isfinite(initial_radius) and initial_radius > 0):
        raise ValueError(f"sensors: initial_radius must be a positive finite number, got {initial_radius}")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"sensors: alpha must lie in (0, 1), got {alpha}")
    ps = prepared if prepared is not None else prepare(scene)
    n = len(sensors)
    points = {"pix": np.arange(n), "depth": np.zeros(n, np.int64), "p": sensors.points, "ng": sensors.normals,
              "n": sensors.normals, "w": np.ones((n, 3)), "footprint": np.zeros(n)}
    r_floor = 1e-9 * ps.geom.extent
    trace = np.zeros((groups, passes, n, 3))
    radius = np.zeros((groups, passes, n))
    step_time = np.zeros(passes)
    rays = 0
    seed32 = int(seed) & 0xFFFFFFFF
    for g in range(groups):
        R = np.full(n, max(float(initial_radius), r_floor))
        N = np.zeros(n)
        tau = np.zeros((n, 3))
        direct_sum = np.zeros((n, 3))
        for it in range(passes):
            tp = time.perf_counter()
            global_pass = g * passes + it
            rng_direct = np.random.default_rng([seed32, global_pass, 0])
            rng_photons = np.random.default_rng([seed32, global_pass, 1])
            direct, nr = direct_at(ps, points, rng_direct)
            direct_sum += direct
            phi, M, pr = photon_pass_at(ps, points, R, photons_per_pass, rng_photons, max_depth)
            rays += nr + pr
            found = M > 0
            n_new = N[found] + alpha * M[found]
            r_new = np.maximum(R[found] * np.sqrt(n_new / (N[found] + M[found])), r_floor)
            tau[found] = (tau[found] + phi[found]) * ((r_new / R[found]) ** 2)[:, None]
            N[found], R[found] = n_new, r_new
            done = it + 1
            density = tau / (done * photons_per_pass * np.pi * R * R)[:, None]
            trace[g, it] = direct_sum / done + density
            radius[g, it] = R
            step_time[it] += time.perf_counter() - tp
    if not np.all(np.isfinite(trace)):
        raise FloatingPointError("sensors: non-finite photon estimate (a bug: please report)")
    return PhotonEstimate(trace, radius, np.cumsum(step_time), photons_per_pass,
                          {"rays": int(rays), "time_s": time.perf_counter() - t_start})
