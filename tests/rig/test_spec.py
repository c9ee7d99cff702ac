"""Scene specs: built-in scenes load; malformed specs fail with one line naming the field."""
from pathlib import Path

import numpy as np
import pytest
import yaml

from rig.build import box_face_quads, load_scene
from rig.spec import SCENES_DIR, SpecError, load_spec


def _write(tmp_path: Path, data: dict, name="scene.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data))
    return p


def minimal_spec(**over) -> dict:
    spec = {
        "name": "mini",
        "materials": {"grey": {"type": "lambertian", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"name": "ball", "shape": {"sphere": {"radius": 0.1}}, "material": "grey", "subject": True}],
        "lights": [{"type": "directional", "direction": [0, 0, -1], "irradiance": [1, 1, 1]}],
        "cameras": {"intrinsics": {"width": 32, "height": 24, "fov_y_deg": 40},
                    "train": [{"ring": {"elevation_deg": 30, "count": 4, "distance": 1.0}}]},
    }
    spec.update(over)
    return spec


@pytest.mark.parametrize("name", sorted(p.stem for p in SCENES_DIR.glob("*.yaml")))
def test_builtin_scenes_load(name):
    rig = load_scene(name)
    assert rig.scene.objects and rig.cameras
    for cams in rig.cameras.values():
        for c in cams:
            assert np.allclose(c.cam_to_world[:3, :3] @ c.cam_to_world[:3, :3].T, np.eye(3), atol=1e-12)


def test_turntable_has_two_rings_and_held_out_views():
    rig = load_scene("turntable")
    train, test = rig.cameras["train"], rig.cameras["test"]
    assert len(train) >= 48 and len(test) >= 4
    elev = {round(np.degrees(np.arcsin((c.center[2] - 0.05) / 1.1)), 3) for c in train}
    assert len(elev) == 2
    # held-out views sit at another elevation than either ring
    assert all(round(np.degrees(np.arcsin((c.center[2] - 0.05) / 1.1)), 3) not in elev for c in test)
    names = [c.name for c in train + test]
    assert len(set(names)) == len(names)
    assert "board" in rig.targets


def test_cornell_camera_sees_red_wall_on_the_left():
    rig = load_scene("cornell")
    cam = rig.cameras["scene"][0]
    red = next(o for o in rig.scene.objects if o.name == "left_red")
    uv, z = cam.project(red.mesh.vertices)
    assert np.all(z > 0) and uv[:, 0].mean() < cam.intrinsics.width / 2
    assert np.isclose(np.degrees(cam.intrinsics.fov_y), 39.3077, atol=1e-4)
    light = next(o for o in rig.scene.objects if o.name == "light")
    # emits downwards only: face normals point to -y, and the light sits just below the ceiling
    assert np.allclose(light.mesh.face_normals, [0, -1, 0])
    assert np.all(light.mesh.vertices[:, 1] < 548.8)


def test_box_faces_are_outward_and_unmirrored():
    for corners in box_face_quads((2, 2, 2), (0, 0, 0)):
        n = np.cross(corners[1] - corners[0], corners[3] - corners[0])
        centre = corners.mean(0)
        assert np.dot(n, centre) > 0  # counter-clockwise seen from outside


@pytest.mark.parametrize("mutate, field", [
    (lambda s: s.update(colour="red"), "colour"),                                         # unknown field
    (lambda s: s["cameras"]["intrinsics"].update(width=-64), "cameras.intrinsics.width"),  # negative resolution
    (lambda s: s["cameras"]["intrinsics"].update(height="tall"), "cameras.intrinsics.height"),  # wrong type
    (lambda s: s["objects"][0].update(material="gold"), "gold"),                           # dangling reference
    (lambda s: s["lights"][0].update(type="laser"), "lights.0"),                           # unknown light type
    (lambda s: s["materials"]["grey"].update(albedo=[1.5, 0, 0]), "materials.grey"),       # albedo out of range
])
def test_malformed_spec_names_the_field(tmp_path, mutate, field):
    data = minimal_spec()
    mutate(data)
    with pytest.raises(SpecError) as err:
        load_scene(_write(tmp_path, data))
    msg = str(err.value)
    assert "\n" not in msg and field in msg and "scene.yaml" in msg


def test_missing_mesh_file_is_named(tmp_path):
    data = minimal_spec(objects=[{"name": "bunny", "shape": {"mesh": {"file": "bunny.obj"}}, "material": "grey"}])
    with pytest.raises(SpecError, match=r"objects\.0\.mesh\.file: file not found: .*bunny\.obj"):
        load_scene(_write(tmp_path, data))


def test_unknown_builtin_scene_lists_the_known_ones():
    with pytest.raises(SpecError, match="built-in: .*turntable"):
        load_spec("no_such_scene")


def test_texture_on_shape_without_uv_is_refused(tmp_path):
    data = minimal_spec(textures={"n": {"procedural": {"kind": "noise", "size": 16}}},
                        materials={"grey": {"type": "lambertian", "texture": "n"}})
    with pytest.raises(SpecError, match="texture coordinates"):
        load_scene(_write(tmp_path, data))


# ---------------------------------------------------------------- heterogeneous media
def _fog(**medium) -> dict:
    m = {"bounds": {"box": {"size": [1, 1, 1], "center": [0, 0, 0.5]}}, "sigma_s": [1, 1, 1]}
    m.update(medium)
    return minimal_spec(media=[m])


def test_smoke_density_is_deterministic_bounded_and_fades_at_the_box():
    from rig.volumes import smoke_density

    a, b = smoke_density(24, seed=3), smoke_density(24, seed=3)
    assert np.array_equal(a, b) and not np.array_equal(a, smoke_density(24, seed=4))
    assert a.min() >= 0 and a.max() == 1.0 and np.all(np.isfinite(a))
    # the plume never touches the sides or the bottom of its box (no visible box edges)
    assert a[0].max() == a[-1].max() == a[:, 0].max() == a[:, -1].max() == a[:, :, 0].max() == 0
    assert 0.05 < (a > 0).mean() < 0.5


def test_glowing_smoke_scene_has_a_grid_medium_and_needs_volpath():
    from render.effects import scene_effects
    from render.pathtracer import choose_integrator

    rig = load_scene("glowing_smoke")
    (medium,) = rig.scene.media
    assert medium.density is not None and medium.density.ndim == 3 and medium.emission.max() > 0
    assert choose_integrator(scene_effects(rig.scene)) == "volpath"


def test_density_file_is_loaded_and_checked(tmp_path):
    grid = np.zeros((4, 5, 6))
    grid[1:3, 1:4, 2:5] = 2.0
    np.save(tmp_path / "g.npy", grid)
    rig = load_scene(_write(tmp_path, _fog(density={"file": "g.npy"})))
    assert np.array_equal(rig.scene.media[0].density, grid)
    np.save(tmp_path / "bad.npy", -grid)
    with pytest.raises(SpecError, match=r"media\.0\.density\.file: .*non-negative"):
        load_scene(_write(tmp_path, _fog(density={"file": "bad.npy"})))
    with pytest.raises(SpecError, match=r"media\.0\.density\.file: file not found"):
        load_scene(_write(tmp_path, _fog(density={"file": "missing.npy"})))
    (tmp_path / "text.npy").write_text("not an array")
    with pytest.raises(SpecError, match=r"media\.0\.density\.file: .*not a readable"):
        load_scene(_write(tmp_path, _fog(density={"file": "text.npy"})))


@pytest.mark.parametrize("medium, field", [
    ({"density": {"file": "g.npy", "smoke": {"resolution": 8}}}, "media.0.density"),
    ({"density": {"smoke": {"resolution": 2}}}, "media.0.density.smoke.resolution"),
    ({"sigma_a": [-1, 0, 0]}, "media.0.sigma_a"),
])
def test_malformed_medium_names_the_field(tmp_path, medium, field):
    with pytest.raises(SpecError) as err:
        load_scene(_write(tmp_path, _fog(**medium)))
    assert field in str(err.value) and "\n" not in str(err.value)
