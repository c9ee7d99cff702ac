"""Light slabs from the rig: slab layouts around captured content, direct acquisition assembly
(sheared-perspective renders handed in by the pipeline), rebinning of calibrated captures
through a depth proxy (Lumigraph / unstructured lumigraph), and compression by vector
quantization. Rendering from slabs is :mod:`render.lightfield`; slab-set files are
:mod:`render.lightfield.storage`.

The compression names (``VQConfig``, ``VQStats``, ``compress_slabs``) load :mod:`.compress`, and
with it torch, on first use: the rest is numpy, so the CLI reads :class:`LayoutConfig`'s defaults
without paying for torch.
"""
from .direct import DirectConfig, acquire_direct, acquire_row, renders_per_uv, uv_subsamples
from .layout import (LayoutConfig, box_normals, content_bounds, fit_slabs, layout_rays, ring_normals, slab_layout,
                     st_density)
from .rebin import RebinConfig, RebinStats, SourceView, rebin_slabs

__all__ = ["VQConfig", "VQStats", "compress_slabs", "DirectConfig", "acquire_direct", "acquire_row", "renders_per_uv",
           "uv_subsamples", "LayoutConfig", "box_normals", "content_bounds", "fit_slabs", "layout_rays", "ring_normals",
           "st_density", "slab_layout", "SourceView", "RebinConfig", "RebinStats", "rebin_slabs"]

_COMPRESS = ("VQConfig", "VQStats", "compress_slabs")


def __getattr__(name: str):
    if name in _COMPRESS:
        from . import compress

        return getattr(compress, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
