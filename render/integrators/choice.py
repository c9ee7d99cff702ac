"""The effect-driven choice of an integrator (DESIGN.md, "Effects"): what each one reaches.

A leaf of the package: :class:`render.integrators.prepared.PreparedScene` and every integrator
module may import it, and it imports none of them.
"""
from __future__ import annotations

__all__ = ["INTEGRATOR_EFFECTS", "SMALL_SOURCE_SR", "choose_integrator"]

_EYE_PATHS = frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics"})
#: light-transport effects each integrator reaches (sensor effects are applied downstream)
INTEGRATOR_EFFECTS = {
    "direct": frozenset({"direct", "shadows", "soft_shadows", "specular"}),
    "path": _EYE_PATHS,
    "volpath": _EYE_PATHS | {"media"},
    "sppm": _EYE_PATHS,
    "bdpt": _EYE_PATHS,
    "pssmlt": _EYE_PATHS,
    # Ward's cache at the first diffuse vertex: camera rays do not follow specular surfaces
    "irradiance_cache": frozenset({"direct", "shadows", "soft_shadows", "interreflection"}),
}
#: integrators that trace light subpaths, and so reach caustics from point/spot/directional lights
_LIGHT_TRACING = frozenset({"sppm", "bdpt"})
_TRANSPORT = frozenset({"direct", "shadows", "soft_shadows", "specular", "interreflection", "caustics", "media"})

#: emitters subtending less than this solid angle (sr) from the scene's centre make caustics hard
#: for path tracing. bench_hard_paths' source-size sweep with both integrators compiled (``--sweep``:
#: glass ball under a square source 2.35 m from the scene's centre, same power, 48 x 48; the run of
#: bench/results/hard_paths_source_sweep.json, load 11-12) measures bdpt's equal-time image RMSE at
#: 0.71x path's for glass_caustic.yaml's 0.4 m source (0.029 sr; 0.22x in the caustic), 0.52x,
#: 0.21x, 0.02x for 0.2, 0.1, 0.05 m, 0.90x for a 0.8 m source (0.116 sr) and 1.52x for 1.6 m
#: (0.46 sr): a crossover near 0.23 sr. The threshold stays at the geometric mean of 0.029 and
#: 0.116 sr, set when the previous sweep measured 1.12x at 0.8 m: the two sweeps disagree there
#: (0.90x / 1.12x, both under load), and 0.23 sr would also move the Cornell box's light (0.18 sr,
#: cornell_spheres' glass) onto bdpt, unmeasured there. (With the numpy bdpt it was 0.0036 sr.)
SMALL_SOURCE_SR = 0.058


def choose_integrator(effects, requested: str = "auto", has_delta_lights: bool = False,
                      glossy: bool = False, small_sources: bool = False) -> str:
    """The cheapest integrator covering ``effects`` (a set of effect names) and nothing more.

    ``auto``: "volpath" when media are needed or the scene has GGX materials (``glossy``: the
    compiled kernels do not shade them), else "direct" unless interreflection or caustics are
    needed, then "path", or "bdpt" when the caustics come from point/spot/directional lights
    (a delta light seen through a delta BSDF: only light tracing reaches it, and bdpt is the
    unbiased integrator that does; sppm is consistent only and never chosen by auto) or from
    ``small_sources`` (every area emitter below SMALL_SOURCE_SR: path finds their caustics only
    when a BSDF sample happens to hit them, bdpt's light subpaths do not depend on size). A
    requested integrator that cannot reach an effect (or shade a glossy material) raises
    ValueError naming it, as do delta-light caustics asked of an eye-path-only integrator.
    """
    eff = frozenset(effects) & _TRANSPORT
    if (requested == "auto" and "caustics" in eff and (has_delta_lights or small_sources)
            and not (glossy or "media" in eff)):
        return "bdpt"
    if glossy and requested not in ("auto", "volpath"):
        raise ValueError(f"integrator '{requested}' cannot shade glossy (GGX) materials; use 'volpath' or 'auto'")
    if "caustics" in eff and has_delta_lights and requested not in _LIGHT_TRACING:
        raise ValueError("effect 'caustics' with point/spot/directional lights is unreachable by a path "
                         "tracer (a delta light seen through a delta BSDF); use area lights, integrator "
                         "'bdpt' or 'sppm', or drop 'caustics' from the scene's effects")
    if requested == "auto":
        if "media" in eff or glossy:
            return "volpath"
        return "path" if eff & {"interreflection", "caustics"} else "direct"
    if requested not in INTEGRATOR_EFFECTS:
        raise ValueError(f"unknown integrator {requested!r}; known: auto, {', '.join(INTEGRATOR_EFFECTS)}")
    missing = sorted(eff - INTEGRATOR_EFFECTS[requested])
    if missing:
        raise ValueError(f"integrator '{requested}' cannot reach effect '{missing[0]}' "
                         f"(needed: {sorted(eff)}); use 'auto'")
    return requested
