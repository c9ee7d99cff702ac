"""Structure from motion with COLMAP (pycolmap): SIFT features, matching, incremental mapping, CPU.

Two modes (:class:`ColmapConfig.known_intrinsics`):

* known intrinsics: one PINHOLE camera with the given ``fx fy cx cy``; bundle adjustment keeps
  focal length and principal point fixed, only poses and points move;
* self-calibration: one SIMPLE_RADIAL camera (``f cx cy k1``, COLMAP's default model) started
  from COLMAP's default focal guess (1.2 x the larger image side), focal and k1 refined; the
  principal point stays at the image centre unless ``refine_principal_point``. (An OPENCV
  camera, 4 distortion terms free, registered only 2 of 56 default-scene views.)

COLMAP and we put pixel centres at +0.5, so intrinsics pass to and from COLMAP unchanged.
Images can be resized by ``image_scale`` first (intrinsics scaled with them); the returned
cameras always have the input resolution's intrinsics. Poses come back in COLMAP's arbitrary
similarity frame: align them with :func:`recon.poses.align.umeyama` before comparing.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time
from contextlib import contextmanager
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from render.camera import Camera, Intrinsics

from .pairing import ViewOrder, capture_order_pairs

__all__ = ["ColmapConfig", "ColmapResult", "ReconstructionError", "estimate_colmap"]


class ReconstructionError(ValueError):
    """Structure from motion produced no usable model (one line: what failed)."""


@dataclass(frozen=True)
class ColmapConfig:
    """Options that matter for accuracy and time; the defaults give the figures in the report.

    known_intrinsics: PINHOLE with fixed calibration (True) or self-calibrated SIMPLE_RADIAL (False).
    image_scale: resize factor applied before feature extraction (1 = capture resolution).
    max_features: SIFT features per image.
    matcher: ``exhaustive`` (every pair), ``capture_order`` (the shooting order's pairs,
        :mod:`recon.poses.pairing`: neighbours within each ring with loop closure, same-phase
        links between rings; needs the order), ``sequential`` (neighbours in name order, loop
        detection off), or ``auto``: exhaustive up to ``exhaustive_max_images`` images, then
        capture_order when the order is known, else sequential.
    sequential_overlap: neighbours matched ahead per image by the sequential and capture-order
        matchers (the capture-order window).
    link_window: half-width of the capture-order links between sequences (frames either side of
        the same phase).
    mapper: ``incremental`` (COLMAP's incremental mapper), ``global`` (COLMAP 4's global mapper,
        GLOMAP: rotation averaging, global positioning, one bundle adjustment), or ``auto``:
        global from ``global_min_images`` images on.

    Why ``auto`` switches at 150 images (measured; rotation error mean after alignment):

    * 20 views, 400x300 (tests/recon/conftest.py's small capture; ``lumigraph poses CAPTURE
      --method colmap --matcher M --mapper P``): exhaustive + incremental 190 pairs, 0.113 deg;
      capture_order + incremental 110 pairs, 0.119 deg; capture_order + global 110 pairs,
      0.131 deg; all 20/20.
    * 56 views, the default scene (issue 21's figures, same stage): exhaustive + incremental
      1540 pairs, 0.018 deg; the global mapper on the same matches 0.019 deg, mapping 9 s
      instead of 14; capture_order + incremental 700 pairs, 0.0196 deg, 56/56
      (``python -m bench.bench_poses --views 56 --configs capture_order+incremental``).
    * 224 views, rings of 96 + 96 and 32 held out (``python -m bench.bench_poses --views 224
      --configs capture_order+global``): 3168 pairs (exhaustive: 24,976), 224/224, 0.024 deg
      (issue 21: name-order sequential + incremental 0.029 deg).
    * 1000 views (issue 21): the incremental mapper on 8,977 sequential pairs was stopped after
      77 minutes, still mapping; the global mapper on the same matches registered 1000/1000 at
      0.029 deg in 11.3 minutes.

    Below 150 views exhaustive matching and the incremental mapper stay the most accurate at a
    cost that is still small; above, pairs must grow linearly and only the global mapper
    finishes. ``bench/results/bench_poses_scale.json`` holds the stage's own figures at 56 / 224
    / 1000 views.
    final_ba_iterations: iterations of one extra global bundle adjustment with tight tolerances
        after mapping (0 skips it).
    seed: COLMAP's RANSAC seeds (two-view verification, mapper, triangulation) and its global PRNG.
    num_threads: threads of feature extraction and matching (-1 = all cores); the result does not
        depend on it. COLMAP numbers images in the order its extraction threads finish, and the
        mapper breaks ties by image id, so two runs registered the views in different orders
        (and once folded the model): the images are imported in name order before extraction, so
        their ids are fixed. Incremental mapping and bundle adjustment run on one thread, since
        Ceres sums residuals in scheduling order on more.
    """

    known_intrinsics: bool = True
    image_scale: float = 1.0
    max_features: int = 8192
    matcher: Literal["auto", "exhaustive", "capture_order", "sequential"] = "auto"
    exhaustive_max_images: int = 150
    sequential_overlap: int = 12
    link_window: int = 1
    mapper: Literal["auto", "incremental", "global"] = "auto"
    global_min_images: int = 150
    refine_principal_point: bool = False
    final_ba_iterations: int = 100
    seed: int = 0
    num_threads: int = -1

    def __post_init__(self) -> None:
        if not 0.05 <= self.image_scale <= 4.0:
            raise ValueError(f"image_scale must be in [0.05, 4], got {self.image_scale}")
        if self.max_features < 64:
            raise ValueError(f"max_features must be >= 64, got {self.max_features}")
        if self.matcher not in ("auto", "exhaustive", "capture_order", "sequential"):
            raise ValueError(f"matcher must be auto, exhaustive, capture_order or sequential, got {self.matcher!r}")
        if self.mapper not in ("auto", "incremental", "global"):
            raise ValueError(f"mapper must be auto, incremental or global, got {self.mapper!r}")
        if self.sequential_overlap < 1 or self.link_window < 0:
            raise ValueError("sequential_overlap must be >= 1 and link_window >= 0")


@dataclass
class ColmapResult:
    """Registered cameras (input-resolution intrinsics, COLMAP's frame, camera-to-world OpenCV
    axes, named by image stem), the names COLMAP could not register, and model statistics.

    points: (P, 3) float64 sparse points in COLMAP's frame. reprojection_error_px is the mean
    over all observations, in input-resolution pixels. matcher/mapper: what ran (``auto``
    resolved); pairs: image pairs matched; times_s: wall seconds of ``extract``, ``match``,
    ``map`` (the mapper and the final bundle adjustment).
    """

    cameras: list[Camera]
    unregistered: list[str]
    reprojection_error_px: float
    points: np.ndarray
    num_models: int
    mean_track_length: float
    reconstruction: object = field(repr=False)  # pycolmap.Reconstruction, in COLMAP's frame
    matcher: str = ""
    mapper: str = ""
    pairs: int = 0
    times_s: dict = field(default_factory=dict)


def _prepare_images(images: Mapping[str, Path], scale: float, folder: Path) -> list[str]:
    """Copy (scale 1) or resize (INTER_AREA down, INTER_CUBIC up) every image into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for stem, path in images.items():
        name = f"{stem}{Path(path).suffix.lower() or '.png'}"
        if scale == 1.0:
            shutil.copyfile(path, folder / name)
        else:
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise ReconstructionError(f"{path}: unreadable image")
            h, w = img.shape[:2]
            size = (int(round(w * scale)), int(round(h * scale)))  # as Intrinsics.scaled
            interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
            cv2.imwrite(str(folder / name), cv2.resize(img, size, interpolation=interp))
        names.append(name)
    return names


def _image_size(path: Path) -> tuple[int, int]:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ReconstructionError(f"{path}: unreadable image")
    return img.shape[1], img.shape[0]


def _camera_from_colmap(cam, scale_back: float, width: int, height: int) -> Intrinsics:
    """A pycolmap PINHOLE/SIMPLE_RADIAL/OPENCV camera -> our Intrinsics at the input resolution."""
    p = np.asarray(cam.params, dtype=np.float64)
    if cam.model_name == "SIMPLE_RADIAL":
        f, cx, cy, k1 = p
        fx = fy = f
        dist = (k1, 0.0, 0.0, 0.0, 0.0)
    elif cam.model_name == "PINHOLE":
        fx, fy, cx, cy = p
        dist = (0.0,) * 5
    elif cam.model_name == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
        dist = (k1, k2, p1, p2, 0.0)
    else:  # pragma: no cover - we only create these two models
        raise ReconstructionError(f"unexpected COLMAP camera model {cam.model_name}")
    return Intrinsics(width, height, fx * scale_back, fy * scale_back, cx * scale_back, cy * scale_back, dist)


def _diagnose(db: Path) -> str:
    """Why the mapper found nothing, from the feature database: too few features, or matched
    pairs that show no camera motion (COLMAP's WATERMARK / PANORAMIC / PLANAR_OR_PANORAMIC
    two-view geometries: content that stays put in the image, e.g. a static background)."""
    import pycolmap

    database = pycolmap.Database.open(str(db))
    try:
        n_img = max(database.num_images(), 1)
        per_image = database.num_keypoints() / n_img
        _, geoms = database.read_two_view_geometries()
    finally:
        database.close()
    cfg = pycolmap.TwoViewGeometryConfiguration
    static = {int(cfg.WATERMARK), int(cfg.PANORAMIC), int(cfg.PLANAR_OR_PANORAMIC)}
    moving = {int(cfg.CALIBRATED), int(cfg.UNCALIBRATED), int(cfg.PLANAR)}
    n_static = sum(int(g.config) in static for g in geoms)
    n_moving = sum(int(g.config) in moving for g in geoms)
    if per_image < 100 or n_static + n_moving == 0:
        return f"{per_image:.0f} features per image, {n_moving} verified pairs (textureless subject?)"
    if n_static > n_moving:
        return (f"{n_static} of {n_static + n_moving} matched pairs show no camera motion "
                "(static content in view: a background that does not turn with the object?)")
    return f"{n_moving} verified pairs but no initial pair could be triangulated"


def estimate_colmap(images: Mapping[str, Path], intrinsics: Intrinsics | None, workdir: Path,
                    config: ColmapConfig = ColmapConfig(), order: Sequence[ViewOrder] | None = None) -> ColmapResult:
    """Run feature extraction, matching and mapping on ``images``.

    images: view name (file stem) -> image file (8-bit PNG/JPEG), all one size.
    intrinsics: the true calibration at the images' resolution; required when
        ``config.known_intrinsics``, else ignored. workdir: an empty scratch folder (database,
        resized images, raw models). order: the views' shooting order (the capture's
        ``capture_order.json``), needed by the capture_order matcher; views it lacks are refused.
        Returns a :class:`ColmapResult` for the largest model.
    Raises :class:`ReconstructionError` when COLMAP builds no model (e.g. a textureless
    object: no features survive matching, the mapper returns nothing).
    """
    import pycolmap

    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = max(level, 2)  # COLMAP's INFO/WARNING chatter off; errors stay
    try:
        return _estimate(images, intrinsics, workdir, config, order)
    finally:
        pycolmap.logging.minloglevel = level


def resolve_matcher(config: ColmapConfig, n_images: int, have_order: bool) -> str:
    """The matcher ``auto`` stands for (ColmapConfig.matcher)."""
    if config.matcher != "auto":
        return config.matcher
    if n_images <= config.exhaustive_max_images:
        return "exhaustive"
    return "capture_order" if have_order else "sequential"


def resolve_mapper(config: ColmapConfig, n_images: int) -> str:
    """The mapper ``auto`` stands for (ColmapConfig.mapper)."""
    if config.mapper != "auto":
        return config.mapper
    return "global" if n_images >= config.global_min_images else "incremental"


def _estimate(images: Mapping[str, Path], intrinsics: Intrinsics | None, workdir: Path,
              config: ColmapConfig, order: Sequence[ViewOrder] | None) -> ColmapResult:
    import pycolmap

    if len(images) < 2:
        raise ReconstructionError(f"structure from motion needs at least 2 images, got {len(images)}")
    if len({hashlib.sha256(Path(p).read_bytes()).digest() for p in images.values()}) == 1:
        raise ReconstructionError(f"all {len(images)} images are identical: no camera motion to reconstruct from")
    if config.known_intrinsics and intrinsics is None:
        raise ValueError("known_intrinsics needs the intrinsics")
    matcher = resolve_matcher(config, len(images), order is not None)
    mapper = resolve_mapper(config, len(images))
    if matcher == "capture_order":
        if order is None:
            raise ValueError("the capture_order matcher needs the capture order")
        known = {v.name for v in order}
        missing = [n for n in images if n not in known]
        if missing:
            raise ValueError(f"capture order lacks {len(missing)} view(s), e.g. {missing[0]!r}")
    workdir = Path(workdir)
    image_dir, db = workdir / "images", workdir / "database.db"
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    first = next(iter(images.values()))
    width, height = _image_size(Path(first))
    names = _prepare_images(images, config.image_scale, image_dir)
    sw, sh = _image_size(image_dir / names[0])
    scale_back = width / sw

    reader = pycolmap.ImageReaderOptions()
    if config.known_intrinsics:
        k = intrinsics.scaled(sw / width)
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(repr(float(v)) for v in (k.fx, k.fy, k.cx, k.cy))
    else:
        reader.camera_model = "SIMPLE_RADIAL"
    pycolmap.set_random_seed(config.seed)
    # image ids in name order, whatever order the extraction threads finish in (see ColmapConfig)
    pycolmap.Database.open(db).close()  # import_images needs the database file to exist
    pycolmap.import_images(db, image_dir, camera_mode=pycolmap.CameraMode.SINGLE, image_names=names, options=reader)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = config.num_threads
    extraction.sift.max_num_features = config.max_features
    extraction.use_gpu = False
    pycolmap.extract_features(db, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)

    times["extract"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.num_threads
    matching.use_gpu = False
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = config.seed
    if matcher == "capture_order":
        suffix = {Path(n).stem: Path(n).suffix for n in names}
        wanted = [v for v in order if v.name in suffix]
        pairs = capture_order_pairs(wanted, config.sequential_overlap, config.link_window)
        pair_file = workdir / "pairs.txt"
        with open(pair_file, "w") as f:
            f.writelines(f"{a}{suffix[a]} {b}{suffix[b]}\n" for a, b in pairs)
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = str(pair_file)
        pycolmap.match_image_pairs(db, matching_options=matching, pairing_options=pairing,
                                   verification_options=verification, device=pycolmap.Device.cpu)
    elif matcher == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = config.sequential_overlap
        pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_exhaustive(db, matching_options=matching, verification_options=verification,
                                  device=pycolmap.Device.cpu)
    if matcher == "capture_order":
        n_pairs = len(pairs)
    elif matcher == "exhaustive":
        n_pairs = len(names) * (len(names) - 1) // 2
    else:
        database = pycolmap.Database.open(str(db))
        try:
            n_pairs = int(database.num_matched_image_pairs())
        finally:
            database.close()
    times["match"] = time.perf_counter() - t0
    t0 = time.perf_counter()

    fixed = config.known_intrinsics
    (workdir / "sparse").mkdir(exist_ok=True)
    if mapper == "global":
        with _info_lines_dropped(workdir / "mapper.log"):
            models = pycolmap.global_mapping(db, image_dir, workdir / "sparse",
                                             options=_global_options(config, len(names)))
    else:
        opts = pycolmap.IncrementalPipelineOptions()
        opts.random_seed = config.seed
        opts.mapper.random_seed = config.seed
        opts.triangulation.random_seed = config.seed
        opts.num_threads = 1  # scheduling-independent (see ColmapConfig)
        opts.mapper.num_threads = 1
        opts.min_model_size = min(10, len(names))
        opts.ba_refine_focal_length = not fixed
        opts.ba_refine_extra_params = not fixed
        opts.ba_refine_principal_point = (not fixed) and config.refine_principal_point
        opts.mapper.abs_pose_refine_focal_length = not fixed
        opts.mapper.abs_pose_refine_extra_params = not fixed
        models = pycolmap.incremental_mapping(db, image_dir, workdir / "sparse", options=opts)
    models = {i: m for i, m in (models or {}).items() if m.num_reg_images() > 0}
    if not models:
        raise ReconstructionError(f"COLMAP built no model from {len(names)} images: {_diagnose(db)}")
    rec = max(models.values(), key=lambda m: m.num_reg_images())

    if config.final_ba_iterations > 0:
        ba = pycolmap.BundleAdjustmentOptions()
        ba.refine_focal_length = not fixed
        ba.refine_extra_params = not fixed
        ba.refine_principal_point = (not fixed) and config.refine_principal_point
        ba.print_summary = False
        ba.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
        so = ba.ceres.solver_options
        so.max_num_iterations = config.final_ba_iterations
        so.function_tolerance, so.gradient_tolerance, so.parameter_tolerance = 1e-12, 1e-12, 1e-12
        so.num_threads = 1
        with _info_lines_dropped(workdir / "ba.log"):
            pycolmap.bundle_adjustment(rec, ba)

    times["map"] = time.perf_counter() - t0
    cameras, registered = [], set()
    for img in rec.images.values():
        if not img.has_pose:
            continue
        stem = Path(img.name).stem
        w2c = np.eye(4)
        w2c[:3, :] = np.asarray(img.cam_from_world().matrix(), dtype=np.float64)
        c2w = np.eye(4)
        c2w[:3, :3] = w2c[:3, :3].T
        c2w[:3, 3] = -w2c[:3, :3].T @ w2c[:3, 3]
        cameras.append(Camera(_camera_from_colmap(img.camera, scale_back, width, height), c2w, stem))
        registered.add(stem)
    order = {n: i for i, n in enumerate(images)}
    cameras.sort(key=lambda c: order[c.name])
    points = np.array([p.xyz for p in rec.points3D.values()], dtype=np.float64).reshape(-1, 3)
    err = float(rec.compute_mean_reprojection_error()) * scale_back if len(points) else 0.0
    return ColmapResult(cameras=cameras, unregistered=[n for n in images if n not in registered],
                        reprojection_error_px=err if np.isfinite(err) else 0.0, points=points,
                        num_models=len(models), mean_track_length=float(rec.compute_mean_track_length())
                        if len(points) else 0.0, reconstruction=rec, matcher=matcher, mapper=mapper,
                        pairs=n_pairs, times_s={k: round(v, 3) for k, v in times.items()})


@contextmanager
def _info_lines_dropped(log: Path):
    """Run the block with file descriptor 2 sent to ``log``, then pass on all but glog's INFO
    lines. pycolmap.bundle_adjustment logs its heading and timer at INFO whatever
    ``pycolmap.logging.minloglevel`` says, and a CLI's bad-input exit must print one line."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(log, "wb") as f:
            os.dup2(f.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)
    for line in log.read_text(errors="replace").splitlines():
        if line and not line.startswith("I"):
            print(line, file=sys.stderr)


def _global_options(config: ColmapConfig, n_images: int):
    """COLMAP's global mapper (GLOMAP) seeded, on one thread (scheduling-independent, as the
    incremental mapper), intrinsics refined only when self-calibrating."""
    import pycolmap

    opts = pycolmap.GlobalPipelineOptions()
    opts.random_seed = config.seed
    opts.num_threads = 1
    opts.min_model_size = min(10, n_images)
    m = opts.mapper
    m.random_seed = config.seed
    m.num_threads = 1
    m.rotation_averaging.random_seed = config.seed
    m.global_positioning.random_seed = config.seed
    m.global_positioning.use_gpu = False
    fixed = config.known_intrinsics
    ba = m.bundle_adjustment
    ba.refine_focal_length = not fixed
    ba.refine_extra_params = not fixed
    ba.refine_principal_point = (not fixed) and config.refine_principal_point
    ba.ceres.use_gpu = False
    ba.ceres.solver_options.num_threads = 1
    return opts
