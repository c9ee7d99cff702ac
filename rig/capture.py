"""Capture: render every view of a scene with the renderer its effects call for.

The rasterizer (:mod:`rig.raster`) is used when it simulates every effect of the scene exactly;
otherwise the path tracer (:mod:`render.integrators`). Sensor effects (:mod:`rig.sensor`) are
applied to the linear image afterwards, only when the spec asks for them. Nothing here knows
the artifact layout: views are yielded and the pipeline writes them.
"""
from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from render.camera import Camera, Intrinsics
from render.effects import SENSOR_EFFECTS, raster_limitations, scene_effects
from render.scene import DirectionalLight, PointLight, SpotLight

from .build import RigScene

__all__ = ["CapturedView", "CapturePlan", "plan_capture", "capture_list", "check_capture",
           "render_ideal", "finish_view", "sensor_config", "CaptureError", "CAPTURE_SPP"]


class CaptureError(ValueError):
    """The scene cannot be captured as asked (reported to the user as bad input)."""


@dataclass
class CapturedView:
    """One captured view. ``rgb`` (H, W, 3) float32 linear radiance after sensor effects;
    ``depth`` (H, W) float32 z-depth (0 = nothing hit); ``mask`` (H, W) bool subject coverage."""

    camera: Camera
    split: str
    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray


@dataclass
class CapturePlan:
    renderer: str  # "raster" or "pathtracer"
    effects: frozenset[str]
    reasons: list[str]  # why the path tracer is needed (empty for the rasterizer)


def sensor_config(rig: RigScene):
    """The spec's sensor as a :class:`rig.sensor.SensorConfig`."""
    from .sensor import SensorConfig

    s = rig.spec.sensor
    return SensorConfig(
        exposure=s.exposure if s.exposure is not None else 1.0,
        vignetting=tuple(s.vignetting) if s.vignetting is not None else None,
        noise=tuple(s.noise) if s.noise is not None else None,
        distortion=s.distortion,
    )


def plan_capture(rig: RigScene) -> CapturePlan:
    """Decide the renderer from the scene's effects; never silently simulate less."""
    from .sensor import sensor_effects

    effects = scene_effects(rig.scene, sensor_effects(sensor_config(rig)))
    reasons = raster_limitations(rig.scene, effects)
    return CapturePlan("pathtracer" if reasons else "raster", effects, reasons)


def _has_delta_lights(rig: RigScene) -> bool:
    return any(isinstance(l, (PointLight, SpotLight, DirectionalLight)) for l in rig.scene.lights)


def _ideal(k: Intrinsics) -> Intrinsics:
    return Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)


#: path tracer samples per pixel of a path-traced capture
CAPTURE_SPP = 64


def capture_list(rig: RigScene, splits: tuple[str, ...] = ("train", "test")) -> list[tuple[str, Camera]]:
    """(split, camera) of every view of ``splits`` the scene has, in capture order (a view's
    index in this list seeds its sensor noise). CaptureError when there are none."""
    views = [(split, cam) for split in splits for cam in rig.cameras.get(split, [])]
    if not views:
        raise CaptureError(f"scene '{rig.scene.name}' has no cameras in splits {list(splits)} "
                           f"(it has: {sorted(rig.cameras)})")
    return views


def check_capture(rig: RigScene, plan: CapturePlan) -> None:
    """CaptureError when the path tracer has no integrator for a path-traced plan's effects."""
    if plan.renderer == "raster":
        return
    from render import integrators

    try:
        integrators.choose_integrator(plan.effects - frozenset(SENSOR_EFFECTS), "auto", _has_delta_lights(rig))
    except ValueError as exc:
        raise CaptureError(f"scene '{rig.scene.name}': {exc}") from None


def render_ideal(scene, plan: CapturePlan, cam: Camera, renderer, seed: int = 0, spp: int = CAPTURE_SPP,
                 threads: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb, z-depth, subject mask) of ``cam``'s ideal pinhole view (distortion ignored).

    renderer: for a ``raster`` plan anything with ``render(camera) -> rig.raster.RasterFrame``
    (a :class:`rig.raster.RasterRenderer` of the view's size); for a path-traced plan the scene's
    :class:`render.integrators.PreparedScene`. threads: path tracer threads (never change the
    result)."""
    ideal = Camera(_ideal(cam.intrinsics), cam.cam_to_world, cam.name)
    if plan.renderer == "raster":
        frame = renderer.render(ideal)
        return frame.rgb, frame.depth, frame.mask
    from render import integrators
    from render.gbuffer import first_hit_buffers

    settings = integrators.RenderSettings(integrator="auto", spp=spp, seed=seed, threads=threads)
    result = integrators.render(scene, ideal, settings, effects=plan.effects - frozenset(SENSOR_EFFECTS),
                               prepared=renderer)
    depth, mask = first_hit_buffers(scene, ideal, renderer.accel)
    return result.mean, depth, mask


def finish_view(cam: Camera, split: str, index: int, seed: int, config, rgb: np.ndarray, depth: np.ndarray,
                mask: np.ndarray) -> CapturedView:
    """Apply the sensor (``config``: :func:`sensor_config`) to an ideal view: noise from a
    generator seeded by (seed, index), distortion of rgb, depth and mask."""
    from .sensor import apply_sensor, distort_map

    rng = np.random.default_rng([seed, index])
    rgb = apply_sensor(rgb, cam.intrinsics, config, rng)
    if config.distortion and cam.intrinsics.has_distortion:
        depth = distort_map(depth, cam.intrinsics, "nearest")
        mask = distort_map(mask.astype(np.uint8), cam.intrinsics, "nearest").astype(bool)
    return CapturedView(cam, split, rgb.astype(np.float32), depth.astype(np.float32), mask)
