"""How to render: :class:`RenderSettings` (every integrator) and the helpers every integrator's
options share (sample ranges, MIS heuristics, reporting options an integrator does not use).

An integrator's own options are a frozen dataclass in its module (``Options``: e.g.
:class:`render.integrators.path.Options`), built from the settings by :meth:`RenderSettings.options`:
an option the settings give that the chosen integrator does not read is an error naming both
(pbrt-v4's ``ParameterDictionary::ReportUnused``), never silently ignored.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

from ..sobol import INDEX_BITS
from .choice import INTEGRATOR_EFFECTS

__all__ = ["RenderSettings", "MAX_SAMPLE_INDEX", "OPTION_NAMES", "STRATEGIES", "HEURISTICS", "SAMPLER_NAMES", "check_strategy",
           "check_heuristic", "check_sampler", "heuristic_exponent", "parse_sample_range"]

#: next-event strategies: both techniques MIS-weighted, light sampling alone, BSDF sampling alone
STRATEGIES = ("mis", "light", "bsdf")
#: MIS heuristics (Veach and Guibas 1995) and the exponent each raises density ratios to
HEURISTICS = {"power": 2.0, "balance": 1.0}
#: random number samplers (render.sobol.SAMPLERS): Owen-scrambled Sobol, independent hash
SAMPLER_NAMES = ("sobol", "sobol-blocks", "independent")
#: the RenderSettings fields that belong to some integrators' options only (None: not given)
OPTION_NAMES = ("roulette", "rr_depth", "strategy", "heuristic", "photons_per_pass", "sampler")


def check_strategy(strategy: str) -> None:
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy must be mis, light or bsdf, got {strategy!r}")


def check_heuristic(heuristic: str) -> None:
    if heuristic not in HEURISTICS:
        raise ValueError(f"heuristic must be power or balance, got {heuristic!r}")


def check_sampler(sampler: str) -> None:
    if sampler not in SAMPLER_NAMES:
        raise ValueError(f"sampler must be sobol, sobol-blocks or independent, got {sampler!r}")


def heuristic_exponent(heuristic: str) -> float:
    """The exponent of ``heuristic`` ("power" 2, "balance" 1) that render.sampling.mis_weight takes."""
    check_heuristic(heuristic)
    return HEURISTICS[heuristic]


#: samples per pixel a render may reach (render.sobol.INDEX_BITS: a Sobol key holds a pixel's
#: sample index in 27 bits; at 128 x 128 pixels that is 2.2e12 paths)
MAX_SAMPLE_INDEX = 1 << INDEX_BITS


def parse_sample_range(spp: int, sample_range, integrator: str) -> tuple[int, int]:
    """The half-open sample range [a, b) of a render: ``sample_range`` or (0, spp). ValueError
    naming ``integrator`` unless 0 <= a < b <= MAX_SAMPLE_INDEX."""
    a, b = (0, int(spp)) if sample_range is None else (int(sample_range[0]), int(sample_range[1]))
    if not 0 <= a < b:
        raise ValueError(f"{integrator}: sample_range must satisfy 0 <= start < stop, got {(a, b)}")
    if b > MAX_SAMPLE_INDEX:
        raise ValueError(f"{integrator}: sample_range stop {b} exceeds {MAX_SAMPLE_INDEX} (the Sobol keys' 27 index bits)")
    return a, b


@dataclass(frozen=True)
class RenderSettings:
    """How to render, whatever the integrator, plus the integrator options the caller sets.

    integrator: "auto" (chosen from the scene's effects) or a name of
    :data:`render.integrators.INTEGRATORS`. spp: samples per pixel when no sample range is given
    (sppm: passes; pssmlt: mutations per pixel on average). max_depth: maximum bounces
    (scattering events). seed: the render's seed. threads: worker threads. batch_paths: camera
    samples per wavefront batch. Neither threads nor batch_paths changes the bytes of path and
    direct (samples are summed per pixel in sample order).

    Integrator options (None: the chosen integrator's default; given to an integrator whose
    ``Options`` lacks the field: ValueError naming the option and the integrator):
    roulette / rr_depth: Russian roulette when leaving vertices of index >= rr_depth (path,
    volpath, bdpt, pssmlt). strategy: "mis", "light" or "bsdf" (direct, path, volpath). heuristic:
    "power" or "balance" (direct, path, volpath, bdpt, pssmlt). photons_per_pass: sppm only.
    sampler: "sobol-blocks" (one Owen-scrambled Sobol sequence per pixel, variance from its blocks
    under a fitted power law, render.film.blocks_variance; their default), "sobol" (R interleaved
    independent replicates: noisier, model-free variance) or "independent" (direct, path, volpath).
    """

    integrator: str = "auto"
    spp: int = 16
    max_depth: int = 8
    roulette: bool | None = None
    rr_depth: int | None = None
    seed: int = 0
    strategy: str | None = None
    heuristic: str | None = None
    threads: int = 2
    batch_paths: int = 1 << 16
    photons_per_pass: int | None = None
    sampler: str | None = None

    def __post_init__(self):
        if self.integrator not in ("auto", *INTEGRATOR_EFFECTS):
            raise ValueError(f"integrator must be auto or one of {', '.join(INTEGRATOR_EFFECTS)}, "
                             f"got {self.integrator!r}")
        if self.strategy is not None:
            check_strategy(self.strategy)
        if self.heuristic is not None:
            check_heuristic(self.heuristic)
        if self.sampler is not None:
            check_sampler(self.sampler)
        if self.spp < 1 or self.max_depth < 0 or (self.rr_depth or 0) < 0 or self.threads < 1 or self.batch_paths < 1:
            raise ValueError("spp, threads and batch_paths must be >= 1; max_depth, rr_depth >= 0")
        if self.spp > MAX_SAMPLE_INDEX:
            raise ValueError(f"spp must be at most {MAX_SAMPLE_INDEX} (the Sobol keys' 27 index bits), got {self.spp}")
        if self.photons_per_pass is not None and self.photons_per_pass < 1:
            raise ValueError(f"photons_per_pass must be >= 1, got {self.photons_per_pass}")

    def given_options(self) -> dict:
        """The integrator options these settings set (name -> value, the fields that are not None)."""
        return {n: getattr(self, n) for n in OPTION_NAMES if getattr(self, n) is not None}

    def options(self, integrator: str, options_type: type):
        """``options_type`` (an integrator's ``Options`` dataclass) from the options given here;
        ValueError naming the first given option that ``integrator`` does not use."""
        known = {f.name for f in fields(options_type)}
        given = self.given_options()
        for name in given:
            if name not in known:
                uses = ", ".join(sorted(known)) or "none of them"
                raise ValueError(f"option '{name}' is not used by integrator '{integrator}' (its options: {uses})")
        return options_type(**given)
