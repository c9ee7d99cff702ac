"""``lumigraph run``: every stage in order for one scene, with the defaults of params.yaml
(:class:`pipeline.params.RunParams`)."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from rig.rig_scene import RigScene

from .artifacts import BadInput, stage_dir
from .distributed import ClusterConfig, engine
from .inspect import inspect_folder
from .params import RunParams

__all__ = ["run_pipeline", "slab_layout_for", "warm_reference_kernels"]


def warm_reference_kernels(rig: RigScene) -> subprocess.Popen | None:
    """Start compiling the kernels of the integrator the reference stage will choose for ``rig``
    (``python -m pipeline.warm_kernels --only NAME``) in a background process, or None when this
    source tree's kernels for it are already in numba's cache.

    On a fresh checkout numba compiles the path tracer's kernels on one core for ~30 s; the
    capture stage before the reference keeps about one core of two busy, so the compile runs
    beside it instead of before it. The caller waits for the process before the reference renders
    (two processes compiling the same kernels would only duplicate the work)."""
    from render import integrators
    from render._kernel_cache import kernel_cache_dir
    from render.effects import scene_effects

    from .warm_kernels import MARKER, WARM_RENDERS

    folder = kernel_cache_dir()
    if (folder / MARKER).is_file():
        return None  # every integrator warm (`make setup`): no need to prepare the scene to choose
    try:
        name = integrators.prepare(rig.scene).choose(frozenset(scene_effects(rig.scene)), "auto")
    except ValueError:
        return None  # the reference stage refuses this scene itself, with its own message
    if name not in {i for _, i in WARM_RENDERS} or (folder / f"{MARKER}.{name}").is_file():
        return None
    return subprocess.Popen([sys.executable, "-m", "pipeline.warm_kernels", "--only", name],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def slab_layout_for(params: RunParams = RunParams()):
    """The slab layout ``lumigraph run`` uses: LayoutConfig's other defaults, uv_res =
    params.slab_uv_res and st sampled at params.slab_st_per_pixel samples per capture pixel of
    the subject's footprint (:func:`recon.slab.st_density`: a tiny scene's small views get a
    small slab, the demo's 1280x960 views one that keeps the board's markers)."""
    from recon.slab import LayoutConfig

    return LayoutConfig(uv_res=params.slab_uv_res, st_per_pixel=params.slab_st_per_pixel)


def run_pipeline(rig: RigScene, scene_file: Path, root: Path, params: RunParams = RunParams(),
                 seed: int | None = None, quiet: bool = False, cluster: ClusterConfig | None = None,
                 overwrite: bool = False) -> list[str]:
    """Run capture, reference, poses (gt, colmap, charuco when the scene has a board), slab (direct,
    and rebinned on COLMAP's cameras when they exist; layout :func:`slab_layout_for`), NeRF,
    validate and report.

    cluster: one engine for every stage (pipeline.distributed; started once, dashboard printed
    once): None in this process; a :class:`ClusterConfig` whose default (no scheduler, no
    ``workers``) is sized to the machine and in process on 2 cores (docs/scaling.md). Capture,
    reference, slab and NeRF renders run their units on it; poses, NeRF training and validate run
    in this process.

    Returns summary lines, the last one the report's path. A stage that fails on its input
    (BadInput) stops the run, except a failed pose estimate: that is a finding, recorded in its
    metrics.json and shown by the report, and only the models built on it are skipped.
    params: reference spp, COLMAP's image scale, slab resolution, NeRF model and minutes (0 skips
    the NeRF); seed: every stage's (None: the spec's for the capture, 0 for the others).
    """
    spp, colmap_image_scale = params.reference_spp, params.poses_image_scale
    nerf_model, nerf_minutes = params.nerf_model, params.nerf_minutes
    from recon.poses import ColmapConfig

    from .report import write_report
    from .stages.capture import run_capture
    from .stages.nerf import NerfStageConfig, run_nerf
    from .stages.poses import PosesConfig, run_poses
    from .stages.reference import ReferenceConfig, run_reference
    from .stages.slab import SlabStageConfig, run_slab
    from .stages.validate import run_validate

    with engine(cluster, quiet) as eng:
        name = rig.scene.name
        t0 = time.perf_counter()
        lines = []
        cap = stage_dir(name, "capture", root)
        warming = warm_reference_kernels(rig) if "test" in rig.cameras else None
        try:
            m = run_capture(rig, scene_file, cap, seed, quiet, eng, overwrite=overwrite)
        except BaseException:
            if warming is not None:
                warming.kill()  # numba writes each cache file whole (temporary name, then rename)
            raise
        if warming is not None:
            warming.wait()  # a failed warm-up leaves the reference to compile (and report) itself
        lines.append(f"capture    {m['metrics']['views']} views, {m['params']['renderer']}, {m['wall_time_s']:.1f} s")
        if not quiet:
            inspect_folder(cap)
        if "test" not in rig.cameras:
            lines.append("no held-out views: the model stages need a 'test' split; stopping after capture")
            return lines
        ref = stage_dir(name, "reference", root)
        m = run_reference(rig, scene_file, ref, ReferenceConfig(spp=spp, seed=seed or 0),
                          quiet=quiet, cluster=eng, overwrite=overwrite)
        lines.append(f"reference  {m['metrics']['views']} views, {m['params']['integrator']} {spp} spp, "
                     f"{m['wall_time_s']:.1f} s")
        methods = ["gt", "colmap"] + (["charuco"] if rig.targets else [])
        estimated = {}
        for method in methods:
            out = stage_dir(name, f"poses/{method}", root)
            try:
                m = run_poses(cap, method, out, PosesConfig(colmap=ColmapConfig(image_scale=colmap_image_scale)), quiet,
                              overwrite=overwrite)
            except BadInput as exc:
                lines.append(f"poses      {method}: failed: {exc}")
                continue
            estimated[method] = out
            mt = m["metrics"]
            lines.append(f"poses      {method}: {mt['views_registered']}/{mt['views_total']} views, rotation error "
                         f"{mt['rotation_error_deg_mean']:.4f} deg mean, {m['wall_time_s']:.1f} s")

        def slab_line(label: str, m: dict) -> str:
            return (f"{label:10s} {m['metrics']['mode']}: display PSNR {m['metrics']['display_psnr_mean']:.2f} dB, "
                    f"SSIM {m['metrics']['display_ssim_mean']:.4f}, {m['wall_time_s']:.1f} s")

        layout = slab_layout_for(params)
        m = run_slab(cap, None, stage_dir(name, "slab", root), SlabStageConfig(layout=layout), reference_dir=ref,
                     quiet=quiet, cluster=eng, overwrite=overwrite)
        lines.append(slab_line("slab", m))
        if "colmap" in estimated:
            m = run_slab(cap, estimated["colmap"], stage_dir(name, "slab-colmap", root),
                         SlabStageConfig(method="rebin", layout=layout), reference_dir=ref, quiet=quiet, cluster=eng,
                         overwrite=overwrite)
            lines.append(slab_line("slab-colmap", m))
        if nerf_minutes > 0:
            m = run_nerf(cap, None, stage_dir(name, f"nerf/{nerf_model}", root),
                         NerfStageConfig(nerf_model, nerf_minutes, seed=seed or 0), ref, quiet=quiet, cluster=eng,
                         overwrite=overwrite)
            mt = m["metrics"]
            lines.append(f"nerf       {nerf_model}: display PSNR {mt['display_psnr_mean']:.2f} dB, SSIM {mt['display_ssim_mean']:.4f}, "
                         f"{mt['steps']} steps, {m['wall_time_s']:.1f} s")
        m = run_validate(stage_dir(name, "", root), quiet=quiet, overwrite=overwrite)
        best = m["metrics"]["best"]
        lines.append(f"validate   {m['metrics']['models']} models; best at the held-out views: {best}")
        report = write_report(stage_dir(name, "", root), overwrite=overwrite)
        lines.append(f"total      {time.perf_counter() - t0:.1f} s; artifacts in {Path(root) / name}")
        lines.append(f"report     {report}")
    return lines
