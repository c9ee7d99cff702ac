"""The effects vocabulary (DESIGN.md): which light paths and capture effects a scene needs.

A scene's light-transport effects are inferred from its content; a spec may list effects to
restrict them (never to add what the content lacks). Renderers are chosen from the result:
the rasterizer only when it simulates every effect exactly, else the path tracer.
"""
from __future__ import annotations

from .scene import (ALPHA_SMOOTH, Dielectric, DirectionalLight, Emissive, Lambertian, Mirror, PointLight,
                    RoughConductor, RoughDielectric, Scene, SpotLight)

__all__ = [
    "TRANSPORT_EFFECTS", "SENSOR_EFFECTS", "ALL_EFFECTS", "RASTER_EFFECTS",
    "infer_effects", "scene_effects", "raster_limitations",
]

TRANSPORT_EFFECTS = ("direct", "shadows", "soft_shadows", "interreflection", "specular", "caustics", "media")
SENSOR_EFFECTS = ("noise", "distortion", "vignetting", "exposure", "motion_blur", "defocus")
ALL_EFFECTS = frozenset(TRANSPORT_EFFECTS + SENSOR_EFFECTS)

#: what the rig's rasterizer simulates exactly (Lambertian, spot/directional shadow maps, sensor
#: effects applied to its linear output); motion blur and defocus are not implemented anywhere yet.
RASTER_EFFECTS = frozenset({"direct", "shadows", "noise", "distortion", "vignetting", "exposure"})


def _glossy(m) -> bool:
    """A GGX microfacet material rough enough to be sampled as a non-delta lobe."""
    return isinstance(m, (RoughConductor, RoughDielectric)) and m.alpha >= ALPHA_SMOOTH


def _smooth_microfacet(m) -> bool:
    return isinstance(m, (RoughConductor, RoughDielectric)) and m.alpha < ALPHA_SMOOTH


def infer_effects(scene: Scene) -> frozenset[str]:
    """Light-transport effects the scene's content can produce (sensor effects excluded).

    Glossy (GGX) surfaces scatter light like diffuse ones in Heckbert's classes (a non-delta
    vertex: direct light, interreflection, caustic receivers); GGX at alpha below
    render.scene.ALPHA_SMOOTH is specular.
    """
    mats = [o.material for o in scene.objects]
    diffuse = [m for m in mats if (isinstance(m, Lambertian) and m.albedo.max() > 0) or _glossy(m)]
    specular = any(isinstance(m, (Mirror, Dielectric)) or _smooth_microfacet(m) for m in mats)
    delta_lights = any(isinstance(l, (PointLight, SpotLight, DirectionalLight)) for l in scene.lights)
    area_lights = any(isinstance(m, Emissive) for m in mats)
    lit = delta_lights or area_lights
    out: set[str] = set()
    if lit and diffuse:
        out.add("direct")
    if delta_lights and len(scene.objects) > 0:
        out.add("shadows")
    if area_lights and diffuse:
        out.add("soft_shadows")
    # diffuse-to-diffuse transport needs two diffuse objects or one non-convex diffuse mesh
    diffuse_objs = [o for o in scene.objects
                    if (isinstance(o.material, Lambertian) and o.material.albedo.max() > 0) or _glossy(o.material)]
    if lit and (len(diffuse_objs) > 1 or any(not o.mesh.is_convex for o in diffuse_objs)):
        out.add("interreflection")
    if specular and lit:
        out.add("specular")
        if diffuse:
            out.add("caustics")
    if scene.media:
        out.add("media")
    return frozenset(out)


def scene_effects(scene: Scene, sensor: frozenset[str] = frozenset()) -> frozenset[str]:
    """The effects to simulate: inferred content restricted by ``scene.effects``, plus sensor ones."""
    inferred = infer_effects(scene)
    if scene.effects is not None:
        unknown = set(scene.effects) - ALL_EFFECTS
        if unknown:
            raise ValueError(f"unknown effects {sorted(unknown)}; known: {sorted(ALL_EFFECTS)}")
        inferred &= frozenset(scene.effects)
    return inferred | frozenset(sensor)


def raster_limitations(scene: Scene, effects: frozenset[str]) -> list[str]:
    """Reasons the rasterizer cannot render ``scene`` exactly with ``effects``; empty if it can."""
    reasons = [f"effect '{e}' needs the path tracer" for e in sorted(effects - RASTER_EFFECTS)]
    for o in scene.objects:
        if not isinstance(o.material, Lambertian):
            reasons.append(f"object '{o.name}': {type(o.material).__name__} material needs the path tracer")
    if "direct" in effects and scene.background.max() > 0:
        reasons.append("a non-black background lights the scene as an environment, which the rasterizer "
                       "does not simulate")
    if "shadows" in effects and any(isinstance(l, PointLight) for l in scene.lights):
        reasons.append("point-light shadows are not simulated by the rasterizer (use spot lights)")
    return reasons
