"""Turn a validated :class:`rig.spec.SceneSpec` into the render scene model and cameras."""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from render.camera import Camera
from render.scene import RoughConductor, RoughDielectric
from render.scene import (Dielectric, DirectionalLight, Emissive, Lambertian, Medium, Mirror, PointLight,
                          Scene, SceneObject, SpotLight, TriangleMesh)

from .layouts import layout_cameras, make_intrinsics
from .rig_scene import RigScene
from .spec import (MAX_MAGNITUDE, DielectricSpec, EmissiveSpec, LambertianSpec, MirrorSpec, PointLightSpec,
                   RoughConductorSpec, RoughDielectricSpec, SceneSpec, ShapeSpec, SpecError, SpotLightSpec, load_spec,
                   resolve_file, resolve_scene_path)
from .textures import load_texture
from .volumes import load_density_file, smoke_density

if TYPE_CHECKING:  # imported where a sphere, a cylinder or a mesh file needs it: quads and boxes are
    import trimesh  # arrays, so a scene of those (the Cornell box) renders without trimesh's ~1 s import

__all__ = ["RigScene", "build_scene", "load_scene", "quad_mesh", "box_mesh", "box_face_quads"]


#: trimesh.creation.box's unit cube (vertices at +-0.5, x slowest) and its faces, outward-wound:
#: the same triangles in the same order as before boxes stopped importing trimesh
_BOX_CORNERS = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
_BOX_FACES = np.array([[1, 3, 0], [4, 1, 0], [0, 3, 2], [2, 4, 0], [1, 7, 3], [5, 1, 4], [5, 7, 1], [3, 7, 2],
                       [6, 4, 2], [2, 7, 6], [6, 5, 4], [7, 5, 6]])


def quad_mesh(corners) -> TriangleMesh:
    """Two triangles over four corners (counter-clockwise seen from the front), with uv
    corner 0 -> (0, 0), 1 -> (1, 0), 2 -> (1, 1), 3 -> (0, 1). Open, so not convex (trimesh's
    answer for the same quad)."""
    v = np.asarray(corners, dtype=np.float64)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    return TriangleMesh(v, np.array([[0, 1, 2], [0, 2, 3]]), uv=uv, is_convex=False)


def box_mesh(size, center) -> TriangleMesh:
    """An axis-aligned box of ``size`` (3,) centred at ``center`` (3,): 8 vertices, 12 outward
    triangles (trimesh.creation.box's layout), closed and convex, no uv."""
    v = _BOX_CORNERS * np.asarray(size, dtype=np.float64) + np.asarray(center, dtype=np.float64)
    return TriangleMesh(v, _BOX_FACES, is_convex=True)


def box_face_quads(size, center) -> list[np.ndarray]:
    """Corners of the six faces of an axis-aligned box, order +x, -x, +y, -y, +z, -z.

    Each face's corners run counter-clockwise seen from outside, starting bottom-left, with +z up
    on the side faces and +y up on the top and bottom, so textures appear unmirrored from outside.
    """
    c, h = np.asarray(center, float), np.asarray(size, float) / 2
    ex, ey, ez = np.eye(3)
    faces = []
    for n, up in ((ex, ez), (-ex, ez), (ey, ez), (-ey, ez), (ez, ey), (-ez, ey)):
        right = np.cross(-n, up)  # a viewer looking along -n with ``up`` up has this on the right
        fc, r, u = c + n * h, right * h, up * h
        faces.append(np.array([fc - r - u, fc + r - u, fc + r + u, fc - r + u]))
    return faces


def _shape_mesh(shape: ShapeSpec, up: np.ndarray, base_dir: Path, where: str) -> TriangleMesh | trimesh.Trimesh:
    if shape.box is not None:
        return box_mesh(shape.box.size, shape.box.center)
    if shape.quad is not None:
        return quad_mesh(shape.quad.corners)
    import trimesh  # the loader of files and the builder of spheres and cylinders (see above)

    if shape.sphere is not None:
        m = trimesh.creation.icosphere(subdivisions=shape.sphere.subdivisions, radius=shape.sphere.radius)
        m.apply_translation(shape.sphere.center)
        return m
    if shape.cylinder is not None:
        c = shape.cylinder
        m = trimesh.creation.cylinder(radius=c.radius, height=c.height, sections=c.sections)
        m.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], up))
        m.apply_translation(c.center)
        return m
    path = resolve_file(base_dir, shape.mesh.file, f"{where}.mesh.file")
    # numpy's overflow warnings on hostile files would add lines to the one-line error
    with np.errstate(all="ignore"):
        try:
            m = trimesh.load(path, force="mesh")
        except Exception as exc:  # trimesh raises many types for unreadable files
            why = " ".join(str(exc).split()) or type(exc).__name__
            raise SpecError(f"{where}.mesh.file: cannot read {path}: {why}") from None
        if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
            raise SpecError(f"{where}.mesh.file: {path} holds no triangles")
        placed = m.vertices * shape.mesh.scale + np.asarray(shape.mesh.translate)
        if not np.all(np.abs(placed) <= MAX_MAGNITUDE):  # False for NaN too
            raise SpecError(f"{where}.mesh: {path} has vertices that are not finite or beyond +-{MAX_MAGNITUDE:.0e} "
                            "(after scale and translate)")
    m.apply_scale(shape.mesh.scale)
    m.apply_translation(shape.mesh.translate)
    # finite vertices (above) with at least one triangle of non-zero area: else the subject would vanish
    if not np.any(m.area_faces > 0):
        raise SpecError(f"{where}.mesh.file: {path} holds only zero-area triangles")
    return m


def _density(medium, up: np.ndarray, base_dir: Path, where: str) -> np.ndarray | None:
    """A medium's (X, Y, Z) density grid, or None for a homogeneous medium."""
    d = medium.density
    if d is None:
        return None
    if d.smoke is not None:
        return smoke_density(d.smoke.resolution, d.smoke.seed, d.smoke.octaves, up_axis=int(np.argmax(np.abs(up))))
    path = resolve_file(base_dir, d.file, f"{where}.file")
    try:
        return load_density_file(path)
    except ValueError as exc:
        raise SpecError(f"{where}.file: {exc}") from None


def _material(spec, textures: dict[str, np.ndarray]):
    if isinstance(spec, LambertianSpec):
        return Lambertian(np.array(spec.albedo), textures[spec.texture] if spec.texture else None)
    if isinstance(spec, MirrorSpec):
        return Mirror(np.array(spec.reflectance))
    if isinstance(spec, DielectricSpec):
        return Dielectric(spec.ior)
    if isinstance(spec, EmissiveSpec):
        return Emissive(np.array(spec.radiance), spec.two_sided)
    if isinstance(spec, RoughConductorSpec):
        return RoughConductor(spec.alpha, np.array(spec.eta), np.array(spec.k))
    if isinstance(spec, RoughDielectricSpec):
        return RoughDielectric(spec.alpha, spec.ior)
    raise TypeError(spec)


def _board_to_world(corners: np.ndarray, board, where: str) -> np.ndarray:
    """OpenCV board frame (origin at the image's top-left corner, x right, y down the image,
    z into the board) for a board texture on a quad whose corner 3 is the image's top-left."""
    x = corners[2] - corners[3]
    y = corners[0] - corners[3]
    width, height = board.squares[0] * board.square_length, board.squares[1] * board.square_length
    if not (np.isclose(np.linalg.norm(x), width, rtol=1e-6) and np.isclose(np.linalg.norm(y), height, rtol=1e-6)):
        raise SpecError(f"{where}.shape.quad.corners: the charuco board is {width:.6g} x {height:.6g} but its quad is "
                        f"{np.linalg.norm(x):.6g} x {np.linalg.norm(y):.6g}")
    m = np.eye(4)
    m[:3, 0], m[:3, 1] = x / np.linalg.norm(x), y / np.linalg.norm(y)
    m[:3, 2] = np.cross(m[:3, 0], m[:3, 1])
    m[:3, 3] = corners[3]
    return m


@contextmanager
def _field(where: str):
    """Report a ValueError raised while building ``where`` (a spec field) as a SpecError naming it.
    The schema refuses what it can see; this catches what only the built objects can."""
    try:
        yield
    except SpecError:
        raise
    except ValueError as exc:
        raise SpecError(f"{where}: {' '.join(str(exc).split())}") from None


def build_scene(spec: SceneSpec, base_dir: Path) -> RigScene:
    """Spec -> scene model, cameras per split, calibration targets. Raises SpecError naming the field."""
    up = np.asarray(spec.up, float)
    if np.linalg.norm(up) < 1e-12:  # the schema refuses it too; build_scene also takes hand-made specs
        raise SpecError("up: must be a non-zero vector")
    up = up / np.linalg.norm(up)
    textures = {name: load_texture(name, t, base_dir) for name, t in spec.textures.items()}
    materials = {}
    for name, m in spec.materials.items():
        with _field(f"materials.{name}"):
            materials[name] = _material(m, textures)
    objects: list[SceneObject] = []
    targets: dict[str, dict] = {}
    for i, o in enumerate(spec.objects):
        where = f"objects.{i}"
        if o.face_materials is not None:
            parts = [(f"{o.name}.{face}", quad_mesh(q), mat) for face, q, mat in
                     zip(("px", "nx", "py", "ny", "pz", "nz"), box_face_quads(o.shape.box.size, o.shape.box.center),
                         o.face_materials)]
        else:
            with _field(f"{where}.shape"):
                parts = [(o.name, _shape_mesh(o.shape, up, base_dir, where), o.material)]
        for name, mesh, mat_name in parts:
            mat = materials[mat_name]
            if isinstance(mat, Lambertian) and mat.texture is not None and getattr(mesh.visual, "uv", None) is None:
                raise SpecError(f"{where}.material: texture '{spec.materials[mat_name].texture}' needs a shape with "
                                "texture coordinates (quad, box faces or a mesh file with uv)")
            objects.append(SceneObject(name, mesh, mat, is_subject=o.subject))
            tex = spec.materials[mat_name]
            if isinstance(tex, LambertianSpec) and tex.texture and spec.textures[tex.texture].charuco is not None:
                if o.shape.quad is None:
                    raise SpecError(f"{where}.shape: a charuco texture must sit on a quad")
                board = spec.textures[tex.texture].charuco
                targets[name] = {"board": board.model_dump(mode="json"),
                                 "board_to_world": _board_to_world(np.asarray(o.shape.quad.corners, float), board,
                                                                   where).tolist()}
    lights = []
    for i, light in enumerate(spec.lights):
        with _field(f"lights.{i}"):
            if isinstance(light, PointLightSpec):
                lights.append(PointLight(np.array(light.position), np.array(light.intensity)))
            elif isinstance(light, SpotLightSpec):
                lights.append(SpotLight(np.array(light.position), np.subtract(light.target, light.position),
                                        np.array(light.intensity), np.radians(light.inner_deg),
                                        np.radians(light.outer_deg)))
            else:
                lights.append(DirectionalLight(np.array(light.direction), np.array(light.irradiance)))
    media = []
    for i, m in enumerate(spec.media):
        with _field(f"media.{i}"):
            media.append(Medium(_shape_mesh(m.bounds, up, base_dir, f"media.{i}.bounds"), np.array(m.sigma_a),
                                np.array(m.sigma_s), np.array(m.emission), m.g,
                                _density(m, up, base_dir, f"media.{i}.density")))
    with _field("objects"):
        scene = Scene(spec.name, objects, lights, media, np.array(spec.background), up,
                      frozenset(spec.effects) if spec.effects is not None else None)
    with _field("cameras.intrinsics"):
        intrinsics = make_intrinsics(spec.cameras.intrinsics)
    cameras = {}
    for split in ("train", "test", "scene"):
        if getattr(spec.cameras, split):
            with _field(f"cameras.{split}"):
                cameras[split] = layout_cameras(getattr(spec.cameras, split), intrinsics, up, split)
    return RigScene(spec, scene, cameras, targets)


def load_scene(scene: str | Path, raw: bytes | None = None) -> RigScene:
    """Load a built-in scene name or a YAML path into a :class:`RigScene` (SpecError on bad input).
    raw: the file's bytes when already read (:mod:`rig.scene_cache`)."""
    spec, base_dir = load_spec(scene, raw)
    try:
        return build_scene(spec, base_dir)
    except SpecError as exc:  # name the file as load_spec's errors do
        raise SpecError(f"{resolve_scene_path(scene)}: {exc}") from None
