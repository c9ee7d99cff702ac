"""The defaults of ``lumigraph run``, stated once: the CLI's ``run`` options and
:func:`pipeline.pipeline_run.run_pipeline` take them from :class:`RunParams`, and ``params.yaml``
(what ``dvc repro`` runs with) holds the same values (``RunParams().as_params_yaml()``; a test
checks they agree). The slab's sampling is :class:`recon.slab.LayoutConfig`'s own default.
"""
from __future__ import annotations

from dataclasses import dataclass

from recon.slab.layout import LayoutConfig

__all__ = ["RunParams"]


@dataclass(frozen=True)
class RunParams:
    """scene: built-in scene name; seed: the DVC pipeline's seed (``lumigraph run`` without
    ``--seed`` uses the spec's own); reference_spp: path tracer samples per pixel of the reference
    (the default scene is direct-only under delta lights: little noise per sample); poses_method:
    the estimate DVC's slab and validate stages read (``run`` tries gt, colmap and charuco);
    poses_image_scale: COLMAP's feature extraction scale (0.5: 0.08 deg mean rotation error in
    about a quarter of full resolution's time); slab_uv_res: uv samples along a slab's uv quad's
    longer side; slab_st_per_pixel: st samples per capture pixel of the subject's footprint on the
    st plane (memory goes to st: with depth correction the held-out views follow the st sampling,
    hardly the uv; :class:`recon.slab.LayoutConfig`; the run takes half the footprint, a quarter
    of its rays, so that ``make demo`` fits its 15 minutes: ``lumigraph slab`` alone defaults to
    the full footprint); nerf_model: NeRF model name; nerf_minutes:
    its wall-clock budget (0 skips it; 3.5: with the compiled held-out renderer the stage spends
    its budget on training, where 4 minutes left ~30 s of it unused; make demo's 15 minutes)."""

    scene: str = "turntable"
    seed: int = 0
    reference_spp: int = 16
    poses_method: str = "colmap"
    poses_image_scale: float = 0.5
    slab_uv_res: int = LayoutConfig.uv_res
    slab_st_per_pixel: float = 0.5
    nerf_model: str = "fast"
    nerf_minutes: float = 3.5

    def as_params_yaml(self) -> dict:
        """The nested mapping ``params.yaml`` holds (the keys ``dvc.yaml`` interpolates)."""
        return {"scene": self.scene, "seed": self.seed, "reference": {"spp": self.reference_spp},
                "poses": {"method": self.poses_method, "image_scale": self.poses_image_scale},
                "slab": {"uv_res": self.slab_uv_res, "st_per_pixel": self.slab_st_per_pixel},
                "nerf": {"model": self.nerf_model, "minutes": self.nerf_minutes}}
