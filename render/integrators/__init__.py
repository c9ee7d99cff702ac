"""The integrators: Monte Carlo estimators of the pixel measurement, chosen from a scene's effects.

One module per integrator (pbrt-v4's ``Integrator::Create``, Mitsuba's one plugin a file), each
with its options (``Options``, one documented line per field) and ``render_result``; the lazy
registry :data:`INTEGRATORS` maps names to them (a module is imported on first lookup). In
Heckbert's notation (render.effects):

* ``direct`` (:mod:`.direct`, compiled): L D E and L D S* E / L S* E: camera rays follow mirror
  and glass, light gathered at the first diffuse vertex by NEE and one BSDF sample (MIS).
* ``path`` (:mod:`.path`, compiled kernels in :mod:`.path_kernels`): L (S|D)* E with NEE + MIS
  at every diffuse vertex and Russian roulette; caustics from area sources by BSDF sampling.
* ``volpath`` (:mod:`.volpath`, compiled kernels in :mod:`.volpath_kernels`; its numpy version
  kept as the tested reference): path plus participating media (delta tracking, NEE through
  media by ratio tracking) and GGX microfacet surfaces, which path's kernels do not shade:
  ``auto`` picks it when the scene has media or glossy materials, and only then.
* ``bdpt`` (:mod:`.bdpt`, compiled kernels in :mod:`.bdpt_kernels`; its numpy version kept as
  the tested reference): bidirectional path tracing with every (s, t) strategy, MIS-weighted;
  ``auto`` picks it for caustics from delta lights or small area sources.
* ``sppm`` (:mod:`.sppm`, compiled kernels in :mod:`.sppm_kernels`; its numpy version kept as
  the tested reference): stochastic progressive photon mapping (consistent, not unbiased);
  ``spp`` passes in independent groups. Never chosen by ``auto``.
* ``pssmlt`` (:mod:`.pssmlt`, its path sampler compiled in :mod:`.volpath_kernels`): Metropolis
  light transport in primary sample space; ``spp`` mutations per pixel in independent chain
  groups. Never chosen by ``auto``.
* ``irradiance_cache`` (:mod:`.irradiance_cache`, on path's kernels): Ward's irradiance cache
  at the first diffuse vertex, direct light per sample; biased (consistent as its error bound
  goes to 0), ``spp`` samples in independent groups. Never chosen by ``auto``.

Around them: :mod:`.choice` (what each reaches; the effect-driven choice), :mod:`.prepared`
(:class:`PreparedScene`, built once per scene by :func:`prepare`), :mod:`.settings`
(:class:`RenderSettings`, shared option checks). A render is a pure function of (scene, camera,
settings, sample range): renders of disjoint sample ranges merge exactly
(:func:`render.film.merge_results`) and :func:`refine` adds samples (sppm and pssmlt: ranges of
whole independent groups, :func:`work_units`).

Usage (what ``lumigraph reference`` calls)::

    ps = prepare(scene)                                   # BVHs, lights, materials: once per scene
    res = render(scene, camera, RenderSettings(integrator="auto", spp=256, seed=0), prepared=ps)
    res.mean, res.variance                                # (H, W, 3) float32 radiance, its variance
    res = refine(res, scene, camera, settings, 256, prepared=ps)   # 256 more samples
    part = render(scene, camera, settings, sample_range=(256, 512))  # a batch for another worker
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

from ..camera import Camera
from ..effects import scene_effects
from ..film import RenderResult, group_ranges, merge_results
from ..scene import Scene
from .choice import INTEGRATOR_EFFECTS, SMALL_SOURCE_SR, choose_integrator
from .prepared import PreparedScene, prepare
from .settings import RenderSettings, parse_sample_range

__all__ = [
    "RenderSettings", "PreparedScene", "prepare", "choose_integrator", "render", "refine", "work_units",
    "INTEGRATORS", "INTEGRATOR_OPTIONS", "INTEGRATOR_EFFECTS", "SMALL_SOURCE_SR",
]

# The registry is lazy: an integrator's module (its numba kernels, and scipy.spatial for the
# irradiance cache) is imported when that integrator is first looked up, not when the package is,
# so a render with one integrator pays for that one (start-up cost, issue 16). Each loader is a
# plain function-level import (no importlib: the import graph stays readable from the source).
def _direct():
    from . import direct
    return direct


def _path():
    from . import path
    return path


def _volpath():
    from . import volpath
    return volpath


def _bdpt():
    from . import bdpt
    return bdpt


def _sppm():
    from . import sppm
    return sppm


def _pssmlt():
    from . import pssmlt
    return pssmlt


def _irradiance_cache():
    from . import irradiance_cache
    return irradiance_cache


class _LazyRegistry(Mapping):
    """A read-only mapping name -> value whose value is computed (an import) on first lookup.
    Its keys, their order and ``len`` need no import; ``items()``/``values()`` import them all."""

    def __init__(self, loaders: dict, attribute: str | None = None):
        self._loaders, self._attribute = loaders, attribute

    def __getitem__(self, name: str):
        module = self._loaders[name]()  # KeyError for an unknown name, as a dict
        return module if self._attribute is None else getattr(module, self._attribute)

    def __contains__(self, name) -> bool:  # Mapping's default would import the module to answer
        return name in self._loaders

    def __iter__(self):
        return iter(self._loaders)

    def __len__(self) -> int:
        return len(self._loaders)

    def __repr__(self) -> str:
        return f"<lazy registry of {', '.join(self._loaders)}>"


_LOADERS = {"direct": _direct, "path": _path, "volpath": _volpath, "bdpt": _bdpt, "sppm": _sppm,
            "pssmlt": _pssmlt, "irradiance_cache": _irradiance_cache}
#: name -> integrator module (imported on first lookup); each has ``Options`` (a frozen dataclass
#: of its options, built from RenderSettings) and ``render_result(scene, camera, settings, options,
#: sample_range, effects, prepared, progress)``; sppm, pssmlt and irradiance_cache also ``GROUPS``
#: (their independent groups)
INTEGRATORS: Mapping = _LazyRegistry(_LOADERS)
#: name -> the integrator's options (one hop from here to every option and its documentation;
#: imports that integrator's module on lookup)
INTEGRATOR_OPTIONS: Mapping = _LazyRegistry(_LOADERS, "Options")


def render(scene: Scene, camera: Camera, settings: RenderSettings = RenderSettings(),
           sample_range: tuple[int, int] | None = None, effects=None,
           prepared: PreparedScene | None = None, progress=None) -> RenderResult:
    """Render ``camera``'s view of ``scene``: mean radiance and its per-pixel variance.

    sample_range: half-open range of sample indices [a, b) (default [0, settings.spp)); renders
    of disjoint ranges merge exactly. effects: the effects to simulate (default:
    :func:`render.effects.scene_effects`); the integrator is chosen from them when
    ``settings.integrator == "auto"``. Caustic paths are dropped when 'caustics' is not among
    them. prepared: a :class:`PreparedScene` from :func:`prepare` to reuse. progress: optional
    callable ``progress(done_paths, total_paths)`` called after each batch (path and direct).
    An option of ``settings`` that the chosen integrator does not use raises ValueError naming
    both. Returns a :class:`render.film.RenderResult` (mean and variance (H, W, 3) float32).
    """
    eff = scene_effects(scene) if effects is None else frozenset(effects)
    ps = prepared if prepared is not None else prepare(scene, threads=settings.threads)
    name = ps.choose(eff, settings.integrator)
    integrator = INTEGRATORS[name]
    options = settings.options(name, integrator.Options)
    a, b = parse_sample_range(settings.spp, sample_range, name)
    return integrator.render_result(scene, camera, settings, options, (a, b), eff, ps, progress)


def work_units(integrator: str, spp: int, batch: int) -> list[tuple[int, int]]:
    """The half-open sample ranges, in sample order, that a render of ``spp`` samples with
    ``integrator`` (a chosen one, not "auto") splits into as independent units of work: runs of
    ``batch`` samples, or for sppm and pssmlt their independent groups
    (:func:`render.film.group_ranges`). Renders of the units merge, in this order, to the same
    bytes wherever they ran (render.film.merge_results; the ``reference`` stage's fold)."""
    spp, batch = int(spp), int(batch)
    if spp < 1 or batch < 1:
        raise ValueError(f"spp and batch must be >= 1, got {spp}, {batch}")
    groups = getattr(INTEGRATORS[integrator], "GROUPS", None)
    if groups is not None:
        return group_ranges(spp, groups)
    return [(a, min(a + batch, spp)) for a in range(0, spp, batch)]


def refine(result: RenderResult, scene: Scene, camera: Camera, settings: RenderSettings,
           extra_spp: int, effects=None, prepared: PreparedScene | None = None, progress=None) -> RenderResult:
    """Progressive rendering: add ``extra_spp`` samples after ``result``'s range and merge."""
    a = result.sample_range[1]
    more = render(scene, camera, replace(settings, integrator=result.integrator), (a, a + int(extra_spp)),
                  effects, prepared, progress)
    return merge_results(result, more)
