"""What the path tracer's kernels read, without numba: the NamedTuples they take
(:class:`KernelScene`, :class:`PathConfig`, :class:`PinholeCamera`), :func:`kernel_scene` that
packs a prepared scene into one, and the constants (material and light kinds, strategies,
samplers, path flags, the hash's multipliers).

:mod:`render.integrators.path_kernels` (numba) re-imports all of it, so the names stay importable
from there; :mod:`render.integrators.path` imports them from here, so a process whose kernels
come from the ahead-of-time extension (:mod:`render.path_aot`) never imports numba.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["KernelScene", "kernel_scene", "PathConfig", "PinholeCamera", "LAMBERT", "MIRROR", "DIELECTRIC",
           "EMISSIVE", "POINT", "SPOT", "DIRECTIONAL", "STRAT_MIS", "STRAT_LIGHT", "STRAT_BSDF",
           "SAMPLER_INDEPENDENT", "SAMPLER_SOBOL", "F_DELTA", "F_AFTER_DIFF", "example_kernel_scene"]

LAMBERT, MIRROR, DIELECTRIC, EMISSIVE = 0, 1, 2, 3
POINT, SPOT, DIRECTIONAL = 0, 1, 2
STRAT_MIS, STRAT_LIGHT, STRAT_BSDF = 0, 1, 2
SAMPLER_INDEPENDENT, SAMPLER_SOBOL = 0, 1  # render.sobol.SAMPLERS
F_DELTA, F_AFTER_DIFF = np.uint8(1), np.uint8(2)  # per-path flags: previous vertex delta, a diffuse vertex behind

_INV_PI = 1.0 / math.pi
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_INV_2_53 = 1.0 / 9007199254740992.0
_COS_FLOOR = 1e-12
_OFFSET_REL = 1e-6  # render.accel.OFFSET_REL
_TMAX_CAP = 3e38  # largest tmax handed to Embree (float32)


class KernelScene(NamedTuple):
    """A prepared scene as flat arrays for the kernels (built once by :func:`kernel_scene`).

    tri: (T, 12) float64 rows [v0, e1, e2, unit normal]; tri_obj: (T,) int64; uv: (T, 3, 2)
    float64. Per object (M): kind (int64), albedo (M, 3), ior, Le (M, 3), emits, two_sided
    (bool), tex (M, 3) int64 [offset into tex_data, height, width] (height 0: untextured),
    tex_data flat float32 linear RGB. Lights: cdf (K,), pmf (K,), area rows (n_area, 17)
    [v0, e1, e2, normal, pdf_area, Le, two_sided], tri_pdf_area (T,), delta lights d_kind (D,),
    d_pos, d_dir, d_I (D, 3), d_cos (D, 2). ids / emit_ids: Embree primID -> global triangle
    of the full and emitter-only BVHs. bg: (3,) background radiance. scal: (2,) float64
    [extent, light distance floor^2, number of area entries].
    """

    tri: np.ndarray
    tri_obj: np.ndarray
    uv: np.ndarray
    kind: np.ndarray
    albedo: np.ndarray
    ior: np.ndarray
    Le: np.ndarray
    emits: np.ndarray
    two_sided: np.ndarray
    tex: np.ndarray
    tex_data: np.ndarray
    cdf: np.ndarray
    pmf: np.ndarray
    area: np.ndarray
    tri_pdf_area: np.ndarray
    d_kind: np.ndarray
    d_pos: np.ndarray
    d_dir: np.ndarray
    d_I: np.ndarray
    d_cos: np.ndarray
    ids: np.ndarray
    emit_ids: np.ndarray
    bg: np.ndarray
    scal: np.ndarray



def kernel_scene(geom, mats, lights, ids: np.ndarray, emit_ids: np.ndarray, background: np.ndarray) -> KernelScene:
    """Pack a scene's :class:`render.accel.Geometry`, :class:`render.bsdf.MaterialTable` and
    :class:`render.lights.LightSet` (and the BVHs' primID maps) into a :class:`KernelScene`."""
    m = len(mats.kind)
    tex = np.zeros((m, 3), np.int64)
    chunks, off = [], 0
    for i, t in sorted(mats.textures.items()):
        t = np.ascontiguousarray(t[..., :3], dtype=np.float32)
        tex[i] = off, t.shape[0], t.shape[1]
        chunks.append(t.ravel())
        off += t.size
    tex_data = np.concatenate(chunks) if chunks else np.zeros(1, np.float32)
    tri = np.ascontiguousarray(np.concatenate([geom.v0, geom.e1, geom.e2, geom.normal], axis=1), dtype=np.float64)
    if len(tri) == 0:
        tri = np.zeros((1, 12))
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    i64 = lambda a: np.ascontiguousarray(a, dtype=np.int64)  # noqa: E731
    floor = (1e-9 * geom.extent) ** 2
    return KernelScene(
        tri, i64(geom.obj if len(geom.obj) else np.zeros(1, np.int64)),
        f64(geom.uv if len(geom.uv) else np.zeros((1, 3, 2))),
        i64(mats.kind), f64(mats.albedo), f64(mats.ior), f64(mats.Le),
        np.ascontiguousarray(mats.emits, dtype=np.bool_), np.ascontiguousarray(mats.two_sided, dtype=np.bool_),
        tex, tex_data,
        f64(lights.cdf if len(lights.cdf) else np.zeros(1)), f64(lights.pmf if len(lights.pmf) else np.zeros(1)),
        f64(lights._packed if len(lights._packed) else np.zeros((1, 17))),
        f64(lights.tri_pdf_area if len(lights.tri_pdf_area) else np.zeros(1)),
        i64(lights.d_kind), f64(lights.d_pos), f64(lights.d_dir), f64(lights.d_I), f64(lights.d_cos),
        i64(ids if len(ids) else np.zeros(1, np.int64)), i64(emit_ids if len(emit_ids) else np.zeros(1, np.int64)),
        f64(np.asarray(background, dtype=np.float64).reshape(3)), np.array([geom.extent, floor, lights.n_area], np.float64))



class PinholeCamera(NamedTuple):
    """A camera-to-world pinhole as the kernels read it (:func:`render.integrators.path.pinhole_of`)."""

    fx: float  #: focal length in pixels along x
    fy: float  #: focal length in pixels along y
    cx: float  #: principal point x (pixel centres at +0.5)
    cy: float  #: principal point y
    rotation: np.ndarray  #: (3, 3) float64 camera-to-world rotation (columns: the camera's x, y, z axes)
    origin: np.ndarray  #: (3,) float64 the camera centre in world coordinates



class PathConfig(NamedTuple):
    """What the bounce kernels read of the settings and the scene (:func:`render.integrators.path.path_config`)."""

    max_depth: int  #: maximum bounces: paths end at the vertex of this index
    direct: bool  #: integrator `direct`: paths end at their first diffuse vertex (with one last BSDF ray)
    caustics: bool  #: keep light reaching a diffuse vertex through specular ones (else dropped)
    strategy: int  #: STRAT_MIS, STRAT_LIGHT or STRAT_BSDF (next-event estimation vs BSDF sampling)
    mis_exponent: float  #: 2.0 power heuristic, 1.0 balance heuristic
    roulette: bool  #: Russian roulette on (path only)
    rr_depth: int  #: roulette when leaving vertices of index >= rr_depth
    has_bg: bool  #: escaping rays gather a non-black background
    nee_area: bool  #: next-event estimation samples area lights
    nee_any: bool  #: next-event estimation runs at all (area lights sampled, or delta lights present)
    mis_on_hits: bool  #: emission found by BSDF rays is MIS-weighted against light sampling
    continue_diffuse: bool  #: diffuse vertices sample a BSDF ray (false: `direct` with light sampling alone)
    has_area: bool  #: the scene has area lights
    sampler: int = SAMPLER_INDEPENDENT  #: SAMPLER_INDEPENDENT (the hash) or SAMPLER_SOBOL (render.sobol)


def example_kernel_scene() -> KernelScene:
    """A KernelScene of one triangle and no lights with the dtypes, ranks and layouts every
    :func:`kernel_scene` has (what the ahead-of-time kernels are compiled for: render.path_aot)."""
    z = lambda *s: np.zeros(s)  # noqa: E731
    zi = lambda *s: np.zeros(s, np.int64)  # noqa: E731
    zb = np.zeros(1, np.bool_)
    return KernelScene(z(1, 12), zi(1), z(1, 3, 2), zi(1), z(1, 3), z(1), z(1, 3), zb, zb.copy(), zi(1, 3),
                       np.zeros(1, np.float32), z(1), z(1), z(1, 17), z(1), zi(0), z(0, 3), z(0, 3), z(0, 3),
                       z(0, 2), zi(1), zi(1), z(3), z(3))
