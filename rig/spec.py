"""Scene specs: the YAML schema, validated with pydantic, with one-line errors naming the field.

A spec file describes geometry, materials, textures, lights, optional media, camera layouts
per split (``train``, ``test``, ``scene``) and optional sensor effects. Paths inside a spec
(mesh files, texture images) are relative to the spec file's folder. See ``scenes/*.yaml``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

__all__ = ["SceneSpec", "SpecError", "load_spec", "resolve_scene_path", "SCENES_DIR"]

SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"

Vec3 = tuple[float, float, float]
Rgb = Annotated[tuple[float, float, float], Field(description="linear RGB")]


class SpecError(ValueError):
    """A scene spec is malformed; the message is one line naming the file and field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _non_negative(v: tuple[float, ...], what: str) -> tuple[float, ...]:
    if any(x < 0 for x in v):
        raise ValueError(f"{what} must be non-negative")
    return v


# ---------------------------------------------------------------- textures
class ImageTexture(_Strict):
    """An RGB image: ``skimage:<name>`` (images bundled with scikit-image) or a file path."""
    image: str


class CharucoTexture(_Strict):
    """A ChArUco board drawn by OpenCV: ``squares`` (columns, rows), lengths in scene units."""
    squares: tuple[Annotated[int, Field(ge=3)], Annotated[int, Field(ge=3)]] = (8, 8)
    square_length: float = Field(gt=0)
    marker_length: float = Field(gt=0)
    dictionary: str = "DICT_5X5_100"
    pixels_per_square: int = Field(128, ge=16)

    @model_validator(mode="after")
    def _marker_fits(self):
        if self.marker_length >= self.square_length:
            raise ValueError("marker_length must be smaller than square_length")
        return self


class ProceduralTexture(_Strict):
    """Seeded procedural texture (``noise``: multi-octave colour noise; ``checker``)."""
    kind: Literal["noise", "checker"] = "noise"
    size: int = Field(512, ge=8, le=8192)
    seed: int = 0
    cells: int = Field(8, ge=1)


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
class LambertianSpec(_Strict):
    type: Literal["lambertian"]
    albedo: Rgb = (0.8, 0.8, 0.8)
    texture: str | None = None

    @field_validator("albedo")
    @classmethod
    def _albedo_range(cls, v):
        if any(not 0 <= x <= 1 for x in v):
            raise ValueError("albedo components must lie in [0, 1]")
        return v


class MirrorSpec(_Strict):
    type: Literal["mirror"]
    reflectance: Rgb = (1.0, 1.0, 1.0)


class DielectricSpec(_Strict):
    type: Literal["dielectric"]
    ior: float = Field(1.5, gt=0)


class EmissiveSpec(_Strict):
    type: Literal["emissive"]
    radiance: Rgb
    two_sided: bool = False

    @field_validator("radiance")
    @classmethod
    def _nonneg(cls, v):
        return _non_negative(v, "radiance")


class RoughConductorSpec(_Strict):
    """GGX metal (render.microfacet.RoughConductor): roughness alpha, complex IOR eta + i k per RGB."""
    type: Literal["rough_conductor"]
    alpha: float = Field(0.2, ge=0, le=1)
    eta: Rgb = (0.143, 0.374, 1.442)
    k: Rgb = (3.983, 2.385, 1.603)


class RoughDielectricSpec(_Strict):
    """GGX frosted glass (render.microfacet.RoughDielectric)."""
    type: Literal["rough_dielectric"]
    alpha: float = Field(0.2, ge=0, le=1)
    ior: float = Field(1.5, gt=0)


MaterialSpec = Annotated[Union[LambertianSpec, MirrorSpec, DielectricSpec, EmissiveSpec, RoughConductorSpec,
                               RoughDielectricSpec], Field(discriminator="type")]


# ---------------------------------------------------------------- shapes
class BoxShape(_Strict):
    size: Vec3
    center: Vec3 = (0.0, 0.0, 0.0)

    @field_validator("size")
    @classmethod
    def _positive(cls, v):
        if any(x <= 0 for x in v):
            raise ValueError("box size must be positive")
        return v


class SphereShape(_Strict):
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: float = Field(gt=0)
    subdivisions: int = Field(4, ge=1, le=7)


class CylinderShape(_Strict):
    """Axis along the scene's up axis; ``center`` is the centre of the cylinder."""
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: float = Field(gt=0)
    height: float = Field(gt=0)
    sections: int = Field(64, ge=3)


class QuadShape(_Strict):
    """Four corners in order; the front side is the one they run counter-clockwise around.

    Texture coordinates: corner 0 -> (0, 0), 1 -> (1, 0), 2 -> (1, 1), 3 -> (0, 1).
    """
    corners: tuple[Vec3, Vec3, Vec3, Vec3]


class MeshFileShape(_Strict):
    file: str
    scale: float = Field(1.0, gt=0)
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
    name: str = Field(min_length=1)
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
    inner_deg: float = Field(25.0, ge=0, lt=90)
    outer_deg: float = Field(35.0, gt=0, lt=90)

    @model_validator(mode="after")
    def _cone(self):
        if self.inner_deg > self.outer_deg:
            raise ValueError("inner_deg must not exceed outer_deg")
        _non_negative(self.intensity, "intensity")
        return self


class DirectionalLightSpec(_Strict):
    type: Literal["directional"]
    direction: Vec3
    irradiance: Rgb

    @field_validator("irradiance")
    @classmethod
    def _nonneg(cls, v):
        return _non_negative(v, "irradiance")


LightSpec = Annotated[Union[PointLightSpec, SpotLightSpec, DirectionalLightSpec], Field(discriminator="type")]


class SmokeDensity(_Strict):
    """Procedural plume (rig.volumes.smoke_density) rising along the scene's up axis."""
    resolution: int = Field(32, ge=4, le=256)
    seed: int = 0
    octaves: int = Field(4, ge=1, le=8)


class DensitySpec(_Strict):
    """Voxel grid scaling a medium's coefficients over its bounds' box: a .npy (X, Y, Z) file
    (relative to the spec's folder) or a procedural smoke plume."""
    file: str | None = None
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
    g: float = Field(0.0, gt=-1, lt=1)
    density: DensitySpec | None = None

    @field_validator("sigma_a", "sigma_s", "emission")
    @classmethod
    def _nonneg(cls, v, info):
        return _non_negative(v, info.field_name)


# ---------------------------------------------------------------- cameras
class IntrinsicsSpec(_Strict):
    width: int = Field(gt=0, le=16384)
    height: int = Field(gt=0, le=16384)
    fov_y_deg: float | None = Field(None, gt=0, lt=180)
    fx: float | None = Field(None, gt=0)
    fy: float | None = Field(None, gt=0)
    cx: float | None = None
    cy: float | None = None
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _focal(self):
        if (self.fov_y_deg is None) == (self.fx is None):
            raise ValueError("give exactly one of fov_y_deg, fx (with fy)")
        return self


class RingLayout(_Strict):
    """``count`` cameras on a circle around the up axis through ``target``, looking at ``target``."""
    elevation_deg: float = Field(ge=-89, le=89)
    count: int = Field(ge=1)
    distance: float = Field(gt=0)
    target: Vec3 = (0.0, 0.0, 0.0)
    azimuth_offset_deg: float = 0.0


class GantryLayout(_Strict):
    """Levoy-Hanrahan gantry: an ``nu`` x ``nv`` grid of cameras in a plane, all with the same
    orientation, looking along the plane normal towards ``look_at`` (the centre of the focal plane)."""
    center: Vec3
    look_at: Vec3
    extent: tuple[float, float] = Field(description="grid width and height in scene units")
    nu: int = Field(ge=1)
    nv: int = Field(ge=1)
    up: Vec3 | None = None


class ViewLayout(_Strict):
    name: str | None = None
    eye: Vec3
    target: Vec3
    up: Vec3 | None = None


class LayoutSpec(_Strict):
    ring: RingLayout | None = None
    gantry: GantryLayout | None = None
    view: ViewLayout | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        if sum(getattr(self, k) is not None for k in ("ring", "gantry", "view")) != 1:
            raise ValueError("a camera layout has exactly one of: ring, gantry, view")
        return self


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
        return self


# ---------------------------------------------------------------- sensor
class SensorSpec(_Strict):
    """Capture effects, all off unless given."""
    exposure: float | None = Field(None, gt=0, description="linear multiplier on radiance")
    vignetting: tuple[float, float] | None = Field(None, description="(a2, a4): gain 1 + a2 r^2 + a4 r^4")
    noise: tuple[float, float] | None = Field(None, description="(photons per unit radiance, read noise sigma)")
    distortion: bool = Field(False, description="apply the intrinsics' dist to the images")


class SceneSpec(_Strict):
    name: str = Field(min_length=1)
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
    seed: int = 0

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
        for n in names:
            if names.count(n) > 1:
                raise ValueError(f"objects: name '{n}' is used twice")
        for e in self.effects or []:
            if e not in ALL_EFFECTS:
                raise ValueError(f"effects: unknown effect '{e}' (known: {', '.join(sorted(ALL_EFFECTS))})")
        return self


def _format_error(path: Path, err: ValidationError) -> str:
    e = err.errors()[0]
    loc = ".".join(str(p) for p in e["loc"] if not str(p).startswith(("function-", "tagged-union")))
    msg = e["msg"].removeprefix("Value error, ")
    where = f"{loc}: " if loc and not msg.startswith(loc) else ""
    return f"{path}: {where}{msg}"


def resolve_scene_path(scene: str | Path) -> Path:
    """A built-in scene name (``scenes/<name>.yaml``) or a path to a YAML file."""
    p = Path(scene)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise SpecError(f"{p}: scene file not found")
        return p
    builtin = SCENES_DIR / f"{scene}.yaml"
    if not builtin.is_file():
        known = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.yaml")))
        raise SpecError(f"{scene}: not a scene file nor a built-in scene (built-in: {known})")
    return builtin


def load_spec(scene: str | Path) -> tuple[SceneSpec, Path]:
    """Parse and validate a spec; returns (spec, folder that relative paths resolve against).

    Raises SpecError with one line naming the file and the field.
    """
    path = resolve_scene_path(scene)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        raise SpecError(f"{path}:{where} not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if not isinstance(data, dict):
        raise SpecError(f"{path}: a scene spec must be a YAML mapping")
    try:
        spec = SceneSpec.model_validate(data)
    except ValidationError as err:
        raise SpecError(_format_error(path, err)) from None
    return spec, path.parent
