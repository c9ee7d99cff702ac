"""Camera exporters and importers: ``cameras.json``, COLMAP text model, ``transforms.json``.

Pure functions over lists of :class:`render.camera.Camera`. Every writer is atomic (a temporary
name renamed when complete, :func:`render.image_io.atomic_path`) and every format round-trips
(tested in ``tests/render/test_camera_io.py``).

Conventions on our side (see :mod:`render.camera`): poses are camera-to-world 4x4 float64 in
OpenCV axes (x right, y down, z forward); ``cx, cy`` put pixel (row i, col j)'s centre at
(j + 0.5, i + 0.5); distortion is OpenCV/Brown ``(k1, k2, p1, p2, k3)``. The world frame is
never changed by an exporter.

* ``cameras.json`` (ours, lossless): names, train/test split, intrinsics incl. distortion and
  camera-to-world in OpenCV axes, with a ``convention`` block stating all of the above in words.
* COLMAP model, text or binary, written and read by pycolmap (``Reconstruction``): world-to-camera
  (``cam_from_world``; a scalar-first quaternion ``QW QX QY QZ`` plus ``TX TY TZ`` in the text
  files), optional 3D points with tracks; COLMAP's principal point uses the same
  pixel-centre-at-+0.5 convention as ours, so ``cx, cy`` are written unchanged.
* ``transforms.json`` (nerfstudio / instant-ngp): camera-to-world in OpenGL axes (x right, y up,
  z backward), ``fl_x fl_y cx cy w h``, ``k1 k2 p1 p2`` (``k3`` too when non-zero). Nerfstudio's
  ray generation (``nerfstudio/cameras/cameras.py``: ``Cameras.get_image_coords`` defaults to
  ``pixel_offset=0.5`` and ``_generate_rays_from_coords`` uses ``(x - cx) / fx``) samples pixel
  centres at index + 0.5, so its ``cx, cy`` follow our convention too and are written unchanged;
  its COLMAP converter likewise copies COLMAP's principal point as is.

File-name convention for the COLMAP and ``transforms.json`` readers: a camera's ``name`` is the
stem of its image file name (``"images/view_003.png"`` -> ``"view_003"``), as artifacts pair
views by file stem.
"""
from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera import Camera, Intrinsics
from .image_io import atomic_path
from .poses import c2w_to_rigid3d, opencv_to_opengl, opengl_to_opencv, rigid3d_to_c2w

__all__ = [
    "colmap_camera",
    "SPLITS", "CAMERAS_JSON_FORMAT", "MAX_IMAGE_SIDE", "MAX_NAME_BYTES", "view_name_problem",
    "write_cameras_json", "read_cameras_json",
    "ColmapPoints", "colmap_reconstruction", "write_colmap_model", "write_colmap_text", "read_colmap_model",
    "read_colmap_text",
    "transforms_doc", "write_transforms_json", "write_blender_transforms_json", "read_transforms_json",
]

#: the split labels ``cameras.json`` accepts
SPLITS = ("train", "test", "scene")  # "scene": a scene's own camera(s), e.g. the Cornell box's
CAMERAS_JSON_FORMAT = "lumigraph.cameras/1"
#: largest image side a camera file may state (a larger one is a corrupt file, not a camera)
MAX_IMAGE_SIDE = 1 << 15
#: longest view name in UTF-8 bytes: the stem plus our suffixes and temporary-name decorations
#: (``.<stem>.<random>.partial.exr``) must fit a 255-byte file name
MAX_NAME_BYTES = 200

_CONVENTION = {
    "camera_frame": "OpenCV: x right, y down, z forward",
    "cam_to_world": "4x4 row-major camera-to-world matrix in OpenCV camera axes, world units of the scene",
    "pixel_centers": "pixel (row i, col j) has its centre at continuous image coordinates (j + 0.5, i + 0.5) "
                     "(COLMAP's convention); cx, cy are given in it; OpenCV calls need cx - 0.5, cy - 0.5",
    "intrinsics": "fx, fy, cx, cy in pixels; width, height in pixels",
    "distortion": "OpenCV/Brown (k1, k2, p1, p2, k3) applied to normalized coordinates (x/z, y/z)",
}


# --------------------------------------------------------------------------- checks


def view_name_problem(name) -> str | None:
    """Why ``name`` cannot be a view name, or None when it can.

    A view name becomes a file stem in every stage folder (``linear/<name>.exr``), so it must be
    a plain file name component: a non-empty string of at most :data:`MAX_NAME_BYTES` UTF-8
    bytes, without path separators (``/``, ``\\``), NUL or other control characters, or
    whitespace (COLMAP's image lists split on it), not starting with ``.`` (hidden names are our
    temporary files; ``.`` and ``..`` are the folder itself and its parent)."""
    if not isinstance(name, str):
        return f"must be a string, got {type(name).__name__}"
    if not name:
        return "must not be empty"
    if len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        return f"is longer than {MAX_NAME_BYTES} bytes"
    if "/" in name or "\\" in name:
        return f"{name!r} holds a path separator (a view name is a plain file name, not a path)"
    if any(ord(ch) < 32 or ord(ch) == 127 for ch in name):
        return f"{name!r} holds a control character"
    if any(ch.isspace() for ch in name):
        return f"{name!r} holds whitespace"
    if name.startswith("."):
        return f"{name!r} starts with '.' (hidden names are reserved for temporary files)"
    return None


def _check_view_name(name, where: str) -> str:
    problem = view_name_problem(name)
    if problem is not None:
        raise ValueError(f"{where}: field 'name' {problem}")
    return name


def _check_intrinsics(k: Intrinsics, where: str) -> Intrinsics:
    """Finite focal lengths and principal point, finite distortion, sides in [1, MAX_IMAGE_SIDE]."""
    for field_name in ("fx", "fy", "cx", "cy"):
        v = getattr(k, field_name)
        if not math.isfinite(v):
            raise ValueError(f"{where}: field 'intrinsics.{field_name}' must be finite, got {v!r}")
    if len(k.dist) != 5 or not all(math.isfinite(d) for d in k.dist):
        raise ValueError(f"{where}: field 'intrinsics.dist' must be 5 finite numbers (k1 k2 p1 p2 k3), "
                         f"got {list(k.dist)}")
    for field_name in ("width", "height"):
        v = getattr(k, field_name)
        if v > MAX_IMAGE_SIDE:
            raise ValueError(f"{where}: field 'intrinsics.{field_name}' is {v}, above {MAX_IMAGE_SIDE}")
    return k


def _check_cameras(cameras: Sequence[Camera]) -> list[Camera]:
    cams = list(cameras)
    if not cams:
        raise ValueError("need at least one camera")
    for c in cams:
        if not isinstance(c, Camera):
            raise ValueError(f"expected render.camera.Camera, got {type(c).__name__}")
    return cams


def _check_unique_names(cameras: Sequence[Camera]) -> None:
    names = [c.name for c in cameras]
    if any(not isinstance(n, str) or not n for n in names):
        raise ValueError("every camera needs a non-empty name")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"camera names must be unique, repeated: {dup}")


def _check_file_names(names: Sequence[str], n: int, what: str) -> list[str]:
    out = [str(s) for s in names]
    if len(out) != n:
        raise ValueError(f"{what}: got {len(out)} names for {n} cameras")
    for s in out:
        if not s or any(ch.isspace() for ch in s):
            raise ValueError(f"{what}: names must be non-empty without whitespace, got {s!r}")
    dup = sorted({s for s in out if out.count(s) > 1})
    if dup:
        raise ValueError(f"{what}: names must be unique, repeated: {dup}")
    return out


def _finite(x, what: str) -> float:
    v = float(x)
    if not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {x!r}")
    return v


def _rigid(m: np.ndarray, what: str) -> np.ndarray:
    """Validate a (4, 4) rigid transform (rotation part orthonormal, det +1, last row 0 0 0 1)."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"{what}: expected a (4, 4) matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{what}: holds non-finite values (NaN or infinity)")
    R = m[:3, :3]
    if (not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0
            or not np.allclose(m[3], [0, 0, 0, 1], atol=1e-12)):
        raise ValueError(f"{what}: not a rigid transform (rotation must be orthonormal with det +1)")
    return m


def _intrinsics_dict(k: Intrinsics) -> dict:
    """:meth:`Intrinsics.to_dict` with plain Python numbers (numpy scalars are not JSON)."""
    d = k.to_dict()
    return {"width": int(d["width"]), "height": int(d["height"]),
            **{n: float(d[n]) for n in ("fx", "fy", "cx", "cy")}, "dist": [float(v) for v in d["dist"]]}


def _stem(file_name: str) -> str:
    return Path(file_name).stem


# --------------------------------------------------------------------------- cameras.json


def write_cameras_json(path, cameras: Sequence[Camera], splits: Sequence[str]) -> None:
    """Write ``cameras.json`` (lossless: floats are written with Python's round-trip repr).

    cameras: N :class:`Camera` with unique names, poses camera-to-world in OpenCV axes.
    splits: N split labels, one per camera, each in :data:`SPLITS` (``"train"``, ``"test"`` or ``"scene"``).
    """
    cams = _check_cameras(cameras)
    _check_unique_names(cams)
    splits = [str(s) for s in splits]
    if len(splits) != len(cams):
        raise ValueError(f"cameras.json: got {len(splits)} split labels for {len(cams)} cameras")
    bad = sorted({s for s in splits if s not in SPLITS})
    if bad:
        raise ValueError(f"cameras.json: unknown split labels {bad}; known: {list(SPLITS)}")
    doc = {
        "format": CAMERAS_JSON_FORMAT,
        "convention": _CONVENTION,
        "cameras": [
            {"name": c.name, "split": s, "intrinsics": _intrinsics_dict(c.intrinsics),
             "cam_to_world": _rigid(c.cam_to_world, f"camera {c.name!r}").tolist()}
            for c, s in zip(cams, splits)
        ],
    }
    _write_json(path, doc)


def read_cameras_json(path) -> tuple[list[Camera], list[str]]:
    """Read ``cameras.json``: ``(cameras, splits)`` in file order (see :func:`write_cameras_json`)."""
    doc = _read_json(path)
    if doc.get("format") != CAMERAS_JSON_FORMAT:
        raise ValueError(f"{path}: not a {CAMERAS_JSON_FORMAT} file (format={doc.get('format')!r})")
    entries = doc.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: 'cameras' must be a non-empty list")
    cams, splits = [], []
    for i, e in enumerate(entries):
        where = f"{path}: camera {i}"
        if not isinstance(e, dict):
            raise ValueError(f"{where}: expected an object, got {type(e).__name__}")
        for key in ("name", "split", "intrinsics", "cam_to_world"):
            if key not in e:
                raise ValueError(f"{where}: missing field {key!r}")
        name = _check_view_name(e["name"], where)
        where = f"{path}: camera {i} ({name})"
        split = e["split"]
        if not isinstance(split, str) or split not in SPLITS:
            raise ValueError(f"{where}: field 'split': unknown split {split!r}; known: {list(SPLITS)}")
        try:
            k = Intrinsics.from_dict(e["intrinsics"])
        except (KeyError, TypeError, ValueError, OverflowError) as err:
            raise ValueError(f"{where}: field 'intrinsics': missing or malformed ({str(err).splitlines()[0]})") from None
        try:
            pose = np.array(e["cam_to_world"], dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{where}: field 'cam_to_world': not a 4x4 matrix of numbers ({err})") from None
        cam = Camera(_check_intrinsics(k, where), _rigid(pose, f"{where}: field 'cam_to_world'"), name)
        cams.append(cam)
        splits.append(split)
    try:
        _check_unique_names(cams)
    except ValueError as err:
        raise ValueError(f"{path}: field 'name': {err}") from None
    return cams, splits


# --------------------------------------------------------------------------- COLMAP text


def colmap_camera(k: Intrinsics) -> tuple[str, tuple[float, ...]]:
    """Our intrinsics -> COLMAP ``(model, params)``; principal point unchanged (same convention)."""
    k1, k2, p1, p2, k3 = k.dist
    base = (k.fx, k.fy, k.cx, k.cy)
    if not k.has_distortion:
        return "PINHOLE", base
    if k3 == 0.0:
        return "OPENCV", base + (k1, k2, p1, p2)
    # FULL_OPENCV's rational radial term reduces to ours with k4 = k5 = k6 = 0
    return "FULL_OPENCV", base + (k1, k2, p1, p2, k3, 0.0, 0.0, 0.0)


def _intrinsics_from_colmap(model: str, w: int, h: int, p: Sequence[float], where: str) -> Intrinsics:
    """COLMAP camera ``(model, width, height, params)`` -> :class:`Intrinsics` (perspective models only)."""
    expected = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12}
    if model not in expected:
        raise ValueError(f"{where}: unsupported COLMAP camera model {model!r}; supported: {sorted(expected)}")
    if len(p) != expected[model]:
        raise ValueError(f"{where}: {model} needs {expected[model]} parameters, got {len(p)}")
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = p
        return Intrinsics(w, h, f, f, cx, cy)
    if model == "PINHOLE":
        return Intrinsics(w, h, *p)
    if model == "SIMPLE_RADIAL":
        f, cx, cy, k1 = p
        return Intrinsics(w, h, f, f, cx, cy, (k1, 0.0, 0.0, 0.0, 0.0))
    if model == "RADIAL":
        f, cx, cy, k1, k2 = p
        return Intrinsics(w, h, f, f, cx, cy, (k1, k2, 0.0, 0.0, 0.0))
    fx, fy, cx, cy, k1, k2, p1, p2 = p[:8]
    k3 = 0.0
    if model == "FULL_OPENCV":
        k3 = p[8]
        if any(v != 0.0 for v in p[9:]):
            raise ValueError(f"{where}: FULL_OPENCV with rational terms k4..k6 != 0 is not representable")
    return Intrinsics(w, h, fx, fy, cx, cy, (k1, k2, p1, p2, k3))


@dataclass(frozen=True)
class ColmapPoints:
    """3D points and their tracks for a COLMAP model (``points3D``, and the images' ``POINTS2D``).

    xyz: (P, 3) float64 world points; rgb: (P, 3) uint8 colours. One observation per row of
    obs_point (K,) int point index, obs_image (K,) int index of the observing camera in the
    cameras given to :func:`write_colmap_model`, obs_xy (K, 2) float64 pixel position in that
    image (centres at +0.5, COLMAP's convention as ours). A point needs >= 1 observation.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    obs_point: np.ndarray
    obs_image: np.ndarray
    obs_xy: np.ndarray

    def check(self, n_images: int) -> None:
        p = len(self.xyz)
        k = len(self.obs_point)
        shapes_ok = (np.shape(self.xyz) == (p, 3) and np.shape(self.rgb) == (p, 3) and np.shape(self.obs_image) == (k,)
                     and np.shape(self.obs_xy) == (k, 2))
        if not shapes_ok:
            raise ValueError("COLMAP points: xyz (P, 3), rgb (P, 3), obs_point (K,), obs_image (K,), obs_xy (K, 2)")
        if not (np.all(np.isfinite(self.xyz)) and np.all(np.isfinite(self.obs_xy))):
            raise ValueError("COLMAP points: non-finite coordinates")
        if k and (self.obs_point.min() < 0 or self.obs_point.max() >= p or self.obs_image.min() < 0
                  or self.obs_image.max() >= n_images):
            raise ValueError("COLMAP points: observation refers to a missing point or image")
        if p and len(np.unique(self.obs_point)) != p:
            raise ValueError("COLMAP points: every point needs at least one observation")


def colmap_reconstruction(cameras: Sequence[Camera], image_names: Sequence[str], points: ColmapPoints | None = None):
    """Our cameras (and optional 3D points) as a ``pycolmap.Reconstruction`` in our world frame.

    cameras: N :class:`Camera` (camera-to-world, OpenCV axes); image_names: N file names exactly
    as COLMAP should see them (relative to its image folder, no whitespace). One COLMAP camera
    per distinct intrinsics (ids 1.. in first-seen order): PINHOLE without distortion, OPENCV
    (fx fy cx cy k1 k2 p1 p2) with distortion and k3 = 0, FULL_OPENCV (k4..k6 = 0) when k3 != 0.
    Images get ids 1..N in the given order, each in its own trivial rig and frame; their poses
    are world-to-camera (``cam_from_world``). Point ids are 1..P in ``points`` order.
    """
    import pycolmap

    cams = _check_cameras(cameras)
    names = _check_file_names(image_names, len(cams), "COLMAP image names")
    if points is not None:
        points.check(len(cams))
    rec = pycolmap.Reconstruction()
    cam_ids: dict[tuple, int] = {}
    keypoints: list[np.ndarray] = [np.zeros((0, 2))] * len(cams)
    kp_index = np.zeros(0, dtype=np.int64)  # per observation: its row in its image's keypoints
    if points is not None and len(points.obs_point):
        order = np.lexsort((np.arange(len(points.obs_image)), points.obs_image))
        kp_index = np.empty(len(order), dtype=np.int64)
        starts = np.searchsorted(points.obs_image[order], np.arange(len(cams)))
        kp_index[order] = np.arange(len(order)) - starts[points.obs_image[order]]
        keypoints = np.split(np.asarray(points.obs_xy, dtype=np.float64)[order], starts[1:])
    for img_id, (c, name) in enumerate(zip(cams, names), start=1):
        k = c.intrinsics
        model, params = colmap_camera(k)
        key = (model, k.width, k.height, params)
        if key not in cam_ids:
            cam_ids[key] = len(cam_ids) + 1
            rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=cam_ids[key], model=model, width=k.width,
                                                            height=k.height, params=list(params)))
        image = pycolmap.Image(name=name, keypoints=keypoints[img_id - 1], camera_id=cam_ids[key], image_id=img_id)
        rec.add_image_with_trivial_frame(image, c2w_to_rigid3d(_rigid(c.cam_to_world, f"camera {c.name!r}")))
    if points is not None and len(points.xyz):
        by_point = np.argsort(points.obs_point, kind="stable")
        bounds = np.searchsorted(points.obs_point[by_point], np.arange(len(points.xyz) + 1))
        image_ids = (points.obs_image + 1).astype(np.int64)
        # pycolmap adds points one at a time (no batch call): one call per point, its track built in C++
        for i, (xyz, rgb) in enumerate(zip(np.asarray(points.xyz, np.float64), np.asarray(points.rgb, np.uint8))):
            rows = by_point[bounds[i]:bounds[i + 1]]
            track = pycolmap.Track([pycolmap.TrackElement(i_img, i_kp)
                                    for i_img, i_kp in zip(image_ids[rows].tolist(), kp_index[rows].tolist())])
            rec.add_point3D(xyz, track, rgb)
    return rec


def write_colmap_model(directory, cameras: Sequence[Camera], image_names: Sequence[str],
                       points: ColmapPoints | None = None, binary: bool = False) -> None:
    """Write a COLMAP model through pycolmap (``Reconstruction.write_text`` / ``write_binary``):
    ``cameras``, ``images``, ``points3D``, ``rigs`` and ``frames`` (``.txt`` or ``.bin``), as
    COLMAP >= 3.12 and its GUI read them (older COLMAP reads the first three and ignores the rest).
    See :func:`colmap_reconstruction` for the cameras, images and points. Every file is written
    complete under a temporary name first, then renamed into ``directory``."""
    import shutil
    import tempfile

    rec = colmap_reconstruction(cameras, image_names, points)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".colmap.", suffix=".partial", dir=directory))
    try:
        (rec.write_binary if binary else rec.write_text)(str(tmp))
        for f in sorted(tmp.iterdir()):
            os.replace(f, directory / f.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_colmap_text(directory, cameras: Sequence[Camera], image_names: Sequence[str],
                      points: ColmapPoints | None = None) -> None:
    """:func:`write_colmap_model` as text (``cameras.txt``, ``images.txt``, ``points3D.txt``, ...)."""
    write_colmap_model(directory, cameras, image_names, points, binary=False)


def read_colmap_model(directory) -> list[Camera]:
    """Read a COLMAP model's cameras and images through pycolmap (text or binary, whichever the
    folder holds; 3D points are ignored).

    Returns one :class:`Camera` per registered image, sorted by image id, named by the image
    name's stem, with camera-to-world poses in OpenCV axes. Supported camera models:
    SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV with k4 = k5 = k6 = 0.
    ValueError (one line naming the folder) on a model pycolmap cannot read or we cannot represent.
    """
    import pycolmap

    directory = Path(directory)
    kind = "bin" if (directory / "cameras.bin").is_file() else "txt"
    for part in ("cameras", "images"):
        if not (directory / f"{part}.{kind}").is_file():
            raise FileNotFoundError(f"{directory / f'{part}.{kind}'}: no such file")
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = max(level, 3)  # its reader logs before raising: our one line says it
    try:
        rec = pycolmap.Reconstruction()
        rec.read(str(directory))
    except Exception as exc:  # pycolmap raises IndexError, ValueError, RuntimeError ... on malformed models
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"{directory}: unreadable COLMAP model ({reason})") from None
    finally:
        pycolmap.logging.minloglevel = level
    intrinsics = {}
    for camera_id in sorted(rec.cameras):  # every camera, used or not: a model we cannot represent is refused
        pc = rec.cameras[camera_id]
        where = f"{directory}: camera {camera_id}"
        params = [_finite(v, f"{where}: camera parameter") for v in np.asarray(pc.params, dtype=np.float64)]
        intrinsics[camera_id] = _intrinsics_from_colmap(pc.model.name, int(pc.width), int(pc.height), params, where)
    entries = []
    for image_id in sorted(rec.images):
        im = rec.images[image_id]
        where = f"{directory}: image {image_id} ({im.name})"
        if not im.has_pose:
            continue
        k = intrinsics[im.camera_id]
        c2w = rigid3d_to_c2w(im.cam_from_world())
        if not np.all(np.isfinite(c2w)):
            raise ValueError(f"{where}: non-finite pose")
        entries.append(Camera(_check_intrinsics(k, where), c2w, _check_view_name(_stem(im.name), where)))
    if not entries:
        raise ValueError(f"{directory}: no registered images")
    return entries


def read_colmap_text(directory) -> list[Camera]:
    """:func:`read_colmap_model` (kept under its old name: the reader takes text or binary)."""
    return read_colmap_model(directory)


# --------------------------------------------------------------------------- transforms.json


def _ngp_intrinsics(k: Intrinsics) -> dict:
    """Intrinsics as transforms.json keys (principal point unchanged: nerfstudio samples +0.5)."""
    k1, k2, p1, p2, k3 = k.dist
    d = {"fl_x": float(k.fx), "fl_y": float(k.fy), "cx": float(k.cx), "cy": float(k.cy),
         "w": int(k.width), "h": int(k.height), "k1": k1, "k2": k2, "p1": p1, "p2": p2}
    if k3 != 0.0:
        d["k3"] = k3  # nerfstudio reads k3 (radial r^6 term, as OpenCV's)
    return d


def transforms_doc(cameras: Sequence[Camera], file_paths: Sequence[str],
                   frame_extras: Sequence[dict] | None = None, extra: dict | None = None) -> dict:
    """The ``transforms.json`` document (see :func:`write_transforms_json`) as a dict."""
    cams = _check_cameras(cameras)
    paths = _check_file_names(file_paths, len(cams), "transforms.json file paths")
    if frame_extras is not None and len(frame_extras) != len(cams):
        raise ValueError(f"transforms.json: got {len(frame_extras)} frame extras for {len(cams)} cameras")
    shared = all(c.intrinsics == cams[0].intrinsics for c in cams)
    doc: dict = {"camera_model": "OPENCV" if any(c.intrinsics.has_distortion for c in cams) else "PINHOLE"}
    if shared:
        doc.update(_ngp_intrinsics(cams[0].intrinsics))
    frames = []
    for i, (c, p) in enumerate(zip(cams, paths)):
        f = {"file_path": p,
             "transform_matrix": opencv_to_opengl(_rigid(c.cam_to_world, f"camera {c.name!r}")).tolist()}
        if not shared:
            f.update(_ngp_intrinsics(c.intrinsics))
        if frame_extras is not None:
            f.update(frame_extras[i])
        frames.append(f)
    doc["frames"] = frames
    doc.update(extra or {})
    return doc


def write_transforms_json(path, cameras: Sequence[Camera], file_paths: Sequence[str],
                          frame_extras: Sequence[dict] | None = None, extra: dict | None = None) -> None:
    """Write a nerfstudio / instant-ngp ``transforms.json``.

    cameras: N :class:`Camera`; file_paths: N image paths relative to the json's folder.
    Each frame has ``file_path`` and ``transform_matrix`` (4x4 camera-to-world, OpenGL axes:
    x right, y up, z backward; the world frame is ours, unchanged) plus ``frame_extras[i]``
    (e.g. nerfstudio's ``mask_path``, ``depth_file_path``). Intrinsics
    ``fl_x fl_y cx cy w h k1 k2 p1 p2`` (+ ``k3`` when non-zero) sit at the top level when every
    camera shares them, else in every frame (nerfstudio reads either). ``camera_model`` is
    ``"OPENCV"`` when any camera has distortion, else ``"PINHOLE"``. ``extra`` adds top-level
    keys (e.g. ``train_filenames``, ``applied_transform``, instant-ngp's ``aabb_scale``).
    """
    _write_json(path, transforms_doc(cameras, file_paths, frame_extras, extra))


def write_blender_transforms_json(path, cameras: Sequence[Camera], file_paths: Sequence[str]) -> None:
    """Write a split file in the Blender synthetic-NeRF convention (``transforms_train.json``, as
    NeRF's, TensoRF's and nerfstudio's ``blender-data`` loaders read it).

    file_paths: N image paths relative to the json's folder WITHOUT extension (those loaders add
    ``.png``). ``camera_angle_x`` = 2 atan(w / (2 fx)) is the only intrinsic they read: they put
    the principal point at the image centre, assume square pixels and no distortion, so cameras
    that differ from that are refused (ValueError). The exact ``fl_x fl_y cx cy w h`` keys are
    written too (instant-ngp prefers them). Poses as in :func:`write_transforms_json`.
    """
    cams = _check_cameras(cameras)
    k = cams[0].intrinsics
    if any(c.intrinsics != k for c in cams):
        raise ValueError(f"{path}: the Blender convention has one camera_angle_x for all frames; intrinsics differ")
    if k.has_distortion or abs(k.fx - k.fy) > 1e-9 * k.fx or abs(k.cx - k.width / 2) > 1e-9 * k.width \
            or abs(k.cy - k.height / 2) > 1e-9 * k.height:
        raise ValueError(f"{path}: the Blender convention needs square pixels, a centred principal point and no "
                         "distortion (use transforms.json)")
    bad = [p for p in file_paths if Path(p).suffix]
    if bad:
        raise ValueError(f"{path}: Blender file paths carry no extension (its loaders add .png), got {bad[0]!r}")
    doc = transforms_doc(cams, file_paths, extra={"camera_angle_x": 2.0 * math.atan(k.width / (2.0 * k.fx))})
    _write_json(path, doc)


def read_transforms_json(path) -> list[Camera]:
    """Read a ``transforms.json``: one :class:`Camera` per frame in file order, named by the
    ``file_path`` stem, camera-to-world converted back to OpenCV axes.

    Each intrinsic key is taken from the frame when present there, else from the top level
    (nerfstudio's rule); ``k1 k2 k3 p1 p2`` default to 0.
    """
    doc = _read_json(path)
    frames = doc.get("frames")
    if not isinstance(frames, list) or not frames:
        raise ValueError(f"{path}: 'frames' must be a non-empty list")
    model = doc.get("camera_model", "OPENCV")
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise ValueError(f"{path}: unsupported camera_model {model!r}")
    cams = []
    for i, f in enumerate(frames):
        where = f"{path}: frame {i}"

        def get(key, default=None):
            v = f.get(key, doc.get(key, default))
            if v is None:
                raise ValueError(f"{where}: missing {key!r} (neither in the frame nor at the top level)")
            return v

        try:
            fp = str(f["file_path"])
            m = np.array(f["transform_matrix"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{where}: missing or malformed field {err}") from None
        k = Intrinsics(int(get("w")), int(get("h")), _finite(get("fl_x"), "fl_x"), _finite(get("fl_y"), "fl_y"),
                       _finite(get("cx"), "cx"), _finite(get("cy"), "cy"),
                       tuple(_finite(get(n, 0.0), n) for n in ("k1", "k2", "p1", "p2", "k3")))
        cams.append(Camera(_check_intrinsics(k, where), opengl_to_opencv(_rigid(m, where)),
                           _check_view_name(_stem(fp), f"{where}: file_path")))
    return cams


# --------------------------------------------------------------------------- file helpers


def _write_text(path, text: str) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)


def _write_json(path, doc: dict) -> None:
    # allow_nan=False: a NaN would silently produce invalid JSON
    _write_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


def _read_json(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: invalid JSON ({err})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level")
    return doc
