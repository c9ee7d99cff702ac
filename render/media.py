"""Participating media: Henyey-Greenstein phase function, media bounded by meshes, free-flight
sampling by delta tracking and transmittance by ratio tracking.

The radiative transfer equation along a ray x(t) = o + t d inside a medium (the lecture's
absorption, emission and scattering along a ray):

    L(o, -d) = int_0^t_s T(t) [sigma_a(x) Le + sigma_s(x) int p(d, w') L(x, w') dw'] dt + T(t_s) L_s,
    T(t) = exp(-int_0^t sigma_t(x(s)) ds),  sigma_t = sigma_a + sigma_s.

Media (:class:`render.scene.Medium`) are bounded by closed meshes; their boundaries are
index-matched (they change the medium, never the direction). Media must not overlap or nest,
and the rays' medium is the one whose bounds contain the point (outside all: vacuum). A medium's
coefficients are constant, or scaled by a voxel grid ``density[ix, iy, iz]`` (X, Y, Z) spanning
the bounds' axis-aligned box (cell (i, j, k) covers lo + (i, j, k) (hi - lo) / (X, Y, Z) to the
next corner; nearest lookup, as :class:`recon.nerf.volume.VoxelField`); emission radiance Le is
constant (the source term is sigma_a(x) Le).

Delta tracking (Woodcock; pbrt-v4's SampleT_maj): tentative collisions at rate mu (the
majorant, a scalar per medium >= max over channels and voxels of sigma_t); at each, emission
beta sigma_a Le / mu is collected, then absorption, real scattering or a null collision is
chosen with probabilities mean(sigma_a) / mu, mean(sigma_s) / mu, mean(mu - sigma_t) / mu, and
beta is multiplied by sigma_x / (mu P_x) per channel (weighted tracking: unbiased for coloured
coefficients). Ratio tracking multiplies transmittance by (1 - sigma_t / mu) at each tentative
collision, with Russian roulette once it falls below 0.1; homogeneous media use exp(-sigma_t d)
exactly. A majorant below the true density would make null-collision weights negative: it is
rejected at construction and checked at every collision (:class:`MajorantError`), never a
silently biased image.

Phase function convention: ``d`` is the direction the light travels (the ray direction) and
``cos = d . wi`` for the scattered direction wi; g > 0 scatters forwards.
"""
from __future__ import annotations

import numpy as np

from .accel import Accel, Geometry, spawn_origin
from .sampling import orthonormal_frame
from .scene import Lambertian, Medium, Scene, SceneObject

__all__ = ["hg_pdf", "hg_sample", "MajorantError", "MediumSet", "EV_PASS", "EV_SCATTER", "EV_ABSORB"]

EV_PASS, EV_SCATTER, EV_ABSORB = 0, 1, 2
_RR_T = 0.1


class MajorantError(ValueError):
    """A medium's majorant is below its true extinction: delta / ratio tracking would be biased."""


def hg_pdf(g: np.ndarray | float, d: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """Henyey-Greenstein phase function (= its sampling density) (N,) per steradian.

    p = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^1.5), cos = d . wi; d: (N, 3) travel directions.
    """
    g = np.asarray(g, dtype=np.float64)
    c = np.clip(np.einsum("ij,ij->i", d, wi), -1.0, 1.0)
    den = np.maximum(1.0 + g * g - 2.0 * g * c, 1e-12)
    return (1.0 - g * g) / (4.0 * np.pi * den * np.sqrt(den))


def hg_sample(g: np.ndarray | float, d: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Directions (N, 3) with density :func:`hg_pdf` about travel directions d (N, 3); u (N, 2).

    Inverse CDF: cos = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g u))^2) / (2 g); uniform for |g| < 1e-3.
    """
    n = len(d)
    g = np.broadcast_to(np.asarray(g, dtype=np.float64), (n,))
    small = np.abs(g) < 1e-3
    gs = np.where(small, 1.0, g)
    sq = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u[:, 0])
    c = np.where(small, 1.0 - 2.0 * u[:, 0], (1.0 + gs * gs - sq * sq) / (2.0 * gs))
    c = np.clip(c, -1.0, 1.0)
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    phi = 2.0 * np.pi * u[:, 1]
    t1, t2 = orthonormal_frame(d)
    return (s * np.cos(phi))[:, None] * t1 + (s * np.sin(phi))[:, None] * t2 + c[:, None] * d


class MediumSet:
    """A scene's media as arrays, their boundary BVH, and the tracking estimators.

    majorants: optional {medium index: mu} overriding the computed majorant
    max(sigma_t) * max(density); a value below the true maximum raises :class:`MajorantError`.
    Arrays (K media): sigma_a, sigma_s, Le (K, 3); g (K,); mu (K,) scalar majorants; grids:
    {k: (X, Y, Z) float64 density}; lo, hi (K, 3) bounds' boxes.
    """

    def __init__(self, media: list[Medium], majorants: dict | None = None, threads: int = 1):
        k = len(media)
        self.media = list(media)
        self.sigma_a = np.array([m.sigma_a for m in media]).reshape(k, 3)
        self.sigma_s = np.array([m.sigma_s for m in media]).reshape(k, 3)
        self.Le = np.array([m.emission for m in media]).reshape(k, 3)
        self.g = np.array([m.g for m in media], dtype=np.float64)
        self.lo = np.array([m.bounds.bounds[0] for m in media]).reshape(k, 3)
        self.hi = np.array([m.bounds.bounds[1] for m in media]).reshape(k, 3)
        self.grids: dict[int, np.ndarray] = {}
        self.mu = np.zeros(k)
        for i, m in enumerate(media):
            st = (self.sigma_a[i] + self.sigma_s[i]).max()
            dmax = 1.0
            if m.density is not None:
                grid = np.asarray(m.density, dtype=np.float64)
                if grid.ndim != 3 or not np.all(np.isfinite(grid)) or np.any(grid < 0):
                    raise ValueError(f"medium {i}: density must be a finite non-negative (X, Y, Z) grid")
                self.grids[i] = grid
                dmax = float(grid.max()) if grid.size else 0.0
            self.mu[i] = st * dmax
            if majorants and i in majorants:
                mu = float(majorants[i])
                if not mu >= self.mu[i] * (1 - 1e-12):
                    raise MajorantError(f"medium {i}: majorant {mu:g} is below the maximum extinction "
                                        f"{self.mu[i]:g} (max sigma_t x max density)")
                self.mu[i] = mu
        self.homogeneous = np.array([i not in self.grids for i in range(k)], bool)
        objs = [SceneObject(f"medium{i}", m.bounds, Lambertian()) for i, m in enumerate(media)]
        self.geom = Geometry.from_scene(Scene("media", objs))
        self.accel = Accel(Scene("media", objs), threads=threads, geometry=self.geom) if k else None

    def __len__(self) -> int:
        return len(self.media)

    # ------------------------------------------------------------ coefficients
    def density(self, mid: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(N,) density scale at points p (N, 3) of media mid (N,) (1 for homogeneous media)."""
        out = np.ones(len(mid))
        for i, grid in self.grids.items():
            s = np.nonzero(mid == i)[0]
            if len(s) == 0:
                continue
            res = np.array(grid.shape)
            u = (p[s] - self.lo[i]) / (self.hi[i] - self.lo[i]) * res
            inside = np.all((u >= 0) & (u < res), axis=1)
            idx = np.clip(np.floor(u).astype(np.int64), 0, res - 1)
            out[s] = grid[idx[:, 0], idx[:, 1], idx[:, 2]] * inside
        return out

    def coefficients(self, mid: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sigma_a (N, 3), sigma_s (N, 3)) at points p (N, 3) inside media mid (N,)."""
        dens = self.density(mid, p)[:, None]
        return self.sigma_a[mid] * dens, self.sigma_s[mid] * dens

    def _check(self, mid, st, mu):
        bad = st.max(axis=1) > mu * (1 + 1e-9) + 1e-300
        if np.any(bad):
            i = int(mid[np.argmax(bad)])
            raise MajorantError(f"medium {i}: extinction {st[bad].max():g} above the majorant {self.mu[i]:g} "
                                "during tracking (the estimate would be biased)")

    # ------------------------------------------------------------ which medium contains a point
    def medium_at(self, p: np.ndarray, max_crossings: int = 64) -> np.ndarray:
        """(N,) int64 medium containing each point p (N, 3), -1 for vacuum (crossing parity of
        a ray along a fixed oblique direction against each medium's closed bounds)."""
        n = len(p)
        out = np.full(n, -1, np.int64)
        if not len(self) or n == 0:
            return out
        d = np.tile(np.array([0.5773, 0.5774, 0.5775]) / np.linalg.norm([0.5773, 0.5774, 0.5775]), (n, 1))
        parity = np.zeros((n, len(self)), bool)
        o = p.copy()
        live = np.arange(n)
        for _ in range(max_crossings):
            h = self.accel.intersect(o[live], d[live])
            hit = h.tri >= 0
            live, tri, t = live[hit], h.tri[hit], h.t[hit]
            if len(live) == 0:
                break
            m = self.geom.obj[tri]
            parity[live, m] ^= True
            x = o[live] + t[:, None] * d[live]
            o[live] = spawn_origin(x, self.geom.normal[tri], d[live], self.geom.extent)
        anyin = parity.any(axis=1)
        out[anyin] = np.argmax(parity[anyin], axis=1)
        return out

    def boundary(self, o: np.ndarray, d: np.ndarray):
        """Next boundary crossing of rays (N, 3): (t (N,) inf if none, medium (N,) int64 whose
        boundary is crossed, entering (N,) bool, triangle (N,))."""
        h = self.accel.intersect(o, d)
        tri = np.maximum(h.tri, 0)
        m = np.where(h.tri >= 0, self.geom.obj[tri], -1)
        entering = np.einsum("ij,ij->i", d, self.geom.normal[tri]) < 0
        return h.t, m, entering, h.tri

    # ------------------------------------------------------------ estimators
    def delta_track(self, mid: np.ndarray, o: np.ndarray, d: np.ndarray, tmax: np.ndarray,
                    rng: np.random.Generator):
        """Sample the first real collision along rays inside media mid (N,) before tmax (N,).

        Returns (event (N,) EV_PASS / EV_SCATTER / EV_ABSORB, t (N,) collision distance (tmax
        when passing), weight (N, 3) throughput factor to apply, emitted (N, 3) radiance collected
        (already weighted by the tracking weights, to be multiplied by the path throughput)).
        """
        n = len(mid)
        event = np.zeros(n, np.int64)
        t = np.zeros(n)
        w = np.ones((n, 3))
        em = np.zeros((n, 3))
        mu_all = self.mu[mid]
        live = np.nonzero(mu_all > 0)[0]
        t[mu_all <= 0] = tmax[mu_all <= 0]
        while len(live):
            mu = mu_all[live]
            t[live] -= np.log1p(-rng.random(len(live))) / mu
            out = t[live] >= tmax[live]
            t[live[out]] = tmax[live[out]]
            live = live[~out]
            if len(live) == 0:
                break
            mu = mu_all[live]
            m = mid[live]
            x = o[live] + t[live, None] * d[live]
            sa, ss = self.coefficients(m, x)
            st = sa + ss
            self._check(m, st, mu)
            em[live] += w[live] * sa * self.Le[m] / mu[:, None]
            sn = np.maximum(mu[:, None] - st, 0.0)
            pa, ps, pn = sa.mean(1) / mu, ss.mean(1) / mu, sn.mean(1) / mu
            tot = pa + ps + pn
            u = rng.random(len(live)) * tot
            absorb = u < pa
            scat = ~absorb & (u < pa + ps)
            null = ~absorb & ~scat
            event[live[absorb]] = EV_ABSORB
            w[live[absorb]] = 0.0
            event[live[scat]] = EV_SCATTER
            w[live[scat]] *= ss[scat] / (mu[scat, None] * (ps[scat] / tot[scat])[:, None])
            w[live[null]] *= sn[null] / (mu[null, None] * (pn[null] / tot[null])[:, None])
            live = live[null]
        return event, t, w, em

    def transmittance(self, mid: np.ndarray, o: np.ndarray, d: np.ndarray, tmax: np.ndarray,
                      rng: np.random.Generator) -> np.ndarray:
        """Unbiased transmittance (N, 3) along rays inside media mid (N,) over [0, tmax] (N,):
        exp(-sigma_t tmax) for homogeneous media, ratio tracking with roulette for grids."""
        n = len(mid)
        T = np.ones((n, 3))
        hom = self.homogeneous[mid]
        if np.any(hom):
            h = np.nonzero(hom)[0]
            T[h] = np.exp(-(self.sigma_a[mid[h]] + self.sigma_s[mid[h]]) * tmax[h, None])
        mu_all = self.mu[mid]
        live = np.nonzero(~hom & (mu_all > 0))[0]
        t = np.zeros(n)
        while len(live):
            mu = mu_all[live]
            t[live] -= np.log1p(-rng.random(len(live))) / mu
            live = live[t[live] < tmax[live]]
            if len(live) == 0:
                break
            mu = mu_all[live]
            m = mid[live]
            x = o[live] + t[live, None] * d[live]
            sa, ss = self.coefficients(m, x)
            st = sa + ss
            self._check(m, st, mu)
            T[live] *= np.maximum(1.0 - st / mu[:, None], 0.0)
            low = T[live].max(axis=1) < _RR_T
            if np.any(low):
                lv = live[low]
                die = rng.random(len(lv)) < 0.5
                T[lv[die]] = 0.0
                T[lv[~die]] *= 2.0
            live = live[T[live].max(axis=1) > 0]
        return T
