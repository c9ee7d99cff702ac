"""Training and held-out views for a NeRF, read from a capture folder (and optionally a poses folder
and a reference folder), downsampled by area averaging.

* Images are the capture's linear radiance ``linear/<view>.exr`` (float32, linear RGB); the masks
  are not used (the background is black and the field learns it as empty space).
* Training cameras come from ``<poses>/cameras.json`` when a poses folder is given (estimated
  poses, aligned to the ground-truth frame), else from the capture's ``cameras.json``; views of the
  capture's train split that the poses folder lacks (not registered) are left out.
* Held-out views always use the capture's ground-truth test cameras, because the images they are
  compared with were rendered from those cameras: the reference folder's ``linear/<view>.exr``
  when given (the path tracer), else the capture's own test images (the rasterizer: exact for
  direct-only scenes).
* Downsampling by an integer factor f averages f x f pixel blocks of linear radiance (what a
  sensor with f x larger pixels records) and scales the intrinsics with ``Intrinsics.scaled``.

Poses are camera-to-world 4x4 in OpenCV axes; rays are (N, 3) float32 origins and unit directions
in world units, pixel centres at +0.5.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from render.camera import Camera
from render.camera_io import read_cameras_json
from render.image_io import read_exr

__all__ = ["NerfInputError", "View", "NerfData", "area_downsample", "scene_box", "camera_rays", "load_data",
           "stack_rays", "auto_downsample", "WORKING_WIDTH", "PixelSampler"]

#: the default working width: 160 pixels (160x120 for 4:3 captures) trains in minutes on 2 cores
WORKING_WIDTH = 160


def auto_downsample(width: int, height: int, target_width: int = WORKING_WIDTH) -> int:
    """The largest integer factor dividing both sides that keeps the width >= ``target_width``
    (1 when the image is already that small): 640x480 -> 4, 1280x960 -> 8."""
    best = 1
    for f in range(1, width // max(target_width, 1) + 1):
        if width % f == 0 and height % f == 0:
            best = f
    return best


class NerfInputError(ValueError):
    """Bad NeRF input (missing or malformed file): one line naming the file; exit code 2."""


@dataclass(frozen=True)
class View:
    """One view: ``camera`` and ``rgb`` (H, W, 3) float32 at the working scale; ``full_camera`` at
    the image's original resolution (renders are written at that size)."""

    name: str
    camera: Camera
    rgb: np.ndarray
    full_camera: Camera
    full_rgb: np.ndarray | None = None


@dataclass(frozen=True)
class NerfData:
    """Training and held-out views, the scene box (lo, hi) (3,) float64, and provenance."""

    train: list[View]
    test: list[View]
    lo: np.ndarray
    hi: np.ndarray
    downsample: int
    reference: str
    poses: str


def area_downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Average ``factor`` x ``factor`` blocks: (H, W, C) -> (H / f, W / f, C) float32.

    H and W must be divisible by ``factor`` (so the pixel grid and the scaled intrinsics agree).
    """
    a = np.asarray(image, dtype=np.float32)
    if factor == 1:
        return a
    h, w = a.shape[:2]
    if h % factor or w % factor:
        raise NerfInputError(f"image size {w}x{h} is not divisible by the downsampling factor {factor}")
    return a.reshape(h // factor, factor, w // factor, factor, *a.shape[2:]).mean(axis=(1, 3))


def scene_box(cameras: list[Camera], margin: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The cube every camera sees: centred on the point nearest to all optical axes (least
    squares), half-side r = min_i dist(centre, camera_i) sin(half the smaller field of view),
    times ``margin``. A ball of radius r there lies in every camera's view cone. Returns
    (lo, hi), (3,) float64, world units."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cameras:
        z = c.cam_to_world[:3, 2]
        P = np.eye(3) - np.outer(z, z)
        A += P
        b += P @ c.center
    if np.linalg.cond(A) > 1e8:
        raise NerfInputError("cameras: optical axes are (nearly) parallel, cannot find the scene centre")
    centre = np.linalg.solve(A, b)
    half = min(min(np.arctan(0.5 * c.intrinsics.width / c.intrinsics.fx),
                   np.arctan(0.5 * c.intrinsics.height / c.intrinsics.fy)) for c in cameras)
    r = margin * min(np.linalg.norm(c.center - centre) for c in cameras) * np.sin(half)
    return centre - r, centre + r


def camera_rays(camera: Camera, pixels: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays through every pixel centre, row-major: (H W, 3) float32 origins and unit dirs; with
    ``pixels`` ((P,) flat row-major indices) through those pixels' centres only, (P, 3): the same
    rays as the whole view's at those rows, without the cost of the others (a 1280x960 view's
    rays cost about a second on 2 loaded cores, more than a 256-ray render probe)."""
    if pixels is None:
        o, d = camera.pixel_rays()
    else:
        w = camera.intrinsics.width
        idx = np.asarray(pixels, dtype=np.int64).reshape(-1)
        o, d = camera.pixel_rays(np.stack([idx % w + 0.5, idx // w + 0.5], axis=1).astype(np.float64))
    return torch.from_numpy(o.astype(np.float32)), torch.from_numpy(d.astype(np.float32))


def stack_rays(views: list[View]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """All pixels of ``views``: (N, 3) origins, (N, 3) unit dirs, (N, 3) linear RGB, float32."""
    os_, ds, cs = [], [], []
    for v in views:
        o, d = camera_rays(v.camera)
        os_.append(o)
        ds.append(d)
        cs.append(torch.from_numpy(np.ascontiguousarray(v.rgb.reshape(-1, 3))))
    return torch.cat(os_), torch.cat(ds), torch.cat(cs)


class PixelSampler:
    """Training rays through the capture's own pixels (not the working scale's averages), or through
    the pixels of the capture area-averaged by ``factor`` (a level of a pyramid: what a sensor with
    factor x larger pixels records; the camera scaled by 1 / factor, as the working scale's is):
    random (view, row, col) triples drawn uniformly over every pixel of ``views``' ``full_rgb``
    (all the same size) at that level, the ray through that pixel's centre (``Camera.pixel_rays``:
    distortion inverted exactly) and its linear colour. Images are kept as float16 (a relative
    rounding of 5e-4, below the 8-bit display step of any radiance above 0.002): (V, H, W, 3)."""

    def __init__(self, views: list[View], factor: int = 1):
        if not views or any(v.full_rgb is None for v in views):
            raise ValueError("PixelSampler needs the views' full-resolution images (load_data(..., train_full=True))")
        if int(factor) != factor or factor < 1:
            raise ValueError(f"PixelSampler factor must be an integer >= 1, got {factor}")
        self.factor = int(factor)
        if self.factor == 1:
            self.cameras = [v.full_camera for v in views]
            self.images = torch.from_numpy(np.stack([np.asarray(v.full_rgb, dtype=np.float16) for v in views]))
        else:
            self.cameras = [Camera(v.full_camera.intrinsics.scaled(1.0 / self.factor), v.full_camera.cam_to_world,
                                   v.full_camera.name) for v in views]
            self.images = torch.from_numpy(np.stack([area_downsample(v.full_rgb, self.factor).astype(np.float16)
                                                     for v in views]))
        self.height, self.width = int(self.images.shape[1]), int(self.images.shape[2])

    @property
    def n_pixels(self) -> int:
        return int(self.images.shape[0]) * self.height * self.width

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """n random pixels: (n, 3) float32 origins, unit directions, linear RGB."""
        idx = torch.randint(self.n_pixels, (n,), generator=generator)
        view, rest = idx // (self.height * self.width), idx % (self.height * self.width)
        row, col = rest // self.width, rest % self.width
        o, d = self._rays(view, row, col)
        return o, d, self.images[view, row, col].float()

    def _rays(self, view: torch.Tensor, row: torch.Tensor, col: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        n = int(view.shape[0])
        o = torch.empty(n, 3)
        d = torch.empty(n, 3)
        xy = torch.stack([col.double() + 0.5, row.double() + 0.5], dim=1).numpy()
        for v in torch.unique(view).tolist():
            sel = (view == v).nonzero()[:, 0]
            ov, dv = self.cameras[v].pixel_rays(xy[sel.numpy()])
            o[sel] = torch.from_numpy(ov.astype(np.float32))
            d[sel] = torch.from_numpy(dv.astype(np.float32))
        return o, d


def _read_image(path: Path) -> np.ndarray:
    try:
        img = read_exr(path)
    except FileNotFoundError:
        raise NerfInputError(f"{path}: missing image") from None
    except Exception as exc:  # OpenEXR raises various types for corrupt files
        raise NerfInputError(f"{path}: unreadable EXR ({type(exc).__name__})") from None
    if img.ndim != 3 or img.shape[2] != 3:
        raise NerfInputError(f"{path}: expected an RGB image, got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise NerfInputError(f"{path}: non-finite pixel values")
    return img


def _read_cameras(path: Path) -> tuple[list[Camera], list[str]]:
    try:
        return read_cameras_json(path)
    except FileNotFoundError:
        raise NerfInputError(f"{path}: missing cameras.json") from None
    except ValueError as exc:
        raise NerfInputError(str(exc).splitlines()[0]) from None


def _view(name: str, cam: Camera, img: np.ndarray, downsample: int, where: Path, keep_full: bool = False) -> View:
    """The view at the working size (the camera's size / downsample), whatever the image's size
    (a reference may be rendered at another resolution: the camera is scaled to it first)."""
    h, w = img.shape[:2]
    k = cam.intrinsics
    if (w, h) != (k.width, k.height):
        if abs(w / k.width - h / k.height) > 1e-9:
            raise NerfInputError(f"{where}: image is {w}x{h} but camera {name!r} is {k.width}x{k.height}")
        cam = Camera(k.scaled(w / k.width), cam.cam_to_world, name)
    target_w = k.width // downsample
    factor = w // target_w if target_w else 0
    if factor < 1 or factor * target_w != w:
        raise NerfInputError(f"{where}: width {w} is not a multiple of the working width {target_w}")
    small = cam if factor == 1 else Camera(cam.intrinsics.scaled(1.0 / factor), cam.cam_to_world, name)
    return View(name, small, area_downsample(img, factor), cam, img if keep_full else None)


def load_data(capture_dir, poses_dir=None, reference_dir=None, downsample: int | None = None,
              train_full: bool = False) -> NerfData:
    """Read the views of a capture folder (see the module docstring).

    capture_dir: ``artifacts/<scene>/capture``; poses_dir: ``artifacts/<scene>/poses/<method>``
    or None (ground truth); reference_dir: a folder with ``linear/<view>.exr`` of the held-out
    views or None (the capture's test images); downsample: integer factor >= 1, or None for
    :func:`auto_downsample` (working width about 160 pixels); train_full: keep the training
    views' full-resolution images too (``View.full_rgb``, float16) for :class:`PixelSampler`.
    """
    capture_dir = Path(capture_dir)
    cams, splits = _read_cameras(capture_dir / "cameras.json")
    if downsample is None:
        downsample = auto_downsample(cams[0].intrinsics.width, cams[0].intrinsics.height)
    if int(downsample) != downsample or downsample < 1:
        raise NerfInputError(f"downsample must be an integer >= 1, got {downsample}")
    gt = {c.name: c for c in cams}
    train_names = [c.name for c, s in zip(cams, splits) if s == "train"]
    test_names = [c.name for c, s in zip(cams, splits) if s == "test"]
    if not train_names or not test_names:
        raise NerfInputError(f"{capture_dir / 'cameras.json'}: needs both train and test views")
    train_cams = gt
    if poses_dir is not None:
        est, _ = _read_cameras(Path(poses_dir) / "cameras.json")
        train_cams = {c.name: c for c in est}
        train_names = [n for n in train_names if n in train_cams]
        if not train_names:
            raise NerfInputError(f"{Path(poses_dir) / 'cameras.json'}: no camera of the capture's train split")
    def train_view(n: str) -> View:
        v = _view(n, train_cams[n], _read_image(capture_dir / "linear" / f"{n}.exr"), downsample,
                  capture_dir / "linear" / f"{n}.exr", keep_full=train_full)
        # half the bytes, one view at a time: 48 views of 1280x960 are 354 MB
        return replace(v, full_rgb=v.full_rgb.astype(np.float16)) if train_full else v

    train = [train_view(n) for n in train_names]
    ref_root = Path(reference_dir) if reference_dir is not None else capture_dir
    test = []
    for n in test_names:
        p = ref_root / "linear" / f"{n}.exr"
        test.append(_view(n, gt[n], _read_image(p), downsample, p, keep_full=True))
    lo, hi = scene_box([train_cams[n] for n in train_names])
    return NerfData(train, test, lo, hi, int(downsample),
                    str(ref_root / "linear") if reference_dir is not None else f"{capture_dir / 'linear'} (test split)",
                    str(poses_dir) if poses_dir is not None else f"{capture_dir / 'cameras.json'} (ground truth)")
