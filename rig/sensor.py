"""Sensor effects applied to rendered linear images, each only when asked for.

The renderers produce the ideal pinhole image of linear radiance. :func:`apply_sensor` turns
it into what the simulated camera records, in the physical order:

1. ``distortion``: the lens bends rays; the image is resampled so that a world point lands
   where :meth:`render.camera.Camera.project` (with ``intrinsics.dist``) puts it.
2. ``vignetting``: the lens darkens the sensor towards its rim; a radial gain
   ``V(r) = 1 + a2 r^2 + a4 r^4`` at each (distorted) pixel centre, ``r`` its distance from the
   principal point divided by the image half-diagonal ``0.5 sqrt(W^2 + H^2)`` (so ``r`` is 1 at
   the corners for a centred principal point; ``a2 < 0`` darkens).
3. ``exposure``: a linear multiplier on radiance (integration time x aperture); ``2 ** ev`` for
   ``ev`` stops. It scales the photon count, so more exposure means less relative noise.
4. ``noise``: Poisson-Gaussian. With ``noise = (gain, read_sigma)``: photo-electron count
   ``n ~ Poisson(gain * x)`` for the exposed, vignetted radiance ``x``, plus Gaussian read noise
   ``e ~ N(0, read_sigma^2)`` (in electrons); the output ``max(n + e, 0) / gain`` is back in
   radiance units. Before the clip at 0: mean ``x``, variance ``x / gain + (read_sigma / gain)^2``
   (Foi et al. 2008's model with alpha = 1 / gain, b = (read_sigma / gain)^2).

Every effect is off by default and the default config is the identity (bit-exact for float32
input). Randomness comes only from the caller's ``numpy.random.Generator``.

Pixel convention: pixel (row i, col j) has its centre at continuous coordinates (j + 0.5, i + 0.5)
(:mod:`render.camera`); OpenCV's remap puts centres at integers, so maps are shifted by -0.5 at
that boundary only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from render.camera import Intrinsics, distort_normalized, undistort_normalized
from render.remap import INTERPOLATIONS, remap_image

__all__ = ["SensorConfig", "apply_sensor", "sensor_effects", "distort_map", "distortion_maps", "vignetting_gain"]

#: map value for output pixels whose ray the distortion model cannot invert: far outside the
#: ideal image, so the remap fills them with the border value 0
_OUTSIDE = -1.0e4


@dataclass(frozen=True)
class SensorConfig:
    """Which capture effects to simulate, with their parameters; all off by default.

    exposure: linear multiplier on radiance (> 0; 1 = off; ``2 ** ev`` for ``ev`` stops).
    vignetting: ``(a2, a4)`` of the radial gain ``1 + a2 r^2 + a4 r^4`` (``r`` normalized by the
        half-diagonal, measured from the principal point), or None (off).
    noise: ``(gain, read_sigma)``: photo-electrons per unit radiance (> 0) and the Gaussian read
        noise standard deviation in electrons (>= 0), or None (off).
    distortion: apply the camera's ``intrinsics.dist`` (OpenCV/Brown) to the ideal image.
    """

    exposure: float = 1.0
    vignetting: tuple[float, float] | None = None
    noise: tuple[float, float] | None = None
    distortion: bool = False

    def __post_init__(self) -> None:
        e = float(self.exposure)
        if not (math.isfinite(e) and e > 0):
            raise ValueError(f"sensor.exposure must be a finite multiplier > 0, got {self.exposure!r}")
        object.__setattr__(self, "exposure", e)
        if self.vignetting is not None:
            v = _pair(self.vignetting, "sensor.vignetting", "(a2, a4)")
            object.__setattr__(self, "vignetting", v)
        if self.noise is not None:
            gain, read = _pair(self.noise, "sensor.noise", "(gain, read_sigma)")
            if gain <= 0:
                raise ValueError(f"sensor.noise: gain (photo-electrons per unit radiance) must be > 0, got {gain}")
            if read < 0:
                raise ValueError(f"sensor.noise: read_sigma must be >= 0, got {read}")
            object.__setattr__(self, "noise", (gain, read))
        if not isinstance(self.distortion, (bool, np.bool_)):
            raise ValueError(f"sensor.distortion must be true or false, got {self.distortion!r}")
        object.__setattr__(self, "distortion", bool(self.distortion))


def _pair(value, name: str, what: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two numbers {what}, got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return a, b


def sensor_effects(config: SensorConfig) -> frozenset[str]:
    """The effects ``config`` turns on: a subset of {"noise", "distortion", "vignetting", "exposure"}
    (names from :data:`render.effects.SENSOR_EFFECTS`). ``distortion`` is listed when asked for,
    even if a camera has no distortion coefficients (then it is a no-op for that camera)."""
    on = set()
    if config.noise is not None:
        on.add("noise")
    if config.distortion:
        on.add("distortion")
    if config.vignetting is not None and config.vignetting != (0.0, 0.0):
        on.add("vignetting")
    if config.exposure != 1.0:
        on.add("exposure")
    return frozenset(on)


# --------------------------------------------------------------------------- distortion


@lru_cache(maxsize=32)
def _maps(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    xy_d = np.stack([(jj.ravel() - k.cx) / k.fx, (ii.ravel() - k.cy) / k.fy], axis=1)
    xy = undistort_normalized(xy_d, k.dist)
    # where the fixed-point inversion did not converge (outside the model's invertible region)
    # the pixel sees nothing of the ideal image
    ok = np.all(np.isfinite(xy), axis=1)
    resid = np.full(len(xy), np.inf)
    resid[ok] = np.abs(distort_normalized(xy[ok], k.dist) - xy_d[ok]).max(axis=1)
    ok &= resid * max(k.fx, k.fy) < 1e-3  # pixels
    # ideal-image position in our convention, then -0.5 for OpenCV's integer pixel centres
    mx = np.where(ok, k.fx * xy[:, 0] + k.cx - 0.5, _OUTSIDE).astype(np.float32).reshape(k.height, k.width)
    my = np.where(ok, k.fy * xy[:, 1] + k.cy - 0.5, _OUTSIDE).astype(np.float32).reshape(k.height, k.width)
    mx.setflags(write=False)
    my.setflags(write=False)
    return mx, my


def distortion_maps(intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap`` maps that distort the ideal pinhole image (cached per intrinsics).

    For output (distorted) pixel (i, j), ``(map_x[i, j], map_y[i, j])`` is where to sample the
    ideal image, in OpenCV's integer-centre coordinates: the pixel centre (j + 0.5, i + 0.5) is
    normalized, undistorted with :func:`render.camera.undistort_normalized`, re-projected with the
    ideal intrinsics, and shifted by -0.5. Pixels the model cannot invert map far outside.
    Returns two read-only (H, W) float32 arrays.
    """
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"expected render.camera.Intrinsics, got {type(intrinsics).__name__}")
    return _maps(intrinsics)


def distort_map(image: np.ndarray, intrinsics: Intrinsics, interpolation: str = "linear") -> np.ndarray:
    """Resample an ideal pinhole image (or depth, mask) into the distorted camera's image.

    image: (H, W) or (H, W, C) array of the intrinsics' size (float, uint8, uint16 or bool).
    interpolation: ``"linear"`` for radiance, ``"nearest"`` for depth and masks (no new values
    invented at edges; z-depth is unchanged by distortion since the 3D point is the same).
    Pixels whose source lies outside the ideal image get 0 (depth 0 = nothing hit). Returns the
    same shape and dtype; an exact copy when the intrinsics have no distortion. Bilinear weights
    in ``cv2.remap`` are quantized to 1/32 px.
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {sorted(INTERPOLATIONS)}, got {interpolation!r}")
    a = np.asarray(image)
    k = intrinsics
    if a.ndim not in (2, 3) or a.shape[:2] != (k.height, k.width):
        raise ValueError(f"image shape {a.shape} does not match the intrinsics' {k.height}x{k.width}")
    if not k.has_distortion:
        return a.copy()
    mx, my = distortion_maps(k)
    return remap_image(a, mx, my, interpolation)


# --------------------------------------------------------------------------- vignetting


def vignetting_gain(intrinsics: Intrinsics, a2: float, a4: float) -> np.ndarray:
    """(H, W) float64 radial gain ``1 + a2 r^2 + a4 r^4`` at pixel centres.

    ``r`` = distance from the principal point (cx, cy) divided by the half-diagonal
    ``0.5 sqrt(W^2 + H^2)``. Raises ValueError if the gain is negative anywhere on the image.
    """
    k = intrinsics
    jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    r2 = ((jj - k.cx) ** 2 + (ii - k.cy) ** 2) / (0.25 * (k.width ** 2 + k.height ** 2))
    gain = 1.0 + a2 * r2 + a4 * r2 * r2
    if gain.min() < 0:
        raise ValueError(f"sensor.vignetting {(a2, a4)} gives a negative gain ({gain.min():.3g}) on the image")
    return gain


# --------------------------------------------------------------------------- all together


def apply_sensor(image: np.ndarray, intrinsics: Intrinsics, config: SensorConfig,
                 rng: np.random.Generator | None = None) -> np.ndarray:
    """Apply the effects ``config`` turns on to a linear radiance image.

    image: (H, W, 3) float linear radiance (ideal pinhole image, non-negative, finite) of the
    intrinsics' size. rng: the generator for noise (required when noise is on; nothing else
    draws from it). Returns (H, W, 3) float32: distortion, vignetting, exposure, noise in that
    order (see the module docstring). The default config returns an exact float32 copy.
    """
    a = np.asarray(image)
    k = intrinsics
    if not isinstance(config, SensorConfig):
        raise ValueError(f"expected a SensorConfig, got {type(config).__name__}")
    if a.ndim != 3 or a.shape != (k.height, k.width, 3):
        raise ValueError(f"image must be ({k.height}, {k.width}, 3) for these intrinsics, got {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"image must be float linear radiance, got {a.dtype}")
    if not np.all(np.isfinite(a)):
        raise ValueError("image has non-finite values")
    if config.noise is not None and not isinstance(rng, np.random.Generator):
        raise ValueError("sensor noise needs an explicit numpy.random.Generator (rng)")

    out = a.astype(np.float32, copy=True)
    if config.distortion and k.has_distortion:
        out = distort_map(out, k, "linear")
    if config.vignetting is not None and config.vignetting != (0.0, 0.0):
        out = (out * vignetting_gain(k, *config.vignetting)[..., None]).astype(np.float32)
    if config.exposure != 1.0:
        out = (out * np.float64(config.exposure)).astype(np.float32)
    if config.noise is not None:
        out = _poisson_gaussian(out, *config.noise, rng)
    return out


#: largest mean drawn from numpy's Poisson sampler; above it, the Gaussian limit (see below)
_POISSON_MAX = 1e12


def _poisson_gaussian(x: np.ndarray, gain: float, read_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float32 radiance -> noisy float32 (see the module docstring)."""
    lam = np.maximum(x.astype(np.float64) * gain, 0.0)  # interpolation may undershoot 0 by rounding
    if lam.max() <= _POISSON_MAX:
        counts = rng.poisson(lam).astype(np.float64)
    else:
        # numpy's Poisson sampler refuses means above ~9.2e18 (int64 counts). There Poisson(lam) is
        # N(lam, lam) to far below float32 resolution (skewness lam^-1/2 < 1e-6): draw that instead.
        # Images without such pixels draw exactly as before.
        big = lam > _POISSON_MAX
        counts = np.empty_like(lam)
        counts[~big] = rng.poisson(lam[~big])
        counts[big] = rng.normal(lam[big], np.sqrt(lam[big]))
    if read_sigma > 0:
        counts += rng.normal(0.0, read_sigma, size=counts.shape)
    return (np.maximum(counts, 0.0) / gain).astype(np.float32)
