"""A scene prepared once for rendering: BVHs, triangle arrays, material table, light distribution.

:func:`prepare` is the one construction path of :class:`PreparedScene`; every integrator takes
one (and builds it with :func:`prepare` when not given one).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..accel import Accel, Geometry
from ..bsdf import MaterialTable
from ..lights import LightSet
from ..scene import DirectionalLight, PointLight, Scene, SpotLight
from .choice import SMALL_SOURCE_SR, choose_integrator

__all__ = ["PreparedScene", "prepare", "emitter_solid_angle"]


@dataclass
class PreparedScene:
    """A scene's BVH, triangle arrays, material table and light distribution (reusable).

    emit_accel: a BVH over the emissive triangles alone: `direct` finds what its last BSDF ray
    could hit there first, and asks the full BVH only an occlusion query up to that emitter.
    kernel: the same scene packed as flat arrays for the compiled kernels
    (:class:`render.integrators.path_kernels.KernelScene`, built on first use by
    :func:`render.integrators.path.kernel_scene_of`).
    """

    geom: Geometry
    accel: Accel
    mats: MaterialTable
    lights: LightSet
    background: np.ndarray
    has_delta_lights: bool
    emit_accel: Accel | None = None
    kernel: object | None = None
    #: largest solid angle (sr) an area emitter subtends from the scene's centre (0: none)
    emitter_solid_angle: float = 0.0

    @property
    def small_sources(self) -> bool:
        """Area emitters exist and each subtends less than SMALL_SOURCE_SR."""
        return 0.0 < self.emitter_solid_angle < SMALL_SOURCE_SR

    def choose(self, effects, requested: str = "auto") -> str:
        """:func:`render.integrators.choice.choose_integrator` with this scene's lights and materials."""
        return choose_integrator(effects, requested, self.has_delta_lights, self.mats.has_glossy, self.small_sources)


def emitter_solid_angle(geom: Geometry, mats: MaterialTable) -> float:
    """Largest A / d^2 over emissive objects: A the object's area, d the distance from its
    area-weighted centre to the centre of the bounding box of everything that does not emit.
    A / d^2 bounds the solid angle of any shape's projection (a sphere's is a quarter of it)."""
    if len(geom.obj) == 0:
        return 0.0
    emit = mats.emits[geom.obj] & geom.valid
    if not emit.any() or emit.all():
        return 0.0
    rest = np.concatenate([geom.v0[~emit], (geom.v0 + geom.e1)[~emit], (geom.v0 + geom.e2)[~emit]])
    centre = 0.5 * (rest.min(axis=0) + rest.max(axis=0))
    best = 0.0
    for k in sorted(set(geom.obj[emit].tolist())):  # np.unique would import numpy.ma: 40 ms of start-up
        t = emit & (geom.obj == k)
        a = geom.area[t]
        c = ((geom.v0[t] + (geom.e1[t] + geom.e2[t]) / 3.0) * a[:, None]).sum(axis=0) / max(a.sum(), 1e-300)
        d2 = float(np.sum((c - centre) ** 2))
        best = max(best, min(2.0 * np.pi, float(a.sum()) / max(d2, 1e-300)))
    return best


def prepare(scene: Scene, threads: int = 2) -> PreparedScene:
    """Build everything a render of ``scene`` needs once (reuse it across views and refinements).
    threads: the BVH's query threads."""
    geom = Geometry.from_scene(scene)
    accel = Accel(scene, threads=threads, geometry=geom)
    mats = MaterialTable.from_scene(scene)
    lights = LightSet(scene, geom, mats)
    delta = any(isinstance(l, (PointLight, SpotLight, DirectionalLight)) for l in scene.lights)
    emitters = mats.emits[geom.obj] if len(geom.obj) else np.zeros(0, bool)
    emit_accel = Accel(scene, threads=1, geometry=geom, subset=emitters) if emitters.any() else None
    return PreparedScene(geom, accel, mats, lights, np.asarray(scene.background, np.float64), delta, emit_accel,
                         emitter_solid_angle=emitter_solid_angle(geom, mats))
