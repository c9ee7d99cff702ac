"""The scene model every renderer shares: meshes, materials, lights, media.

Units and light conventions (the rasterizer and the path tracer must agree on these):

* Radiance is linear RGB float32, in W / (m^2 sr) per channel ("scene units").
* ``PointLight.intensity`` and ``SpotLight.intensity`` are radiant intensity I (W/sr): the
  irradiance at distance r on a surface tilted by theta is ``I cos(theta) / r^2``
  (times the spot falloff).
* ``DirectionalLight.irradiance`` is the irradiance E (W/m^2) on a surface facing the light.
* An area light is a mesh whose material is :class:`Emissive` with radiance ``Le``, emitting
  from the front side (the side its face normals point to) unless ``two_sided``.
* A Lambertian surface of albedo rho under irradiance E has radiance ``rho E / pi``.
* Texture albedo is stored as an sRGB-encoded uint8 image (as photographs are) and decoded
  to linear albedo with :func:`render.color.srgb_to_linear` by every renderer alike.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # meshes are TriangleMesh or trimesh.Trimesh, of which only the arrays are read here:
    import trimesh  # trimesh (and the scipy and networkx it pulls in, ~1-2 s) stays out of renders

__all__ = [
    "Lambertian", "Mirror", "Dielectric", "Emissive", "DiffuseEmitter", "RoughConductor", "RoughDielectric",
    "ALPHA_SMOOTH", "Material",
    "PointLight", "SpotLight", "DirectionalLight", "Light", "Medium",
    "SceneObject", "Scene", "TriangleMesh", "spot_falloff",
]


def _rgb(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be three finite non-negative numbers, got {v!r}")
    return a


@dataclass
class Lambertian:
    """Diffuse reflector. ``albedo`` (3,) in [0, 1]; ``texture`` (H, W, 3) uint8 sRGB or None.

    With a texture, albedo at a point = srgb_to_linear(texel) * albedo (albedo acts as a tint).
    """

    albedo: np.ndarray = field(default_factory=lambda: np.full(3, 0.8))
    texture: np.ndarray | None = None

    def __post_init__(self):
        self.albedo = _rgb(self.albedo, "albedo")
        if np.any(self.albedo > 1):
            raise ValueError(f"albedo must lie in [0, 1], got {self.albedo.tolist()}")
        if self.texture is not None:
            t = np.asarray(self.texture)
            if t.ndim != 3 or t.shape[2] != 3 or t.dtype != np.uint8:
                raise ValueError(f"texture must be (H, W, 3) uint8, got {t.shape} {t.dtype}")


@dataclass
class Mirror:
    """Perfect specular reflector with reflectance ``reflectance`` (3,)."""

    reflectance: np.ndarray = field(default_factory=lambda: np.ones(3))

    def __post_init__(self):
        self.reflectance = _rgb(self.reflectance, "reflectance")


@dataclass
class Dielectric:
    """Smooth glass-like interface with index of refraction ``ior`` (outside is 1)."""

    ior: float = 1.5

    def __post_init__(self):
        if not (np.isfinite(self.ior) and self.ior > 0):
            raise ValueError(f"ior must be positive, got {self.ior}")


@dataclass
class Emissive:
    """Area source: emits radiance ``radiance`` (3,) from its front side (or both sides).

    Emissive surfaces reflect nothing (black body apart from emission).
    """

    radiance: np.ndarray = field(default_factory=lambda: np.ones(3))
    two_sided: bool = False

    def __post_init__(self):
        self.radiance = _rgb(self.radiance, "radiance")


class DiffuseEmitter(Lambertian):
    """A Lambertian surface that also emits ``radiance`` (3,) (front side, or both if two_sided).

    The scene model's :class:`render.scene.Emissive` reflects nothing; this one reflects like
    a Lambertian of ``albedo`` and emits, which the white-furnace closed form needs. Renderers
    other than the path tracer see it as a plain Lambertian (it subclasses one).
    """

    def __init__(self, albedo=0.8, radiance=1.0, two_sided: bool = False, texture=None):
        super().__init__(albedo=albedo, texture=texture)
        r = np.asarray(radiance, dtype=np.float64).reshape(-1)
        r = np.repeat(r, 3) if r.size == 1 else r
        if r.shape != (3,) or not np.all(np.isfinite(r)) or np.any(r < 0):
            raise ValueError(f"radiance must be three finite non-negative numbers, got {radiance!r}")
        self.radiance = r
        self.two_sided = bool(two_sided)


#: GGX roughness below which a rough material is smooth (pbrt's EffectivelySmooth): sampled as a
#: delta lobe by render.microfacet, and specular in render.effects
ALPHA_SMOOTH = 1e-3


@dataclass
class RoughConductor:
    """A metal: GGX roughness ``alpha`` in [0, 1] and complex IOR ``eta + i k`` per RGB channel.

    Defaults: gold-ish (pbrt's Au at R, G, B). alpha < ALPHA_SMOOTH is a perfect mirror with
    the conductor's Fresnel reflectance.
    """

    alpha: float = 0.2
    eta: np.ndarray = field(default_factory=lambda: np.array([0.143, 0.374, 1.442]))
    k: np.ndarray = field(default_factory=lambda: np.array([3.983, 2.385, 1.603]))

    def __post_init__(self):
        self.eta = _rgb(self.eta, "eta")
        self.k = _rgb(self.k, "k")
        if not (np.isfinite(self.alpha) and 0 <= self.alpha <= 1):
            raise ValueError(f"alpha must lie in [0, 1], got {self.alpha}")
        if np.any(self.eta <= 0):
            raise ValueError(f"eta must be positive, got {self.eta.tolist()}")


@dataclass
class RoughDielectric:
    """Frosted glass: GGX roughness ``alpha`` in [0, 1], index of refraction ``ior`` (outside 1)."""

    alpha: float = 0.2
    ior: float = 1.5

    def __post_init__(self):
        if not (np.isfinite(self.alpha) and 0 <= self.alpha <= 1):
            raise ValueError(f"alpha must lie in [0, 1], got {self.alpha}")
        if not (np.isfinite(self.ior) and self.ior > 0):
            raise ValueError(f"ior must be positive, got {self.ior}")


Material = Lambertian | Mirror | Dielectric | Emissive | RoughConductor | RoughDielectric


@dataclass
class PointLight:
    """Isotropic point source of radiant intensity ``intensity`` (3,) W/sr."""

    position: np.ndarray
    intensity: np.ndarray

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=np.float64)
        self.intensity = _rgb(self.intensity, "intensity")


def spot_falloff(cos_theta, cos_inner: float, cos_outer: float):
    """Spot-light angular falloff in [0, 1] (pbrt-v4's smoothstep between the cone cosines).

    cos_theta: array of cosines between the spot axis and the direction to the point.
    1 inside the inner cone, 0 outside the outer cone, smoothstep in between.
    """
    width = max(cos_inner - cos_outer, 1e-9)
    x = np.clip((np.asarray(cos_theta) - cos_outer) / width, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass
class SpotLight:
    """Point source restricted to a cone: intensity ``intensity`` (W/sr) times :func:`spot_falloff`.

    ``direction`` is the unit axis the spot points along; angles are half-angles in radians.
    """

    position: np.ndarray
    direction: np.ndarray
    intensity: np.ndarray
    inner_angle: float = np.radians(25.0)
    outer_angle: float = np.radians(35.0)

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=np.float64)
        d = np.asarray(self.direction, dtype=np.float64)
        n = np.linalg.norm(d)
        if n < 1e-12:
            raise ValueError("spot direction must be non-zero")
        self.direction = d / n
        self.intensity = _rgb(self.intensity, "intensity")
        if not (0 <= self.inner_angle <= self.outer_angle < np.pi / 2):
            raise ValueError("spot angles must satisfy 0 <= inner <= outer < 90 degrees")


@dataclass
class DirectionalLight:
    """Distant source: light travels along unit ``direction``; irradiance ``irradiance`` (W/m^2)."""

    direction: np.ndarray
    irradiance: np.ndarray

    def __post_init__(self):
        d = np.asarray(self.direction, dtype=np.float64)
        n = np.linalg.norm(d)
        if n < 1e-12:
            raise ValueError("directional light direction must be non-zero")
        self.direction = d / n
        self.irradiance = _rgb(self.irradiance, "irradiance")


Light = PointLight | SpotLight | DirectionalLight


class _Visual:
    """``mesh.visual`` of a :class:`TriangleMesh`: only ``uv``, as trimesh's TextureVisuals has it."""

    __slots__ = ("uv",)

    def __init__(self, uv):
        self.uv = uv


class TriangleMesh:
    """A triangle mesh as arrays: the part of ``trimesh.Trimesh``'s interface the renderers read,
    without importing trimesh (start-up cost: the rig builds quads and boxes as these; trimesh
    stays the loader of mesh files and the builder of spheres and cylinders).

    vertices: (V, 3) float64 world coordinates; faces: (F, 3) int64 vertex indices, counter-clockwise
    seen from the front (the side ``face_normals`` point to); uv: (V, 2) float64 texture
    coordinates (OpenGL's: v up) or None, read as ``visual.uv``; is_convex: whether the closed
    surface is convex (trimesh's meaning: an open mesh such as a quad is not).
    """

    __slots__ = ("vertices", "faces", "visual", "is_convex")

    def __init__(self, vertices, faces, uv=None, is_convex: bool = False):
        self.vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise ValueError(f"faces index vertices 0..{len(self.vertices) - 1}, got {self.faces.min()}..{self.faces.max()}")
        self.visual = _Visual(None if uv is None else np.asarray(uv, dtype=np.float64).reshape(-1, 2))
        self.is_convex = bool(is_convex)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: the vertices' minimum and maximum corners."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    @property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float64 corner positions."""
        return self.vertices[self.faces]

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit normals (right-handed winding; zeros for degenerate faces)."""
        t = self.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    @property
    def area_faces(self) -> np.ndarray:
        """(F,) float64 triangle areas."""
        t = self.triangles
        return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)

    def __repr__(self) -> str:
        return f"<TriangleMesh {len(self.vertices)} vertices, {len(self.faces)} faces>"


@dataclass
class Medium:
    """Participating medium bounded by a closed mesh (data only for now).

    Coefficients in 1/scene-unit: absorption ``sigma_a`` (3,), scattering ``sigma_s`` (3,),
    emission radiance ``emission`` (3,), Henyey-Greenstein ``g``. ``density`` is an optional
    (D, H, W) float32 voxel grid scaling the coefficients over the bounds' box.
    """

    bounds: trimesh.Trimesh
    sigma_a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    g: float = 0.0
    density: np.ndarray | None = None

    def __post_init__(self):
        self.sigma_a = _rgb(self.sigma_a, "sigma_a")
        self.sigma_s = _rgb(self.sigma_s, "sigma_s")
        self.emission = _rgb(self.emission, "emission")
        if not -1 < self.g < 1:
            raise ValueError(f"g must lie in (-1, 1), got {self.g}")


@dataclass
class SceneObject:
    """A triangle mesh in world coordinates with one material.

    ``mesh.visual.uv`` (V, 2) holds texture coordinates when the material is textured
    (u right, v up, OpenGL convention: v = 0 is the bottom row of the texture image).
    ``is_subject`` marks the captured object (what the capture's masks show).
    """

    name: str
    mesh: trimesh.Trimesh
    material: Material
    is_subject: bool = False

    @property
    def uv(self) -> np.ndarray | None:
        uv = getattr(self.mesh.visual, "uv", None)
        return None if uv is None else np.asarray(uv, dtype=np.float64)


@dataclass
class Scene:
    """Everything a renderer needs. ``up`` is the world up axis (unit (3,)).

    ``effects`` is the set of light-transport effects to simulate (see
    :mod:`render.effects`); ``None`` means "infer from content".
    """

    name: str
    objects: list[SceneObject]
    lights: list[Light] = field(default_factory=list)
    media: list[Medium] = field(default_factory=list)
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    effects: frozenset[str] | None = None

    def __post_init__(self):
        self.background = _rgb(self.background, "background")
        names = [o.name for o in self.objects]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"object names must be unique, repeated: {sorted(dup)}")

    @property
    def emitters(self) -> list[SceneObject]:
        return [o for o in self.objects if isinstance(o.material, Emissive)]

    def bounds(self) -> np.ndarray:
        """(2, 3) float64 axis-aligned bounds of all geometry."""
        if not self.objects:
            return np.zeros((2, 3))
        b = np.array([o.mesh.bounds for o in self.objects])
        return np.stack([b[:, 0].min(0), b[:, 1].max(0)])
