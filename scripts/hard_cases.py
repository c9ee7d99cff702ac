"""The hard-case catalogue: one registry of every named hard case, per module, and the doc made from it.

DESIGN.md asks for hard cases as named tests that state the case and assert finite, bounded
output. This file is the one place that lists them (CATALOGUE: module, case, test), and
``python scripts/hard_cases.py`` writes docs/hard_cases.md from it, taking each test's one-line
summary from its docstring. ``python scripts/hard_cases.py --check`` exits 1 when the doc is
stale or the registry and the tests disagree; tests/test_hard_case_catalogue.py runs the same
checks in the suite.

A test counts as a hard case, and must be registered here, when its name starts with
``test_hard_case``, its docstring starts with "Hard case", or it lives in a
``test_hard_cases*.py`` file. Registered tests may be named otherwise (older ones).
"""
from __future__ import annotations

import ast
import re
import sys
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "hard_cases.md"


@dataclass(frozen=True)
class HardCase:
    """module: the code the case exercises (a path, or a package); case: what is hard, in a few
    words; test: ``tests/...py::function`` with an optional ``[parameter]``."""

    module: str
    case: str
    test: str


HC = "tests/render/test_hard_cases.py::"
HCI = "tests/render/test_hard_cases_integrators.py::"

CATALOGUE: tuple[HardCase, ...] = (
    # ---- the reference path tracer (`path`, render/integrators/path.py and its kernels)
    HardCase("render/integrators/path.py", "grazing camera rays (1e-4 rad)", HC + "test_grazing_camera_rays"),
    HardCase("render/integrators/path.py", "grazing secondary rays at millimetre scale", HC + "test_grazing_secondary_rays_at_millimetre_scale"),
    HardCase("render/integrators/path.py", "shading point almost touching an area source", HC + "test_shading_point_almost_touching_an_area_source"),
    HardCase("render/integrators/path.py", "degenerate triangles", HC + "test_degenerate_triangles_in_meshes"),
    HardCase("render/integrators/path.py", "total internal reflection", HC + "test_total_internal_reflection"),
    HardCase("render/integrators/path.py", "albedo exactly 0 with roulette", HC + "test_albedo_exactly_zero_with_roulette"),
    HardCase("render/integrators/path.py", "albedo exactly 1 with roulette", HC + "test_albedo_exactly_one_with_roulette"),
    HardCase("render/integrators/path.py", "camera inside an object", HC + "test_camera_inside_an_object"),
    HardCase("render/integrators/path.py", "light facing away", HC + "test_light_facing_away"),
    HardCase("render/integrators/path.py", "point light on the surface", HC + "test_point_light_on_the_surface"),
    HardCase("render/integrators/path.py", "absent light", HCI + "test_hard_case_absent_light[path]"),
    HardCase("render/integrators/path.py", "zero-area light", HCI + "test_hard_case_zero_area_light[path]"),
    HardCase("render/film.py", "blocks variance model without spread or beyond the fitted rate",
             "tests/render/test_sobol.py::test_hard_case_blocks_variance_without_spread_or_beyond_the_fitted_rate"),
    # ---- volpath
    HardCase("render/integrators/volpath.py", "absent light", HCI + "test_hard_case_absent_light[volpath]"),
    HardCase("render/integrators/volpath.py", "zero-area light", HCI + "test_hard_case_zero_area_light[volpath]"),
    HardCase("render/integrators/volpath.py", "degenerate triangles", HCI + "test_hard_case_degenerate_triangles[volpath]"),
    HardCase("render/integrators/volpath.py", "camera inside an object", HCI + "test_hard_case_camera_inside_an_object[volpath]"),
    # ---- bdpt
    HardCase("render/integrators/bdpt.py", "absent light", HCI + "test_hard_case_absent_light[bdpt]"),
    HardCase("render/integrators/bdpt.py", "zero-area light", HCI + "test_hard_case_zero_area_light[bdpt]"),
    HardCase("render/integrators/bdpt.py", "degenerate triangles", HCI + "test_hard_case_degenerate_triangles[bdpt]"),
    HardCase("render/integrators/bdpt.py", "point-light caustic through glass", "tests/render/test_bdpt.py::test_hard_case_point_light_caustic_through_glass"),
    HardCase("render/integrators/bdpt.py", "light facing away", "tests/render/test_bdpt.py::test_hard_case_light_facing_away"),
    HardCase("render/integrators/bdpt.py", "light vertices behind the camera and outside the image",
             "tests/render/test_bdpt.py::test_hard_case_light_vertices_behind_the_camera_and_outside_the_image"),
    HardCase("render/integrators/bdpt.py", "camera inside an object", "tests/render/test_bdpt.py::test_hard_case_camera_inside_an_object"),
    # ---- sppm
    HardCase("render/integrators/sppm.py", "degenerate triangles", HCI + "test_hard_case_degenerate_triangles[sppm]"),
    HardCase("render/integrators/sppm.py", "camera inside an object", HCI + "test_hard_case_camera_inside_an_object[sppm]"),
    HardCase("render/integrators/sppm.py", "photon radii shrinking towards zero", "tests/render/test_sppm.py::test_hard_case_photon_radius_shrinking_towards_zero"),
    # ---- pssmlt
    HardCase("render/integrators/pssmlt.py", "camera inside an object", HCI + "test_hard_case_camera_inside_an_object[pssmlt]"),
    HardCase("render/integrators/pssmlt.py", "chains stuck in a tiny bright region",
             "tests/render/test_pssmlt.py::test_hard_case_metropolis_chains_stuck_in_a_tiny_bright_region"),
    HardCase("render/integrators/pssmlt.py", "the bootstrap finds no light", "tests/render/test_pssmlt.py::test_hard_case_bootstrap_finds_no_light"),
    # ---- irradiance cache
    HardCase("render/integrators/irradiance_cache.py", "records at corners, edges and grazing or inward normals",
             "tests/render/test_irradiance_cache.py::test_hard_cases_are_finite_and_bounded"),
    # ---- media, microfacets, volume rendering, light slabs, metrics
    HardCase("render/media.py", "optically thick emitting slab (sigma_t = 1e4)", "tests/render/test_media.py::test_emitting_absorbing_slab_closed_form"),
    HardCase("render/media.py", "majorant below the density", "tests/render/test_media.py::test_hard_case_majorant_below_density_is_reported"),
    HardCase("render/media.py", "zero- and unit-albedo dense fog", "tests/render/test_media.py::test_hard_case_zero_and_unit_albedo_dense_fog"),
    HardCase("render/microfacet.py", "grazing directions at roughness near 0 and 1", "tests/render/test_microfacet.py::test_hard_case_grazing_any_roughness"),
    HardCase("recon/nerf/volume.py", "huge and zero densities", "tests/recon/test_volume.py::test_hard_case_huge_and_zero_densities"),
    HardCase("recon/nerf/volume.py", "zero-length segments", "tests/recon/test_volume.py::test_hard_case_zero_length_segments_contribute_nothing"),
    HardCase("recon/nerf/volume.py", "an all-transparent ray", "tests/recon/test_volume.py::test_hard_case_all_transparent_ray_shows_background"),
    HardCase("recon/nerf/volume.py", "an all-opaque ray", "tests/recon/test_volume.py::test_hard_case_all_opaque_ray_takes_first_colour"),
    HardCase("recon/nerf/volume.py", "infinite optical depth", "tests/recon/test_volume.py::test_hard_case_infinite_optical_depth_is_clamped"),
    HardCase("render/lightfield/", "rays parallel to the planes", "tests/render/test_slab.py::test_hard_case_rays_parallel_to_the_planes"),
    HardCase("render/lightfield/", "rays from behind the planes", "tests/render/test_slab.py::test_hard_case_rays_from_behind_the_planes"),
    HardCase("render/lightfield/", "rays outside the slab's extents", "tests/render/test_slab.py::test_hard_case_rays_outside_the_slab_extents"),
    HardCase("render/lightfield/", "camera exactly on the uv plane", "tests/render/test_slab.py::test_hard_case_camera_exactly_on_the_uv_plane"),
    HardCase("render/lightfield/", "cameras along the planes and beyond st (compiled path)",
             "tests/render/test_slab.py::test_hard_case_cameras_along_the_planes_and_beyond_st_compiled_path"),
    HardCase("render/lightfield/", "depth mode beside an occluder and into empty space",
             "tests/render/test_lightfield_occlusion.py::test_depth_mode_has_no_ghosts_beside_an_occluder_or_in_empty_space"),
    HardCase("render/metrics.py", "identical images through every metric", "tests/render/test_metrics.py::test_identical_images_through_every_metric"),
    HardCase("render/metrics.py", "HDR-ꟻLIP of mostly or entirely black frames", "tests/render/test_metrics.py::test_hard_case_hdr_flip_on_dark_references"),
    HardCase("render/metrics.py", "ꟻLIP of radiance whose square overflows float32", "tests/render/test_metrics.py::test_hard_case_flip_of_radiance_past_float32_squares_is_white"),
    # ---- the rasterizer
    HardCase("rig/raster.py", "degenerate triangles", "tests/rig/test_raster_hard_cases.py::test_hard_case_degenerate_triangles"),
    HardCase("rig/raster.py", "camera inside an object", "tests/rig/test_raster_hard_cases.py::test_hard_case_camera_inside_an_object"),
    HardCase("rig/raster.py", "camera inside an object: exactly black (strict xfail: light leaks at the inner corners)",
             "tests/rig/test_raster_hard_cases.py::test_hard_case_camera_inside_an_object_is_exactly_black"),
    # ---- NeRF and poses
    HardCase("recon/nerf", "a dark capture (vanilla model)", "tests/recon/test_nerf.py::test_vanilla_keeps_its_density_on_a_dark_capture"),
    HardCase("recon/nerf", "all-black images", "tests/recon/test_nerf_hard_cases.py::test_hard_case_all_black_images"),
    HardCase("recon/nerf", "a single training view", "tests/recon/test_nerf_hard_cases.py::test_hard_case_a_single_training_view"),
    HardCase("recon/nerf", "rays missing the scene box", "tests/recon/test_nerf_hard_cases.py::test_hard_case_rays_missing_the_scene_box"),
    HardCase("recon/poses/colmap.py", "only duplicate images", "tests/recon/test_colmap_hard_cases.py::test_hard_case_only_duplicate_images"),
    HardCase("recon/poses/colmap.py", "duplicates among distinct views", "tests/recon/test_colmap_hard_cases.py::test_hard_case_duplicates_among_distinct_views"),
    # ---- pipeline stages
    HardCase("pipeline/stages/validate.py", "identical images with zero variance",
             "tests/pipeline/test_validate.py::test_identical_and_zero_variance_images_stay_finite"),
    HardCase("pipeline/stages/slab.py", "a model that reproduces its reference exactly",
             "tests/pipeline/test_matrix.py::test_exact_match_metrics_are_written_as_finite_json"),
)

#: What issue 14 asked the catalogue to hold (module, case): a registry entry must match each.
REQUIRED = (
    ("render/integrators/path.py", "absent light"), ("render/integrators/path.py", "zero-area light"),
    ("render/integrators/volpath.py", "absent light"), ("render/integrators/volpath.py", "zero-area light"),
    ("render/integrators/bdpt.py", "absent light"), ("render/integrators/bdpt.py", "zero-area light"),
    ("rig/raster.py", "degenerate triangles"), ("render/integrators/volpath.py", "degenerate triangles"),
    ("render/integrators/bdpt.py", "degenerate triangles"), ("render/integrators/sppm.py", "degenerate triangles"),
    ("rig/raster.py", "camera inside an object"), ("render/integrators/volpath.py", "camera inside an object"),
    ("render/integrators/sppm.py", "camera inside an object"), ("render/integrators/pssmlt.py", "camera inside an object"),
    ("recon/nerf", "all-black images"), ("recon/nerf", "a single training view"),
    ("recon/nerf", "rays missing the scene box"), ("recon/poses/colmap.py", "only duplicate images"),
    ("render/metrics.py", "identical images through every metric"),
)


# ------------------------------------------------------------------------------------- the tests


def _split(test: str) -> tuple[str, str, str | None]:
    path, _, rest = test.partition("::")
    m = re.fullmatch(r"(\w+)(?:\[(.+)\])?", rest)
    if not path or m is None:
        raise ValueError(f"bad test id {test!r}: expected tests/...py::function[param]")
    return path, m.group(1), m.group(2)


def _functions(path: Path) -> dict[str, ast.FunctionDef]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith("test_")}


def summary(fn: ast.FunctionDef, sentences: int = 2, limit: int = 300) -> str:
    """The docstring's first ``sentences`` sentences on one line (at most ``limit`` characters),
    without a leading "Hard case:", for a Markdown table cell."""
    doc = " ".join((ast.get_docstring(fn) or "").split())
    doc = re.sub(r"^Hard case(, [^:]*)?:\s*", "", doc)
    text = " ".join(re.split(r"(?<=[.!?])\s", doc)[:sentences])
    if len(text) > limit:
        text = text[:limit - 3].rsplit(" ", 1)[0] + "..."
    return (text[:1].upper() + text[1:]).replace("|", "\\|")


def _is_hard_case(path: Path, fn: ast.FunctionDef) -> bool:
    doc = (ast.get_docstring(fn) or "").lstrip()
    return fn.name.startswith("test_hard_case") or doc.startswith("Hard case") or path.name.startswith("test_hard_cases")


def problems(repo: Path = REPO) -> list[str]:
    """Disagreements between CATALOGUE and the tests: registered tests that do not exist (or a
    parameter their source does not name), hard-case tests nobody registered, required cases
    missing, duplicates. Empty when all is well."""
    out: list[str] = []
    seen: set[str] = set()
    registered: set[tuple[str, str]] = set()
    for hc in CATALOGUE:
        if hc.test in seen:
            out.append(f"{hc.test}: registered twice")
        seen.add(hc.test)
        path, name, param = _split(hc.test)
        file = repo / path
        if not file.is_file():
            out.append(f"{hc.test}: no such file")
            continue
        fns = _functions(file)
        if name not in fns:
            out.append(f"{hc.test}: no such test")
            continue
        if param is not None and not re.search(r"""["']""" + re.escape(param) + r"""["']""", ast.unparse(fns[name])):
            out.append(f"{hc.test}: the test's parameters do not name {param!r}")
        registered.add((path, name))
    for file in sorted((repo / "tests").rglob("test_*.py")):
        rel = file.relative_to(repo).as_posix()
        for name, fn in _functions(file).items():
            if _is_hard_case(file, fn) and (rel, name) not in registered:
                out.append(f"{rel}::{name}: a hard case missing from the catalogue (scripts/hard_cases.py)")
    have = {(hc.module, hc.case) for hc in CATALOGUE}
    out += [f"required hard case missing: {m}: {c}" for m, c in REQUIRED if (m, c) not in have]
    return out


# ------------------------------------------------------------------------------------- the doc


def render_doc(repo: Path = REPO) -> str:
    """docs/hard_cases.md's text: one table per module, in CATALOGUE's order."""
    lines = ["# Hard cases", "",
             "Every named hard case of the project, per module: the case, its test, and what the test says",
             "(the start of its docstring). Generated by `python scripts/hard_cases.py` from the registry",
             "in that script; do not edit by hand. `tests/test_hard_case_catalogue.py` fails when this page is",
             "stale, when a registered test is gone, or when a test that calls itself a hard case (named",
             "`test_hard_case*`, a docstring starting \"Hard case\", or in a `test_hard_cases*.py` file) is not",
             "registered. Each test asserts finite, bounded output, and the closed form where one exists.", ""]
    modules: dict[str, list[HardCase]] = {}
    for hc in CATALOGUE:
        modules.setdefault(hc.module, []).append(hc)
    cache: dict[str, dict[str, ast.FunctionDef]] = {}
    for module, cases in modules.items():
        lines += [f"## `{module}`", "", "| case | test | the test says |", "|---|---|---|"]
        for hc in cases:
            path, name, _ = _split(hc.test)
            fns = cache.setdefault(path, _functions(repo / path)) if (repo / path).is_file() else {}
            text = summary(fns[name]) if name in fns else "(missing)"
            lines.append(f"| {hc.case} | `{hc.test}` | {text} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """``[--check] [--doc PATH]``: write the doc (default docs/hard_cases.md), or with --check
    compare it with what would be written; exit 1 on a stale doc or any of :func:`problems`."""
    check = "--check" in argv
    doc = Path(argv[argv.index("--doc") + 1]) if "--doc" in argv else DOC
    issues = problems()
    for p in issues:
        print(p, file=sys.stderr)
    text = render_doc()
    if check:
        stale = not doc.is_file() or doc.read_text(encoding="utf-8") != text
        if stale:
            print(f"{doc}: stale, run python scripts/hard_cases.py", file=sys.stderr)
        return 1 if issues or stale else 0
    doc.write_text(text, encoding="utf-8")
    print(f"wrote {doc}: {len(CATALOGUE)} hard cases in {len({hc.module for hc in CATALOGUE})} modules")
    return 1 if issues else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
