"""Where the slabs go: a set of slabs around the captured content, sized from the cameras.

Each slab has a *viewing normal* n (unit, from the content towards the viewers; its eye rays
travel along ``forward = -n``). Its st plane passes through the centre of the content bounds
(the focal plane through the object, as Levoy and Hanrahan place it), its uv plane lies at the
cameras' median distance. The quads are fitted, with a margin, to every line from a camera
through the content bounds whose steepest slab is this one, so each eye ray that sees content
from inside the camera region crosses both quads of the slab it is looked up in.

Layouts: ``ring`` (``count`` slabs whose normals share the cameras' median elevation about
``up``, at equal azimuth steps: a band facing turntable rings) and ``box`` (the faces of a box:
+-x, +-y and +up, the bottom omitted since nothing looks from below a turntable).

st sampling follows the capture's pixel footprint on the focal (st) plane (:func:`st_density`):
a capture pixel of focal length f (pixels) at distance r from the content centre covers
r / (f sqrt(1 - (e . d)^2)) metres of the plane along its axis e (d: the viewing direction), so an
st quad of width W needs W f sqrt(1 - (e . d)^2) / r samples per pixel of detail, taken at the
slab's most head-on camera. With depth correction a surface off the plane is looked up through
the same sheared cameras, whose rays fan out as the capture's do, so this one density holds at
every depth. A fixed ``st_res`` (the slab study's sweeps) overrides it.
"""
from __future__ import annotations

from collections.abc import Sequence
import math
from dataclasses import dataclass

import numpy as np

from render.lightfield import SlabGeometry

__all__ = ["LayoutConfig", "ring_normals", "box_normals", "content_bounds", "st_density", "fit_slabs", "slab_layout",
           "layout_rays"]


@dataclass(frozen=True)
class LayoutConfig:
    """kind: ``ring`` or ``box``; count: ring slabs; uv_res: samples along the longer side of each
    uv quad (the shorter side in proportion, at least 2); st_per_pixel: st samples per capture
    pixel of the subject's footprint on the st plane, along each side (:func:`st_density`; the
    default: detail down to the capture's own pixels); st_res: a fixed count along the longer
    side of each st quad instead (None: from the footprint); margin: fraction of each quad's
    size added on every side.

    Why st follows the capture: with depth correction the held-out views' display PSNR follows
    the st sampling and hardly the uv sampling (slab study, 1280x960 turntable, depth mode,
    linear PSNR: st 192 -> 24.0 / 24.1 / 24.0 dB at uv 8 / 16 / 24; uv 8 x st 384 -> 28.1 dB),
    and at st 384 a ChArUco board ~540 capture pixels wide got ~250 samples: soft markers. The
    footprint gives the default scene ~1000-1200 samples per st side (docs/architecture.md has
    the measured figures), so memory goes to st. uv 8 holds once the depth mode searches each eye
    ray's depth and drops occluded uv taps (render.lightfield.rendering._depth_search): with the
    nearest sample's depth alone, the taps 15 cm apart ghosted the box over the board (test_000
    at the footprint, display PSNR: uv 8 27.2 dB, uv 16 31.1; with the search uv 8 32.3, and 33.0
    with the capture's own depth, so uv 16 has little left to give)."""

    kind: str = "ring"
    count: int = 8
    uv_res: int = 8
    st_res: int | None = None
    st_per_pixel: float = 1.0
    margin: float = 0.04

    def __post_init__(self):
        if self.kind not in ("ring", "box"):
            raise ValueError(f"layout kind must be 'ring' or 'box', got {self.kind!r}")
        if self.count < 3 or self.uv_res < 1 or (self.st_res is not None and self.st_res < 2) or not 0 <= self.margin < 1:
            raise ValueError(f"bad slab layout {self}")
        if not (math.isfinite(self.st_per_pixel) and 0 < self.st_per_pixel <= 16):
            raise ValueError(f"st_per_pixel must be in (0, 16], got {self.st_per_pixel}")


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("zero-length direction")
    return v / n


def _perp_frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    a = _unit(np.cross(up, helper))
    return a, np.cross(up, a)


def ring_normals(count: int, elevation_rad: float, up, azimuth_offset_rad: float = 0.0) -> np.ndarray:
    """(count, 3) unit viewing normals at one elevation above the plane perpendicular to ``up``."""
    up = _unit(up)
    a, b = _perp_frame(up)
    az = azimuth_offset_rad + 2 * np.pi * np.arange(count) / count
    return (np.cos(elevation_rad) * (np.cos(az)[:, None] * a + np.sin(az)[:, None] * b)
            + np.sin(elevation_rad) * up)


def box_normals(up) -> np.ndarray:
    """(5, 3) viewing normals of a box's faces: the four sides and the top (world axes)."""
    up = _unit(up)
    axes = [e for e in np.eye(3) if abs(e @ up) < 0.5]
    return np.array([axes[0], -axes[0], axes[1], -axes[1], up])


def content_bounds(points: np.ndarray, percentile: float = 0.1) -> np.ndarray:
    """(2, 3) axis-aligned bounds of content points (N, 3), trimmed by ``percentile`` per side
    (silhouette pixels carry depths averaged across an edge: a few points float in space)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < 10:
        raise ValueError(f"need at least 10 content points to bound the content, got {len(p)}")
    return np.stack([np.percentile(p, percentile, axis=0), np.percentile(p, 100 - percentile, axis=0)])


def _box_points(bounds: np.ndarray) -> np.ndarray:
    lo, hi = bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return np.vstack([corners, (lo + hi) / 2])


def _axes(forward: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e_s, e_t): image right and down of a view along ``forward`` with ``up`` up (OpenCV)."""
    x = np.cross(forward, up)
    if np.linalg.norm(x) < 1e-6:  # looking along up: pick any right vector
        x = np.cross(forward, _perp_frame(up)[0])
    x = _unit(x)
    return x, np.cross(forward, x)


def _counts(size: tuple[float, float], res: int) -> tuple[int, int]:
    w, h = size
    if w >= h:
        return res, max(2, int(round(res * h / w)))
    return max(2, int(round(res * w / h))), res


def st_density(centre: np.ndarray, eyes: np.ndarray, focal_px: np.ndarray, axes: Sequence[np.ndarray]) -> np.ndarray:
    """(len(axes),) capture pixels per metre along each unit ``axes`` vector of a plane through
    ``centre`` (3,), at its most head-on camera: max over cameras at ``eyes`` (M, 3) with focal
    lengths ``focal_px`` (M,) pixels of f / r sqrt(1 - (e . d)^2) (r, d: distance and unit
    direction from the eye to ``centre``; a pinhole looking at the centre)."""
    to_c = np.asarray(centre, np.float64) - np.asarray(eyes, np.float64).reshape(-1, 3)
    r = np.linalg.norm(to_c, axis=1)
    if np.any(r < 1e-9):
        raise ValueError("a camera sits at the content centre: no pixel footprint")
    d = to_c / r[:, None]
    f = np.asarray(focal_px, np.float64).reshape(-1)
    return np.array([np.max(f / r * np.sqrt(np.clip(1.0 - (d @ e) ** 2, 0.0, 1.0))) for e in axes])


def fit_slabs(normals: np.ndarray, bounds: np.ndarray, eyes: np.ndarray, up, uv_res: int = LayoutConfig.uv_res,
              st_res: int | None = LayoutConfig.st_res, margin: float = LayoutConfig.margin,
              names: Sequence[str] | None = None, focal_px=None,
              st_per_pixel: float = LayoutConfig.st_per_pixel) -> list[SlabGeometry]:
    """Slab geometries for viewing ``normals`` (K, 3) around content ``bounds`` (2, 3) seen from
    camera centres ``eyes`` (M, 3). A slab no camera looks through is left out.

    st counts: ``st_res`` along each st quad's longer side, or (``st_res`` None) ceil(st_per_pixel
    x side x :func:`st_density`) per side from the cameras' focal lengths ``focal_px`` (M,) or
    scalar, pixels, over the cameras that look through that slab."""
    normals = _unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    bounds = np.asarray(bounds, dtype=np.float64)
    eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
    up = _unit(up)
    if bounds.shape != (2, 3) or not np.all(np.isfinite(bounds)) or np.any(bounds[1] < bounds[0]):
        raise ValueError(f"bounds must be finite (2, 3) [lo, hi], got {bounds.tolist()}")
    if len(eyes) == 0 or not np.all(np.isfinite(eyes)):
        raise ValueError("need finite camera centres to fit slabs")
    if st_res is None:
        if focal_px is None:
            raise ValueError("st sampling from the pixel footprint needs the cameras' focal lengths (focal_px)")
        focal_px = np.broadcast_to(np.asarray(focal_px, np.float64), (len(eyes),))
        if not (np.all(np.isfinite(focal_px)) and np.all(focal_px > 0)):
            raise ValueError("focal lengths must be finite and positive")
    centre = bounds.mean(0)
    X = _box_points(bounds)                                   # (9, 3)
    rays = X[None] - eyes[:, None]                            # (M, 9, 3) eye -> content
    fwd = -normals                                            # (K, 3)
    cos = np.einsum("mpc,kc->mpk", _unit(rays), fwd)
    steepest = np.argmax(cos, axis=2)                         # (M, 9)
    geoms = []
    for k in range(len(normals)):
        f = fwd[k]
        mine = np.any(steepest == k, axis=1)
        if not mine.any():
            continue
        e_s, e_t = _axes(f, up)
        r = rays[mine]                                        # (m, 9, 3)
        E = eyes[mine][:, None, :]
        along = r @ f                                         # (m, 9) > 0: content ahead
        ok = along > 1e-9
        dist = np.median((centre - eyes[mine]) @ f)           # uv plane: the cameras' median distance
        if not dist > 0:
            continue
        quads = {}
        for plane, depth in (("st", 0.0), ("uv", -dist)):
            # line E + lam r meets the plane {x : (x - centre) . f = depth}
            lam = ((centre - E[:, 0]) @ f + depth)[:, None] / np.where(ok, along, 1.0)
            P = E + lam[..., None] * r - centre
            xy = np.stack([P @ e_s, P @ e_t], axis=-1)[ok]
            lo, hi = xy.min(0), xy.max(0)
            pad = margin * (hi - lo) + 1e-9
            quads[plane] = (lo - pad, hi + pad)
        corners = {}
        for plane, depth in (("st", 0.0), ("uv", -dist)):
            (x0, y0), (x1, y1) = quads[plane]
            o = centre + depth * f
            corners[plane] = np.array([o + x0 * e_s + y0 * e_t, o + x1 * e_s + y0 * e_t,
                                       o + x1 * e_s + y1 * e_t, o + x0 * e_s + y1 * e_t])
        size = lambda q: (q[1][0] - q[0][0], q[1][1] - q[0][1])  # noqa: E731
        nu, nv = _counts(size(quads["uv"]), uv_res)
        if st_res is None:
            density = st_density(centre, eyes[mine], focal_px[mine], (e_s, e_t))
            ns, nt = (max(2, math.ceil(st_per_pixel * w * dens - 1e-9)) for w, dens in zip(size(quads["st"]), density))
        else:
            ns, nt = _counts(size(quads["st"]), st_res)
        name = names[k] if names is not None else f"slab{k:02d}"
        geoms.append(SlabGeometry(corners["uv"], corners["st"], (nu, nv, ns, nt), name))
    if not geoms:
        raise ValueError("no camera looks at the content through any slab")
    return geoms


def slab_layout(config: LayoutConfig, bounds: np.ndarray, eyes: np.ndarray, up, focal_px=None) -> list[SlabGeometry]:
    """The slab geometries of ``config`` around ``bounds`` (2, 3) for cameras at ``eyes`` (M, 3)
    with focal lengths ``focal_px`` (M,) pixels (needed when ``config.st_res`` is None).

    The ring's elevation is the cameras' median elevation seen from the content centre."""
    up = _unit(up)
    eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
    if config.kind == "ring":
        d = _unit(eyes - np.asarray(bounds, dtype=np.float64).mean(0))
        elevation = float(np.median(np.arcsin(np.clip(d @ up, -1, 1))))
        normals = ring_normals(config.count, elevation, up)
    else:
        normals = box_normals(up)
    return fit_slabs(normals, bounds, eyes, up, config.uv_res, config.st_res, config.margin, focal_px=focal_px,
                     st_per_pixel=config.st_per_pixel)


def layout_rays(geometries: Sequence[SlabGeometry]) -> int:
    """Rays (samples) of a slab set: what its arrays' size is proportional to."""
    return int(sum(g.n_rays for g in geometries))
