"""``lumigraph study uniqueness``: is a NeRF unique? (issue 19, part 1; the lecture's slides
"NERF - worrying issues", "More on uniqueness" and the three orthographic cameras).

The measurements are :mod:`recon.nerf.uniqueness`'s; this module sizes them per profile, adds
the SVG plots and writes the lecture contract's ``summary.json`` (title, claim, headline,
figures; see :mod:`pipeline.stages.lecture`). Files written into the study folder::

    ghost_points.csv     B's pairwise and least-squares triangulations: closed form and from the images
    three_cameras.csv    per NeRF: steps, training and held-out display PSNR, density mass in balls of
                         one sphere radius around A, B, the purple and yellow ghosts, and elsewhere
    three_cameras.png    training images, held-out truth, each NeRF's renders and top-down density map
    nerf_masses.svg      those masses, in units of one true sphere's mass
    same_images.csv      two fields with identical training renders, per set of turntable rings
    same_images.png      the held-out renders and their difference
    same_images.svg      held-out display PSNR between the two fields against training views
    linear_rank.csv      rank of colour -> images against views, per fixed density
    linear_rank.svg      (and .png) that rank against the number of views
    summary.json         the front page, plus every figure of the three parts

Profiles: ``quick`` trains each NeRF a fixed 1000 steps (vanilla: 256 rays a step, some 170
passes over the three 64 x 8 images' 1536 rays; the same steps on a loaded machine, only slower) and
runs the other two parts at full size (measured on a 4-8x loaded machine with the NeRFs stopped
early by a wall-clock cap since removed: 1909 s wall, 784 CPU-s); ``full`` trains each up to
:data:`recon.nerf.uniqueness.STUDY_STEPS` within 5 minutes (the issue's 10 minutes for both) and
uses the finer grids. The environment variable
``LUMIGRAPH_UNIQUENESS_SIZE=tiny`` shrinks every part to seconds (a few NeRF steps, small
grids): for tests of the files and the exact claims only; the summary records the size used.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

from .lecture import size_name as lecture_size_name
from ..artifacts import write_json
from ..plot import Series, svg_plot, write_svg

__all__ = ["SIZE_ENV", "size_name", "run", "headline", "metrics"]

#: environment variable selecting the tests' ``tiny`` size instead of the profile's
SIZE_ENV = "LUMIGRAPH_UNIQUENESS_SIZE"


def size_name(profile: str) -> str:
    """The name of the size to run (a key of :data:`recon.nerf.uniqueness.STUDY_SIZES`): the
    profile's, or ``tiny`` when ``$LUMIGRAPH_UNIQUENESS_SIZE`` says so (any other value of it is
    refused: BadInput naming the variable)."""
    return lecture_size_name(profile, SIZE_ENV)


def run(out: Path, profile: str = "quick", seed: int = 0, quiet: bool = False) -> dict:
    """Fill ``out`` (the lecture dispatch's temporary folder) with the study (module docstring);
    returns the manifest's metrics (flat numbers)."""
    name = size_name(profile)
    from recon.nerf import uniqueness as u  # torch: loaded only when the study runs

    from ..progress import progress_bar

    out = Path(out)
    t0 = time.perf_counter()
    size = u.STUDY_SIZES[name]
    with progress_bar(quiet) as bar:
        task = bar.add_task("uniqueness", total=3)

        def on_part(label: str) -> None:
            if on_part.started:
                bar.advance(task)
            on_part.started = True
            bar.update(task, info=label)
        on_part.started = False
        parts = u.run_parts(out, size, seed, on_part)
        bar.advance(task)
    part1, part2, part3 = parts["three_cameras"], parts["same_images"], parts["linear"]
    write_svg(out / "nerf_masses.svg", masses_plot(part1))
    write_svg(out / "same_images.svg", same_images_plot(part2["rows"]))
    write_svg(out / "linear_rank.svg", rank_plot(part3["rows"]))
    summary = {"study": "uniqueness", "title": "Is a NeRF unique?", "claim": CLAIM,
               "headline": headline(u.ThreeCameraScene(), part1, part2, part3), "figures": FIGURES,
               "profile": profile, "size": size.name, "seed": seed,
               "nerf_steps": size.nerf_steps, "nerf_seconds_cap": size.nerf_seconds, **parts,
               "wall_s": round(time.perf_counter() - t0, 2)}
    write_json(out / "summary.json", summary)
    return metrics(part1, part2, part3, size.name)


CLAIM = ("Images do not determine a radiance field. Three orthographic cameras, one of them slightly "
         "mis-calibrated, triangulate a point into ghosts, and a NeRF trained on their images puts "
         "density where the rays agree, not where the point is; density behind opaque surfaces and colour "
         "where transmittance is zero change no training pixel (bit for bit) but change a held-out view; "
         "with the density fixed, colour -> images is linear and injective for constant density once a "
         "few views are taken, and loses rank wherever the density hides cells.")

FIGURES = ["three_cameras.png", "nerf_masses.svg", "same_images.png", "same_images.svg", "linear_rank.svg"]


def _num(v: float, digits: int = 4) -> float:
    return round(float(v), digits)


def headline(scene, part1: dict, part2: dict, part3: dict) -> list[dict]:
    """The summary's headline rows ({figure, value, unit, note}) from the three parts' figures."""
    ghosts = part1["ghost_points"]
    dist = lambda a, b: math.dist(ghosts[a], ghosts[b])  # noqa: E731
    exact = part1["exact_sphere_mass"]
    rows = [
        {"figure": "ghost triangle side (purple-yellow)", "value": _num(dist("purple", "yellow")), "unit": "world units",
         "note": f"closed form for a {scene.red_error_deg:g} deg red-camera error; sphere radius {scene.radius:g}"},
        {"figure": "least-squares point's distance from B", "value": _num(dist("least_squares", "blue_green")),
         "unit": "world units", "note": "all three cameras: lands inside the triangle, on no sphere"},
        {"figure": "blob matching error", "value": _num(part1["blob_centroid_error_px"]), "unit": "px",
         "note": "colour centroids in the images against the exact projections"},
    ]
    for name, m in part1["models"].items():
        ghost = m["mass_purple"] + m["mass_yellow"]
        rows += [
            {"figure": f"{name} NeRF: density mass at A, B, ghosts (purple + yellow)",
             "value": f"{m['mass_A'] / exact:.2f} / {m['mass_B'] / exact:.2f} / {ghost / exact:.2f}",
             "unit": "true sphere masses",
             "note": f"{m['steps']} steps; the truth is 1 / 1 / 0; elsewhere {m['mass_elsewhere'] / exact:.2f}"},
            {"figure": f"{name} NeRF: display PSNR, training views / held-out 4th camera",
             "value": f"{m['train_display_psnr']:.1f} / {m['held_out_display_psnr']:.1f}", "unit": "dB",
             "note": f"an all-black held-out image scores {part1['held_out_black_display_psnr']:.1f} dB"},
        ]
    srows = part2["rows"]
    rows += [
        {"figure": "two fields: largest training-pixel difference", "value": max(r["train_max_abs_diff"] for r in srows),
         "unit": "linear radiance", "note": "bitwise identical training renders in every ring set: "
         + ("yes" if all(r["train_bitwise_identical"] for r in srows) else "NO")},
        {"figure": "two fields: held-out display PSNR as rings are added",
         "value": " -> ".join(f"{r['held_out_display_psnr']:.1f}" for r in srows), "unit": "dB",
         "note": ", ".join(f"{r['training_set']} ({r['views']} views)" for r in srows)},
    ]
    lrows = part3["rows"]
    cells = lrows[0]["cells"]
    for fname in dict.fromkeys(r["field"] for r in lrows):
        fr = [r for r in lrows if r["field"] == fname]
        full = [r["views"] for r in fr if r["rank"] == cells]
        if fname.startswith("opaque"):
            hit = [r["views"] for r in fr if r["null_dim"] == r["predicted_null_dim"]]
            rows.append({"figure": f"linear map, {fname}: null space", "value": fr[-1]["null_dim"], "unit": "cells",
                         "note": f"predicted {fr[-1]['predicted_null_dim']} (empty + occluded cells); reached from "
                         + (f"{hit[0]} views" if hit else "no view count tried")})
        else:
            rows.append({"figure": f"linear map, {fname}: views for full rank", "value": full[0] if full else "never",
                         "unit": "views", "note": f"{cells} cells; rank at the most views {fr[-1]['rank']}, "
                         f"at 1e-3 relative {fr[-1]['rank_rtol_1e-3']}"})
    return rows


def metrics(part1: dict, part2: dict, part3: dict, size: str) -> dict:
    """Flat numbers for the manifest."""
    exact = part1["exact_sphere_mass"]
    out = {"ghost_triangle_side": _num(math.dist(part1["ghost_points"]["purple"], part1["ghost_points"]["yellow"]), 6)}
    for name, m in part1["models"].items():
        for k in ("A", "B", "purple", "yellow", "elsewhere"):
            out[f"{name}_mass_{k}_spheres"] = _num(m[f"mass_{k}"] / exact)
        out[f"{name}_steps"] = m["steps"]
        out[f"{name}_held_out_display_psnr"] = m["held_out_display_psnr"]
    out["same_images_train_max_abs_diff"] = max(r["train_max_abs_diff"] for r in part2["rows"])
    out["same_images_held_out_psnr_min"] = min(r["held_out_display_psnr"] for r in part2["rows"])
    out["same_images_held_out_psnr_max"] = max(r["held_out_display_psnr"] for r in part2["rows"])
    out["size"] = size
    return out


def masses_plot(part1: dict) -> str:
    """SVG: each NeRF's density mass per region (A, B, purple, yellow, elsewhere) in true sphere masses."""
    exact = part1["exact_sphere_mass"]
    regions = ["A", "B", "purple", "yellow", "elsewhere"]
    series = [Series(name, list(range(len(regions))), [m[f"mass_{k}"] / exact for k in regions], regions,
                     line=True, annotate=i == 0) for i, (name, m) in enumerate(part1["models"].items())]
    series.append(Series("truth", list(range(len(regions))), [1.0, 1.0, 0.0, 0.0, 0.0], regions, colour="#000000",
                         line=True, dashed=True))
    return svg_plot(series, "region: 0 A, 1 B, 2 purple ghost, 3 yellow ghost, 4 elsewhere",
                    "density mass (true sphere masses)", "where the NeRFs put density (three cameras)")


def same_images_plot(rows: list[dict]) -> str:
    """SVG: held-out display PSNR between the two identical-training-render fields against views."""
    return svg_plot([Series("held-out PSNR, field 2 vs field 1", [r["views"] for r in rows],
                            [r["held_out_display_psnr"] for r in rows], [r["training_set"] for r in rows],
                            line=True, annotate=True)],
                    "training views (turntable rings)", "held-out display PSNR (dB)",
                    "same training images, different held-out view")


def rank_plot(rows: list[dict]) -> str:
    """SVG: rank of colour -> images against the number of views, one line per fixed density."""
    series = []
    for fname in dict.fromkeys(r["field"] for r in rows):
        fr = [r for r in rows if r["field"] == fname]
        series.append(Series(fname, [r["views"] for r in fr], [r["rank"] for r in fr], line=True))
    cells = rows[0]["cells"]
    return svg_plot(series, "orthographic views", "rank", f"rank of colour -> images ({cells} cells)",
                    hlines=[(cells, f"full rank {cells}")])
