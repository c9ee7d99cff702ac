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
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from render.lightfield import SlabGeometry

__all__ = ["LayoutConfig", "ring_normals", "box_normals", "content_bounds", "fit_slabs", "slab_layout"]


@dataclass(frozen=True)
class LayoutConfig:
    """kind: ``ring`` or ``box``; count: ring slabs; uv_res / st_res: samples along the longer
    side of each uv / st quad (the shorter side in proportion, at least 2); margin: fraction of
    each quad's size added on every side.

    Defaults (uv 8, st 384; ~500 MB of float32 radiance for the default scene's 8 ring slabs):
    with depth correction the held-out views' PSNR follows the st sampling and hardly the uv
    sampling (slab study on the 1280x960 turntable, depth mode: st 192 -> 24.0 / 24.1 / 24.0 dB
    at uv 8 / 16 / 24, st 256 -> 25.6 / 25.7 / 25.8 dB; uv 8 x st 384 -> 28.1 dB), so memory goes
    to st. uv 16 x st 192, the previous default, is the same memory at 24.1 dB."""

    kind: str = "ring"
    count: int = 8
    uv_res: int = 8
    st_res: int = 384
    margin: float = 0.04

    def __post_init__(self):
        if self.kind not in ("ring", "box"):
            raise ValueError(f"layout kind must be 'ring' or 'box', got {self.kind!r}")
        if self.count < 3 or self.uv_res < 1 or self.st_res < 2 or not 0 <= self.margin < 1:
            raise ValueError(f"bad slab layout {self}")


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


def fit_slabs(normals: np.ndarray, bounds: np.ndarray, eyes: np.ndarray, up, uv_res: int = LayoutConfig.uv_res,
              st_res: int = LayoutConfig.st_res, margin: float = LayoutConfig.margin, names: Sequence[str] | None = None) -> list[SlabGeometry]:
    """Slab geometries for viewing ``normals`` (K, 3) around content ``bounds`` (2, 3) seen from
    camera centres ``eyes`` (M, 3). A slab no camera looks through is left out."""
    normals = _unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    bounds = np.asarray(bounds, dtype=np.float64)
    eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
    up = _unit(up)
    if bounds.shape != (2, 3) or not np.all(np.isfinite(bounds)) or np.any(bounds[1] < bounds[0]):
        raise ValueError(f"bounds must be finite (2, 3) [lo, hi], got {bounds.tolist()}")
    if len(eyes) == 0 or not np.all(np.isfinite(eyes)):
        raise ValueError("need finite camera centres to fit slabs")
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
        ns, nt = _counts(size(quads["st"]), st_res)
        name = names[k] if names is not None else f"slab{k:02d}"
        geoms.append(SlabGeometry(corners["uv"], corners["st"], (nu, nv, ns, nt), name))
    if not geoms:
        raise ValueError("no camera looks at the content through any slab")
    return geoms


def slab_layout(config: LayoutConfig, bounds: np.ndarray, eyes: np.ndarray, up) -> list[SlabGeometry]:
    """The slab geometries of ``config`` around ``bounds`` (2, 3) for cameras at ``eyes`` (M, 3).

    The ring's elevation is the cameras' median elevation seen from the content centre."""
    up = _unit(up)
    eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
    if config.kind == "ring":
        d = _unit(eyes - np.asarray(bounds, dtype=np.float64).mean(0))
        elevation = float(np.median(np.arcsin(np.clip(d @ up, -1, 1))))
        normals = ring_normals(config.count, elevation, up)
    else:
        normals = box_normals(up)
    return fit_slabs(normals, bounds, eyes, up, config.uv_res, config.st_res, config.margin)
