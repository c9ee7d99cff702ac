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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .accel import Geometry
from .bsdf import MaterialTable
from .sampling import dot3
from .scene import DirectionalLight, PointLight, Scene, SpotLight, spot_falloff

__all__ = ["LightSample", "LightSet", "POINT", "SPOT", "DIRECTIONAL"]

POINT, SPOT, DIRECTIONAL = 0, 1, 2
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
