"""The scene cache (rig/scene_cache.py): a hit is the scene a fresh load builds, any change to the
file or to a file it names is a miss, bad input is refused as without the cache, and an entry
that is broken, foreign or in a folder others can write is never used."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from rig import scene_cache
from rig.build import load_scene as load_uncached
from rig.spec import SpecError

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("LUMIGRAPH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("LUMIGRAPH_SCENE_CACHE", raising=False)
    return tmp_path / "cache" / "scenes"


def _entries(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.pkl")) if folder.is_dir() else []


def _textured(folder: Path, pixel=(200, 30, 30)) -> Path:
    """A quad with an image texture from a file beside the spec, lit by a point light."""
    folder.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (8, 8), pixel).save(folder / "tex.png")
    spec = {"name": "textured", "textures": {"t": "tex.png"},
            "materials": {"m": {"type": "lambertian", "texture": "t"}},
            "objects": [{"name": "q", "material": "m", "subject": True, "shape": {"quad": {
                "corners": [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]}}}],
            "lights": [{"type": "point", "position": [0, 0, 2], "intensity": [1, 1, 1]}],
            "cameras": {"intrinsics": {"width": 16, "height": 12, "fov_y_deg": 40},
                        "scene": [{"ring": {"elevation_deg": 60, "count": 1, "distance": 3.0}}]}}
    path = folder / "textured.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def _same(a, b, where: str = "", seen: set | None = None) -> None:
    """a and b equal in type and value all the way down (each object once: trimesh's meshes and
    visuals point at each other): arrays bit for bit with their dtypes."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} != {type(b).__name__}"
    seen = set() if seen is None else seen
    if not isinstance(a, (int, float, str, bytes, np.generic, type(None))):  # interned: compared each time
        if id(a) in seen:
            return
        seen.add(id(a))
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), where
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}", seen)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]", seen)
    elif isinstance(a, (frozenset, set)):
        assert a == b, where
    elif hasattr(a, "__dict__") or hasattr(type(a), "__slots__") and not isinstance(a, (np.generic, str)):
        state = lambda o: {**getattr(o, "__dict__", {}),  # noqa: E731
                           **{k: getattr(o, k) for c in type(o).__mro__ for k in getattr(c, "__slots__", ())
                              if hasattr(o, k)}}
        _same(state(a), state(b), where, seen)
    else:
        assert a == b or (a != a and b != b), f"{where}: {a!r} != {b!r}"


def _assert_same_scene(a, b) -> None:
    """The render scene, the cameras and the targets equal in type and value (arrays bit for bit), and the spec."""
    for part in ("scene", "cameras", "targets"):
        _same(getattr(a, part), getattr(b, part), part)
    assert a.spec.model_dump() == b.spec.model_dump()


@pytest.mark.parametrize("name", ["cornell", "glowing_smoke", "turntable"])
def test_a_hit_is_the_scene_a_fresh_load_builds(cache, name):
    first = scene_cache.load_scene(name)
    assert len(_entries(cache)) == 1
    hit = scene_cache.load_scene(name)
    assert hit is not first and hit._spec is None  # from the entry: the spec not yet validated
    _assert_same_scene(hit, load_uncached(name))
    assert len(_entries(cache)) == 1


def test_a_hit_in_a_new_process_imports_neither_pydantic_nor_yaml(cache):
    script = ("import json, sys\nfrom rig.scene_cache import load_scene\nrig = load_scene('cornell')\n"
              "print(json.dumps({'spec_read': rig._spec is not None, "
              "'modules': [m for m in ('pydantic', 'yaml', 'rig.spec', 'rig.build') if m in sys.modules]}))")
    runs = [json.loads(subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True,
                                      env=os.environ, check=True, timeout=300).stdout.splitlines()[-1])
            for _ in range(2)]
    assert runs[0]["modules"] and runs[0]["spec_read"]  # the miss validated the spec
    assert runs[1] == {"spec_read": False, "modules": []}


def test_changing_the_file_or_a_file_it_names_is_a_miss(cache, tmp_path):
    path = _textured(tmp_path / "scene")
    red = scene_cache.load_scene(path)
    assert len(_entries(cache)) == 1
    # the texture changes, the spec does not: the entry's recorded stamp no longer matches
    os.utime(path.parent / "tex.png", ns=(1, 1))
    Image.new("RGB", (8, 8), (30, 30, 200)).save(path.parent / "tex.png")
    blue = scene_cache.load_scene(path)
    _assert_same_scene(blue, load_uncached(path))
    assert not np.array_equal(red.scene.objects[0].material.texture, blue.scene.objects[0].material.texture)
    # the spec changes: another key
    path.write_text(path.read_text().replace("distance: 3.0", "distance: 2.5"))
    moved = scene_cache.load_scene(path)
    _assert_same_scene(moved, load_uncached(path))
    assert len(_entries(cache)) == 2
    _assert_same_scene(scene_cache.load_scene(path), moved)


def test_bad_input_is_refused_as_without_the_cache_and_nothing_is_stored(cache, tmp_path):
    good = _textured(tmp_path / "scene")
    cases = {"dup.yaml": good.read_text() + "name: again\n",
             "bad_value.yaml": good.read_text().replace("fov_y_deg: 40", "fov_y_deg: -40"),
             "empty.yaml": ""}
    (tmp_path / "scene" / "tex.png").rename(tmp_path / "scene" / "moved.png")
    cases["missing_texture.yaml"] = good.read_text()
    for name, text in cases.items():
        path = tmp_path / "scene" / name
        path.write_text(text)
        with pytest.raises(SpecError) as uncached:
            load_uncached(path)
        with pytest.raises(SpecError) as cached:
            scene_cache.load_scene(path)
        assert str(cached.value) == str(uncached.value), name
    with pytest.raises(SpecError, match="not a scene file nor a built-in scene"):
        scene_cache.load_scene("no_such_scene")
    assert _entries(cache) == []


def test_a_broken_entry_is_a_miss_and_is_replaced(cache):
    scene_cache.load_scene("cornell")
    (entry,) = _entries(cache)
    for garbage in (b"", b"not a pickle", entry.read_bytes()[:100]):
        entry.write_bytes(garbage)
        _assert_same_scene(scene_cache.load_scene("cornell"), load_uncached("cornell"))
        assert _entries(cache) == [entry] and len(entry.read_bytes()) > 1000


def test_a_folder_others_can_write_is_not_used(cache):
    cache.mkdir(parents=True)
    cache.chmod(0o777)
    _assert_same_scene(scene_cache.load_scene("cornell"), load_uncached("cornell"))
    assert _entries(cache) == []
    cache.chmod(0o700)
    scene_cache.load_scene("cornell")
    assert len(_entries(cache)) == 1


def test_switched_off_it_writes_nothing(cache, monkeypatch):
    monkeypatch.setenv("LUMIGRAPH_SCENE_CACHE", "0")
    _assert_same_scene(scene_cache.load_scene("cornell"), load_uncached("cornell"))
    assert not cache.exists()


def test_a_scene_naming_a_mesh_file_is_not_cached(cache, tmp_path):
    folder = tmp_path / "mesh"
    folder.mkdir()
    (folder / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    spec = yaml.safe_load(_textured(tmp_path / "scene").read_text())
    spec["objects"].append({"name": "tri", "material": "grey", "shape": {"mesh": {"file": "tri.obj"}}})
    spec["materials"]["grey"] = {"type": "lambertian", "albedo": [0.5, 0.5, 0.5]}
    spec["textures"] = {}
    spec["materials"]["m"] = {"type": "lambertian", "albedo": [0.2, 0.2, 0.2]}
    path = folder / "mesh.yaml"
    path.write_text(yaml.safe_dump(spec))
    _assert_same_scene(scene_cache.load_scene(path), load_uncached(path))
    assert _entries(cache) == []


def test_the_least_recently_used_entries_go_first(cache, tmp_path, monkeypatch):
    monkeypatch.setattr(scene_cache, "MAX_ENTRIES", 2)
    paths = [_textured(tmp_path / f"s{i}", pixel=(10 * i, 0, 0)) for i in range(3)]
    scene_cache.load_scene(paths[0])
    scene_cache.load_scene(paths[1])
    oldest = _entries(cache)
    os.utime(max(oldest, key=lambda p: p.stat().st_mtime_ns), ns=(1, 1))  # s1's entry: the least recent
    scene_cache.load_scene(paths[2])
    assert len(_entries(cache)) == 2
    # s0 kept (its entry is now the most recently used of the first two), s1 gone: a miss rewrites it
    kept = {e.name for e in _entries(cache)}
    scene_cache.load_scene(paths[0])
    assert {e.name for e in _entries(cache)} == kept


def test_a_hit_from_another_working_folder_reads_its_own_spec(cache, tmp_path, monkeypatch):
    path = _textured(tmp_path / "scene")
    monkeypatch.chdir(path.parent)
    scene_cache.load_scene("textured.yaml")  # a relative name: the entry must not keep it
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "textured.yaml").write_text("name: a_decoy\n")
    monkeypatch.chdir(elsewhere)
    hit = scene_cache.load_scene(path)
    assert hit._spec is None and hit.spec.name == "textured"
    _assert_same_scene(hit, load_uncached(path))


def test_a_bundled_image_is_stamped_by_the_scikit_image_that_gave_it(cache, tmp_path):
    spec = yaml.safe_load(_textured(tmp_path / "scene").read_text())
    spec["textures"] = {"t": "skimage:astronaut"}
    path = tmp_path / "scene" / "bundled.yaml"
    path.write_text(yaml.safe_dump(spec))
    scene_cache.load_scene(path)
    (entry,) = _entries(cache)
    import pickle

    import skimage.data

    reads = pickle.loads(entry.read_bytes())["reads"]
    assert [p for p, _ in reads] == [str(Path(skimage.data.__file__).resolve())]


def test_a_charuco_board_is_stamped_by_the_opencv_that_drew_it(cache):
    import pickle

    import cv2

    scene_cache.load_scene("turntable")
    (entry,) = _entries(cache)
    reads = [p for p, _ in pickle.loads(entry.read_bytes())["reads"]]
    assert str(Path(cv2.__file__).resolve()) in reads


def test_a_file_edited_while_the_scene_builds_is_a_miss_next_time(cache, tmp_path, monkeypatch):
    """The stamp is taken when the spec names the file, before it is read: an edit in between
    leaves an entry whose stamp no longer matches, never a stale hit."""
    import rig.textures

    path = _textured(tmp_path / "scene")
    read = rig.textures._read_image

    def edited_then_read(p, field):
        Image.new("RGB", (8, 9), (1, 2, 3)).save(p)  # another size: another stamp
        return read(p, field)

    monkeypatch.setattr(rig.textures, "_read_image", edited_then_read)
    scene_cache.load_scene(path)
    monkeypatch.setattr(rig.textures, "_read_image", read)
    again = scene_cache.load_scene(path)
    assert again._spec is not None  # rebuilt (a hit's spec is not validated until read)
    _assert_same_scene(again, load_uncached(path))
    assert scene_cache.load_scene(path)._spec is None  # and stored again with the right stamp
