"""``direct``: L D E and L D S* E / L S* E, on :mod:`render.integrators.path`'s driver and kernels.

Camera rays follow mirror and glass, and at the first diffuse vertex light is gathered by
next-event estimation and / or one BSDF sample (combined by MIS); that last BSDF ray is traced
against an emitter-only BVH plus one occlusion query. Reaches effects direct, shadows,
soft_shadows, specular. This module is thin on purpose: it shares path's compiled kernels
(:mod:`render.integrators.path_kernels`, whose ``PathConfig.direct`` ends paths at the first
diffuse vertex) and path's wavefront driver; only its options differ (no roulette: its paths
end after one diffuse vertex anyway).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..camera import Camera
from ..film import RenderResult
from ..scene import Scene
from .path import trace_view
from .prepared import PreparedScene
from .settings import RenderSettings, check_heuristic, check_sampler, check_strategy

__all__ = ["Options", "render_result"]


@dataclass(frozen=True)
class Options:
    """Options of ``direct`` (RenderSettings fields of the same names)."""

    #: "mis" (light + BSDF sampling, MIS-weighted), "light" (next-event estimation alone) or
    #: "bsdf" (BSDF sampling alone for area sources; delta lights are always sampled)
    strategy: str = "mis"
    #: MIS weights: "power" or "balance" (Veach and Guibas)
    heuristic: str = "power"
    #: random numbers: "sobol-blocks" (one Owen-scrambled Sobol sequence per pixel, model
    #: variance: render.film.blocks_variance; the default), "sobol" (R interleaved replicates,
    #: model-free variance) or "independent" (hash)
    sampler: str = "sobol-blocks"

    def __post_init__(self):
        check_strategy(self.strategy)
        check_heuristic(self.heuristic)
        check_sampler(self.sampler)


def render_result(scene: Scene, camera: Camera, settings: RenderSettings, options: Options,
                  sample_range: tuple[int, int], effects: frozenset, prepared: PreparedScene,
                  progress=None) -> RenderResult:
    """Render samples [a, b) = ``sample_range`` of ``camera``'s view with ``direct`` (the
    registry's interface). progress: optional ``progress(done_paths, total_paths)`` per batch."""
    return trace_view(scene, camera, settings, options, sample_range, effects, prepared, progress, direct=True)
