"""render: the lowest layer; imports nothing else of ours.

- ``scene``, ``effects``, ``camera``, ``poses``, ``camera_io``: the scene model every renderer
  shares, the effects vocabulary, pinhole cameras and their files.
- ``integrators/``: the reference Monte Carlo renderers (``path``, ``direct``, ``volpath``,
  ``bdpt``, ``sppm``, ``pssmlt``), one registry and one options dataclass each; start at
  ``render/integrators/__init__.py``.
- ``accel``, ``embree_direct``, ``sampling``, ``bsdf``, ``microfacet``, ``lights``, ``media``,
  ``film``, ``gbuffer``, ``texture``: what the integrators (and the rig) are built from.
- ``lightfield/``: Levoy-Hanrahan light slabs: geometry, rendering, storage.
- ``image_io``, ``color``, ``metrics``: EXR/PNG files, sRGB, and the project's image metrics.
"""

from ._kernel_cache import use_keyed_cache as _use_keyed_cache

# before any kernel module is imported: numba's cache keyed by render/'s sources (see _kernel_cache)
_use_keyed_cache()
