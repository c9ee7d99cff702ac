"""Fixtures for the path tracer's tests (the Cornell box and its cached references).

Helpers live in ptutil.py and cornell_box.py beside this file (put on sys.path here).
"""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cornell_box import cornell_camera, cornell_scene  # noqa: E402
from ptutil import CORNELL_EFFECTS_DIRECT, CORNELL_REF_SPP, CORNELL_RES  # noqa: E402
from render.integrators import RenderSettings, prepare, render  # noqa: E402


@pytest.fixture(scope="session")
def cornell():
    """(scene, prepared scene, camera) of the Cornell box at CORNELL_RES^2."""
    sc = cornell_scene()
    return sc, prepare(sc, threads=2), cornell_camera(CORNELL_RES, CORNELL_RES)


@pytest.fixture(scope="session")
def cornell_path_reference(cornell):
    """High-spp `path` render (MIS, roulette) of the Cornell box, cached for the session."""
    sc, ps, cam = cornell
    return render(sc, cam, RenderSettings(integrator="path", spp=CORNELL_REF_SPP, max_depth=6, seed=1000),
                  prepared=ps)


@pytest.fixture(scope="session")
def cornell_direct_reference(cornell):
    """High-spp `direct` MIS render of the Cornell box (effects restricted to direct light)."""
    sc, ps, cam = cornell
    return render(sc, cam, RenderSettings(integrator="direct", spp=2 * CORNELL_REF_SPP, seed=2000),
                  effects=CORNELL_EFFECTS_DIRECT, prepared=ps)
