"""Pose accuracy versus time: method x image scale x feature count, and COLMAP's cost growth with
the number of views, one command.

    .venv/bin/python -m bench.bench_poses [--capture DIR] [--scales 0.5,1] [--features 1024,4096,8192]
    .venv/bin/python -m bench.bench_poses --views 56,224,1000 [--configs auto,capture_order+incremental]

Study (``--views`` empty): without ``--capture`` the default scene is captured into a temporary
folder first. Writes ``bench/results/bench_poses.csv`` (one row per cell) and
``bench/results/bench_poses.json`` (the rows plus each cell's time as a ratio to the ChArUco
full-scale baseline of the same run), and prints the table. Each cell runs once (COLMAP cells
take tens of seconds on 2 cores).

Lens (``--lens self,charuco``): ``scenes/real_lens.yaml`` (the default scene through a distorting
lens, principal point off centre, noise, vignetting; 56 views at 1280x960) captured once, then
posed by the stage with each calibration: ``self`` (COLMAP self-calibration, ``--camera-model
auto``; ``self:OPENCV`` names a model), ``charuco`` (cv2.calibrateCamera on the capture's
calibration sequence, 41 views of the board alone, held fixed) or ``auto`` (``--self-calibrate``'s
default: the sequence's lens when it fits within 0.2 px, else ``self``). Writes
``bench/results/bench_poses_lens.json``: per run focal / principal point / projection errors
against the truth, rotation error, model chosen, times, load average.

Scale (``--views``, the default 56,224,1000): the default scene at 1280x960 with the layouts of
:data:`LAYOUTS` (56: its own rings of 24 + 24 and 8 held out; 224: 96 + 96 and 32; 1000: three
train rings of 320 at 20, 35 and 50 deg and 40 held out), captured, then posed by the ``poses``
stage (COLMAP, known intrinsics) with each of ``--configs`` (``auto`` = the stage's defaults, or
``MATCHER+MAPPER[+oOCTAVE]``, :func:`colmap_config`). Writes ``bench/results/bench_poses_scale.json``: per run the extract /
match / map seconds (wall, and CPU seconds of the stage's threads: on the shared machine the
wall time follows the load, the CPU time much less), the extractor, pairs, registered views and
rotation error, with the 1-minute load
average before and after (the machine is shared: times are only comparable within a run), and
``growth``: seconds per view and the exponent of time against views between consecutive counts
(1 = linear). The rows of the previous run are set aside as ``earlier_rows`` (other code, other
load), or with ``--add`` kept beside this run's (a run continued: ``--views 224 --add`` after
``--views 56``).
"""
from __future__ import annotations

import argparse
import copy
import csv
import json
import os
import tempfile
import time
from pathlib import Path

from bench.common import RESULTS_DIR, write_result


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_poses", description=__doc__.splitlines()[0],
                                 allow_abbrev=False)
    ap.add_argument("--capture", type=Path, default=None)
    ap.add_argument("--scales", default="0.5,1")
    ap.add_argument("--features", default="1024,4096,8192")
    ap.add_argument("--methods", default="charuco,colmap")
    ap.add_argument("--views", default="56,224,1000", help="scale benchmark view counts ('' runs the study)")
    ap.add_argument("--configs", default="auto", help="scale benchmark: auto or MATCHER+MAPPER, comma-separated")
    ap.add_argument("--keep", type=Path, default=None, help="scale benchmark: keep the captures under this folder")
    ap.add_argument("--add", action="store_true", help="scale benchmark: add this run's rows to the saved ones "
                                                       "(same code, e.g. 224 views after 56) instead of setting "
                                                       "them aside as earlier rows")
    ap.add_argument("--lens", default="", help="lens benchmark: comma-separated calibrations (self, charuco, "
                                               "self:MODEL) on scenes/real_lens.yaml; runs instead of the others")
    a = ap.parse_args(argv)
    if a.lens:
        return lens_benchmark(a.lens.split(","), a.keep)
    if a.views:
        return scale_benchmark([int(v) for v in a.views.split(",")], a.configs.split(","), a.keep, a.add)
    from pipeline.stages.poses import load_capture
    from recon.poses.study import STUDY_COLUMNS, pose_study

    with tempfile.TemporaryDirectory(prefix="bench-poses-") as tmp:
        cap_dir = a.capture
        if cap_dir is None:
            from pipeline.cli import main as cli

            cap_dir = Path(tmp) / "capture"
            if cli(["capture", "turntable", "--out", str(cap_dir), "--quiet"]) != 0:
                raise SystemExit("capture failed")
        cap = load_capture(cap_dir)
        rows = pose_study(cap.images, cap.cameras, cap.targets, [float(s) for s in a.scales.split(",")],
                          [int(f) for f in a.features.split(",")], a.methods.split(","))
    base = next((r["wall_time_s"] for r in rows if r["method"] == "charuco" and r["image_scale"] == 1.0), None)
    for r in rows:
        r["time_ratio_to_charuco_full"] = round(r["wall_time_s"] / base, 2) if base else None
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    cols = list(STUDY_COLUMNS) + ["time_ratio_to_charuco_full"]
    with open(RESULTS_DIR / "bench_poses.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    print(f"{'method':8} {'scale':>5} {'size':>9} {'features':>8} {'time s':>7} {'reg':>6} {'rot mean':>9} {'rot max':>8}")
    for r in rows:
        rot = "-" if r["rotation_error_deg_mean"] is None else f"{r['rotation_error_deg_mean']:.4f}"
        rmax = "-" if r["rotation_error_deg_max"] is None else f"{r['rotation_error_deg_max']:.3f}"
        print(f"{r['method']:8} {r['image_scale']:>5} {r['width']:>4}x{r['height']:<4} {str(r['max_features'] or '-'):>8} "
              f"{r['wall_time_s']:>7.1f} {r['registered']:>3}/{r['views']:<2} {rot:>9} {rmax:>8}")
    write_result("bench_poses", {"capture": str(a.capture or "default scene, fresh capture"), "rows": rows,
                                 "note": "one run per cell; times include image I/O; shared 2-core machine"})


#: view count -> (train rings as (elevation deg, count), held-out ring (elevation deg, count))
LAYOUTS = {56: ([(25, 24), (50, 24)], (37.5, 8)), 224: ([(25, 96), (50, 96)], (37.5, 32)),
           1000: ([(20, 320), (35, 320), (50, 320)], (27.5, 40))}


def scaled_turntable(views: int) -> dict:
    """The default scene's spec with the camera layout of ``LAYOUTS[views]`` (same distance,
    target and size; each ring offset by half a step from the previous one, as the default's)."""
    import yaml

    from rig.spec import SCENES_DIR

    spec = yaml.safe_load((SCENES_DIR / "turntable.yaml").read_text())
    if views == 56:  # the default scene as it is
        return spec
    train, (test_el, test_n) = LAYOUTS[views]
    ring = {"distance": 1.1, "target": [0, 0, 0.05]}
    spec["name"] = f"turntable_{views}"
    spec["cameras"]["train"] = [{"ring": {**ring, "elevation_deg": el, "count": n,
                                          "azimuth_offset_deg": i * 180 / n}} for i, (el, n) in enumerate(train)]
    spec["cameras"]["test"] = [{"ring": {**ring, "elevation_deg": test_el, "count": test_n,
                                         "azimuth_offset_deg": 90 / test_n}}]
    return copy.deepcopy(spec)


def scale_benchmark(view_counts: list[int], configs: list[str], keep: Path | None, add: bool = False) -> None:
    import yaml

    from pipeline.artifacts import BadInput
    from pipeline.cli import main as cli
    from pipeline.stages.poses import PosesConfig, run_poses

    rows = []
    # rows of an earlier run (other code, other load) are kept apart, never mixed into ``growth``,
    # unless ``add``: then they stay rows (a run continued, e.g. 224 views after 56)
    previous = RESULTS_DIR / "bench_poses_scale.json"
    earlier = []
    if previous.is_file():
        old = json.loads(previous.read_text())
        earlier = old.get("earlier_rows", [])
        kept = [{**r, "run_time": r.get("run_time", old.get("time"))} for r in old.get("rows", [])]
        if add:
            rows = kept
        else:
            earlier += kept
    with tempfile.TemporaryDirectory(prefix="bench-poses-scale-") as tmp:
        root = keep or Path(tmp)
        for views in view_counts:
            folder = root / f"views_{views}"
            folder.mkdir(parents=True, exist_ok=True)
            scene = folder / "scene.yaml"
            scene.write_text(yaml.safe_dump(scaled_turntable(views), sort_keys=False))
            t0 = time.perf_counter()
            if not (folder / "capture" / "manifest.json").is_file():
                if cli(["capture", str(scene), "--out", str(folder / "capture"), "--quiet"]) != 0:
                    raise SystemExit(f"capture of {views} views failed")
            capture_s = time.perf_counter() - t0
            for cfg_name in configs:
                cfg = PosesConfig(colmap=colmap_config(cfg_name))
                load_before = os.getloadavg()[0]
                t0 = time.perf_counter()
                try:
                    m = run_poses(folder / "capture", "colmap", folder / f"poses_{cfg_name}", cfg, quiet=True,
                                  overwrite=True)["metrics"]
                    reason = None
                except BadInput as exc:
                    m, reason = {}, str(exc)
                row = {"views": views, "config": cfg_name, "matcher": m.get("matcher"), "mapper": m.get("mapper"),
                       "pairs": m.get("pairs"), "extract_s": m.get("extract_time_s"), "match_s": m.get("match_time_s"),
                       "map_s": m.get("map_time_s"), "refine_s": m.get("refine_time_s"),
                       "extract_cpu_s": m.get("extract_cpu_time_s"), "match_cpu_s": m.get("match_cpu_time_s"),
                       "map_cpu_s": m.get("map_cpu_time_s"), "extractor": m.get("extractor"),
                       "board_corners": m.get("board_corners"), "corners_s": m.get("corners_time_s"),
                       "corners_cpu_s": m.get("corners_cpu_time_s"), "corner_tracks": m.get("corner_tracks"),
                       "corner_observations": m.get("corner_observations"),
                       "first_octave": m.get("first_octave"), "crop_box": _metrics_file(folder / f"poses_{cfg_name}").get("crop_box"),
                       "poses_wall_s": round(time.perf_counter() - t0, 1),
                       "capture_s": round(capture_s, 1), "registered": m.get("views_registered"),
                       "rotation_error_deg_mean": m.get("rotation_error_deg_mean"),
                       "rotation_error_deg_max": m.get("rotation_error_deg_max"),
                       "center_error_rel_max": m.get("center_error_rel_max"), "failure": reason,
                       "load_avg_1min_before": round(load_before, 2), "load_avg_1min_after": round(os.getloadavg()[0], 2)}
                rows.append(row)
                print(row, flush=True)
                write_result("bench_poses_scale", {"rows": rows, "growth": growth(rows), "earlier_rows": earlier,
                                                   "layouts": {str(k): v for k, v in LAYOUTS.items()},
                                                   "note": "one run per cell, poses stage wall time; 1280x960, "
                                                           "known intrinsics; shared 2-core machine (load average): "
                                                           "growth exponents divide out a load shared by the runs "
                                                           "compared, not a load that changed between them"})


#: ``colmap_config`` modifiers: token -> ColmapConfig field (the value parsed from what follows
#: the prefix, or the fixed value)
MODIFIERS = {"o": ("first_octave", int), "t": ("global_tracks_per_view", int), "ba": ("final_ba_iterations", int),
             "nocrop": ("crop_to_subject", False), "consecutive": ("pair_offsets", "consecutive"),
             "noretri": ("global_retriangulate", False), "cvsift": ("extractor", "opencv"),
             "colmapsift": ("extractor", "colmap"), "link": ("link_window", int), "w": ("sequential_overlap", int),
             "nocorners": ("board_corners", False), "feat": ("max_features", int),
             "scale": ("image_scale", float), "bar": ("global_ba_rounds", int)}


def _metrics_file(poses: Path) -> dict:
    """A poses folder's metrics.json (lists included, which the manifest's metrics drop), or {}."""
    path = poses / "metrics.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def colmap_config(name: str):
    """``auto`` (the stage's defaults) or ``[auto|MATCHER+MAPPER]`` followed by ``+``-separated
    modifiers (:data:`MODIFIERS`): ``oN`` SIFT's first octave N, ``tN`` the global mapper's tracks
    per view, ``baN`` final bundle adjustment iterations, ``nocrop`` the whole frame,
    ``consecutive`` capture-order steps 1..overlap, ``noretri`` no retriangulation, ``cvsift`` /
    ``colmapsift`` OpenCV's or COLMAP's SIFT, ``linkN`` the link window, ``wN`` the window,
    ``nocorners`` without the board's corners as tracks, ``featN`` N SIFT features per image,
    ``scaleS`` images resized by S before extraction, ``barN`` N rounds of the global mapper's
    bundle adjustment; e.g.
    ``capture_order+global+o0`` or ``auto+nocrop+consecutive`` -> ColmapConfig."""
    from recon.poses import ColmapConfig

    tokens = name.split("+")
    fields = {}
    if tokens[0] == "auto":
        modifiers = tokens[1:]
    else:
        fields.update(matcher=tokens[0], mapper=tokens[1])
        modifiers = tokens[2:]
    for token in modifiers:
        if token in MODIFIERS:
            key, value = MODIFIERS[token]
        else:
            prefix = next((p for p in sorted(MODIFIERS, key=len, reverse=True)
                           if callable(MODIFIERS[p][1]) and token.startswith(p)), None)
            if prefix is None:
                raise ValueError(f"unknown config modifier {token!r} in {name!r}")
            key, value = MODIFIERS[prefix][0], MODIFIERS[prefix][1](token.removeprefix(prefix))
        fields[key] = value
    return ColmapConfig(**fields)


def growth(rows: list[dict]) -> list[dict]:
    """How each step's time grows with the views, per config: seconds per view at every view count
    and the exponent ``b`` of ``time ~ views^b`` between consecutive counts (log ratio of times over
    log ratio of views; 1 = linear, 2 = quadratic), for extract, match, map and the stage's wall
    time and the steps' CPU seconds, with the pairs' exponent beside them (the matcher's own growth)."""
    import math

    out = []
    for cfg in dict.fromkeys(r["config"] for r in rows):
        latest = {r["views"]: r for r in rows if r["config"] == cfg and r["failure"] is None}  # a repeat replaces
        runs = sorted(latest.values(), key=lambda r: r["views"])
        for a, b in zip(runs, runs[1:]):
            entry = {"config": cfg, "views": [a["views"], b["views"]]}
            for key in ("pairs", "extract_s", "match_s", "map_s", "poses_wall_s", "extract_cpu_s", "match_cpu_s",
                        "map_cpu_s"):
                if a.get(key) and b.get(key):
                    entry[f"{key}_per_view"] = [round(a[key] / a["views"], 3), round(b[key] / b["views"], 3)]
                    entry[f"{key}_exponent"] = round(math.log(b[key] / a[key]) / math.log(b["views"] / a["views"]), 2)
            out.append(entry)
    return out


LENS_FIELDS = ("calibration", "camera_model", "camera_model_note", "views_registered", "focal_rel", "principal_point_px",
               "distortion_abs_max", "projection_error_px_max", "projection_error_px_view_max_mean",
               "projection_error_px_max_covered", "lens_projection_error_px_max", "lens_projection_error_px_max_covered",
               "observed_radius_rel", "rotation_error_deg_mean", "rotation_error_deg_max", "center_error_rel_mean",
               "reprojection_error_px", "lens_steps", "charuco_calibration_rms_px", "charuco_calibration_views",
               "calibration_requested", "charuco_calibration_source", "charuco_calibration_detected_rms_px",
               "charuco_calibration_corners", "charuco_calibration_radius_rel", "projection_error_px_mean",
               "lens_projection_error_px_mean",
               "extract_time_s", "match_time_s", "map_time_s", "wall_time_s")


def lens_benchmark(calibrations: list[str], keep: Path | None) -> None:
    from pipeline.artifacts import BadInput
    from pipeline.cli import main as cli
    from pipeline.stages.poses import PosesConfig, run_poses
    from recon.poses import ColmapConfig

    import json

    mine = []
    with tempfile.TemporaryDirectory(prefix="bench-poses-lens-") as tmp:
        root = keep or Path(tmp)
        capture = root / "real_lens" / "capture"
        if not (capture / "manifest.json").is_file():
            if cli(["capture", "real_lens", "--out", str(capture), "--quiet"]) != 0:
                raise SystemExit("capture of real_lens failed")
        for name in calibrations:
            calibration, _, model = name.partition(":")
            cfg = PosesConfig(colmap=ColmapConfig(known_intrinsics=calibration not in ("self", "auto"),
                                                  camera_model=model or "auto"),
                              calibration=calibration)
            folder = root / "real_lens" / f"poses_{name.replace(':', '_')}"
            load_before = os.getloadavg()[0]
            t0 = time.perf_counter()
            try:
                run_poses(capture, "colmap", folder, cfg, quiet=True, overwrite=True)
                reason = None
            except BadInput as exc:
                reason = str(exc)
            m = json.loads((folder / "metrics.json").read_text()) if (folder / "metrics.json").is_file() else {}
            mine.append({"config": name, **{k: m.get(k) for k in LENS_FIELDS}, "failure": reason,
                         "poses_wall_s": round(time.perf_counter() - t0, 1), "load_avg_1min_before": round(load_before, 2),
                         "load_avg_1min_after": round(os.getloadavg()[0], 2)})
            print(mine[-1], flush=True)
            # rows of other calibrations (an earlier or concurrent run) are kept, this run's replaced
            previous = RESULTS_DIR / "bench_poses_lens.json"
            others = [r for r in (json.loads(previous.read_text()).get("rows", []) if previous.is_file() else [])
                      if r.get("config") not in {r["config"] for r in mine}]
            write_result("bench_poses_lens", {"scene": "scenes/real_lens.yaml (56 views, 1280x960)", "rows": others + mine,
                                              "note": "one run per calibration, poses stage; shared 2-core machine "
                                                      "(load average)"})


if __name__ == "__main__":
    main()
