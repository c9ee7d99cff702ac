"""Light slabs from the rig: slab layouts around captured content, direct acquisition assembly
(sheared-perspective renders handed in by the pipeline), and rebinning of calibrated captures
through a depth proxy (Lumigraph / unstructured lumigraph), and compression by vector quantization. Rendering from slabs is
:mod:`render.lightfield`; slab-set files are :mod:`render.lightfield.storage`."""
from .compress import VQConfig, VQStats, compress_slabs
from .direct import DirectConfig, acquire_direct, acquire_row, renders_per_uv, uv_subsamples
from .layout import LayoutConfig, box_normals, content_bounds, fit_slabs, ring_normals, slab_layout
from .rebin import CapturedView, RebinConfig, RebinStats, rebin_slabs

__all__ = ["VQConfig", "VQStats", "compress_slabs", "DirectConfig", "acquire_direct", "acquire_row", "renders_per_uv", "uv_subsamples", "LayoutConfig", "box_normals", "content_bounds",
           "fit_slabs", "ring_normals", "slab_layout", "CapturedView", "RebinConfig", "RebinStats", "rebin_slabs"]
