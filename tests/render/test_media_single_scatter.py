"""Single scattering from a finite light against closed forms (issue 14, item 6).

The furnace and slab tests of test_media.py never light a scattering medium from a finite
source. Here ``volpath`` is restricted to single scattering (``max_depth=1``: one medium vertex
with next-event estimation and a phase sample that may hit the light, MIS-weighted; nothing
after it) and compared with the single-scattered radiance along one camera ray x(t) = o + t d
through a homogeneous box medium whose index-matched boundary separates it from the light:

    point light (intensity I at q):
        L = int_{t_in}^{t_out} sigma_s p(d . w(t)) I / r(t)^2 T_cam(t) T_box(x(t), q) dt
    one-sided area light (radiance Le, normal n, facing the medium):
        L = int_{t_in}^{t_out} sigma_s T_cam(t) int_A p(d . w) Le (-n . w) / r^2 T_box(x(t), y) dA(y) dt

with w the unit direction from x(t) to the light point, r the distance, p the
Henyey-Greenstein phase function of cos = d . w (render.media's convention: d is the ray's
travel direction; light arriving along -w and leaving towards the camera along -d has
scattering cosine (-w) . (-d), so g > 0 favours vertices lit from ahead of the ray),
T_cam(t) = exp(-sigma_t (t - t_in)) and T_box(x, y) = exp(-sigma_t l) with l the exact length
of the segment x -> y inside the box (the light is outside: the segment crosses the boundary
once, and only the medium part attenuates). scipy's adaptive quadrature in t (relative 1e-10)
and a composite Gauss-Legendre rule over the light (converged to 1e-9 relative, checked below)
evaluate them.

The geometry is the issue's fog Cornell box (millimetres, coefficients per mm): the light
0.1 mm below a (black) ceiling, the fog box's top 4.3 mm below the light, the camera ray 14.4 mm
under the box top, where the shadow rays leave the medium at grazing angles just under the
light. There Mitsuba 3.9.1's volpath loses most of the in-scattered light (its shadow ray, offset
off the null boundary along the normal, overshoots the distance left and hits the emitter
itself); ours must not.

Statistics: fixed seeds; |render - closed form| < Z standard errors of the render's own
variance image (two-sided z-test, Z = 4: alpha = 6.3e-5 per channel).
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import integrate

from render.camera import Camera, Intrinsics
from render.integrators import RenderSettings
from render.poses import look_at
from render.scene import Emissive, Lambertian, Medium, PointLight, Scene, SceneObject
from render.integrators.volpath import render_volpath

Z = 4.0

# the fog box of scenes/cornell_fog.yaml (mm)
BOX_LO = np.array([8.0, 4.4, 4.6])
BOX_HI = np.array([548.0, 544.4, 554.6])
SIGMA_S, SIGMA_A = 0.0015, 0.0002
# the Cornell light: x in [213, 343], z in [227, 332] at y = 548.7, emitting downwards
LIGHT_X, LIGHT_Z, LIGHT_Y = (213.0, 343.0), (227.0, 332.0), 548.7
LIGHT_LE = np.array([17.0, 12.0, 4.0])
# a camera ray 14.4 mm below the box top, across the box under the light (off its centre line)
RAY_O = np.array([600.0, 530.0, 250.0])
RAY_D = np.array([-1.0, 0.0, 0.0])


def _box_mesh(lo, hi) -> trimesh.Trimesh:
    b = trimesh.creation.box(np.subtract(hi, lo))
    b.apply_translation((np.asarray(lo) + np.asarray(hi)) / 2)
    return b


def hg(g: float, cos: np.ndarray) -> np.ndarray:
    """Henyey-Greenstein phase function per steradian (cos between d and w)."""
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos) ** 1.5)


def length_in_box(p: np.ndarray, q: np.ndarray, lo=BOX_LO, hi=BOX_HI) -> np.ndarray:
    """(N,) length of the segments p -> q ((N, 3) each) inside the axis-aligned box [lo, hi]."""
    v = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - p) / v, (hi - p) / v
    # a zero component: inside the slab for all t (nan from 0/0 never occurs: p is not on a face)
    t_near = np.where(v == 0, -np.inf, np.minimum(t0, t1)).max(axis=1)
    t_far = np.where(v == 0, np.inf, np.maximum(t0, t1)).min(axis=1)
    return np.maximum(np.minimum(t_far, 1.0) - np.maximum(t_near, 0.0), 0.0) * np.linalg.norm(v, axis=1)


def ray_in_box(o, d, lo=BOX_LO, hi=BOX_HI) -> tuple[float, float]:
    with np.errstate(divide="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    return float(np.max(np.minimum(t0, t1))), float(np.min(np.maximum(t0, t1)))


def _gauss_square(n: int, panels: int):
    """Composite Gauss-Legendre nodes and weights on [0, 1]: panels x n points."""
    x, w = np.polynomial.legendre.leggauss(n)
    edges = np.linspace(0.0, 1.0, panels + 1)
    nodes = np.concatenate([(a + b) / 2 + (b - a) / 2 * x for a, b in zip(edges[:-1], edges[1:])])
    weights = np.concatenate([(b - a) / 2 * w for a, b in zip(edges[:-1], edges[1:])])
    return nodes, weights


def single_scatter_area(g: float, o=RAY_O, d=RAY_D, n: int = 12, panels: int = 4) -> float:
    """Closed-form single scattering (per unit Le) along o + t d from the Cornell light."""
    sigma_t = SIGMA_S + SIGMA_A
    u, wu = _gauss_square(n, panels)
    xs = LIGHT_X[0] + u * (LIGHT_X[1] - LIGHT_X[0])
    zs = LIGHT_Z[0] + u * (LIGHT_Z[1] - LIGHT_Z[0])
    X, Zl = np.meshgrid(xs, zs, indexing="ij")
    Y = np.stack([X.ravel(), np.full(X.size, LIGHT_Y), Zl.ravel()], axis=1)
    dA = np.outer(wu, wu).ravel() * (LIGHT_X[1] - LIGHT_X[0]) * (LIGHT_Z[1] - LIGHT_Z[0])
    t_in, t_out = ray_in_box(o, d)

    def integrand(t):
        x = o + t * d
        v = Y - x
        r = np.linalg.norm(v, axis=1)
        w = v / r[:, None]
        cos_light = w[:, 1]  # the light's normal is -y: -n . w = w_y
        T = np.exp(-sigma_t * length_in_box(np.broadcast_to(x, Y.shape), Y))
        inner = np.sum(dA * hg(g, w @ d) * cos_light / r ** 2 * T)
        return SIGMA_S * np.exp(-sigma_t * (t - t_in)) * inner

    return integrate.quad(integrand, t_in, t_out, epsabs=0.0, epsrel=1e-10, limit=400)[0]


def single_scatter_point(g: float, q: np.ndarray, o=RAY_O, d=RAY_D) -> float:
    """Closed-form single scattering (per unit intensity) along o + t d from a point light at q."""
    sigma_t = SIGMA_S + SIGMA_A
    t_in, t_out = ray_in_box(o, d)

    def integrand(t):
        x = o + t * d
        v = q - x
        r = np.linalg.norm(v)
        T = np.exp(-sigma_t * length_in_box(x[None], q[None])[0])
        return SIGMA_S * hg(g, v @ d / r) / r ** 2 * np.exp(-sigma_t * (t - t_in)) * T

    return integrate.quad(integrand, t_in, t_out, epsabs=0.0, epsrel=1e-10, limit=400)[0]


def _scene(g: float, light) -> Scene:
    """The fog box, a black ceiling 0.1 mm above the light (it would catch shadow rays that
    overshoot the light), and the light: an area quad or a point light."""
    ceiling = SceneObject("ceiling", _box_mesh([0, 548.8, 0], [556, 560, 560]), Lambertian(0.0))
    objs, lights = [ceiling], []
    if isinstance(light, str):
        v = np.array([[LIGHT_X[0], LIGHT_Y, LIGHT_Z[0]], [LIGHT_X[1], LIGHT_Y, LIGHT_Z[0]],
                      [LIGHT_X[1], LIGHT_Y, LIGHT_Z[1]], [LIGHT_X[0], LIGHT_Y, LIGHT_Z[1]]])
        quad = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)  # normal -y: emits downwards
        assert quad.face_normals[0][1] < -0.99
        objs.append(SceneObject("light", quad, Emissive(LIGHT_LE)))
    else:
        lights.append(PointLight(light, LIGHT_LE))
    fog = Medium(_box_mesh(BOX_LO, BOX_HI), sigma_a=SIGMA_A, sigma_s=SIGMA_S, g=g)
    return Scene("single_scatter", objs, lights=lights, media=[fog])


def _render_ray(scene: Scene, spp: int, seed: int, strategy: str = "mis"):
    """Mean (3,) and standard error (3,) of a 2 x 2 camera of 0.001 degrees along RAY_O, RAY_D
    (the closed form varies by < 1e-7 relative across it), single scattering only."""
    cam = Camera(Intrinsics.from_fov(2, 2, 0.001), look_at(RAY_O, RAY_O + RAY_D, np.array([0, 1.0, 0])), "ray")
    r = render_volpath(scene, cam, RenderSettings(integrator="volpath", spp=spp, max_depth=1, roulette=False,
                                                   seed=seed, strategy=strategy))
    mean = r.mean.reshape(-1, 3).astype(np.float64).mean(0)
    se = np.sqrt(r.variance.reshape(-1, 3).astype(np.float64).sum(0)) / 4
    return mean, se


def test_closed_form_quadrature_converged():
    """The area integral's light quadrature is converged (so the render is judged against the
    integral, not against quadrature error), and flipping g changes it (the test has power)."""
    a = single_scatter_area(0.5)
    b = single_scatter_area(0.5, n=16, panels=6)
    assert abs(a - b) < 1e-9 * abs(b), (a, b)
    assert abs(single_scatter_area(-0.5) - a) > 0.05 * a


@pytest.mark.parametrize("strategy", ["mis", "light", "bsdf"])
def test_single_scatter_area_light_cornell_geometry(strategy):
    """The Cornell light over its fog box, g = 0.5: MIS (NEE + phase sampling), NEE alone and
    phase sampling alone (its rays cross the boundary and must find the light unattenuated
    outside the box)."""
    expected = single_scatter_area(0.5) * LIGHT_LE
    mean, se = _render_ray(_scene(0.5, "area"), spp=60_000, seed=31, strategy=strategy)
    print(f"render / closed form {mean / expected}, z {(mean - expected) / se}")
    assert np.all(np.abs(mean - expected) < Z * se), (mean, expected, se, (mean - expected) / se)


def test_single_scatter_point_light_through_boundary():
    """An isotropic point light 3 mm above the fog box's top, off the ray's vertical plane,
    g = 0.5: the 1-D integral."""
    q = np.array([250.0, 547.4, 300.0])
    expected = single_scatter_point(0.5, q) * LIGHT_LE
    mean, se = _render_ray(_scene(0.5, q), spp=60_000, seed=32)
    print(f"render / closed form {mean / expected}, z {(mean - expected) / se}")
    assert np.all(np.abs(mean - expected) < Z * se), (mean, expected, se, (mean - expected) / se)
