"""A tiny turntable-like scene: small images, few views, so pipeline tests stay fast."""
from pathlib import Path

import pytest
import yaml

TINY_SCENE = {
    "name": "tiny",
    "up": [0, 0, 1],
    "effects": ["direct", "shadows"],
    "textures": {"photo": "skimage:astronaut", "board": {"charuco": {
        "squares": [5, 5], "square_length": 0.06, "marker_length": 0.045, "pixels_per_square": 32}}},
    "materials": {
        "photo": {"type": "lambertian", "texture": "photo"},
        "board": {"type": "lambertian", "texture": "board", "albedo": [0.8, 0.8, 0.8]},
        "grey": {"type": "lambertian", "albedo": [0.5, 0.5, 0.5]},
    },
    "objects": [
        {"name": "cube", "subject": True, "shape": {"box": {"size": [0.1, 0.1, 0.1], "center": [0, 0, 0.0505]}},
         "face_materials": ["photo", "grey", "photo", "grey", "photo", "grey"]},
        {"name": "board", "material": "board",
         "shape": {"quad": {"corners": [[-0.15, -0.15, 0], [0.15, -0.15, 0], [0.15, 0.15, 0], [-0.15, 0.15, 0]]}}},
    ],
    "lights": [{"type": "spot", "position": [0.3, 0.2, 1.0], "target": [0, 0, 0], "intensity": [1.5, 1.5, 1.5],
                "inner_deg": 20, "outer_deg": 28}],
    "cameras": {"intrinsics": {"width": 128, "height": 96, "fov_y_deg": 40},
                "train": [{"ring": {"elevation_deg": 35, "count": 4, "distance": 0.8}}],
                "test": [{"ring": {"elevation_deg": 45, "count": 2, "distance": 0.8, "azimuth_offset_deg": 45}}]},
}


def write_scene(folder: Path, data: dict, name: str = "tiny.yaml") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture
def tiny_scene(tmp_path) -> Path:
    return write_scene(tmp_path / "scenes", TINY_SCENE)
