"""Light sampling for next-event estimation: area sources, point, spot and directional lights.

One discrete distribution covers every light: each emissive triangle is an entry (so picking
"a light" and "a triangle on it" is one choice), and each point/spot/directional light is one.
Entries are chosen in proportion to emitted power (mean of RGB):

* emissive triangle: pi * Le * area (times 2 if two-sided);
* point light: 4 pi I; spot light: 2 pi I (1 - (cos_inner + cos_outer) / 2) (approximate cone);
* directional light: E * pi * (extent / 2)^2 (the power crossing the scene's bounding disk).

Area sources are sampled uniformly by area on the chosen triangle and the density is converted
to solid angle at the shading point: p_omega = p_area * r^2 / |cos theta_light| (the cos/r^2
of the radiosity form factor). Emission is one-sided (towards the triangle's normal) unless
the material is two-sided. Units follow :mod:`render.scene`: a point light gives irradiance
I cos / r^2, a directional light E cos.

:func:`sample_emission` samples rays *leaving* the lights (photons of render.integrators.sppm, the first
vertex and direction of render.integrators.bdpt's light subpaths), with the densities bidirectional
methods weigh them by.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .accel import Geometry
from .accel import spawn_origin
from .bsdf import MaterialTable
from .sampling import cosine_hemisphere, dot3, orthonormal_frame, to_world, uniform_sphere, uniform_triangle
from .scene import DirectionalLight, PointLight, Scene, SpotLight, spot_falloff

__all__ = ["LightSample", "LightSet", "EmissionSample", "sample_emission", "scene_bounds",
           "POINT", "SPOT", "DIRECTIONAL", "AREA"]

POINT, SPOT, DIRECTIONAL = 0, 1, 2
#: EmissionSample.kind of an area source (delta lights use POINT, SPOT, DIRECTIONAL)
AREA = 3
_COS_FLOOR = 1e-12


@dataclass
class LightSample:
    """N light samples seen from shading points.

    wi: (N, 3) unit direction from the point towards the light. dist: (N,) distance to the
    sampled point (inf for directional lights). Li: (N, 3) incident radiance (area), or
    I falloff / r^2 (point, spot), or E (directional): the factor multiplying f |cos|.
    pdf: (N,) solid-angle density (area) or selection probability (delta lights).
    delta: (N,) bool. valid: (N,) bool (False: no light or zero emission; Li is 0 there).
    """

    wi: np.ndarray
    dist: np.ndarray
    Li: np.ndarray
    pdf: np.ndarray
    delta: np.ndarray
    valid: np.ndarray


class LightSet:
    """All lights of a scene as one power-proportional discrete distribution."""

    def __init__(self, scene: Scene, geom: Geometry, mats: MaterialTable):
        self.geom = geom
        tri_emit = mats.emits[geom.obj] & geom.valid if len(geom.obj) else np.zeros(0, bool)
        self.tri = np.nonzero(tri_emit)[0]
        obj = geom.obj[self.tri]
        self.Le = mats.Le[obj]
        self.two_sided = mats.two_sided[obj]
        p_area = np.pi * self.Le.mean(axis=1) * geom.area[self.tri] * np.where(self.two_sided, 2.0, 1.0)
        lights = [l for l in scene.lights if isinstance(l, (PointLight, SpotLight, DirectionalLight))]
        nd = len(lights)
        self.d_kind = np.zeros(nd, np.int64)
        self.d_pos = np.zeros((nd, 3))
        self.d_dir = np.zeros((nd, 3))
        self.d_I = np.zeros((nd, 3))
        self.d_cos = np.zeros((nd, 2))
        p_delta = np.zeros(nd)
        for k, l in enumerate(lights):
            if isinstance(l, PointLight):
                self.d_kind[k], self.d_pos[k], self.d_I[k] = POINT, l.position, l.intensity
                p_delta[k] = 4 * np.pi * l.intensity.mean()
            elif isinstance(l, SpotLight):
                ci, co = np.cos(l.inner_angle), np.cos(l.outer_angle)
                self.d_kind[k], self.d_pos[k], self.d_dir[k], self.d_I[k] = SPOT, l.position, l.direction, l.intensity
                self.d_cos[k] = ci, co
                p_delta[k] = 2 * np.pi * (1 - 0.5 * (ci + co)) * l.intensity.mean()
            else:
                self.d_kind[k], self.d_dir[k], self.d_I[k] = DIRECTIONAL, l.direction, l.irradiance
                p_delta[k] = np.pi * (0.5 * geom.extent) ** 2 * l.irradiance.mean()
        power = np.concatenate([p_area, p_delta])
        total = power.sum()
        self.n_area = len(self.tri)
        self.pmf = power / total if total > 0 else np.zeros_like(power)
        self.cdf = np.cumsum(self.pmf)
        #: (T,) selection probability / area of every scene triangle (0 if not emissive), for MIS
        self.tri_pdf_area = np.zeros(len(geom.obj))
        if self.n_area:
            self.tri_pdf_area[self.tri] = self.pmf[: self.n_area] / geom.area[self.tri]
        # per area-entry copies of the triangle data, gathered once per sample by entry index
        self.a_v0, self.a_e1, self.a_e2 = geom.v0[self.tri], geom.e1[self.tri], geom.e2[self.tri]
        self.a_normal = geom.normal[self.tri]
        self.a_pdf_area = self.pmf[: self.n_area] / np.maximum(geom.area[self.tri], 1e-300)
        # packed per-entry rows [v0, e1, e2, normal, pdf_area, Le, two_sided]: one gather per sample
        self._packed = np.concatenate([self.a_v0, self.a_e1, self.a_e2, self.a_normal, self.a_pdf_area[:, None],
                                       self.Le, self.two_sided[:, None].astype(np.float64)], axis=1)
        self.has_area = self.n_area > 0 and self.pmf[: self.n_area].sum() > 0
        self.has_delta = nd > 0 and p_delta.sum() > 0

    @property
    def empty(self) -> bool:
        return len(self.pmf) == 0 or self.cdf[-1] <= 0

    def pdf_hit(self, tri: np.ndarray, dist: np.ndarray, cos_light: np.ndarray) -> np.ndarray:
        """Solid-angle density with which NEE would have sampled a point a BSDF ray hit.

        tri: (N,) emissive triangles hit; dist: (N,) distances; cos_light: (N,) cosine between
        the ray and the light normal. Returns (N,) float64 (guarded at grazing angles).
        """
        return self.tri_pdf_area[tri] * dist * dist / np.maximum(np.abs(cos_light), _COS_FLOOR)

    def _sample_area(self, p: np.ndarray, u_sel: np.ndarray, u2: np.ndarray) -> LightSample:
        """:meth:`sample` when every light is an area source (no masks, no scatter)."""
        floor = (1e-9 * self.geom.extent) ** 2
        j = np.minimum(np.searchsorted(self.cdf, u_sel * self.cdf[-1], side="right"), len(self.pmf) - 1)
        q = self._packed[j]
        su = np.sqrt(u2[:, 0])
        b1 = (1.0 - su)[:, None]
        b2 = (u2[:, 1] * su)[:, None]
        d = q[:, 0:3] + b1 * q[:, 3:6] + b2 * q[:, 6:9] - p
        r2 = np.maximum(dot3(d, d), floor)
        r = np.sqrt(r2)
        w = d / r[:, None]
        cos_l = -dot3(w, q[:, 9:12])
        emits = (q[:, 16] > 0) | (cos_l > 0)
        pdf = q[:, 12] * r2 / np.maximum(np.abs(cos_l), _COS_FLOOR)
        Li = q[:, 13:16] * emits[:, None]
        return LightSample(w, r, Li, pdf, np.zeros(len(p), bool), emits & (cos_l != 0))

    def sample(self, p: np.ndarray, u_sel: np.ndarray, u2: np.ndarray) -> LightSample:
        """Sample one light per shading point. p (N, 3); u_sel (N,), u2 (N, 2) uniforms."""
        n = len(p)
        if n and not self.empty and len(self.d_kind) == 0:
            return self._sample_area(p, u_sel, u2)
        wi = np.zeros((n, 3))
        wi[:, 2] = 1.0
        dist = np.ones(n)
        Li = np.zeros((n, 3))
        pdf = np.ones(n)
        delta = np.zeros(n, bool)
        valid = np.zeros(n, bool)
        if n == 0 or self.empty:
            return LightSample(wi, dist, Li, pdf, delta, valid)
        floor = (1e-9 * self.geom.extent) ** 2
        k = np.minimum(np.searchsorted(self.cdf, u_sel * self.cdf[-1], side="right"), len(self.pmf) - 1)
        # area sources
        all_area = len(self.d_kind) == 0
        a = slice(None) if all_area else np.nonzero(k < self.n_area)[0]
        j = k if all_area else k[a]
        if len(j):
            su = np.sqrt(u2[a, 0])
            b1 = (1.0 - su)[:, None]
            b2 = (u2[a, 1] * su)[:, None]
            d = self.a_v0[j] + b1 * self.a_e1[j] + b2 * self.a_e2[j] - p[a]
            r2 = np.maximum(np.einsum("ij,ij->i", d, d), floor)
            r = np.sqrt(r2)
            w = d / r[:, None]
            cos_l = -np.einsum("ij,ij->i", w, self.a_normal[j])
            emits = self.two_sided[j] | (cos_l > 0)
            wi[a], dist[a] = w, r
            pdf[a] = self.a_pdf_area[j] * r2 / np.maximum(np.abs(cos_l), _COS_FLOOR)
            Li[a] = self.Le[j] * emits[:, None]
            valid[a] = emits & (np.abs(cos_l) > 0)
        # delta lights: loop over lights (few), vectorized over points
        for li in range(len(self.d_kind)):
            m = np.nonzero(k == self.n_area + li)[0]
            if len(m) == 0:
                continue
            kind = self.d_kind[li]
            delta[m] = True
            pdf[m] = self.pmf[self.n_area + li]
            if kind == DIRECTIONAL:
                wi[m] = -self.d_dir[li]
                dist[m] = np.inf
                Li[m] = self.d_I[li]
                valid[m] = True
                continue
            d = self.d_pos[li] - p[m]
            r2 = np.maximum(np.einsum("ij,ij->i", d, d), floor)
            r = np.sqrt(r2)
            w = d / r[:, None]
            fall = np.ones(len(m))
            if kind == SPOT:
                fall = spot_falloff(-(w @ self.d_dir[li]), self.d_cos[li, 0], self.d_cos[li, 1])
            wi[m], dist[m] = w, r
            Li[m] = self.d_I[li] * (fall / r2)[:, None]
            valid[m] = fall > 0
        return LightSample(wi, dist, Li, pdf, delta, valid)


# ---------------------------------------------------------------- emission (rays leaving the lights)
@dataclass
class EmissionSample:
    """n rays leaving the scene's lights (sppm's photons, bdpt's light subpaths).

    o: (n, 3) ray origins (area sources: offset off the triangle by render.accel.spawn_origin).
    p: (n, 3) the sampled point (area: on the triangle; point, spot: the light's position;
    directional: on a disk of the scene's bounding radius R, upstream of the scene).
    d: (n, 3) unit directions. normal: (n, 3) an area source's normal on the emitting side
    (zeros for the other lights). kind: (n,) int64 AREA, POINT, SPOT or DIRECTIONAL.
    entry: (n,) int64 LightSet entry (-1: no light). pmf: (n,) its selection probability.
    pdf_pos: (n,) density of p without the pmf: 1 / triangle area (area), 1 (point, spot: a delta
    position), 1 / (pi R^2) per unit area of the disk (directional).
    pdf_dir: (n,) solid-angle density of d: |cos| / pi (halved for two-sided sources, whose side
    is chosen with probability 1/2), 1 / (4 pi) (point), uniform in the outer cone (spot),
    1 (directional: a delta direction).
    flux: (n, 3) Le |cos| / (pmf pdf_pos pdf_dir) and the delta lights' equivalents (I falloff /
    (pmf pdf_dir), E / (pmf pdf_pos)): the throughput the ray carries; zero where nothing is
    emitted (e.g. a spot direction outside its falloff).
    """

    o: np.ndarray
    p: np.ndarray
    d: np.ndarray
    normal: np.ndarray
    kind: np.ndarray
    entry: np.ndarray
    pmf: np.ndarray
    pdf_pos: np.ndarray
    pdf_dir: np.ndarray
    flux: np.ndarray


def scene_bounds(geom: Geometry) -> tuple[np.ndarray, float]:
    """(centre (3,), bounding radius) of the valid triangles: the disk directional lights emit from."""
    v = geom.valid
    if not v.any():
        return np.zeros(3), 0.5 * geom.extent
    pts = np.concatenate([geom.v0[v], geom.v0[v] + geom.e1[v], geom.v0[v] + geom.e2[v]])
    lo, hi = pts.min(0), pts.max(0)
    return 0.5 * (lo + hi), 0.5 * geom.extent


def sample_emission(lights: LightSet, geom: Geometry, u_sel: np.ndarray, u_pos: np.ndarray, u_dir: np.ndarray,
                    u_side: np.ndarray) -> EmissionSample:
    """Sample n rays leaving the lights from uniforms u_sel (n,), u_pos (n, 2), u_dir (n, 2), u_side (n,).

    The light is chosen by the LightSet's power pmf (as :meth:`LightSet.sample`). Area sources: a
    uniform point on the chosen triangle, a cosine-weighted direction on the emitting side (a
    random side, u_side < 1/2 the back, if two-sided). Point: uniform sphere. Spot: uniform in
    the outer cone, flux scaled by the smoothstep falloff. Directional: a uniform point on a disk
    of the scene's bounding radius perpendicular to the light, 2 R upstream of the scene's centre.
    """
    n = len(u_sel)
    extent = geom.extent
    o, p, d, nrm, flux = (np.zeros((n, 3)) for _ in range(5))
    d[:, 2] = 1.0
    kind = np.full(n, AREA, np.int64)
    entry = np.full(n, -1, np.int64)
    pmf, pdf_pos, pdf_dir = np.zeros(n), np.ones(n), np.ones(n)
    if lights.empty or n == 0:
        return EmissionSample(o, p, d, nrm, kind, entry, pmf, pdf_pos, pdf_dir, flux)
    ent = np.minimum(np.searchsorted(lights.cdf, u_sel * lights.cdf[-1], side="right"), len(lights.pmf) - 1)
    entry[:] = ent
    pmf[:] = lights.pmf[ent]
    a = np.nonzero(ent < lights.n_area)[0]
    if len(a):
        j = ent[a]
        b = uniform_triangle(u_pos[a])
        pa = lights.a_v0[j] + b[:, 0:1] * lights.a_e1[j] + b[:, 1:2] * lights.a_e2[j]
        nl = lights.a_normal[j]
        two = lights.two_sided[j]
        flip = two & (u_side[a] < 0.5)
        nl = np.where(flip[:, None], -nl, nl)
        t1, t2 = orthonormal_frame(nl)
        loc = cosine_hemisphere(u_dir[a])
        w = to_world(loc, t1, t2, nl)
        area = geom.area[lights.tri[j]]
        # Le cos / (pmf / A  x  cos / pi  [x 1/2 side])
        scale = np.pi * area * np.where(two, 2.0, 1.0) / np.maximum(pmf[a], 1e-300)
        o[a] = spawn_origin(pa, nl, w, extent)
        p[a], d[a], nrm[a] = pa, w, nl
        flux[a] = lights.Le[j] * scale[:, None]
        pdf_pos[a] = 1.0 / np.maximum(area, 1e-300)
        pdf_dir[a] = loc[:, 2] / np.pi * np.where(two, 0.5, 1.0)
    if len(lights.d_kind):
        centre, radius = scene_bounds(geom)
        for li in range(len(lights.d_kind)):  # few lights; vectorized over rays
            m = np.nonzero(ent == lights.n_area + li)[0]
            if len(m) == 0:
                continue
            lk, I, pm = lights.d_kind[li], lights.d_I[li], max(lights.pmf[lights.n_area + li], 1e-300)
            kind[m] = lk
            if lk == POINT:
                o[m], d[m] = lights.d_pos[li], uniform_sphere(u_dir[m])
                p[m] = lights.d_pos[li]
                flux[m] = I * (4.0 * np.pi / pm)
                pdf_dir[m] = 0.25 / np.pi
            elif lk == SPOT:
                ci, co = lights.d_cos[li]
                cz = 1.0 - u_dir[m, 0] * (1.0 - co)  # uniform in the outer cone
                sz = np.sqrt(np.maximum(0.0, 1.0 - cz * cz))
                phi = 2.0 * np.pi * u_dir[m, 1]
                axis = np.broadcast_to(lights.d_dir[li], (len(m), 3))
                t1, t2 = orthonormal_frame(np.ascontiguousarray(axis))
                loc = np.stack([sz * np.cos(phi), sz * np.sin(phi), cz], axis=1)
                o[m], d[m] = lights.d_pos[li], to_world(loc, t1, t2, axis)
                p[m] = lights.d_pos[li]
                fall = spot_falloff(cz, ci, co)
                flux[m] = I[None] * (fall * 2.0 * np.pi * (1.0 - co) / pm)[:, None]
                pdf_dir[m] = 1.0 / (2.0 * np.pi * max(1.0 - co, 1e-300))
            else:  # directional: a disk of the scene's bounding radius, upstream of the scene
                axis = np.broadcast_to(lights.d_dir[li], (len(m), 3))
                t1, t2 = orthonormal_frame(np.ascontiguousarray(axis))
                r = radius * np.sqrt(u_pos[m, 0])
                phi = 2.0 * np.pi * u_pos[m, 1]
                o[m] = (centre - 2.0 * radius * lights.d_dir[li]) + (r * np.cos(phi))[:, None] * t1 \
                    + (r * np.sin(phi))[:, None] * t2
                p[m] = o[m]
                d[m] = axis
                flux[m] = I * (np.pi * radius * radius / pm)
                pdf_pos[m] = 1.0 / (np.pi * radius * radius)
    return EmissionSample(o, p, d, nrm, kind, entry, pmf, pdf_pos, pdf_dir, flux)
