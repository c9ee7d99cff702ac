"""BSDFs vectorized over rays, in local shading frames, and the per-scene material table.

Local frames are z-up (``w.z = cos theta`` against the frame normal). Every sampler returns a
:class:`BSDFSample` holding the sampled direction, its *weight* ``f |cos| / pdf`` (what a path's
throughput is multiplied by), its density, and whether it is a delta (specular) event: for
delta events ``pdf`` is the discrete probability of the chosen lobe and is not a solid-angle
density (never MIS-weighted). ``eval``/``pdf`` of delta BSDFs are zero for every direction.

This split (sample / eval / pdf, local frame, explicit delta flag and per-sample pdf) is what
bidirectional methods and photon mapping reuse: a glossy microfacet lobe adds one more kind.

Conventions: radiance transport (pbrt-v4's TransportMode::Radiance): refraction scales radiance
by (eta_i / eta_t)^2. Lambertian and mirror surfaces are two-sided (callers flip the frame
normal to face ``wo``); a dielectric's frame normal is its outward geometric normal.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Dielectric, DiffuseEmitter, Emissive, Lambertian, Mirror, RoughConductor, RoughDielectric, Scene
from .texture import decode_texture, sample_bilinear
from .sampling import INV_PI, cosine_hemisphere, cosine_hemisphere_pdf

__all__ = [
    "BSDFSample",
    "lambert_eval", "lambert_pdf", "lambert_sample",
    "mirror_sample", "fresnel_dielectric", "dielectric_sample", "bsdf_eval", "bsdf_pdf", "bsdf_sample",
    "MaterialTable", "LAMBERT", "MIRROR", "DIELECTRIC", "EMISSIVE", "CONDUCTOR", "ROUGH_DIELECTRIC",
]

LAMBERT, MIRROR, DIELECTRIC, EMISSIVE = 0, 1, 2, 3
#: GGX microfacet kinds (render.scene's rough materials, BSDFs in render.microfacet); only the numpy integrators (render.integrators.volpath) shade them
CONDUCTOR, ROUGH_DIELECTRIC = 4, 5


@dataclass
class BSDFSample:
    """N sampled directions. wi: (N, 3) local. weight: (N, 3) f |cos| / pdf. pdf: (N,) solid-angle
    density (discrete lobe probability when delta). delta: (N,) bool. valid: (N,) bool (False:
    the path ends; weight is 0 there)."""

    wi: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray
    delta: np.ndarray
    valid: np.ndarray


# ---------------------------------------------------------------- Lambertian
def lambert_eval(albedo: np.ndarray, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """f = albedo / pi when wo and wi lie above the surface, else 0. (N, 3) float64."""
    same = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    return albedo * (INV_PI * same)[:, None]


def lambert_pdf(wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """Cosine-sampling density of wi: cos / pi above the surface (wo above too), else 0. (N,)."""
    return np.where(wo[:, 2] > 0, cosine_hemisphere_pdf(wi[:, 2]), 0.0)


def lambert_sample(albedo: np.ndarray, wo: np.ndarray, u: np.ndarray) -> BSDFSample:
    """Cosine-weighted sampling; weight = albedo. albedo (N, 3), wo (N, 3), u (N, 2)."""
    wi = cosine_hemisphere(u)
    pdf = cosine_hemisphere_pdf(wi[:, 2])
    valid = (wo[:, 2] > 0) & (pdf > 0)
    weight = albedo * valid[:, None]
    return BSDFSample(wi, weight, pdf, np.zeros(len(wo), bool), valid)


# ---------------------------------------------------------------- mirror
def mirror_sample(reflectance: np.ndarray, wo: np.ndarray) -> BSDFSample:
    """Perfect specular reflection wi = (-wo.x, -wo.y, wo.z); weight = reflectance."""
    wi = wo * np.array([-1.0, -1.0, 1.0])
    valid = wo[:, 2] != 0
    return BSDFSample(wi, reflectance * valid[:, None], np.ones(len(wo)), np.ones(len(wo), bool), valid)


# ---------------------------------------------------------------- dielectric
def fresnel_dielectric(cos_i: np.ndarray, eta: np.ndarray | float) -> np.ndarray:
    """Unpolarized Fresnel reflectance of a smooth dielectric interface (pbrt-v4's FrDielectric).

    cos_i: (N,) cosine of the incident direction with the outward normal (negative: arriving
    from inside). eta: relative IOR inside / outside. Returns (N,) in [0, 1]; 1 under total
    internal reflection.
    """
    cos_i = np.clip(np.asarray(cos_i, dtype=np.float64), -1.0, 1.0)
    eta = np.broadcast_to(np.asarray(eta, dtype=np.float64), cos_i.shape)
    inside = cos_i < 0
    eta = np.where(inside, 1.0 / eta, eta)
    ci = np.abs(cos_i)
    sin2_t = (1.0 - ci * ci) / (eta * eta)
    tir = sin2_t >= 1.0
    ct = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    r_par = (eta * ci - ct) / (eta * ci + ct)
    r_perp = (ci - eta * ct) / (ci + eta * ct)
    return np.where(tir, 1.0, 0.5 * (r_par * r_par + r_perp * r_perp))


def dielectric_sample(ior: np.ndarray, wo: np.ndarray, u: np.ndarray) -> BSDFSample:
    """Sample reflection (probability F) or refraction (1 - F) at a smooth dielectric.

    ior: (N,) IOR inside / outside. wo: (N, 3) local to the *outward* normal (wo.z < 0: the
    ray arrived from inside). u: (N,) uniform. Total internal reflection gives F = 1.
    Reflection weight is 1; refraction weight (eta_i / eta_t)^2 (radiance transport).
    """
    cos_o = wo[:, 2]
    F = fresnel_dielectric(cos_o, ior)
    reflect = u < F
    # relative eta for the side wo is on: eta_t / eta_i
    eta = np.where(cos_o >= 0, ior, 1.0 / ior)
    c = np.abs(cos_o)
    sin2_t = (1.0 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    # refraction about the normal on wo's side, n_s = sign(cos_o) z
    sgn = np.where(cos_o >= 0, 1.0, -1.0)
    wt = np.empty_like(wo)
    wt[:, 0] = -wo[:, 0] / eta
    wt[:, 1] = -wo[:, 1] / eta
    wt[:, 2] = -sgn * cos_t
    wr = wo * np.array([-1.0, -1.0, 1.0])
    wi = np.where(reflect[:, None], wr, wt)
    pdf = np.where(reflect, F, 1.0 - F)
    scale = np.where(reflect, 1.0, 1.0 / (eta * eta))
    valid = (cos_o != 0) & (pdf > 0)
    weight = np.repeat((scale * valid)[:, None], 3, axis=1)
    return BSDFSample(wi, weight, pdf, np.ones(len(wo), bool), valid)


# ---------------------------------------------------------------- dispatch over mixed materials
def bsdf_eval(kind: np.ndarray, albedo: np.ndarray, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """f(wo, wi) (N, 3) for per-ray material kinds (N,); zero for delta BSDFs and emitters.

    albedo: (N, 3) diffuse albedo. wo, wi: (N, 3) local directions.
    """
    return np.where((kind == LAMBERT)[:, None], lambert_eval(albedo, wo, wi), 0.0)


def bsdf_pdf(kind: np.ndarray, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """Solid-angle density (N,) with which :func:`bsdf_sample` picks wi; 0 for delta BSDFs."""
    return np.where(kind == LAMBERT, lambert_pdf(wo, wi), 0.0)


def bsdf_sample(kind: np.ndarray, albedo: np.ndarray, ior: np.ndarray, wo: np.ndarray,
                u1: np.ndarray, u2: np.ndarray) -> BSDFSample:
    """Sample every ray's own BSDF. kind (N,); albedo (N, 3) (Lambertian albedo or mirror
    reflectance); ior (N,); wo (N, 3) local (Lambertian/mirror frames facing wo, dielectric frames
    outward); u1 (N,) lobe choice; u2 (N, 2) direction. Emitters return invalid samples."""
    n = len(kind)
    out = BSDFSample(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, bool), np.zeros(n, bool))
    for k, fn in ((LAMBERT, lambda s: lambert_sample(albedo[s], wo[s], u2[s])),
                  (MIRROR, lambda s: mirror_sample(albedo[s], wo[s])),
                  (DIELECTRIC, lambda s: dielectric_sample(ior[s], wo[s], u1[s]))):
        s = np.nonzero(kind == k)[0]
        if len(s):
            bs = fn(s)
            out.wi[s], out.weight[s], out.pdf[s], out.delta[s], out.valid[s] = bs.wi, bs.weight, bs.pdf, bs.delta, bs.valid
    return out


# ---------------------------------------------------------------- material table
@dataclass
class MaterialTable:
    """Scene materials as arrays, one entry per object (M = number of objects).

    kind: (M,) int (LAMBERT, MIRROR, DIELECTRIC, EMISSIVE, CONDUCTOR, ROUGH_DIELECTRIC). albedo:
    (M, 3) Lambertian albedo (texture tint), or mirror reflectance. ior: (M,). Le: (M, 3) emitted
    radiance. emits: (M,) bool. two_sided: (M,) bool (emission). textures: {object index:
    (H, W, 3) float32 linear}. alpha: (M,) GGX roughness; eta, k: (M, 3) conductor complex IOR.
    """

    kind: np.ndarray
    albedo: np.ndarray
    ior: np.ndarray
    Le: np.ndarray
    emits: np.ndarray
    two_sided: np.ndarray
    textures: dict
    alpha: np.ndarray | None = None
    eta: np.ndarray | None = None
    k: np.ndarray | None = None

    @property
    def has_glossy(self) -> bool:
        """Whether any object is a GGX microfacet material (the compiled kernels lack them)."""
        return bool(np.any((self.kind == CONDUCTOR) | (self.kind == ROUGH_DIELECTRIC)))

    @classmethod
    def from_scene(cls, scene: Scene) -> "MaterialTable":
        m = len(scene.objects)
        kind = np.zeros(m, np.int64)
        albedo = np.zeros((m, 3))
        ior = np.ones(m)
        Le = np.zeros((m, 3))
        two = np.zeros(m, bool)
        tex = {}
        alpha, eta, kk = np.zeros(m), np.ones((m, 3)), np.zeros((m, 3))
        for i, o in enumerate(scene.objects):
            mat = o.material
            if isinstance(mat, RoughConductor):
                kind[i], alpha[i], eta[i], kk[i] = CONDUCTOR, mat.alpha, mat.eta, mat.k
            elif isinstance(mat, RoughDielectric):
                kind[i], alpha[i], ior[i] = ROUGH_DIELECTRIC, mat.alpha, mat.ior
            elif isinstance(mat, Lambertian):
                kind[i] = LAMBERT
                albedo[i] = mat.albedo
                if mat.texture is not None:
                    if o.uv is None:
                        raise ValueError(f"object '{o.name}': textured material but the mesh has no UVs")
                    tex[i] = decode_texture(mat.texture)
                if isinstance(mat, DiffuseEmitter):
                    Le[i] = mat.radiance
                    two[i] = mat.two_sided
            elif isinstance(mat, Mirror):
                kind[i] = MIRROR
                albedo[i] = mat.reflectance
            elif isinstance(mat, Dielectric):
                kind[i] = DIELECTRIC
                ior[i] = mat.ior
            elif isinstance(mat, Emissive):
                kind[i] = EMISSIVE
                Le[i] = mat.radiance
                two[i] = mat.two_sided
            else:
                raise ValueError(f"object '{o.name}': unsupported material {type(mat).__name__}")
        emits = Le.max(axis=1) > 0
        return cls(kind, albedo, ior, Le, emits, two, tex, alpha, eta, kk)

    def diffuse_albedo(self, obj: np.ndarray, texcoords) -> np.ndarray:
        """(N, 3) linear albedo at hits on objects ``obj`` (N,); texcoords(mask) -> (K, 2) uv.

        Textured objects: bilinear texture lookup (render.texture) times the albedo tint.
        """
        a = self.albedo[obj]
        for i, t in self.textures.items():
            m = obj == i
            if np.any(m):
                a[m] = sample_bilinear(t, texcoords(m)) * self.albedo[i]
        return a
