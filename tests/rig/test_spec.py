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
    from render.integrators import choose_integrator

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


# ---------------------------------------------------------------- hostile specs (issue 14)
# Each class of malformed value is refused when the spec loads, before anything is built or
# rendered, with one line naming the file and the field.
NAN, INF = float("nan"), float("inf")


def _refused(tmp_path, data, field, name="scene.yaml") -> str:
    with pytest.raises(SpecError) as err:
        load_scene(_write(tmp_path, data, name))
    msg = str(err.value)
    assert "\n" not in msg and name in msg and field in msg, msg
    return msg


def _set(path, value):
    def mutate(s):
        cur = s
        for k in path[:-1]:
            cur = cur[k]
        cur[path[-1]] = value
    return mutate


def _spot(**over):
    light = {"type": "spot", "position": [0, 0, 2], "target": [0, 0, 0], "intensity": [1, 1, 1]}
    light.update(over)
    return lambda s: s.update(lights=[light])


def _add_view(**view):
    return lambda s: s["cameras"].update(test=[{"view": view}])


_NON_FINITE_FIELDS = [
    (["lights", 0, "irradiance"], lambda v: [v, 1, 1], "lights.0.directional.irradiance.0"),
    (["lights", 0, "direction"], lambda v: [0, 0, v], "lights.0.directional.direction.2"),
    (["materials", "grey", "albedo"], lambda v: [0.5, v, 0.5], "materials.grey.lambertian.albedo.1"),
    (["objects", 0, "shape", "sphere", "radius"], lambda v: v, "objects.0.shape.sphere.radius"),
    (["cameras", "train", 0, "ring", "distance"], lambda v: v, "cameras.train.0.ring.distance"),
    (["cameras", "train", 0, "ring", "target"], lambda v: [v, 0, 0], "cameras.train.0.ring.target.0"),
    (["cameras", "intrinsics", "fov_y_deg"], lambda v: v, "cameras.intrinsics.fov_y_deg"),
    (["cameras", "intrinsics", "dist"], lambda v: [v, 0, 0, 0, 0], "cameras.intrinsics.dist.0"),
    (["up"], lambda v: [0, 0, v], "up.2"),
    (["background"], lambda v: [v, 0, 0], "background.0"),
]


@pytest.mark.parametrize("value", [NAN, INF, -INF], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("path, make, field", _NON_FINITE_FIELDS, ids=[f for *_, f in _NON_FINITE_FIELDS])
def test_non_finite_numbers_are_refused(tmp_path, path, make, field, value):
    data = minimal_spec()
    _set(path, make(value))(data)
    assert "finite number" in _refused(tmp_path, data, field)


@pytest.mark.parametrize("mutate, field", [
    (_spot(intensity=[1, NAN, 1]), "lights.0.spot.intensity.1"),
    (_spot(target=[INF, 0, 0]), "lights.0.spot.target.0"),
    (lambda s: s.update(lights=[{"type": "point", "position": [0, NAN, 1], "intensity": [1, 1, 1]}]),
     "lights.0.point.position.1"),
    (lambda s: s["materials"].update(glass={"type": "dielectric", "ior": INF}), "materials.glass.dielectric.ior"),
    (lambda s: s["materials"].update(lamp={"type": "emissive", "radiance": [NAN, 1, 1]}),
     "materials.lamp.emissive.radiance.0"),
    (lambda s: s["materials"].update(gold={"type": "rough_conductor", "eta": [INF, 1, 1]}),
     "materials.gold.rough_conductor.eta.0"),
    (_add_view(eye=[NAN, 1, 1], target=[0, 0, 0]), "cameras.test.0.view.eye.0"),
    (_add_view(eye=[1, 1, 1], target=[0, 0, 0], up=[0, INF, 1]), "cameras.test.0.view.up.1"),
    (lambda s: s["objects"].append({"name": "b", "material": "grey",
                                    "shape": {"box": {"size": [1, 1, 1], "center": [NAN, 0, 0]}}}),
     "objects.1.shape.box.center.0"),
    (lambda s: s["objects"].append({"name": "b", "material": "grey", "shape": {"box": {"size": [INF, 1, 1]}}}),
     "objects.1.shape.box.size.0"),
    (lambda s: s["objects"].append({"name": "q", "material": "grey", "shape": {"quad": {
        "corners": [[0, 0, 0], [1, 0, 0], [1, 1, NAN], [0, 1, 0]]}}}), "objects.1.shape.quad.corners.2.2"),
    (lambda s: s["objects"].append({"name": "m", "material": "grey", "shape": {"mesh": {"file": "m.obj",
                                                                                      "scale": INF}}}),
     "objects.1.shape.mesh.scale"),
    (lambda s: s["objects"].append({"name": "m", "material": "grey", "shape": {"mesh": {
        "file": "m.obj", "translate": [0, -INF, 0]}}}), "objects.1.shape.mesh.translate.1"),
    (lambda s: s.update(sensor={"exposure": INF}), "sensor.exposure"),
    (lambda s: s.update(sensor={"noise": [NAN, 1]}), "sensor.noise.0"),
    (lambda s: s.update(sensor={"vignetting": [0, INF]}), "sensor.vignetting.1"),
    (lambda s: s.update(media=[{"bounds": {"sphere": {"radius": 1}}, "g": NAN}]), "media.0.g"),
    (lambda s: s.update(lights=[{"type": "point", "position": [0, 0, 2e9], "intensity": [1, 1, 1]}]),
     "lights.0.point.position.2"),  # finite but beyond MAX_MAGNITUDE
])
def test_non_finite_and_huge_values_are_refused_everywhere(tmp_path, mutate, field):
    """NaN/inf geometry used to pass the schema: a NaN box centre, an infinite size or mesh scale
    made the subject vanish silently (exit 0, empty mask)."""
    data = minimal_spec()
    mutate(data)
    _refused(tmp_path, data, field)


@pytest.mark.parametrize("mutate, field, says", [
    (_spot(position=[0.3, 0.2, 1.0], target=[0.3, 0.2, 1.0]), "lights.0.spot", "own position"),
    (lambda s: s.update(lights=[{"type": "directional", "direction": [0, 0, 0], "irradiance": [1, 1, 1]}]),
     "lights.0.directional.direction", "non-zero"),
    (lambda s: s.update(up=[0, 0, 0]), "up", "non-zero"),
    (_add_view(eye=[1, 2, 3], target=[1, 2, 3]), "cameras.test.0.view", "coincide"),
    (_add_view(eye=[0, 0, 5], target=[0, 0, 0]), "cameras.test.0.view", "parallel to the up"),  # along scene +z
    (_add_view(eye=[5, 0, 0], target=[0, 0, 0], up=[-2, 0, 0]), "cameras.test.0.view", "parallel to the up"),
    (_add_view(eye=[5, 0, 0], target=[0, 0, 0], up=[0, 0, 0]), "cameras.test.0.view.up", "non-zero"),
    (lambda s: s["cameras"].update(train=[{"gantry": {"center": [0, -1, 0], "look_at": [0, -1, 0],
                                                      "extent": [1, 1], "nu": 2, "nv": 2}}]),
     "cameras.train.0.gantry", "coincide"),
    (lambda s: s["cameras"].update(train=[{"gantry": {"center": [0, -1, 0], "look_at": [0, 0, 0], "up": [0, 3, 0],
                                                      "extent": [1, 1], "nu": 2, "nv": 2}}]),
     "cameras.train.0.gantry", "parallel to the up"),
])
def test_degenerate_directions_are_refused(tmp_path, mutate, field, says):
    data = minimal_spec()
    mutate(data)
    assert says in _refused(tmp_path, data, field)


def test_camera_up_vectors_are_used_by_direction_only(tmp_path):
    """A view's up of any non-zero length gives the same camera as the unit vector."""
    poses = []
    for up in ([0, 0, 1], [0, 0, 1e-10], [0, 0, 250]):  # render.poses.look_at alone refuses up 1e-10
        data = minimal_spec()
        _add_view(name="v", eye=[1, -2, 0.5], target=[0, 0, 0.1], up=up)(data)
        poses.append(load_scene(_write(tmp_path, data)).cameras["test"][0].cam_to_world)
    assert np.allclose(poses[0], poses[1], atol=1e-12) and np.allclose(poses[0], poses[2], atol=1e-12)


@pytest.mark.parametrize("sensor, field, says", [
    ({"exposure": 0}, "sensor.exposure", "greater than 0"),
    ({"exposure": -2}, "sensor.exposure", "greater than 0"),
    ({"noise": [0, 1]}, "sensor.noise", "(0, 1e6]"),
    ({"noise": [-5, 1]}, "sensor.noise", "(0, 1e6]"),
    ({"noise": [1e7, 1]}, "sensor.noise", "(0, 1e6]"),
    ({"noise": [100, -1]}, "sensor.noise", "read noise"),
    ({"vignetting": [-1.0, 0.0]}, "sensor.vignetting", "falls to 0"),  # 1 - r^2 is 0 at the corners
    ({"vignetting": [0.0, -1.5]}, "sensor.vignetting", "falls to -0.5"),
    ({"vignetting": [-4.0, 4.0]}, "sensor.vignetting", "falls to 0"),  # (1 - 2 r^2)^2: 0 at r^2 = 1/2
])
def test_sensor_gains_that_are_not_positive_are_refused(tmp_path, sensor, field, says):
    assert says in _refused(tmp_path, minimal_spec(sensor=sensor), field)


def test_vignetting_min_gain_is_the_minimum_over_the_image():
    """The schema's closed-form minimum of 1 + a2 r^2 + a4 r^4 over the image rectangle against a
    dense evaluation of rig.sensor's convention (r from the principal point over the half-diagonal)
    on a grid 8x finer than the pixels, rectangle edges included; and never above the minimum over
    pixel centres that rig.sensor.vignetting_gain computes."""
    from rig.layouts import make_intrinsics
    from rig.sensor import vignetting_gain
    from rig.spec import IntrinsicsSpec, _vignetting_min_gain

    rng = np.random.default_rng(5)
    for k in (IntrinsicsSpec(width=64, height=48, fov_y_deg=40),
              IntrinsicsSpec(width=64, height=48, fx=50, cx=10, cy=40),
              IntrinsicsSpec(width=40, height=30, fx=50, cx=-20, cy=70)):  # principal point outside
        cx, cy = make_intrinsics(k).cx, make_intrinsics(k).cy
        x, y = np.meshgrid(np.linspace(0, k.width, 8 * k.width + 1), np.linspace(0, k.height, 8 * k.height + 1))
        r2 = ((x - cx) ** 2 + (y - cy) ** 2) / (0.25 * (k.width ** 2 + k.height ** 2))
        for a2, a4 in rng.uniform(-3, 3, size=(200, 2)):
            closed = _vignetting_min_gain(a2, a4, k)
            dense = (1 + a2 * r2 + a4 * r2 * r2).min()
            assert closed <= dense + 1e-12 and dense - closed < 1e-3, (a2, a4, closed, dense)
            if closed > 0:
                assert closed <= vignetting_gain(make_intrinsics(k), a2, a4).min() + 1e-12


@pytest.mark.parametrize("mutate, field", [
    (lambda s: s.update(seed=-1), "seed"),
    (lambda s: s.update(seed=2 ** 64), "seed"),
    (lambda s: s.update(textures={"n": {"procedural": {"seed": -3}}}), "textures.n.procedural.seed"),
    (lambda s: s.update(media=[{"bounds": {"box": {"size": [1, 1, 1]}}, "sigma_s": [1, 1, 1],
                                "density": {"smoke": {"seed": -1}}}]), "media.0.density.smoke.seed"),
])
def test_negative_or_oversized_seeds_are_refused(tmp_path, mutate, field):
    data = minimal_spec()
    mutate(data)
    _refused(tmp_path, data, field)


# ---------------------------------------------------------------- view and scene names
@pytest.mark.parametrize("name", ["../../../escaped_view", "/tmp/abs", "a/b", "a\\b", ".", "..", ".hidden", "",
                                  "x" * 101, "nul\x00byte", "tab\tname", "new\nline", "with space", "bell\x07",
                                  "c:name", "rtl\u202eoverride"])
def test_view_names_must_be_plain_file_stems(tmp_path, name):
    data = minimal_spec()
    _add_view(name=name, eye=[1, 1, 1], target=[0, 0, 0])(data)
    msg = _refused(tmp_path, data, "cameras.test.0.view.name")
    assert msg.isprintable()  # a hostile name cannot break the one line or fool the terminal


@pytest.mark.parametrize("mutate, field", [
    (lambda s: s["objects"][0].update(material="gr\ney\x1b[31m"), "objects.0.material"),
    (lambda s: s["materials"].update({"bad\rkey\u2028": {"type": "lambertian", "albedo": "x"}}), "materials.bad"),
])
def test_names_in_error_lines_are_escaped(tmp_path, mutate, field):
    """Whatever a spec puts in a name, the error stays one printable line (no newline, carriage
    return, line separator or terminal escape from the spec)."""
    data = minimal_spec()
    mutate(data)
    assert _refused(tmp_path, data, field).isprintable()


def test_scene_name_must_be_a_plain_file_stem(tmp_path):
    """The scene name is the default artifacts folder (artifacts/<name>/...)."""
    _refused(tmp_path, minimal_spec(name="../../outside"), "name")


def test_unicode_view_and_scene_names_are_accepted(tmp_path):
    data = minimal_spec(name="scène_場景")
    _add_view(name="vue_été_视图-1", eye=[1, 1, 1], target=[0, 0, 0])(data)
    rig = load_scene(_write(tmp_path, data))
    assert rig.cameras["test"][0].name == "vue_été_视图-1" and rig.scene.name == "scène_場景"


@pytest.mark.parametrize("test_split, says", [
    ([{"view": {"name": "train_001", "eye": [1, 1, 1], "target": [0, 0, 0]}}], "'train_001' is used twice"),
    ([{"view": {"name": "v", "eye": [1, 1, 1], "target": [0, 0, 0]}},
      {"view": {"name": "v", "eye": [2, 1, 1], "target": [0, 0, 0]}}], "'v' is used twice"),
])
def test_view_names_are_unique_across_splits_when_the_spec_loads(tmp_path, test_split, says):
    """Checked by the schema (load_spec), before any camera is built or any view rendered."""
    data = minimal_spec()
    data["cameras"]["test"] = test_split
    with pytest.raises(SpecError, match="cameras.test: view name " + says):
        load_spec(_write(tmp_path, data))


def test_view_names_in_the_schema_are_the_built_cameras_names():
    from rig.spec import view_names

    for name in sorted(p.stem for p in SCENES_DIR.glob("*.yaml")):
        rig = load_scene(name)
        for split, cams in rig.cameras.items():
            assert [c.name for c in cams] == view_names(getattr(rig.spec.cameras, split), split)


# ---------------------------------------------------------------- bounded work
@pytest.mark.parametrize("mutate, field, says", [
    (lambda s: s["cameras"]["train"][0]["ring"].update(count=10_000_000), "cameras.train.0.ring.count", "20000"),
    (lambda s: s["cameras"].update(train=[{"gantry": {"center": [0, -1, 0], "look_at": [0, 0, 0], "extent": [1, 1],
                                                      "nu": 100_000, "nv": 100_000}}]),
     "cameras.train.0.gantry.nu", "20000"),
    (lambda s: s["cameras"].update(train=[{"gantry": {"center": [0, -1, 0], "look_at": [0, 0, 0], "extent": [1, 1],
                                                      "nu": 200, "nv": 200}}]), "cameras", "at most 20000"),
    (lambda s: s["cameras"].update(test=[{"ring": {"elevation_deg": 10, "count": 20_000, "distance": 1}}]),
     "cameras", "20004 views in all splits, at most 20000"),
    (lambda s: s["cameras"]["intrinsics"].update(width=5000, height=5000), "cameras.intrinsics",
     "at most 16777216"),
    (lambda s: s["cameras"]["intrinsics"].update(width=100_000), "cameras.intrinsics.width", "16384"),
    (lambda s: s.update(textures={"n": {"procedural": {"size": 100_000}}}), "textures.n.procedural.size", "4096"),
    (lambda s: s.update(textures={"b": {"charuco": {"square_length": 0.1, "marker_length": 0.07,
                                                    "squares": [10, 10], "pixels_per_square": 1000}}}),
     "textures.b.charuco", "at most 8192 per side"),
    (lambda s: s.update(media=[{"bounds": {"box": {"size": [1, 1, 1]}}, "density": {"smoke": {"resolution": 1000}}}]),
     "media.0.density.smoke.resolution", "128"),
    (lambda s: s["objects"].append({"name": "c", "material": "grey",
                                    "shape": {"cylinder": {"radius": 1, "height": 1, "sections": 10 ** 9}}}),
     "objects.1.shape.cylinder.sections", "4096"),
])
def test_unbounded_work_is_refused_with_its_bound(tmp_path, mutate, field, says):
    data = minimal_spec()
    mutate(data)
    assert says in _refused(tmp_path, data, field)


def test_twenty_thousand_views_are_allowed():
    """Issue 21 wants 1000-view captures: the cap is well above (the poses are cheap)."""
    from rig.spec import MAX_VIEWS, CamerasSpec

    cams = CamerasSpec.model_validate({"intrinsics": {"width": 8, "height": 8, "fov_y_deg": 40},
                                       "train": [{"ring": {"elevation_deg": 10, "count": MAX_VIEWS - 1,
                                                           "distance": 1}}],
                                       "test": [{"view": {"name": "last", "eye": [1, 1, 1], "target": [0, 0, 0]}}]})
    assert MAX_VIEWS >= 20_000 and sum(lay.ring.count for lay in cams.train) + 1 == MAX_VIEWS


def test_oversized_density_grid_is_refused_from_its_header(tmp_path):
    from rig.volumes import MAX_DENSITY_CELLS

    grid = np.lib.format.open_memmap(tmp_path / "big.npy", mode="w+", dtype=np.uint8, shape=(257, 257, 257))
    del grid  # a sparse file: nothing of it is read
    assert 257 ** 3 > MAX_DENSITY_CELLS
    _refused(tmp_path, _fog(density={"file": "big.npy"}), "media.0.density.file")


# ---------------------------------------------------------------- shapes, textures, meshes
@pytest.mark.parametrize("corners", [
    [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]],          # all corners coincide
    [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]],          # collinear
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0.5, 0.5, 0]],      # triangle (0, 2, 3) has zero area
    [[0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0]],          # repeated corner
])
def test_degenerate_quads_are_refused(tmp_path, corners):
    data = minimal_spec()
    data["objects"].append({"name": "q", "material": "grey", "shape": {"quad": {"corners": corners}}})
    assert "degenerate" in _refused(tmp_path, data, "objects.1.shape.quad.corners")


@pytest.mark.parametrize("objects, field", [([], "objects"), ([{"name": "e", "material": "grey", "shape": {}}],
                                                              "objects.0.shape")])
def test_empty_objects_are_refused(tmp_path, objects, field):
    _refused(tmp_path, minimal_spec(objects=objects), field)


def _mesh_spec(file, **mesh):
    return minimal_spec(objects=[{"name": "m", "material": "grey", "subject": True,
                                  "shape": {"mesh": {"file": file, **mesh}}}])


@pytest.mark.parametrize("setup, mesh, says", [
    (lambda d: None, {}, "file not found"),
    (lambda d: (d / "m.obj").mkdir(), {}, "is a folder"),
    (lambda d: (d / "m.obj").write_bytes(np.random.default_rng(0).bytes(4096)), {}, "m.obj"),
    (lambda d: (d / "m.obj").write_text("# no faces\nv 0 0 0\n"), {}, "holds no triangles"),
    (lambda d: (d / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"), {}, "zero-area"),
    (lambda d: (d / "m.obj").write_text("v 0 0 0\nv 1e300 0 0\nv 0 1 0\nf 1 2 3\n"), {}, "not finite or beyond"),
    (lambda d: (d / "m.obj").write_text("v 0 0 0\nv 1e8 0 0\nv 0 1 0\nf 1 2 3\n"), {"scale": 100},
     "not finite or beyond"),
])
def test_unreadable_or_empty_meshes_are_refused(tmp_path, setup, mesh, says):
    setup(tmp_path)
    msg = _refused(tmp_path, _mesh_spec("m.obj", **mesh), "objects.0")
    assert says in msg and ".mesh" in msg


def test_a_valid_mesh_file_loads(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    rig = load_scene(_write(tmp_path, _mesh_spec("m.obj", scale=0.2, translate=[0, 0, 0.1])))
    assert np.isclose(rig.scene.objects[0].mesh.vertices[:, 2].max(), 0.3)


def _textured(image):
    data = minimal_spec(textures={"t": image}, materials={"grey": {"type": "lambertian", "texture": "t"}})
    data["objects"] = [{"name": "q", "material": "grey", "subject": True,
                        "shape": {"quad": {"corners": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}}}]
    return data


@pytest.mark.parametrize("setup, image, says", [
    (lambda d: None, "t.png", "file not found"),
    (lambda d: (d / "t.png").mkdir(), "t.png", "is a folder"),
    (lambda d: (d / "t.png").write_bytes(np.random.default_rng(0).bytes(4096)), "t.png", "cannot read"),
    (lambda d: (d / "t.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40), "t.png", "cannot read"),
    (lambda d: None, "skimage:download_all", "no bundled image"),
    (lambda d: None, "skimage:lily", "no bundled image"),  # fetched from the network on first use
    (lambda d: None, "t\x00.png", "control characters"),
])
def test_unreadable_textures_are_refused_naming_the_field(tmp_path, setup, image, says):
    setup(tmp_path)
    assert says in _refused(tmp_path, _textured(image), "textures.t.image")


def test_oversized_texture_is_refused_from_its_header(tmp_path):
    from PIL import Image

    from rig.spec import MAX_TEXTURE_SIDE

    Image.new("1", (MAX_TEXTURE_SIDE + 1, 8)).save(tmp_path / "wide.png")
    assert f"at most {MAX_TEXTURE_SIDE} per side" in _refused(tmp_path, _textured("wide.png"), "textures.t.image")


def test_bundled_skimage_images_load_offline():
    """SKIMAGE_IMAGES lists only images inside scikit-image's wheel (no download on first use)."""
    import skimage.data

    from rig.spec import SKIMAGE_IMAGES

    for name in SKIMAGE_IMAGES:
        assert np.asarray(getattr(skimage.data, name)()).ndim in (2, 3), name


@pytest.mark.parametrize("charuco, says", [
    ({"dictionary": "DICT_NOPE"}, "unknown ArUco dictionary"),
    ({"squares": [20, 20]}, "200 markers, more than the 100 of DICT_5X5_100"),
    ({"squares": [12, 12], "dictionary": "DICT_4X4_50"}, "72 markers, more than the 50"),
    ({"pixels_per_square": 10_000}, "8192"),
])
def test_impossible_charuco_boards_are_refused(tmp_path, charuco, says):
    board = {"square_length": 0.05, "marker_length": 0.035, **charuco}
    assert says in _refused(tmp_path, _textured({"charuco": board}), "textures.t.charuco")


def test_charuco_dictionary_table_matches_opencv():
    import cv2

    from rig.spec import CHARUCO_DICTIONARIES

    opencv = {n for n in dir(cv2.aruco) if n.startswith("DICT_")}
    assert set(CHARUCO_DICTIONARIES) == opencv
    for name, markers in CHARUCO_DICTIONARIES.items():
        assert cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0] == markers, name


def test_charuco_board_on_a_wrong_size_quad_names_the_field(tmp_path):
    data = _textured({"charuco": {"square_length": 0.05, "marker_length": 0.035, "squares": [4, 4]}})
    _refused(tmp_path, data, "objects.0.shape.quad.corners")  # a 0.2 x 0.2 board on a 1 x 1 quad


# ---------------------------------------------------------------- the YAML file itself
_MINI_YAML = yaml.safe_dump(minimal_spec(), sort_keys=False)


def _write_text(tmp_path, text: str | bytes, name="scene.yaml") -> Path:
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


def _bomb(levels: int = 9) -> str:
    """'Billion laughs': each level repeats the previous one 10 times (10^levels leaves)."""
    lines = ["lol0: &lol0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"lol{i}: &lol{i} [" + ", ".join([f"*lol{i - 1}"] * 10) + "]" for i in range(1, levels + 1)]
    return "\n".join(lines) + "\n"


_TYPE_LINE = _MINI_YAML.splitlines().index("    type: lambertian") + 1


@pytest.mark.parametrize("text, says", [
    (_MINI_YAML + "name: again\n",
     f"line {len(_MINI_YAML.splitlines()) + 1}: duplicate key 'name' (first given at line 1)"),
    (_MINI_YAML.replace("type: lambertian", "type: lambertian\n    type: mirror"),
     f"line {_TYPE_LINE + 1}: duplicate key 'type' (first given at line {_TYPE_LINE})"),
    ("", "the scene file is empty"),
    ("# only a comment\n", "holds no YAML document"),
    ("- a\n- list\n", "must be a YAML mapping, got a list"),
    ("42\n", "must be a YAML mapping, got a int"),
    ("~\n", "must be a YAML mapping, got a NoneType"),
    (_MINI_YAML.encode() + b"description: caf\xe9\n", "not UTF-8 text (byte 0xe9 at offset"),
    (_bomb() + _MINI_YAML, "refused as an alias bomb"),
    ("loop: &loop [*loop]\n" + _MINI_YAML, "line 1: a recursive alias"),
    (_MINI_YAML + "seed: " + "9" * 5000 + "\n", "not a valid YAML value"),
    ("a: " + "[" * 999 + "]" * 999 + "\n" + _MINI_YAML, "a: Extra inputs"),  # libyaml's deepest: read, then refused
    ("a: " + "[" * 1500 + "]" * 1500 + "\n", "nested too deeply"),  # beyond libyaml's 1000 levels
    ("a:\n" + "".join(" " * (i + 1) + f"k{i}:\n" for i in range(1500)) + "\n", "nested too deeply"),
    (_MINI_YAML + "---\n" + _MINI_YAML, "not valid YAML"),
    (_MINI_YAML + "description: !!python/object/apply:os.system [echo]\n", "not valid YAML"),
    (_MINI_YAML + "description: '" + "x" * (4 * 2 ** 20) + "'\n", "bytes, at most 4194304"),
])
def test_malformed_yaml_files_are_one_line(tmp_path, text, says):
    with pytest.raises(SpecError) as err:
        load_spec(_write_text(tmp_path, text))
    msg = str(err.value)
    assert "\n" not in msg and "scene.yaml" in msg and says in msg, msg


def test_alias_bomb_is_refused_with_bounded_memory(tmp_path):
    """10^9 leaves: measured on the node graph (linear), never expanded."""
    import tracemalloc

    path = _write_text(tmp_path, _bomb(9) + _MINI_YAML)
    tracemalloc.start()
    try:
        with pytest.raises(SpecError, match="alias bomb"):
            load_spec(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, peak


def test_benign_aliases_and_merge_keys_still_load(tmp_path):
    text = _MINI_YAML.replace("materials:\n", "materials:\n  base: &base {type: lambertian, albedo: [0.1, 0.2, 0.3]}\n"
                              "  tinted: {<<: *base, albedo: [0.4, 0.4, 0.4]}\n")
    spec, _ = load_spec(_write_text(tmp_path, text))
    assert spec.materials["tinted"].albedo == (0.4, 0.4, 0.4) and spec.materials["base"].albedo == (0.1, 0.2, 0.3)


def test_expanded_size_counts_shared_nodes_once_per_use():
    from rig.spec import _expanded_size

    node = yaml.compose("a: &x [1, 2, 3]\nb: [*x, *x]\n")
    # mapping 1 + keys a, b (2) + list x (4) + list b (1 + 2 x 4)
    assert _expanded_size(node, 10 ** 6) == 1 + 2 + 4 + 9
    assert _expanded_size(yaml.compose(_bomb(3)), 10 ** 6) > 1000


@pytest.mark.parametrize("scene", ["nul\x00.yaml", "x" * 5000 + ".yaml"])
def test_unopenable_scene_paths_are_one_line(scene):
    with pytest.raises(SpecError) as err:
        load_spec(scene)
    assert "\n" not in str(err.value)
