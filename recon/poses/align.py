"""Similarity alignment (Umeyama, through pycolmap) and scoring of estimated cameras against ground truth.

Conventions: poses are camera-to-world (4, 4) float64 in OpenCV axes (x right, y down,
z forward); cameras pair up by ``Camera.name``. A similarity ``(s, R, t)`` maps a point
``x`` of the estimate's frame to ``s R x + t`` in the ground-truth frame; applied to a camera it
maps the centre the same way and left-multiplies the camera-to-world rotation by ``R``.

The scene scale that camera-centre errors are divided by is the median distance of the
ground-truth camera centres from their centroid (the orbit radius on a turntable), so a
relative error of 0.01 is 1 % of the orbit.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from render.camera import Camera

__all__ = ["Similarity", "umeyama", "apply_similarity", "rotation_angles_deg", "scene_scale",
           "score_cameras", "intrinsics_error", "projection_error", "pixel_grid", "subject_point",
           "turntable_self_check", "sequence_rotation_bias"]


@dataclass(frozen=True)
class Similarity:
    """``x -> scale * R @ x + t``: scale float > 0, R (3, 3) float64 rotation, t (3,) float64."""

    scale: float
    R: np.ndarray
    t: np.ndarray

    @classmethod
    def identity(cls) -> "Similarity":
        return cls(1.0, np.eye(3), np.zeros(3))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) float64 points -> (N, 3) float64 transformed points."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.R.T + self.t


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Similarity:
    """Least-squares similarity taking ``src`` onto ``dst`` (Umeyama 1991), computed by pycolmap
    (``estimate_sim3d``; ``estimate_rigid3d`` when ``with_scale`` is False, scale 1).

    src, dst: (N, 3) float64 corresponding points, N >= 3 and not all collinear.
    Returns the :class:`Similarity` minimising sum |dst - (s R src + t)|^2. Raises ValueError on
    degenerate input (pycolmap returns no estimate for it; the checks here say why).
    """
    import pycolmap

    src, dst = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"umeyama: need two (N, 3) arrays of the same shape, got {src.shape} and {dst.shape}")
    if len(src) < 3 or not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise ValueError("umeyama: need at least 3 finite point pairs")
    centred = src - src.mean(0)
    if np.mean(np.sum(centred * centred, axis=1)) < 1e-24:
        raise ValueError("umeyama: source points coincide")
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] <= 1e-12 * sv[0]:
        raise ValueError("umeyama: points are collinear, the rotation is undetermined")
    est = (pycolmap.estimate_sim3d if with_scale else pycolmap.estimate_rigid3d)(src, dst)
    if est is None:
        raise ValueError("umeyama: no similarity fits these points (degenerate configuration)")
    scale = float(est.scale) if with_scale else 1.0
    R = np.asarray(est.rotation.matrix(), dtype=np.float64)
    return Similarity(scale, R, np.asarray(est.translation, dtype=np.float64).copy())


def apply_similarity(cameras: Sequence[Camera], sim: Similarity) -> list[Camera]:
    """Move cameras by ``sim``: centre -> s R c + t, camera-to-world rotation -> R @ R_c2w."""
    out = []
    for c in cameras:
        m = np.eye(4)
        m[:3, :3] = sim.R @ c.cam_to_world[:3, :3]
        m[:3, 3] = sim.apply(c.cam_to_world[None, :3, 3])[0]
        out.append(replace(c, cam_to_world=m))
    return out


def rotation_angles_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations: (N, 3, 3) x (N, 3, 3) -> (N,) float64 degrees.

    Uses atan2(|skew part|, trace part), accurate for tiny angles (arccos of the trace is not).
    """
    D = np.einsum("nji,njk->nik", np.asarray(R_a, float), np.asarray(R_b, float))  # R_a^T R_b
    cos = (np.trace(D, axis1=1, axis2=2) - 1.0) / 2.0
    sin = 0.5 * np.linalg.norm(np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0],
                                         D[:, 1, 0] - D[:, 0, 1]], axis=1), axis=1)
    return np.degrees(np.arctan2(sin, cos))


def scene_scale(truth: Sequence[Camera]) -> float:
    """Median distance of the ground-truth camera centres from their centroid (> 0)."""
    c = np.array([t.center for t in truth])
    d = float(np.median(np.linalg.norm(c - c.mean(0), axis=1)))
    if not d > 0:
        raise ValueError("scene_scale: all ground-truth cameras share one centre")
    return d


def intrinsics_error(est: Camera, truth: Camera) -> dict:
    """Relative focal error, principal-point error (px) and largest distortion difference."""
    a, b = est.intrinsics, truth.intrinsics
    return {"focal_rel": float(max(abs(a.fx - b.fx) / b.fx, abs(a.fy - b.fy) / b.fy)),
            "principal_point_px": float(np.hypot(a.cx - b.cx, a.cy - b.cy)),
            "distortion_abs_max": float(np.max(np.abs(np.subtract(a.dist, b.dist))))}


def pixel_grid(width: int, height: int, step: float = 16.0) -> np.ndarray:
    """(N, 2) float64 continuous pixel positions every ``step`` pixels across the whole image,
    its border included (the image's outer corners (0, 0) ... (width, height) are points of it)."""
    xs = np.linspace(0.0, width, max(int(np.ceil(width / step)), 1) + 1)
    ys = np.linspace(0.0, height, max(int(np.ceil(height / step)), 1) + 1)
    jj, ii = np.meshgrid(xs, ys)
    return np.stack([jj.ravel(), ii.ravel()], axis=1)


def subject_point(truth: Sequence[Camera]) -> np.ndarray:
    """(3,) float64 world point nearest (least squares) every camera's optical axis: the point a
    turntable capture looks at, the subject's centre."""
    C = np.array([c.center for c in truth])
    d = np.array([c.cam_to_world[:3, 2] for c in truth])
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    return np.linalg.lstsq(P.sum(0), np.einsum("nij,nj->i", P, C), rcond=None)[0]


def projection_error(estimated: Sequence[Camera], truth: Mapping[str, Camera], step: float = 16.0,
                     radius_rel: float | None = None) -> dict:
    """How far the estimated cameras project from the true ones, distortion included.

    For each estimated view (already in the ground-truth frame, e.g. :func:`score_cameras`'s
    output) the pixels of :func:`pixel_grid` are cast through the TRUE camera to points at the
    subject's depth (the z of :func:`subject_point` in that view) and projected by the ESTIMATED
    camera; the distance to the pixel they came from is the error (px). This is the whole camera:
    pose, focal, principal point and lens. ``lens_*`` is the lens alone: the same rays projected
    with the estimated intrinsics from the true pose (depth-independent), one figure per distinct
    estimated intrinsics. With ``radius_rel`` (distance from the image centre over the half-diagonal)
    the ``*_covered`` figures repeat the maxima over the grid points inside that radius.

    Returns floats: ``projection_error_px_max`` (max over views and grid), ``..._view_max_mean`` (mean
    over views of each view's max), ``..._mean`` (mean over views and grid), ``lens_projection_error_px_max``
    / ``..._mean``, and the ``_covered`` maxima when ``radius_rel`` is given.
    """
    est, gt = _pair(estimated, truth)
    target = subject_point(list(truth.values()))
    k0 = gt[0].intrinsics
    grid = pixel_grid(k0.width, k0.height, step)
    rel = np.linalg.norm(grid - [k0.width / 2, k0.height / 2], axis=1) / (0.5 * np.hypot(k0.width, k0.height))
    inside = rel <= radius_rel if radius_rel is not None else None
    view_max, view_mean, view_cov, lens = [], [], [], {}
    for e, t in zip(est, gt):
        origins, dirs = t.pixel_rays(grid)
        z_subject = (t.world_to_cam[:3, :3] @ target + t.world_to_cam[:3, 3])[2]
        z_dirs = dirs @ t.cam_to_world[:3, 2]
        points = origins + dirs * (z_subject / z_dirs)[:, None]
        uv, _ = e.project(points)
        err = np.linalg.norm(uv - grid, axis=1)
        view_max.append(err.max())
        view_mean.append(err.mean())
        if inside is not None:
            view_cov.append(err[inside].max())
        if e.intrinsics not in lens:
            uv_lens, _ = Camera(e.intrinsics, t.cam_to_world, t.name).project(points)
            lens[e.intrinsics] = np.linalg.norm(uv_lens - grid, axis=1)
    lens_err = np.concatenate(list(lens.values()))
    out = {"projection_error_px_max": float(max(view_max)), "projection_error_px_view_max_mean": float(np.mean(view_max)),
           "projection_error_px_mean": float(np.mean(view_mean)), "lens_projection_error_px_max": float(lens_err.max()),
           "lens_projection_error_px_mean": float(lens_err.mean())}
    if inside is not None:
        out["projection_error_px_max_covered"] = float(max(view_cov))
        out["lens_projection_error_px_max_covered"] = float(max(v[inside].max() for v in lens.values()))
    return out


def _pair(estimated: Sequence[Camera], truth: Mapping[str, Camera]) -> tuple[list[Camera], list[Camera]]:
    missing = [c.name for c in estimated if c.name not in truth]
    if missing:
        raise ValueError(f"estimated views without ground truth: {missing[:5]}")
    return list(estimated), [truth[c.name] for c in estimated]


def score_cameras(estimated: Sequence[Camera], truth: Mapping[str, Camera], align: bool = True,
                  ) -> tuple[list[Camera], dict, Similarity]:
    """Score estimated cameras against ground truth, optionally after a similarity alignment.

    estimated: registered cameras (any subset of ``truth``'s names); truth: name -> Camera.
    With ``align`` the estimate is first moved by the Umeyama similarity of its centres onto the
    ground truth's (needs >= 3 non-collinear centres). Returns ``(cameras, metrics, similarity)``:
    the (aligned) cameras, the similarity applied (identity without ``align``) and a dict of rotation error in degrees (mean, median, max), camera-centre
    error relative to :func:`scene_scale` (mean, max), the alignment's scale, the registered
    count and the worst view's name. All values are finite floats.
    """
    est, gt = _pair(estimated, truth)
    if not est:
        raise ValueError("no estimated cameras to score")
    sim = Similarity.identity()
    if align:
        sim = umeyama(np.array([c.center for c in est]), np.array([c.center for c in gt]))
        est = apply_similarity(est, sim)
    rot = rotation_angles_deg(np.array([c.cam_to_world[:3, :3] for c in gt]),
                              np.array([c.cam_to_world[:3, :3] for c in est]))
    scale = scene_scale(list(truth.values()))
    cen = np.linalg.norm(np.array([c.center for c in est]) - np.array([c.center for c in gt]), axis=1) / scale
    worst = int(np.argmax(rot))
    metrics = {"rotation_error_deg_mean": float(rot.mean()), "rotation_error_deg_median": float(np.median(rot)),
               "rotation_error_deg_max": float(rot.max()), "center_error_rel_mean": float(cen.mean()),
               "center_error_rel_max": float(cen.max()), "alignment_scale": float(sim.scale),
               "scene_scale": scale, "worst_view": est[worst].name}
    return est, metrics, sim


def sequence_rotation_bias(estimated: Sequence[Camera], truth: Mapping[str, Camera],
                           sequence_of: Mapping[str, str]) -> list[dict]:
    """The rotation error every view of a sequence shares, in the camera's own axes.

    For each view the error rotation ``R_true^T R_est`` (camera-to-world rotations, so the error
    acts in the camera frame) is turned into a rotation vector; its mean over a sequence's views
    is that sequence's common error: ``pitch_deg`` about the camera's x (right) axis (positive
    turns the optical axis towards the camera's up, -y in OpenCV axes), ``yaw_deg`` about y (down),
    ``roll_deg`` about z (forward); ``scatter_deg`` is the per-axis standard deviation around it
    (the views' own error). A ring shifted as a whole shows as a mean far above
    ``scatter / sqrt(views)``; a world-frame mean would cancel around a ring (the camera axes
    turn with the azimuth), hence the camera frame.

    estimated: cameras already in the ground-truth frame (e.g. :func:`score_cameras`'s output);
    truth: name -> Camera; sequence_of: name -> sequence id (views without one are skipped).
    Returns one dict per sequence, sorted by id: ``sequence``, ``views``, ``pitch_deg``,
    ``yaw_deg``, ``roll_deg``, ``scatter_deg`` ([x, y, z]); finite floats.
    """
    groups: dict[str, list[np.ndarray]] = {}
    for c in estimated:
        seq = sequence_of.get(c.name)
        if seq is None or c.name not in truth:
            continue
        D = truth[c.name].cam_to_world[:3, :3].T @ c.cam_to_world[:3, :3]
        # rotation vector of D: axis * angle, the angle by atan2 (accurate for tiny angles)
        w = 0.5 * np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
        sin, cos = float(np.linalg.norm(w)), (float(np.trace(D)) - 1.0) / 2.0
        angle = np.arctan2(sin, cos)
        groups.setdefault(seq, []).append(w * (angle / sin) if sin > 1e-15 else w)
    out = []
    for seq in sorted(groups):
        v = np.degrees(np.array(groups[seq]))
        mean = v.mean(0)
        out.append({"sequence": seq, "views": len(v), "pitch_deg": float(mean[0]), "yaw_deg": float(mean[1]),
                    "roll_deg": float(mean[2]), "scatter_deg": [float(x) for x in v.std(0)]})
    return out


def turntable_self_check(cameras: Sequence[Camera], max_gap_deg: float = 90.0,
                         duplicate_rel: float = 0.05) -> dict:
    """Detect a folded turntable circle from the estimated cameras alone (no ground truth).

    A turntable capture is an orbit: the cameras look at the axis from all around it. The axis
    direction is the mean of the cameras' up vectors (-y column of camera-to-world), its position
    the least-squares point nearest every optical axis. Two symptoms of a circle folded by
    repeated texture are reported:

    * ``max_azimuth_gap_deg``: the largest empty sector of camera azimuths around the axis; a
      full turn leaves gaps of a few view steps, a fold leaves most of the circle empty.
    * ``duplicate_pairs``: pairs of views whose centres lie closer than ``duplicate_rel`` times
      the orbit radius and whose orientations differ by less than 1 degree (identical-looking
      views from different turntable angles stacked onto one pose).

    cameras: (N >= 3) cameras, camera-to-world OpenCV axes. Returns a dict with those two
    figures, ``folded`` (bool) and ``reason`` (str, empty when not folded).
    """
    cams = list(cameras)
    if len(cams) < 3:
        return {"folded": False, "reason": "", "max_azimuth_gap_deg": 0.0, "duplicate_pairs": 0}
    R = np.array([c.cam_to_world[:3, :3] for c in cams])
    C = np.array([c.center for c in cams])
    up = -R[:, :, 1].mean(0)
    up /= max(np.linalg.norm(up), 1e-12)
    d = R[:, :, 2]
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # projectors orthogonal to each optical axis
    A, b = P.sum(0), np.einsum("nij,nj->i", P, C)
    p0 = np.linalg.lstsq(A, b, rcond=None)[0]
    rel = C - p0
    rel -= np.outer(rel @ up, up)
    e1 = rel[np.argmax(np.linalg.norm(rel, axis=1))]
    e1 /= max(np.linalg.norm(e1), 1e-12)
    e2 = np.cross(up, e1)
    az = np.sort(np.degrees(np.arctan2(rel @ e2, rel @ e1)) % 360.0)
    gaps = np.diff(np.concatenate([az, az[:1] + 360.0]))
    max_gap = float(gaps.max())
    radius = float(np.median(np.linalg.norm(rel, axis=1)))
    dist = np.linalg.norm(C[:, None] - C[None], axis=2)
    ang = rotation_angles_deg(np.repeat(R, len(R), 0), np.tile(R, (len(R), 1, 1))).reshape(len(R), len(R))
    iu = np.triu_indices(len(R), 1)
    dup = int(np.sum((dist[iu] < duplicate_rel * max(radius, 1e-12)) & (ang[iu] < 1.0)))
    reasons = []
    if max_gap > max_gap_deg:
        reasons.append(f"camera azimuths leave a {max_gap:.0f} degree sector empty (limit {max_gap_deg:.0f})")
    if dup:
        reasons.append(f"{dup} pairs of views share one pose")
    return {"folded": bool(reasons), "reason": "; ".join(reasons), "max_azimuth_gap_deg": max_gap,
            "duplicate_pairs": dup}
