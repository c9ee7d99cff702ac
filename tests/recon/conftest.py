"""Scenes and captures for the pose tests: the default turntable shrunk to a few small views, and
programmatic failure-mode scenes (textureless object, repeated textures, a board never visible).

Captures are session-scoped and small (400x300, 20 views) so every pose test shares them.
"""
import copy
from pathlib import Path

import pytest
import yaml

from pipeline.cli import main

REPO = Path(__file__).resolve().parents[2]
SIZE = {"width": 400, "height": 300, "fov_y_deg": 40}


def small_turntable() -> dict:
    """The default scene's content (scenes/turntable.yaml) with 16 train + 4 test views at 400x300."""
    spec = yaml.safe_load((REPO / "scenes" / "turntable.yaml").read_text())
    spec["name"] = "turntable_small"
    spec["cameras"] = {
        "intrinsics": dict(SIZE),
        "train": [{"ring": {"elevation_deg": 30, "count": 8, "distance": 0.9, "target": [0, 0, 0.05]}},
                  {"ring": {"elevation_deg": 50, "count": 8, "distance": 0.9, "target": [0, 0, 0.05],
                            "azimuth_offset_deg": 22.5}}],
        "test": [{"ring": {"elevation_deg": 40, "count": 4, "distance": 0.9, "target": [0, 0, 0.05],
                           "azimuth_offset_deg": 45}}]}
    return spec


def textureless() -> dict:
    """A grey box on a grey turntable top: nothing for SIFT to match."""
    spec = small_turntable()
    spec["name"] = "textureless"
    spec["textures"] = {}
    spec["materials"] = {"grey": {"type": "lambertian", "albedo": [0.5, 0.5, 0.5]},
                         "velvet": {"type": "lambertian", "albedo": [0.02, 0.02, 0.02]}}
    spec["objects"][0]["face_materials"] = ["grey"] * 6
    spec["objects"][1]["material"] = "grey"
    spec["objects"][2]["material"] = "velvet"
    return spec


def repeated_texture() -> dict:
    """Four identical side faces and a plain top, four lights in a 4-fold symmetric
    layout: the box looks the same from azimuths 90 degrees apart, and nothing else in view tells
    those views apart."""
    spec = small_turntable()
    spec["name"] = "repeated"
    spec["textures"] = {"photo": "skimage:astronaut"}
    spec["materials"] = {"photo": {"type": "lambertian", "texture": "photo"},
                         "grey": {"type": "lambertian", "albedo": [0.5, 0.5, 0.5]},
                         "velvet": {"type": "lambertian", "albedo": [0.02, 0.02, 0.02]}}
    spec["objects"] = [{"name": "box", "subject": True, "shape": {"box": {"size": [0.16, 0.16, 0.16],
                                                                          "center": [0, 0, 0.0805]}},
                        "face_materials": ["photo"] * 4 + ["grey", "grey"]},
                       {"name": "turntable", "material": "velvet",
                        "shape": {"cylinder": {"center": [0, 0, -0.021], "radius": 0.3, "height": 0.04}}}]
    spec["lights"] = [{"type": "spot", "position": [0.6 * sx, 0.6 * sy, 1.0], "target": [0, 0, 0.08],
                       "intensity": [2.0, 2.0, 2.0], "inner_deg": 25, "outer_deg": 35}
                      for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    spec["cameras"]["train"] = [{"ring": {"elevation_deg": 25, "count": 16, "distance": 0.9, "target": [0, 0, 0.08]}}]
    spec["cameras"]["test"] = [{"ring": {"elevation_deg": 35, "count": 4, "distance": 0.9, "target": [0, 0, 0.08],
                                         "azimuth_offset_deg": 45}}]
    # sensor noise (seeded per view), as any camera has: without it views 90 degrees apart are
    # bit-identical images, which the poses stage refuses as duplicate views before COLMAP runs
    spec["sensor"] = {"noise": [20000, 0.002]}
    return spec


def board_hidden() -> dict:
    """The board lies face up under the opaque turntable: targets.json describes it, no view sees it."""
    spec = small_turntable()
    spec["name"] = "board_hidden"
    board = next(o for o in spec["objects"] if o["name"] == "board")
    board["shape"]["quad"]["corners"] = [[x, y, -0.2] for x, y, _ in board["shape"]["quad"]["corners"]]
    return spec


def capture(root: Path, spec: dict) -> Path:
    """Write ``spec`` as YAML under ``root`` and capture it; returns the capture folder."""
    root.mkdir(parents=True, exist_ok=True)
    scene = root / f"{spec['name']}.yaml"
    scene.write_text(yaml.safe_dump(copy.deepcopy(spec), sort_keys=False))
    out = root / "capture"
    assert main(["capture", str(scene), "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="session")
def small_capture(tmp_path_factory) -> Path:
    return capture(tmp_path_factory.mktemp("small"), small_turntable())


@pytest.fixture(scope="session")
def textureless_capture(tmp_path_factory) -> Path:
    return capture(tmp_path_factory.mktemp("textureless"), textureless())


@pytest.fixture(scope="session")
def repeated_capture(tmp_path_factory) -> Path:
    return capture(tmp_path_factory.mktemp("repeated"), repeated_texture())


@pytest.fixture(scope="session")
def board_hidden_capture(tmp_path_factory) -> Path:
    return capture(tmp_path_factory.mktemp("board_hidden"), board_hidden())
