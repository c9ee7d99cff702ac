"""Light fields as two-plane light slabs (Levoy and Hanrahan 1996): one home for their geometry,
storage and rendering. Building slabs from images or renders is :mod:`recon.slab`.

- :mod:`.geometry`: :class:`SlabGeometry` (the uv and st quads and their conventions),
  :class:`LightSlab`, :class:`VQRadiance` (vector-quantized radiance), ray-to-slab coordinates,
  the sheared-perspective camera of a uv sample;
- :mod:`.rendering`: interpolation modes (:data:`MODES`), lookup and rendering of arbitrary rays
  (numpy) and of pinhole cameras (:func:`render_pinhole`, through :mod:`.kernels`);
- :mod:`.kernels`: the compiled per-pixel kernels of :func:`render_pinhole`;
- :mod:`.storage`: slab-set folders (``slabs.json`` and memory-mappable ``.npy`` files).
"""
from .geometry import MIN_COS, LightSlab, SlabGeometry, SlabHits, VQRadiance, check_rays, sheared_camera, slab_coordinates
from .rendering import MODES, lookup, render_pinhole, render_rays, select_slabs
from .storage import (SLABS_FORMAT, SLABS_JSON, create_slab_arrays, load_slabs, save_slabs, slab_file_bytes,
                      write_slab_index)

__all__ = ["MIN_COS", "LightSlab", "SlabGeometry", "SlabHits", "VQRadiance", "check_rays", "sheared_camera",
           "slab_coordinates", "MODES", "lookup", "render_pinhole", "render_rays", "select_slabs", "SLABS_FORMAT",
           "SLABS_JSON", "create_slab_arrays", "load_slabs", "save_slabs", "slab_file_bytes", "write_slab_index"]
