"""Capture: render every view of a scene with the renderer its effects call for.

The rasterizer (:mod:`rig.raster`) is used when it simulates every effect of the scene exactly;
otherwise the path tracer (:mod:`render.pathtracer`). Sensor effects (:mod:`rig.sensor`) are
applied to the linear image afterwards, only when the spec asks for them. Nothing here knows
the artifact layout: views are yielded and the pipeline writes them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from render.camera import Camera, Intrinsics
from render.effects import SENSOR_EFFECTS, raster_limitations, scene_effects
from render.scene import DirectionalLight, PointLight, SpotLight

from .build import RigScene

__all__ = ["CapturedView", "CapturePlan", "plan_capture", "capture_views", "CaptureError"]


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


def _sensor_config(rig: RigScene):
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

    effects = scene_effects(rig.scene, sensor_effects(_sensor_config(rig)))
    reasons = raster_limitations(rig.scene, effects)
    return CapturePlan("pathtracer" if reasons else "raster", effects, reasons)


def _has_delta_lights(rig: RigScene) -> bool:
    return any(isinstance(l, (PointLight, SpotLight, DirectionalLight)) for l in rig.scene.lights)


def _ideal(k: Intrinsics) -> Intrinsics:
    return Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)


def _pathtraced_views(rig: RigScene, views, plan: CapturePlan, spp: int, seed: int):
    from render import pathtracer
    from render.gbuffer import first_hit_buffers

    settings = pathtracer.RenderSettings(integrator="auto", spp=spp, seed=seed)
    try:
        pathtracer.choose_integrator(plan.effects - frozenset(SENSOR_EFFECTS), "auto", _has_delta_lights(rig))
    except ValueError as exc:
        raise CaptureError(f"scene '{rig.scene.name}': {exc}") from None
    prepared = pathtracer.prepare(rig.scene)
    for split, cam in views:
        ideal = Camera(_ideal(cam.intrinsics), cam.cam_to_world, cam.name)
        result = pathtracer.render(rig.scene, ideal, settings, effects=plan.effects - frozenset(SENSOR_EFFECTS), prepared=prepared)
        depth, mask = first_hit_buffers(rig.scene, ideal, prepared.accel)
        yield split, cam, result.mean, depth, mask


def capture_views(rig: RigScene, seed: int = 0, splits: tuple[str, ...] = ("train", "test"),
                  spp: int = 64) -> Iterator[CapturedView]:
    """Render the cameras of ``splits`` (those the scene has) in order; deterministic in ``seed``.

    Each view's sensor noise uses its own generator seeded by (seed, view index), so any subset
    of views reproduces the same bytes.
    """
    from .sensor import apply_sensor, distort_map

    plan = plan_capture(rig)
    views = [(split, cam) for split in splits for cam in rig.cameras.get(split, [])]
    if not views:
        raise CaptureError(f"scene '{rig.scene.name}' has no cameras in splits {list(splits)} "
                           f"(it has: {sorted(rig.cameras)})")
    config = _sensor_config(rig)
    if plan.renderer == "raster":
        frames = _rasterized_views(rig, views)
    else:
        frames = _pathtraced_views(rig, views, plan, spp, seed)
    for index, (split, cam, rgb, depth, mask) in enumerate(frames):
        rng = np.random.default_rng([seed, index])
        rgb = apply_sensor(rgb, cam.intrinsics, config, rng)
        if config.distortion and cam.intrinsics.has_distortion:
            depth = distort_map(depth, cam.intrinsics, "nearest")
            mask = distort_map(mask.astype(np.uint8), cam.intrinsics, "nearest").astype(bool)
        yield CapturedView(cam, split, rgb.astype(np.float32), depth.astype(np.float32), mask)


def _rasterized_views(rig: RigScene, views):
    from .raster import RasterRenderer

    k = views[0][1].intrinsics
    with RasterRenderer(rig.scene, k.width, k.height) as renderer:
        for split, cam in views:
            frame = renderer.render(Camera(_ideal(cam.intrinsics), cam.cam_to_world, cam.name))
            yield split, cam, frame.rgb, frame.depth, frame.mask
