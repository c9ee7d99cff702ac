"""The ``lumigraph`` command line (DESIGN.md's CLI contract).

Exit codes: 0 success, 2 bad input (one line on stderr naming the field or file), 1 a bug.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer

from .artifacts import DEFAULT_ROOT, BadInput, stage_dir

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="lumigraph: capture, estimate poses, build light slabs and NeRFs, validate against a path tracer.")

QUIET = typer.Option(False, "--quiet", "-q", help="no progress bar")
SCHEDULER = typer.Option(None, envvar="LUMIGRAPH_SCHEDULER", help="existing Dask scheduler address (default: local)")
OVERWRITE = typer.Option(False, "--overwrite", help="replace whatever --out holds (default: only a finished "
                                                    "folder of this stage; anything else is refused)")
WORKERS = typer.Option(None, help="local Dask workers (default: cores/2, in process when that is 1; 0: in process)")


def _version() -> str:
    from . import __version__

    return __version__


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"lumigraph {_version()}")
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_show_version, is_eager=True,
                                       help="print the version and exit")):
    """lumigraph: capture, estimate poses, build light slabs and NeRFs, validate against a path tracer."""


def _cluster(scheduler: Optional[str], workers: Optional[int]):
    from .distributed import ClusterConfig

    return ClusterConfig(scheduler=scheduler, workers=workers)


def _load(scene: str):
    # through the scene cache: a scene loaded before skips pydantic and YAML (rig/scene_cache.py)
    from rig.scene_cache import load_scene
    from rig.scene_file import resolve_scene_path

    return load_scene(scene), resolve_scene_path(scene)


@app.command()
def capture(scene: str = typer.Argument(..., help="built-in scene name or path to a scene YAML"),
            out: Optional[Path] = typer.Option(None, help="capture folder (default artifacts/<scene>/capture)"),
            seed: Optional[int] = typer.Option(None, help="seed for sensor noise (default: the spec's)"),
            root: Path = typer.Option(DEFAULT_ROOT, help="artifacts root"),
            scheduler: Optional[str] = SCHEDULER,
            workers: Optional[int] = WORKERS,
            quiet: bool = QUIET,
            overwrite: bool = OVERWRITE):
    """Render a scene's train and test views with ground-truth cameras."""
    from .stages.capture import run_capture

    rig, path = _load(scene)
    out = out or stage_dir(rig.scene.name, "capture", root)
    m = run_capture(rig, path, out, seed, quiet, _cluster(scheduler, workers), overwrite=overwrite)
    typer.echo(f"capture: {m['metrics']['views']} views ({m['params']['renderer']}) in {m['wall_time_s']:.1f} s -> {out}")


@app.command()
def reference(scene: str = typer.Argument(..., help="built-in scene name or path to a scene YAML"),
              spp: int = typer.Option(64, help="samples per pixel; under the Sobol samplers rounded up to at most "
                                               "four binary digits (<= 12.5% more: whole nets; powers of two "
                                               "stratify best: docs/architecture.md, issue 16)"),
              size: Optional[tuple[int, int]] = typer.Option(None, help="render size W H (default: the views' own)"),
              views: str = typer.Option("auto", help="auto (test views if the scene has them, else its scene camera) | test | all | scene"),
              integrator: str = typer.Option("auto", help="auto (from the scene's effects) | direct | path | volpath | bdpt | pssmlt | sppm | irradiance_cache"),
              seed: int = typer.Option(0, help="render seed"),
              max_depth: Optional[int] = typer.Option(None, help="maximum bounces (default: 64 for path and volpath, "
                                                                 "whose paths Russian roulette ends; 8 for the others)"),
              sampler: Optional[str] = typer.Option(None, help="path/direct/volpath random numbers: sobol-blocks (one "
                                                               "Owen-scrambled Sobol sequence per pixel, variance "
                                                               "from its blocks by a fitted power law; the default "
                                                               "where the integrator reads it) | sobol (independent "
                                                               "replicates: noisier, model-free variance) | independent"),
              out: Optional[Path] = typer.Option(None, help="folder (default artifacts/<scene>/reference)"),
              root: Path = typer.Option(DEFAULT_ROOT, help="artifacts root"),
              scheduler: Optional[str] = SCHEDULER,
              workers: Optional[int] = WORKERS,
              quiet: bool = QUIET,
              overwrite: bool = OVERWRITE):
    """Path-traced reference renders of a scene's views, with per-pixel variance images."""
    from .stages.reference import ReferenceConfig, run_reference

    rig, path = _load(scene)
    out = out or stage_dir(rig.scene.name, "reference", root)
    config = ReferenceConfig(spp=spp, size=size, views=views, integrator=integrator, seed=seed, max_depth=max_depth,
                             sampler=sampler)
    m = run_reference(rig, path, out, config, quiet, _cluster(scheduler, workers), overwrite=overwrite)
    rendered = m["params"]["spp"]
    asked = f" ({spp} asked, rounded up to whole Sobol nets)" if rendered != spp else ""
    typer.echo(f"reference: {m['metrics']['views']} views, {m['params']['integrator']} at {rendered} spp{asked}, "
               f"{m['metrics']['paths_per_s'] / 1e6:.2f} M paths/s -> {out}")


@app.command()
def poses(capture_dir: Path = typer.Argument(..., help="a capture folder"),
          method: str = typer.Option("colmap", help="gt | colmap | charuco"),
          out: Optional[Path] = typer.Option(None, help="folder (default <capture>/../poses/<method>)"),
          self_calibrate: bool = typer.Option(False, help="estimate intrinsics and lens from the images (COLMAP)"),
          camera_model: str = typer.Option("auto", help="COLMAP self-calibration's lens: auto | SIMPLE_RADIAL | "
                                                        "RADIAL | OPENCV | FULL_OPENCV"),
          calibration: Optional[str] = typer.Option(None, help="COLMAP intrinsics: known | self | charuco "
                                                               "(cv2.calibrateCamera on the capture's calibration "
                                                               "sequence, else its views' boards, held fixed) | auto "
                                                               "(the sequence if it has one that fits, else self); "
                                                               "default auto with --self-calibrate, else known"),
          image_scale: Optional[float] = typer.Option(None, help="COLMAP: scale images before feature extraction "
                                                                 "(default: 1, 0.75 from 500 views on)"),
          max_features: int = typer.Option(8192, help="COLMAP: SIFT features per image"),
          matcher: str = typer.Option("auto", help="COLMAP: auto | exhaustive | capture_order | sequential"),
          mapper: str = typer.Option("auto", help="COLMAP: auto | incremental | global"),
          quiet: bool = QUIET,
          overwrite: bool = OVERWRITE):
    """Estimate camera poses from a capture's images and score them against its ground truth."""
    from recon.poses import CharucoConfig, ColmapConfig

    from .stages.poses import PosesConfig, run_poses

    try:
        calibration = calibration or ("auto" if self_calibrate else "known")
        if self_calibrate and calibration == "known":
            raise BadInput("--calibration known contradicts --self-calibrate")
        cfg = PosesConfig(colmap=ColmapConfig(known_intrinsics=calibration not in ("self", "auto"),
                                              image_scale=image_scale, max_features=max_features, matcher=matcher,
                                              mapper=mapper, camera_model=camera_model),
                          charuco=CharucoConfig(calibrate=self_calibrate), calibration=calibration)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    out = out or capture_dir.parent / "poses" / method
    m = run_poses(capture_dir, method, out, cfg, quiet, overwrite=overwrite)
    mt = m["metrics"]
    typer.echo(f"poses {method}: {mt['views_registered']}/{mt['views_total']} views, "
               f"rotation error {mt['rotation_error_deg_mean']:.4f} deg mean -> {out}")
    if mt.get("calibration", "known") != "known":
        typer.echo(f"lens ({mt['calibration']}, {mt.get('camera_model', '')}): focal {100 * mt['focal_rel']:.3f}% off, "
                   f"principal point {mt['principal_point_px']:.2f} px off, projection within "
                   f"{mt['projection_error_px_max']:.2f} px over the image")
    if mt.get("camera_model_note"):
        typer.echo(f"note: {mt['camera_model_note']}")


@app.command()
def slab(capture_dir: Path = typer.Argument(..., help="a capture folder"),
         poses: Optional[Path] = typer.Option(None, help="a poses folder (default: the capture's own cameras)"),
         out: Optional[Path] = typer.Option(None, help="folder (default <capture>/../slab)"),
         method: str = typer.Option("direct", help="direct (sheared cameras through the rig) | rebin (from the captures)"),
         mode: str = typer.Option("depth", help="nearest | uv | st | quadrilinear | depth"),
         layout: str = typer.Option("ring", help="ring (slabs around the turntable axis) | box (six faces)"),
         # defaults None = recon.slab.LayoutConfig's: reading them here would import recon.slab (0.4 s, and
         # its numba kernels) for --help and every verb
         uv_res: Optional[int] = typer.Option(None, help="uv samples along a uv quad's longer side "
                                              "(default: recon.slab.LayoutConfig's)"),
         st_res: Optional[int] = typer.Option(None, help="st samples along an st quad's longer side "
                                              "(default: from the capture's pixel footprint, --st-per-pixel)"),
         st_per_pixel: Optional[float] = typer.Option(None, help="st samples per capture pixel of the subject's "
                                                      "footprint on the st plane (default: LayoutConfig's)"),
         precision: str = typer.Option("half", help="slab samples: half (float16) | single (float32)"),
         compress: bool = typer.Option(True, "--compress/--no-compress",
                                       help="also vector-quantize the slabs and score the views from them"),
         reference: Optional[Path] = typer.Option(None, help="reference folder to score against"),
         scheduler: Optional[str] = SCHEDULER,
         workers: Optional[int] = WORKERS,
         quiet: bool = QUIET,
         overwrite: bool = OVERWRITE):
    """Build light slabs from a capture; render and score its held-out views."""
    from recon.slab import LayoutConfig

    from .stages.slab import SlabStageConfig, run_slab

    try:
        cfg = SlabStageConfig(method=method, mode=mode, compress=compress, precision=precision,
                              layout=LayoutConfig(kind=layout, st_res=st_res, **{
                                  k: v for k, v in (("uv_res", uv_res), ("st_per_pixel", st_per_pixel)) if v is not None}))
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    out = out or capture_dir.parent / "slab"
    m = run_slab(capture_dir, poses, out, cfg, reference, quiet, _cluster(scheduler, workers), overwrite=overwrite)
    mt = m["metrics"]
    typer.echo(f"slab: {mt['mode']} display PSNR {mt['display_psnr_mean']:.2f} dB SSIM {mt['display_ssim_mean']:.4f} "
               f"(linear PSNR {mt['linear_psnr_mean']:.2f} dB) -> {out}")


@app.command()
def nerf(capture_dir: Path = typer.Argument(..., help="a capture folder"),
         poses: Optional[Path] = typer.Option(None, help="a poses folder (default: the capture's own cameras)"),
         model: str = typer.Option("fast", help="fast (factored grid + tiny MLP) | vanilla (Mildenhall et al.) | "
                                                "ablations: vanilla_noview, vanilla_nope, fast_noview"),
         minutes: float = typer.Option(10.0, help="training budget in minutes of wall time"),
         out: Optional[Path] = typer.Option(None, help="folder (default <capture>/../nerf/<model>)"),
         reference: Optional[Path] = typer.Option(None, help="reference folder to score against "
                                                            "(default: the capture's held-out images)"),
         downsample: Optional[int] = typer.Option(None, help="train at capture size / N (default: ~160 px wide)"),
         seed: int = typer.Option(0, help="training seed"),
         resume: bool = typer.Option(False, help="continue an interrupted run's checkpoint"),
         scheduler: Optional[str] = SCHEDULER,
         workers: Optional[int] = WORKERS,
         quiet: bool = QUIET,
         overwrite: bool = OVERWRITE):
    """Train a radiance field from a capture; render and score its held-out views."""
    from .stages.nerf import NerfStageConfig, run_nerf

    out = out or capture_dir.parent / "nerf" / model
    cfg = NerfStageConfig(model=model, minutes=minutes, downsample=downsample, seed=seed)
    m = run_nerf(capture_dir, poses, out, cfg, reference, resume=resume, quiet=quiet,
                 cluster=_cluster(scheduler, workers), overwrite=overwrite)
    mt = m["metrics"]
    typer.echo(f"nerf {model}: display PSNR {mt['display_psnr_mean']:.2f} dB SSIM {mt['display_ssim_mean']:.4f} "
               f"(linear PSNR {mt['linear_psnr_mean']:.2f} dB) after {mt['steps']} steps in {mt['train_s']:.0f} s"
               + (f", stage {mt['stage_s']:.0f} s of a {mt['budget_s']:.0f} s budget" if "stage_s" in mt else "")
               + f" -> {out}")


@app.command()
def validate(artifacts_dir: Path = typer.Argument(..., help="a scene's artifacts folder (artifacts/<scene>)"),
             out: Optional[Path] = typer.Option(None, help="folder (default <artifacts_dir>/validate)"),
             quiet: bool = QUIET,
             overwrite: bool = OVERWRITE):
    """Judge every finished model (slab, NeRF, ...) against the reference at the held-out views."""
    from .stages.validate import run_validate

    from .artifacts import read_json

    out = out or artifacts_dir / "validate"
    run_validate(artifacts_dir, out, quiet=quiet, overwrite=overwrite)
    models = read_json(out / "metrics.json")["models"]
    for name, row in models.items():
        flip = "–" if row["flip_ldr_mean"] is None else f"{row['flip_ldr_mean']:.4f}"
        typer.echo(f"validate: {name:24s} display PSNR {row['display_psnr_mean']:6.2f} dB  SSIM "
                   f"{row['display_ssim_mean']:.4f}  ꟻLIP {flip}  linear PSNR {row['linear_psnr_mean']:6.2f} dB  "
                   f"end to end {row['end_to_end_s']:.0f} s")
    typer.echo(f"validate: {len(models)} models -> {out}")


@app.command()
def report(artifacts_dir: Path = typer.Argument(..., help="a scene's artifacts folder with a finished validate stage"),
           out: Optional[Path] = typer.Option(None, help="file (default <artifacts_dir>/validate/report.html)"),
           overwrite: bool = typer.Option(False, "--overwrite", help="replace --out even when it is not a report")):
    """Write a self-contained report.html: every stage, side-by-side views, accuracy against time."""
    from .report import write_report

    typer.echo(f"report: {write_report(artifacts_dir, out, overwrite=overwrite)}")


@app.command()
def study(scene: str = typer.Argument("turntable", help="built-in scene name or path to a scene YAML, or a "
                                       "lecture study: uniqueness | caching | bias, or pose_tolerance"),
          profile: str = typer.Option("quick", help="quick | full"),
          out: Optional[Path] = typer.Option(None, help="folder (default artifacts/<scene>/study)"),
          seed: int = typer.Option(0, help="seed"),
          root: Path = typer.Option(DEFAULT_ROOT, help="artifacts root"),
          capture: Optional[Path] = typer.Option(None, help="pose_tolerance: the capture folder"),
          poses: Optional[Path] = typer.Option(None, help="pose_tolerance: a poses folder, its accuracy marked"),
          only: Optional[list[str]] = typer.Option(None, help="run only this stage's sweep (repeatable): "
                                                  "reference | poses | slab | nerf; the capture and the study's "
                                                  "reference always run"),
          quiet: bool = QUIET,
          overwrite: bool = OVERWRITE):
    """Sweep every stage's accuracy knob, time it, and draw the Pareto fronts of accuracy against time.

    With a lecture study's name instead of a scene, run that study into <root>/lecture/<name>.
    pose_tolerance --capture DIR [--poses DIR]: NeRF and slab display PSNR against perturbed cameras
    (into <capture>/../study_pose_tolerance)."""
    from .stages.lecture import LECTURE_STUDIES

    if only and (scene == "pose_tolerance" or scene in LECTURE_STUDIES):
        raise BadInput(f"study {scene}: --only selects a scene study's sweeps, not a part of {scene}")
    if scene == "pose_tolerance":
        from .stages.pose_tolerance_study import default_out, run_pose_tolerance

        if capture is None:
            raise BadInput("study pose_tolerance: --capture is required (a capture folder)")
        out = out or default_out(capture)
        m = run_pose_tolerance(capture, out, poses, profile=profile, seed=seed, quiet=quiet, overwrite=overwrite)
        typer.echo(f"study pose_tolerance: {m['metrics']['points']} points in {m['metrics']['wall_time_s']:.0f} s -> {out}")
        return
    from .stages.lecture import lecture_dir, run_lecture_study

    if scene in LECTURE_STUDIES:
        out = out or lecture_dir(scene, root)
        m = run_lecture_study(scene, out, profile=profile, seed=seed, quiet=quiet, overwrite=overwrite)
        typer.echo(f"study {scene}: {m['wall_time_s']:.0f} s -> {out}")
        return
    from .stages.study import run_study

    from rig.spec import load_spec

    spec, _ = load_spec(scene)
    out = out or stage_dir(spec.name, "study", root)
    m = run_study(scene, out, profile=profile, seed=seed, root=root, quiet=quiet, overwrite=overwrite,
                  only=tuple(only) if only else None)
    typer.echo(f"study: {m['metrics']['points']} points ({m['metrics']['failed']} failed) "
               f"in {m['wall_time_s']:.0f} s -> {out}")


@app.command()
def export(capture_dir: Path = typer.Argument(..., help="a capture folder"),
           format: str = typer.Option(..., "--format", "-f", help="nerfstudio | instant-ngp | colmap"),
           out: Optional[Path] = typer.Option(None, help="folder (default <capture>/../export/<format>)"),
           quiet: bool = QUIET,
           overwrite: bool = OVERWRITE):
    """Write a capture as nerfstudio, instant-ngp or COLMAP (binary model with 3D points) open it."""
    from .stages.export import run_export

    out = out or capture_dir.parent / "export" / format
    m = run_export(capture_dir, format, out, quiet=quiet, overwrite=overwrite)
    typer.echo(f"export {format}: {m['metrics']['views']} views -> {out}")


@app.command()
def inspect(folder: Path = typer.Argument(..., help="any stage folder"),
            no_sheet: bool = typer.Option(False, "--no-sheet", help="skip the contact sheet")):
    """Show what a stage folder holds: a table, and a contact sheet PNG of its previews."""
    from .inspect import inspect_folder

    inspect_folder(folder, sheet=not no_sheet)


@app.command()
# defaults None = params.yaml's (pipeline.params.RunParams): reading them here would import
# pipeline.params and with it recon.slab (its numba kernels, ~0.4 s) for --help and every verb
def run(scene: Optional[str] = typer.Argument(None, help="built-in scene name or path to a scene YAML "
                                                     "(default: params.yaml's)"),
        root: Path = typer.Option(DEFAULT_ROOT, help="artifacts root"),
        seed: Optional[int] = typer.Option(None, help="seed (default: the spec's)"),
        spp: Optional[int] = typer.Option(None, help="reference samples per pixel (default: params.yaml's)"),
        colmap_image_scale: Optional[float] = typer.Option(None, help="COLMAP's image scale (default: params.yaml's)"),
        nerf_model: Optional[str] = typer.Option(None, help="NeRF model (default: params.yaml's)"),
        nerf_minutes: Optional[float] = typer.Option(None, help="NeRF training budget (0: skip the NeRF; "
                                                                "default: params.yaml's)"),
        scheduler: Optional[str] = SCHEDULER,
        workers: Optional[int] = WORKERS,
        quiet: bool = QUIET,
        overwrite: bool = OVERWRITE):
    """Every stage in order, as dvc.yaml wires them: capture, reference, poses, slab, NeRF, validate,
    report; ends with the report's path. One engine (in process, a local cluster or --scheduler's)
    serves every stage's units of work. Defaults: params.yaml's (pipeline.params.RunParams)."""
    from .params import RunParams
    from .pipeline_run import run_pipeline

    given = {"scene": scene, "reference_spp": spp, "poses_image_scale": colmap_image_scale, "nerf_model": nerf_model,
             "nerf_minutes": nerf_minutes}
    params = RunParams(**{k: v for k, v in given.items() if v is not None})
    rig, path = _load(params.scene)
    summary = run_pipeline(rig, path, Path(root), params, seed=seed, quiet=quiet,
                           cluster=_cluster(scheduler, workers), overwrite=overwrite)
    for line in summary:
        typer.echo(line)


def _usage_error_line(exc: Exception) -> str | None:
    """One line for a command-line usage error (unknown option, missing or malformed argument), or
    None when ``exc`` is not one. typer bundles its own click (``typer._click``) whose exceptions
    are not ``click.ClickException``: both kinds are recognised."""
    import click
    from typer._click import exceptions as typer_click

    if not isinstance(exc, (click.ClickException, typer_click.ClickException)):
        return None
    if isinstance(exc, typer_click.NoArgsIsHelpError):
        typer.echo(exc.format_message())  # the help, on stdout
        return "missing command (see the help above)"
    ctx = getattr(exc, "ctx", None)
    hint = f" (try '{ctx.command_path} --help')" if ctx is not None else ""
    return " ".join(exc.format_message().split()) + hint


def _bad_input_types() -> tuple[type, ...]:
    """The exceptions that mean bad input: BadInput, FileNotFoundError, and rig's SpecError and
    CaptureError when the verb imported their modules (a module never imported cannot have
    raised; importing rig here would load trimesh and scipy for ``--help`` and every verb)."""
    types = [BadInput, FileNotFoundError]
    for module, name in (("rig.scene_file", "SpecError"), ("rig.capture", "CaptureError")):
        if module in sys.modules:
            types.append(getattr(sys.modules[module], name))
    return tuple(types)


def main(argv: list[str] | None = None) -> int:
    """Entry point: bad input and usage errors exit 2 with one line on stderr; bugs surface with
    exit 1 and their traceback."""
    try:
        # typer turns Ctrl-C (and the poses stage's SIGTERM) into Exit(130), which click in
        # non-standalone mode returns rather than raises: commands return None otherwise
        code = app(args=argv, standalone_mode=False, prog_name="lumigraph")
        if isinstance(code, int) and code:
            return code
    except _bad_input_types() as exc:  # evaluated when an exception arrives, after the verb's imports
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"lumigraph: error: {msg}", file=sys.stderr)
        return 2
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        print("lumigraph: aborted", file=sys.stderr)
        return 1
    except Exception as exc:
        line = _usage_error_line(exc)
        if line is None:
            raise
        print(f"lumigraph: error: {line}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
