"""Scene specs: the YAML schema, validated with pydantic, with one-line errors naming the field.

A spec file describes geometry, materials, textures, lights, optional media, camera layouts
per split (``train``, ``test``, ``scene``) and optional sensor effects. Paths inside a spec
(mesh files, texture images) are relative to the spec file's folder. See ``scenes/*.yaml``.

Everything the schema can judge without reading other files is refused here, before anything
is built or rendered: every number is finite and within :data:`MAX_MAGNITUDE`; directions are
non-zero and cameras have a well-defined frame; view and scene names are plain file stems,
unique across splits; the work a spec asks for is bounded (:data:`MAX_VIEWS`,
:data:`MAX_PIXELS_PER_VIEW`, texture, board and smoke sizes). The YAML reader refuses
duplicate keys, alias bombs, files that are not UTF-8 and files over :data:`MAX_SPEC_BYTES`.
What needs the referenced files (textures, meshes, density grids) is checked by
:mod:`rig.build` and :mod:`rig.textures`, still before any rendering.
"""
from __future__ import annotations

import math
import os
import unicodedata
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Literal, Union

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .scene_file import MAX_SPEC_BYTES, SCENES_DIR, SpecError, note_read, read_spec_bytes, resolve_scene_path

__all__ = ["SceneSpec", "SpecError", "load_spec", "resolve_scene_path", "resolve_file", "SCENES_DIR", "view_names",
           "layout_count", "view_sequences",
           "MAX_VIEWS", "MAX_PIXELS_PER_VIEW", "MAX_TEXTURE_SIDE", "MAX_MAGNITUDE", "MAX_NAME_CHARS",
           "MAX_SPEC_BYTES", "MAX_YAML_NODES", "CHARUCO_DICTIONARIES", "SKIMAGE_IMAGES"]

#: every number in a spec lies in [-MAX_MAGNITUDE, MAX_MAGNITUDE], so products of a few of them
#: (radiance x exposure x gain, coordinates squared) stay finite in float32
MAX_MAGNITUDE = 1e9
#: camera views in one spec, all splits together (issue 21 asks for 1000-view captures)
MAX_VIEWS = 20_000
#: pixels of one view (4096 x 4096): a float32 RGB image of 200 MB
MAX_PIXELS_PER_VIEW = 4096 * 4096
#: pixels along either side of a texture image, a ChArUco board image or a procedural texture
MAX_TEXTURE_SIDE = 8192
#: characters of a view or scene name (they become file stems; filesystems allow 255 bytes)
MAX_NAME_CHARS = 100
#: characters of a file path inside a spec
MAX_PATH_CHARS = 4096
#: YAML nodes of a spec with every alias expanded (an alias bomb expands to billions)
MAX_YAML_NODES = 1_000_000
#: largest seed (the renderers hash seeds as unsigned 64-bit integers)
MAX_SEED = 2 ** 63 - 1

#: OpenCV's predefined ArUco dictionaries (the names cv2.aruco knows) -> number of markers
CHARUCO_DICTIONARIES = {
    **{f"DICT_{b}X{b}_{n}": n for b in (4, 5, 6, 7) for n in (50, 100, 250, 1000)},
    "DICT_ARUCO_ORIGINAL": 1024,
    "DICT_APRILTAG_16h5": 30, "DICT_APRILTAG_16H5": 30,
    "DICT_APRILTAG_25h9": 35, "DICT_APRILTAG_25H9": 35,
    "DICT_APRILTAG_36h10": 2320, "DICT_APRILTAG_36H10": 2320,
    "DICT_APRILTAG_36h11": 587, "DICT_APRILTAG_36H11": 587,
    "DICT_ARUCO_MIP_36h12": 250, "DICT_ARUCO_MIP_36H12": 250,
}
#: scikit-image's images that ship inside its wheel (``skimage:<name>``); the others are
#: downloaded on first use, which a spec must not trigger
SKIMAGE_IMAGES = ("astronaut", "brick", "camera", "cat", "cell", "checkerboard", "chelsea", "clock", "coffee",
                  "coins", "colorwheel", "grass", "gravel", "horse", "hubble_deep_field", "immunohistochemistry",
                  "logo", "microaneurysms", "moon", "page", "retina", "rocket", "text")


# ---------------------------------------------------------------- checked scalar types
def _finite_check(v: float) -> float:
    # allow_inf_nan=False covers every float field; this guards values built in validators
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


#: a finite number within +-MAX_MAGNITUDE (every float of a spec)
Real = Annotated[float, Field(ge=-MAX_MAGNITUDE, le=MAX_MAGNITUDE)]
Vec3 = tuple[Real, Real, Real]
Rgb = Annotated[tuple[Real, Real, Real], Field(description="linear RGB")]
Seed = Annotated[int, Field(ge=0, le=MAX_SEED)]


def _non_negative(v: tuple[float, ...], what: str) -> tuple[float, ...]:
    if any(x < 0 for x in v):
        raise ValueError(f"{what} must be non-negative")
    return v


def _positive(v: tuple[float, ...], what: str) -> tuple[float, ...]:
    if any(x <= 0 for x in v):
        raise ValueError(f"{what} must be positive")
    return v


def _check_stem(name: str) -> str:
    """A name that becomes a file stem: printable, no path separators or whitespace, not hidden."""
    if not name:
        raise ValueError("must not be empty")
    if len(name) > MAX_NAME_CHARS:
        raise ValueError(f"must be at most {MAX_NAME_CHARS} characters (it becomes a file name), got {len(name)}")
    bad = next((c for c in name if unicodedata.category(c)[0] in "CZ" or c in "/\\:*?\"<>|" or c.isspace()), None)
    if bad is not None:
        raise ValueError(f"must be a plain file name: no path separators, whitespace, control or reserved "
                         f"characters (found {bad!r})")
    if name.startswith("."):
        raise ValueError("must be a plain file name, not starting with '.'")
    return name


#: a view or scene name: it becomes a file or folder name
Stem = Annotated[str, AfterValidator(_check_stem)]


def _check_path(p: str) -> str:
    if not p:
        raise ValueError("must not be empty")
    if len(p) > MAX_PATH_CHARS:
        raise ValueError(f"must be at most {MAX_PATH_CHARS} characters")
    bad = next((c for c in p if unicodedata.category(c)[0] == "C"), None)
    if bad is not None:
        raise ValueError(f"must be a file path without control characters (found {bad!r})")
    return p


#: a file path inside a spec (relative to the spec's folder)
FilePath = Annotated[str, AfterValidator(_check_path)]


def _norm(v) -> float:
    return math.sqrt(sum(float(x) * float(x) for x in v))


def _unit(v, what: str) -> tuple[float, float, float]:
    """``v`` normalized; ValueError naming ``what`` when it is (numerically) zero."""
    n = _norm(v)
    if not n > 1e-12:
        raise ValueError(f"{what} must be a non-zero vector, got {tuple(v)}")
    return tuple(float(x) / n for x in v)


def _sub(a, b) -> tuple[float, float, float]:
    return tuple(float(x) - float(y) for x, y in zip(a, b))


def _cross(a, b) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _check_frame(eye, target, up, what: str, eye_name: str = "eye", target_name: str = "target") -> None:
    """A camera at ``eye`` looking at ``target`` with ``up`` up has a well-defined frame
    (the conditions under which render.poses.look_at succeeds, with ``up`` normalized)."""
    d = _sub(target, eye)
    if not _norm(d) > 1e-12:
        raise ValueError(f"{what}: {eye_name} and {target_name} coincide")
    if _norm(_cross(_unit(d, "view direction"), _unit(up, "up"))) < 1e-9:
        raise ValueError(f"{what}: the view direction {eye_name} -> {target_name} is parallel to the up vector")


class _Strict(BaseModel):
    # allow_inf_nan=False: NaN and +-inf are refused for every float, tuple elements included
    # defer_build: a model's validator is built on its first use, not at import; validating a
    # SceneSpec builds one schema for the whole tree (importing this module: ~45 ms, not ~110)
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, defer_build=True)


# ---------------------------------------------------------------- textures
class ImageTexture(_Strict):
    """An RGB image: ``skimage:<name>`` (one of :data:`SKIMAGE_IMAGES`) or a file path."""
    image: FilePath

    @field_validator("image")
    @classmethod
    def _bundled(cls, v):
        if v.startswith("skimage:") and v.split(":", 1)[1] not in SKIMAGE_IMAGES:
            raise ValueError(f"scikit-image has no bundled image '{v.split(':', 1)[1]}' "
                             f"(bundled: {', '.join(SKIMAGE_IMAGES)})")
        return v


class CharucoTexture(_Strict):
    """A ChArUco board drawn by OpenCV: ``squares`` (columns, rows), lengths in scene units."""
    squares: tuple[Annotated[int, Field(ge=3)], Annotated[int, Field(ge=3)]] = (8, 8)
    square_length: Real = Field(gt=0)
    marker_length: Real = Field(gt=0)
    dictionary: str = "DICT_5X5_100"
    pixels_per_square: int = Field(128, ge=16, le=MAX_TEXTURE_SIDE)

    @model_validator(mode="after")
    def _marker_fits(self):
        if self.marker_length >= self.square_length:
            raise ValueError("marker_length must be smaller than square_length")
        if self.dictionary not in CHARUCO_DICTIONARIES:
            raise ValueError(f"dictionary: unknown ArUco dictionary '{self.dictionary}' "
                             f"(known: {', '.join(sorted(CHARUCO_DICTIONARIES))})")
        cols, rows = self.squares
        markers, available = cols * rows // 2, CHARUCO_DICTIONARIES[self.dictionary]
        if markers > available:
            raise ValueError(f"squares: a {cols} x {rows} board has {markers} markers, more than the "
                             f"{available} of {self.dictionary}")
        px = self.pixels_per_square
        if max(cols, rows) * px > MAX_TEXTURE_SIDE:
            raise ValueError(f"squares x pixels_per_square: the board image would be {cols * px} x {rows * px} "
                             f"pixels, at most {MAX_TEXTURE_SIDE} per side")
        return self


class ProceduralTexture(_Strict):
    """Seeded procedural texture (``noise``: multi-octave colour noise; ``checker``), ``size`` x ``size``."""
    kind: Literal["noise", "checker"] = "noise"
    # the noise is summed in float64: 4096^2 x 3 x 8 bytes = 400 MB
    size: int = Field(512, ge=8, le=4096)
    seed: Seed = 0
    cells: int = Field(8, ge=1, le=4096)


class TextureSpec(_Strict):
    image: ImageTexture | None = None
    charuco: CharucoTexture | None = None
    procedural: ProceduralTexture | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        if sum(x is not None for x in (self.image, self.charuco, self.procedural)) != 1:
            raise ValueError("a texture has exactly one of: image, charuco, procedural")
        return self

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, v):
        return {"image": {"image": v}} if isinstance(v, str) else v


# ---------------------------------------------------------------- materials
def _unit_interval(v, what: str):
    if any(not 0 <= x <= 1 for x in v):
        raise ValueError(f"{what} components must lie in [0, 1]")
    return v


class LambertianSpec(_Strict):
    type: Literal["lambertian"]
    albedo: Rgb = (0.8, 0.8, 0.8)
    texture: str | None = None

    @field_validator("albedo")
    @classmethod
    def _albedo_range(cls, v):
        return _unit_interval(v, "albedo")


class MirrorSpec(_Strict):
    type: Literal["mirror"]
    reflectance: Rgb = (1.0, 1.0, 1.0)

    @field_validator("reflectance")
    @classmethod
    def _range(cls, v):
        return _unit_interval(v, "reflectance")


class DielectricSpec(_Strict):
    type: Literal["dielectric"]
    ior: Real = Field(1.5, gt=0)


class EmissiveSpec(_Strict):
    type: Literal["emissive"]
    radiance: Rgb
    two_sided: bool = False

    @field_validator("radiance")
    @classmethod
    def _nonneg(cls, v):
        return _non_negative(v, "radiance")


class RoughConductorSpec(_Strict):
    """GGX metal (render.scene.RoughConductor): roughness alpha, complex IOR eta + i k per RGB."""
    type: Literal["rough_conductor"]
    alpha: Real = Field(0.2, ge=0, le=1)
    eta: Rgb = (0.143, 0.374, 1.442)
    k: Rgb = (3.983, 2.385, 1.603)

    @field_validator("eta")
    @classmethod
    def _positive_eta(cls, v):
        return _positive(v, "eta components")

    @field_validator("k")
    @classmethod
    def _nonneg_k(cls, v):
        return _non_negative(v, "k")


class RoughDielectricSpec(_Strict):
    """GGX frosted glass (render.scene.RoughDielectric)."""
    type: Literal["rough_dielectric"]
    alpha: Real = Field(0.2, ge=0, le=1)
    ior: Real = Field(1.5, gt=0)


MaterialSpec = Annotated[Union[LambertianSpec, MirrorSpec, DielectricSpec, EmissiveSpec, RoughConductorSpec,
                               RoughDielectricSpec], Field(discriminator="type")]


# ---------------------------------------------------------------- shapes
class BoxShape(_Strict):
    size: Vec3
    center: Vec3 = (0.0, 0.0, 0.0)

    @field_validator("size")
    @classmethod
    def _positive_size(cls, v):
        return _positive(v, "box size")


class SphereShape(_Strict):
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: Real = Field(gt=0)
    subdivisions: int = Field(4, ge=1, le=7)


class CylinderShape(_Strict):
    """Axis along the scene's up axis; ``center`` is the centre of the cylinder."""
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: Real = Field(gt=0)
    height: Real = Field(gt=0)
    sections: int = Field(64, ge=3, le=4096)


class QuadShape(_Strict):
    """Four corners in order; the front side is the one they run counter-clockwise around.

    Texture coordinates: corner 0 -> (0, 0), 1 -> (1, 0), 2 -> (1, 1), 3 -> (0, 1).
    Both triangles (0, 1, 2) and (0, 2, 3) must have non-zero area.
    """
    corners: tuple[Vec3, Vec3, Vec3, Vec3]

    @field_validator("corners")
    @classmethod
    def _not_degenerate(cls, c):
        for tri in ((0, 1, 2), (0, 2, 3)):
            a, b, d = (c[i] for i in tri)
            e1, e2 = _sub(b, a), _sub(d, a)
            longest = max(_norm(e1), _norm(e2), _norm(_sub(d, b)))
            # twice the area against the longest edge squared: 0 for collinear or repeated corners
            if not _norm(_cross(e1, e2)) > 1e-9 * longest * longest or longest == 0:
                raise ValueError(f"the quad is degenerate: corners {tri} are collinear or coincide (zero area)")
        return c


class MeshFileShape(_Strict):
    file: FilePath
    scale: Real = Field(1.0, gt=0)
    translate: Vec3 = (0.0, 0.0, 0.0)


class ShapeSpec(_Strict):
    box: BoxShape | None = None
    sphere: SphereShape | None = None
    cylinder: CylinderShape | None = None
    quad: QuadShape | None = None
    mesh: MeshFileShape | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        if sum(getattr(self, k) is not None for k in ("box", "sphere", "cylinder", "quad", "mesh")) != 1:
            raise ValueError("a shape has exactly one of: box, sphere, cylinder, quad, mesh")
        return self


class ObjectSpec(_Strict):
    name: str = Field(min_length=1, max_length=MAX_NAME_CHARS)
    shape: ShapeSpec
    material: str | None = None
    #: boxes only: one material per face, in the order +x, -x, +y, -y, +z, -z
    face_materials: tuple[str, str, str, str, str, str] | None = None
    subject: bool = False

    @model_validator(mode="after")
    def _materials(self):
        if (self.material is None) == (self.face_materials is None):
            raise ValueError("give exactly one of material, face_materials")
        if self.face_materials is not None and self.shape.box is None:
            raise ValueError("face_materials is only for box shapes")
        return self


# ---------------------------------------------------------------- lights
class PointLightSpec(_Strict):
    type: Literal["point"]
    position: Vec3
    intensity: Rgb

    @field_validator("intensity")
    @classmethod
    def _nonneg(cls, v):
        return _non_negative(v, "intensity")


class SpotLightSpec(_Strict):
    type: Literal["spot"]
    position: Vec3
    target: Vec3
    intensity: Rgb
    inner_deg: Real = Field(25.0, ge=0, lt=90)
    outer_deg: Real = Field(35.0, gt=0, lt=90)

    @field_validator("intensity")
    @classmethod
    def _nonneg(cls, v):
        return _non_negative(v, "intensity")

    @model_validator(mode="after")
    def _cone(self):
        if self.inner_deg > self.outer_deg:
            raise ValueError("inner_deg must not exceed outer_deg")
        if not _norm(_sub(self.target, self.position)) > 1e-12:
            raise ValueError("target: the spot is aimed at its own position (target equals position)")
        return self


class DirectionalLightSpec(_Strict):
    type: Literal["directional"]
    direction: Vec3
    irradiance: Rgb

    @field_validator("irradiance")
    @classmethod
    def _nonneg(cls, v):
        return _non_negative(v, "irradiance")

    @field_validator("direction")
    @classmethod
    def _nonzero(cls, v):
        _unit(v, "direction")
        return v


LightSpec = Annotated[Union[PointLightSpec, SpotLightSpec, DirectionalLightSpec], Field(discriminator="type")]


class SmokeDensity(_Strict):
    """Procedural plume (rig.volumes.smoke_density) rising along the scene's up axis."""
    # 128^3: ~4 s and ~200 MB; 256^3 takes ~40 s and 1.3 GB
    resolution: int = Field(32, ge=4, le=128)
    seed: Seed = 0
    octaves: int = Field(4, ge=1, le=8)


class DensitySpec(_Strict):
    """Voxel grid scaling a medium's coefficients over its bounds' box: a .npy (X, Y, Z) file
    (relative to the spec's folder) or a procedural smoke plume."""
    file: FilePath | None = None
    smoke: SmokeDensity | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        if (self.file is None) == (self.smoke is None):
            raise ValueError("a density has exactly one of: file, smoke")
        return self


class MediumSpec(_Strict):
    """Participating medium bounded by a closed shape: coefficients per scene unit (render.media),
    optionally scaled by a density grid (heterogeneous)."""
    bounds: ShapeSpec
    sigma_a: Rgb = (0.0, 0.0, 0.0)
    sigma_s: Rgb = (0.0, 0.0, 0.0)
    emission: Rgb = (0.0, 0.0, 0.0)
    g: Real = Field(0.0, gt=-1, lt=1)
    density: DensitySpec | None = None

    @field_validator("sigma_a", "sigma_s", "emission")
    @classmethod
    def _nonneg(cls, v, info):
        return _non_negative(v, info.field_name)


# ---------------------------------------------------------------- cameras
class IntrinsicsSpec(_Strict):
    """Image size (at most :data:`MAX_PIXELS_PER_VIEW` pixels) and focal length: ``fov_y_deg``
    (square pixels, ``fy = fx``), or ``fx`` (``fy`` defaults to ``fx``). ``cx``, ``cy`` (pixels,
    pixel centres at +0.5) default to the image centre with either focal form."""
    width: int = Field(gt=0, le=16384)
    height: int = Field(gt=0, le=16384)
    fov_y_deg: Real | None = Field(None, gt=0, lt=180)
    fx: Real | None = Field(None, gt=0)
    fy: Real | None = Field(None, gt=0)
    cx: Real | None = None
    cy: Real | None = None
    dist: tuple[Real, Real, Real, Real, Real] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _focal(self):
        if (self.fov_y_deg is None) == (self.fx is None):
            raise ValueError("give exactly one of fov_y_deg, fx (with fy)")
        if self.fov_y_deg is not None and self.fy is not None:  # would be dropped silently
            raise ValueError("fy with fov_y_deg: fov_y_deg sets fy; give fx and fy instead")
        if self.width * self.height > MAX_PIXELS_PER_VIEW:
            raise ValueError(f"width x height: {self.width} x {self.height} = {self.width * self.height} pixels "
                             f"per view, at most {MAX_PIXELS_PER_VIEW} (4096 x 4096)")
        return self

    def principal_point(self) -> tuple[float, float]:
        """(cx, cy) in pixels, as rig.layouts.make_intrinsics sets them."""
        return (self.cx if self.cx is not None else self.width / 2,
                self.cy if self.cy is not None else self.height / 2)


class RingLayout(_Strict):
    """``count`` cameras on a circle around the up axis through ``target``, looking at ``target``."""
    elevation_deg: Real = Field(ge=-89, le=89)
    count: int = Field(ge=1, le=MAX_VIEWS)
    distance: Real = Field(gt=0)
    target: Vec3 = (0.0, 0.0, 0.0)
    azimuth_offset_deg: Real = 0.0


class GantryLayout(_Strict):
    """Levoy-Hanrahan gantry: an ``nu`` x ``nv`` grid of cameras in a plane, all with the same
    orientation, looking along the plane normal towards ``look_at`` (the centre of the focal plane)."""
    center: Vec3
    look_at: Vec3
    extent: tuple[Annotated[Real, Field(ge=0)], Annotated[Real, Field(ge=0)]] = Field(
        description="grid width and height in scene units")
    nu: int = Field(ge=1, le=MAX_VIEWS)
    nv: int = Field(ge=1, le=MAX_VIEWS)
    up: Vec3 | None = None

    @field_validator("up")
    @classmethod
    def _nonzero(cls, v):
        if v is not None:
            _unit(v, "up")
        return v


class ViewLayout(_Strict):
    """One camera at ``eye`` looking at ``target``; ``name`` (a file stem) defaults to
    ``<split>_<index:03d>``."""
    name: Stem | None = None
    eye: Vec3
    target: Vec3
    up: Vec3 | None = None

    @field_validator("up")
    @classmethod
    def _nonzero(cls, v):
        if v is not None:
            _unit(v, "up")
        return v


class LayoutSpec(_Strict):
    ring: RingLayout | None = None
    gantry: GantryLayout | None = None
    view: ViewLayout | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        if sum(getattr(self, k) is not None for k in ("ring", "gantry", "view")) != 1:
            raise ValueError("a camera layout has exactly one of: ring, gantry, view")
        return self


SPLITS = ("train", "test", "scene")


def layout_count(layout: LayoutSpec) -> int:
    """Number of cameras a layout expands to."""
    if layout.ring is not None:
        return layout.ring.count
    if layout.gantry is not None:
        return layout.gantry.nu * layout.gantry.nv
    return 1


def view_names(layouts: list[LayoutSpec], split: str) -> list[str]:
    """The names of a split's cameras in order: a view's own name, else ``<split>_<index:03d>``
    with the index counted over the split (the names captured files take)."""
    names: list[str] = []
    for layout in layouts:
        if layout.view is not None and layout.view.name:
            names.append(layout.view.name)
        else:
            start = len(names)
            names.extend(f"{split}_{start + k:03d}" for k in range(layout_count(layout)))
    return names


def view_sequences(layouts: list[LayoutSpec], split: str) -> list[dict]:
    """The capture order of a split's views, one dict per view in :func:`view_names` order:
    ``sequence`` (``<split>/<layout index>``: one ring, gantry or single view, shot as one
    uninterrupted sweep, as a video's frames), ``kind`` (ring, gantry, view), ``frame`` (index
    within the sequence, in shooting order), ``frames`` (the sequence's length) and ``closed``
    (the sweep returns to its start: a ring's last frame neighbours its first). What a rig
    records while shooting, no pose: structure from motion may pair views by it."""
    order = []
    for i, layout in enumerate(layouts):
        kind = "ring" if layout.ring is not None else "gantry" if layout.gantry is not None else "view"
        n = layout_count(layout)
        order += [{"sequence": f"{split}/{i}", "kind": kind, "frame": k, "frames": n,
                   "closed": kind == "ring" and n > 2} for k in range(n)]
    return order


class CamerasSpec(_Strict):
    intrinsics: IntrinsicsSpec
    train: list[LayoutSpec] = []
    test: list[LayoutSpec] = []
    #: the scene's own camera(s), e.g. the Cornell box's measured camera
    scene: list[LayoutSpec] = []

    @model_validator(mode="after")
    def _some(self):
        if not (self.train or self.test or self.scene):
            raise ValueError("at least one camera layout is needed (train, test or scene)")
        total = sum(layout_count(lay) for split in SPLITS for lay in getattr(self, split))
        if total > MAX_VIEWS:  # checked before any name or pose is generated
            raise ValueError(f"{total} views in all splits, at most {MAX_VIEWS} per spec")
        seen: dict[str, str] = {}
        for split in SPLITS:
            for name in view_names(getattr(self, split), split):
                if name in seen:
                    raise ValueError(f"cameras.{split}: view name '{name}' is used twice (also in {seen[name]}); "
                                     "view names become file names and must be unique across splits")
                seen[name] = split
        return self


# ---------------------------------------------------------------- sensor
class SensorSpec(_Strict):
    """Capture effects, all off unless given (rig.sensor)."""
    exposure: Real | None = Field(None, gt=0, le=1e6, description="linear multiplier on radiance")
    vignetting: tuple[Real, Real] | None = Field(None, description="(a2, a4): gain 1 + a2 r^2 + a4 r^4")
    noise: tuple[Real, Real] | None = Field(None, description="(photons per unit radiance, read noise sigma)")
    distortion: bool = Field(False, description="apply the intrinsics' dist to the images")

    @field_validator("noise")
    @classmethod
    def _noise(cls, v):
        # numpy's Poisson sampler refuses means above ~9.2e18: bound the gain so that radiance
        # up to ~1e12 stays samplable
        if v is not None and not 0 < v[0] <= 1e6:
            raise ValueError(f"photons per unit radiance must lie in (0, 1e6], got {v[0]}")
        if v is not None and v[1] < 0:
            raise ValueError(f"read noise sigma must be >= 0, got {v[1]}")
        return v


def _vignetting_min_gain(a2: float, a4: float, k: IntrinsicsSpec) -> float:
    """Smallest ``1 + a2 r^2 + a4 r^4`` over the image rectangle (rig.sensor.vignetting_gain's
    normalization: r = distance from the principal point / half-diagonal), in closed form: the
    quadratic in s = r^2 on [s_min, s_max] is smallest at an end or at its vertex."""
    cx, cy = k.principal_point()
    half_diag2 = 0.25 * (k.width ** 2 + k.height ** 2)
    dx = max(abs(cx), abs(k.width - cx))
    dy = max(abs(cy), abs(k.height - cy))
    s_max = (dx * dx + dy * dy) / half_diag2
    nx = 0.0 if 0 <= cx <= k.width else min(abs(cx), abs(k.width - cx))
    ny = 0.0 if 0 <= cy <= k.height else min(abs(cy), abs(k.height - cy))
    s_min = (nx * nx + ny * ny) / half_diag2
    candidates = [s_min, s_max]
    if a4 > 0 and s_min < -a2 / (2 * a4) < s_max:
        candidates.append(-a2 / (2 * a4))
    return min(1 + a2 * s + a4 * s * s for s in candidates)


#: effects of DESIGN.md's vocabulary that nothing implements: a spec listing one is refused, never
#: captured without it
UNIMPLEMENTED_EFFECTS = ("motion_blur", "defocus")


class CalibrationSpec(_Strict):
    """A calibration sequence shot with the capture's camera (:mod:`rig.calibration`): the
    ChArUco board object ``board`` alone, filling the frame, one frontal view and ``azimuths``
    views at each tilt of ``tilts_deg`` (degrees from the board's normal)."""
    board: str = Field(min_length=1, max_length=MAX_NAME_CHARS, description="the board object's name")
    tilts_deg: list[Annotated[float, Field(gt=0, le=60)]] = Field([15.0, 30.0, 45.0], min_length=1, max_length=4)
    azimuths: int = Field(12, ge=3, le=16)


class SceneSpec(_Strict):
    name: Stem
    description: str = ""
    units: str = "m"
    up: Vec3 = (0.0, 0.0, 1.0)
    background: Rgb = (0.0, 0.0, 0.0)
    effects: list[str] | None = None
    textures: dict[str, TextureSpec] = {}
    materials: dict[str, MaterialSpec]
    objects: list[ObjectSpec] = Field(min_length=1)
    lights: list[LightSpec] = []
    media: list[MediumSpec] = []
    cameras: CamerasSpec
    sensor: SensorSpec = SensorSpec()
    #: a calibration sequence written with the capture (rig.calibration), or none
    calibration: CalibrationSpec | None = None
    seed: Seed = 0

    @field_validator("up")
    @classmethod
    def _nonzero_up(cls, v):
        _unit(v, "up")
        return v

    @field_validator("background")
    @classmethod
    def _nonneg_background(cls, v):
        return _non_negative(v, "background")

    @model_validator(mode="after")
    def _references(self):
        from render.effects import ALL_EFFECTS

        for i, o in enumerate(self.objects):
            for m in ([o.material] if o.material else list(o.face_materials)):
                if m not in self.materials:
                    raise ValueError(f"objects.{i}.material: unknown material '{m}'")
        for name, m in self.materials.items():
            if isinstance(m, LambertianSpec) and m.texture is not None and m.texture not in self.textures:
                raise ValueError(f"materials.{name}.texture: unknown texture '{m.texture}'")
        names = [o.name for o in self.objects]
        seen = set()
        for n in names:
            if n in seen:
                raise ValueError(f"objects: name '{n}' is used twice")
            seen.add(n)
        if self.calibration is not None:
            board = next((o for o in self.objects if o.name == self.calibration.board), None)
            material = self.materials.get(board.material) if board is not None and board.material else None
            texture = self.textures.get(material.texture) if isinstance(material, LambertianSpec) and material.texture \
                else None
            if board is None or board.shape.quad is None or texture is None or texture.charuco is None:
                raise ValueError(f"calibration.board: '{self.calibration.board}' must name a quad object textured "
                                 "with a charuco board")
        for e in self.effects or []:
            if e not in ALL_EFFECTS:
                raise ValueError(f"effects: unknown effect '{e}' (known: {', '.join(sorted(ALL_EFFECTS))})")
            if e in UNIMPLEMENTED_EFFECTS:
                raise ValueError(f"effects: '{e}' is not simulated by any renderer yet; remove it from the list")
        return self

    @model_validator(mode="after")
    def _camera_frames(self):
        """Every camera has a frame: eye != target, view direction not along its up vector."""
        for split in SPLITS:
            for i, layout in enumerate(getattr(self.cameras, split)):
                where = f"cameras.{split}.{i}"
                if layout.view is not None:
                    v = layout.view
                    _check_frame(v.eye, v.target, v.up if v.up is not None else self.up, f"{where}.view")
                elif layout.gantry is not None:
                    g = layout.gantry
                    _check_frame(g.center, g.look_at, g.up if g.up is not None else self.up, f"{where}.gantry",
                                 "center", "look_at")
                # a ring's elevation lies within +-89 degrees: never along the up axis
        return self

    @model_validator(mode="after")
    def _sensor_gain(self):
        v = self.sensor.vignetting
        if v is not None:
            lowest = _vignetting_min_gain(v[0], v[1], self.cameras.intrinsics)
            if not lowest > 0:
                raise ValueError(f"sensor.vignetting: the gain 1 + a2 r^2 + a4 r^4 falls to {lowest:.3g} on the "
                                 "image; it must stay > 0")
        return self


def _format_error(path: Path, err: ValidationError) -> str:
    e = err.errors()[0]
    loc = ".".join(str(p) for p in e["loc"] if not str(p).startswith(("function-", "tagged-union")))
    msg = e["msg"].removeprefix("Value error, ")
    where = f"{loc}: " if loc and not msg.startswith(loc) else ""
    return f"{path}: {where}{msg}"


def resolve_file(base_dir: Path, name: str, field: str) -> Path:
    """A file named in a spec (relative to the spec's folder), checked to be a regular file;
    SpecError naming ``field`` otherwise."""
    path = Path(name)
    path = path if path.is_absolute() else base_dir / path
    try:
        if path.is_dir():
            raise SpecError(f"{field}: {path} is a folder, not a file")
        if not path.is_file():
            raise SpecError(f"{field}: file not found: {path}")
    except OSError as exc:  # a name too long for the filesystem, a permission
        raise SpecError(f"{field}: cannot open {path} ({exc.strerror or type(exc).__name__})") from None
    note_read(path, field)
    return path


# ---------------------------------------------------------------- YAML reading
class _YamlRefusal(Exception):
    """A YAML document the spec reader refuses (duplicate key, alias bomb): line and reason."""

    def __init__(self, line: int, reason: str):
        super().__init__(reason)
        self.line, self.reason = line, reason


class _SpecLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """PyYAML's safe loader (libyaml's parser where PyYAML was built with it: a tenth of the time),
    refusing duplicate mapping keys (the last one would win silently)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            first: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                    continue  # merged keys may be overridden (YAML's merge semantics)
                key = self.construct_object(key_node)
                try:
                    if key in first:
                        raise _YamlRefusal(key_node.start_mark.line + 1,
                                           f"duplicate key '{key}' (first given at line {first[key]})")
                except TypeError:  # an unhashable key: PyYAML refuses it itself
                    continue
                first[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


def _expanded_size(root: yaml.Node, limit: int) -> int:
    """Nodes of the document with every alias expanded (capped at ``limit + 1``), in time linear
    in the node graph: sizes are memoized per node, so an alias bomb is measured, not expanded.
    Raises _YamlRefusal on a recursive alias."""
    done: dict[int, int] = {}
    active: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]

    def children(n: yaml.Node) -> list[yaml.Node]:
        if isinstance(n, yaml.MappingNode):
            return [x for pair in n.value for x in pair]
        return list(n.value) if isinstance(n, yaml.SequenceNode) else []

    while stack:
        node, expanded = stack.pop()
        key = id(node)
        if expanded:
            active.discard(key)
            done[key] = min(limit + 1, 1 + sum(done[id(c)] for c in children(node)))
            continue
        if key in done:
            continue
        if key in active:  # popped again while its own subtree is open: it contains itself
            raise _YamlRefusal(node.start_mark.line + 1, "a recursive alias (a node that contains itself)")
        active.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in children(node) if id(c) not in done)
    return done[id(root)]


def _read_yaml(path: Path, raw: bytes | None = None):
    """The document in ``path`` (or in ``raw``, its bytes already read by
    :func:`rig.scene_file.read_spec_bytes`), or SpecError (one line) for a file the spec reader refuses."""
    if raw is None:
        raw = read_spec_bytes(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start})") from None
    if not text.strip():
        raise SpecError(f"{path}: the scene file is empty")
    loader = _SpecLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise SpecError(f"{path}: the scene file holds no YAML document")
        if _expanded_size(node, MAX_YAML_NODES) > MAX_YAML_NODES:
            raise SpecError(f"{path}: the YAML document expands to more than {MAX_YAML_NODES} nodes "
                            "(aliases expanded): refused as an alias bomb")
        return loader.construct_document(node)
    except SpecError:
        raise
    except _YamlRefusal as exc:
        raise SpecError(f"{path}: line {exc.line}: {exc.reason}") from None
    except yaml.YAMLError as exc:
        if "maximum nesting depth" in str(getattr(exc, "problem", "")):  # libyaml's limit (1000 levels)
            raise SpecError(f"{path}: the YAML document is nested too deeply") from None
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        raise SpecError(f"{path}:{where} not valid YAML ({getattr(exc, 'problem', None) or exc})") from None
    except RecursionError:
        raise SpecError(f"{path}: the YAML document is nested too deeply") from None
    except ValueError as exc:  # e.g. an integer literal longer than Python's digit limit
        raise SpecError(f"{path}: not a valid YAML value ({exc})") from None
    finally:
        loader.dispose()


@contextmanager
def _no_pydantic_plugins():
    """Build the schema's validators without pydantic's plugins: looking them up scans every
    installed package's entry points (~30 ms with importing importlib.metadata); none applies to
    a scene spec. typer does the same for its option adapters."""
    previous = os.environ.get("PYDANTIC_DISABLE_PLUGINS")
    os.environ["PYDANTIC_DISABLE_PLUGINS"] = "__all__"
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop("PYDANTIC_DISABLE_PLUGINS", None)
        else:
            os.environ["PYDANTIC_DISABLE_PLUGINS"] = previous


def load_spec(scene: str | Path, raw: bytes | None = None) -> tuple[SceneSpec, Path]:
    """Parse and validate a spec; returns (spec, folder that relative paths resolve against).
    raw: the file's bytes when already read (the scene cache's lazy spec), else read here.

    Raises SpecError with one line naming the file and the field.
    """
    path = resolve_scene_path(scene)
    data = _read_yaml(path, raw)
    if not isinstance(data, dict):
        raise SpecError(f"{path}: a scene spec must be a YAML mapping, got a {type(data).__name__}")
    try:
        with _no_pydantic_plugins():
            spec = SceneSpec.model_validate(data)
    except ValidationError as err:
        raise SpecError(_format_error(path, err)) from None
    except RecursionError:  # a structure nested deeper than the schema's own
        raise SpecError(f"{path}: the document is nested too deeply") from None
    return spec, path.parent
