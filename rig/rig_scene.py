"""The loaded scene (:class:`RigScene`), in a module that imports neither the schema (pydantic)
nor YAML: a scene from the cache (:mod:`rig.scene_cache`) unpickles without them, and its spec is
validated only when something reads it."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from render.camera import Camera
    from render.scene import Scene

    from .spec import SceneSpec

__all__ = ["RigScene"]


class RigScene:
    """A loaded scene: the render model, cameras per split, and what a capture records about it.

    spec: the validated :class:`rig.spec.SceneSpec`; a scene from the cache holds its file's bytes
    instead and validates them on first access (the same bytes the cached scene was built from).
    targets: calibration targets in the scene: name -> {"board": CharucoTexture dict, "board_to_world": 4x4}.
    """

    __slots__ = ("_spec", "_spec_source", "scene", "cameras", "targets")

    def __init__(self, spec: SceneSpec | None, scene: Scene, cameras: dict[str, list[Camera]],
                 targets: dict[str, dict] | None = None, spec_source: tuple[Path, bytes] | None = None):
        if spec is None and spec_source is None:
            raise ValueError("RigScene needs its spec or the (path, bytes) of its spec file")
        self._spec, self._spec_source = spec, spec_source
        self.scene, self.cameras = scene, cameras
        self.targets = {} if targets is None else targets

    @property
    def spec(self) -> SceneSpec:
        if self._spec is None:
            from .spec import load_spec

            path, raw = self._spec_source
            self._spec = load_spec(path, raw)[0]
        return self._spec

    def __getstate__(self):
        # with its file's bytes the spec travels as them: unpickling needs no pydantic
        return {"spec": self._spec if self._spec_source is None else None, "spec_source": self._spec_source,
                "scene": self.scene, "cameras": self.cameras, "targets": self.targets}

    def __setstate__(self, state):
        self._spec, self._spec_source = state["spec"], state["spec_source"]
        self.scene, self.cameras, self.targets = state["scene"], state["cameras"], state["targets"]

    def __repr__(self) -> str:
        return f"RigScene({self.scene.name!r}, splits={sorted(self.cameras)})"
