"""``lumigraph study uniqueness|caching|bias``: the lecture's open questions, measured.

Each lecture study is a module ``pipeline.stages.<name>_study`` with one entry point::

    run(out: Path, profile: str, seed: int, quiet: bool) -> dict

that fills the (temporary) folder ``out`` with its CSVs, SVG/PNG figures and ``summary.json``,
and returns the metrics for the manifest. This module owns what every study shares: the atomic
folder (:func:`pipeline.artifacts.atomic_stage`, stage name ``lecture_<name>``), the manifest
and the default place, ``<root>/lecture/<name>``.

``summary.json`` is the study's front page, read by the report's lecture section::

    {"title": str, "claim": str (the lecture's claim being tested, one paragraph),
     "headline": [{"figure": str, "value": float | str, "unit": str, "note": str}, ...],
     "figures": [file names in the folder, in the order to show], ...anything else}
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path

from ..artifacts import BadInput, DEFAULT_ROOT, Manifest, atomic_stage

__all__ = ["LECTURE_STUDIES", "PROFILES", "lecture_dir", "run_lecture_study", "size_name"]

#: study name -> (module, one line on what it measures)
LECTURE_STUDIES: dict[str, tuple[str, str]] = {
    "uniqueness": ("pipeline.stages.uniqueness_study",
                   "is a NeRF unique? three cameras, identical renders of different fields, the linear map's rank"),
    "caching": ("pipeline.stages.caching_study",
                "a radiance cache for the path tracer: its bias and time against unbiased path tracing"),
    "bias": ("pipeline.stages.bias_study",
             "biased against unbiased: illuminance at sensor points by path tracing, photon mapping and the cache"),
}

PROFILES = ("quick", "full")


def size_name(profile: str, size_env: str) -> str:
    """The size a study runs at: ``profile``, or ``tiny`` when the environment variable
    ``size_env`` (the tests' knob) says so; any other value of it is BadInput naming it."""
    override = os.environ.get(size_env, "")
    if override:
        if override != "tiny":
            raise BadInput(f"${size_env}: {override!r} is not 'tiny' (unset it for the profile's size)")
        return "tiny"
    return profile


def lecture_dir(name: str, root: Path = DEFAULT_ROOT) -> Path:
    """Default folder of a lecture study: ``<root>/lecture/<name>``."""
    return Path(root) / "lecture" / name


def run_lecture_study(name: str, out: Path, profile: str = "quick", seed: int = 0, quiet: bool = False,
                      overwrite: bool = False) -> dict:
    """Run lecture study ``name`` into ``out`` atomically; returns the manifest's content."""
    if name not in LECTURE_STUDIES:
        raise BadInput(f"study: unknown lecture study {name!r} (known: {', '.join(LECTURE_STUDIES)})")
    if profile not in PROFILES:
        raise BadInput(f"--profile: {profile!r} is not one of {', '.join(PROFILES)}")
    module = importlib.import_module(LECTURE_STUDIES[name][0])
    manifest = Manifest(f"lecture_{name}", params={"study": name, "profile": profile, "seed": seed})
    with atomic_stage(Path(out), f"lecture_{name}", overwrite) as tmp:
        manifest.metrics = module.run(tmp, profile=profile, seed=seed, quiet=quiet)
        data = manifest.write(tmp)
    return data
