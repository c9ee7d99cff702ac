"""Helpers for the path tracer's tests: small scenes, probe cameras, image Z-tests."""
from __future__ import annotations

import numpy as np
import trimesh
from scipy import stats

from cornell_box import cornell_camera, cornell_scene, quads_mesh  # noqa: F401  (tests/render/cornell_box.py)
from render.camera import Camera, Intrinsics
from render.poses import look_at
from render.scene import Emissive, Lambertian, Scene, SceneObject

CORNELL_RES = 16
CORNELL_REF_SPP = 2048
CORNELL_EFFECTS_DIRECT = frozenset({"direct", "soft_shadows"})


def quad(center, half_u, half_v, normal_sign: float = 1.0) -> trimesh.Trimesh:
    """Axis-aligned rectangle in the plane z = center[2]; normal +z (or -z if normal_sign < 0)."""
    cx, cy, cz = center
    corners = [[cx - half_u, cy - half_v, cz], [cx + half_u, cy - half_v, cz],
               [cx + half_u, cy + half_v, cz], [cx - half_u, cy + half_v, cz]]
    m = quads_mesh([corners])
    if np.sign(m.face_normals[0, 2]) != np.sign(normal_sign):
        m.invert()
    return m


def disk(center, radius: float, segments: int, normal_sign: float = -1.0) -> trimesh.Trimesh:
    """Regular ``segments``-gon of circumradius ``radius`` in the plane z = center[2] (triangle fan)."""
    a = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a), np.full(segments, center[2])], 1)
    v = np.vstack([np.asarray(center, float)[None], ring])
    f = np.stack([np.zeros(segments, int), 1 + np.arange(segments), 1 + (np.arange(segments) + 1) % segments], 1)
    m = trimesh.Trimesh(v, f, process=False)
    if np.sign(m.face_normals[0, 2]) != np.sign(normal_sign):
        m.invert()
    return m


def receiver_box(albedo, half: float = 10.0, thickness: float = 0.1) -> SceneObject:
    """Convex diffuse slab whose top face is the plane z = 0."""
    box = trimesh.creation.box([2 * half, 2 * half, thickness])
    box.apply_translation([0, 0, -thickness / 2])
    return SceneObject("receiver", box, Lambertian(albedo))


def probe_camera(target, eye, size: int = 4, fov_deg: float = 0.02, up=(0, 0, 1)) -> Camera:
    """A tiny, very narrow camera whose image centre looks exactly at ``target``."""
    c2w = look_at(np.asarray(eye, float), np.asarray(target, float), np.asarray(up, float))
    return Camera(Intrinsics.from_fov(size, size, fov_deg), c2w, "probe")


def image_mean_and_se(result) -> tuple[np.ndarray, np.ndarray]:
    """(3,) mean over all pixels and its standard error from the variance image."""
    p = result.mean.shape[0] * result.mean.shape[1]
    m = result.mean.reshape(-1, 3).astype(np.float64).mean(0)
    se = np.sqrt(result.variance.reshape(-1, 3).astype(np.float64).sum(0)) / p
    return m, se


# One-number furnaces (pbrt-v4's integrator test: L = 1 inside a closed emitting sphere): the
# image mean must lie within q standard errors of the closed form, q the two-sided quantile at
# FURNACE_ALPHA per channel (normal: 4.0; Student t when the se comes from K independent groups),
# and q se must stay below FURNACE_MAX_TOL so that a 2% bias cannot pass on noise alone.
FURNACE_ALPHA = 6.3e-5
FURNACE_MAX_TOL = 0.0125


def assert_furnace_mean(m, se, expected: float = 1.0, dof: int | None = None) -> float:
    """Assert |m - expected| < q se per channel (m, se: (3,)), q at FURNACE_ALPHA (normal, or
    Student t with ``dof`` degrees of freedom), and q se < FURNACE_MAX_TOL. Returns max |z|."""
    m, se = np.asarray(m, np.float64), np.asarray(se, np.float64)
    q = stats.norm.ppf(1 - FURNACE_ALPHA / 2) if dof is None else stats.t.ppf(1 - FURNACE_ALPHA / 2, dof)
    assert np.all(np.isfinite(m)) and np.all(se > 0), (m, se)
    assert np.all(q * se < FURNACE_MAX_TOL), f"furnace too noisy to see a 2% bias: q se = {q * se}"
    z = np.abs(m - expected) / se
    assert np.all(z < q), f"image mean {m} vs {expected}: |z| = {z} >= {q:.2f} (se {se})"
    return float(z.max())


def _blocks(img: np.ndarray, b: int, var: bool) -> np.ndarray:
    """Average (H, W, 3) over b x b pixel blocks (a block mean's variance is sum var / b^4)."""
    h, w = img.shape[0] // b * b, img.shape[1] // b * b
    x = img[:h, :w].reshape(h // b, b, w // b, b, 3).sum((1, 3))
    return x / (b ** 4 if var else b * b)


#: degrees of freedom treated as infinite (the normal distribution)
_DOF_INF = 1e7


def variance_for_test(result) -> tuple[np.ndarray, np.ndarray]:
    """((H, W, 3) float64 variance of each pixel mean, (H, W, 3) float64 its degrees of freedom)
    as the image tests use them.

    Independent samples (and the independent groups of sppm and pssmlt): the film's variance,
    n - 1 degrees of freedom. The Sobol sampler (a film with replicate sums): the spread of its
    R' replicate means (render.film.Film.variance), R' - 1 degrees of freedom, under which
    (mean - truth) / sqrt(var) is Student's t when the replicate means are normal. They are not
    where a pixel straddles an edge (a light's border: each replicate's stratified points put
    the same count on the light, so all R' replicate means can coincide and the estimate is 0
    while the error is not; seen on the Cornell box at 1024 spp). There the i.i.d. estimate
    s^2 / n of the same samples is used whenever it is larger, with n - 1 degrees of freedom:
    no pixel is held to a stricter yardstick than the same samples would be if independent."""
    film = result.film
    h, w = result.mean.shape[:2]
    var = result.variance.astype(np.float64)
    n = film.n.astype(np.float64).reshape(h, w, 1)
    dof_iid = np.broadcast_to(np.maximum(n - 1.0, 0.0), var.shape)
    if film.r1 is None:
        return var, np.array(dof_iid)
    nn = np.maximum(n, 2.0)
    s1, s2 = film.s1.reshape(h, w, 3), film.s2.reshape(h, w, 3)
    var_iid = np.where(n >= 2, np.maximum(s2 - s1 * s1 / nn, 0.0) / (nn * (nn - 1.0)), 0.0)
    reps = float(max(int(np.count_nonzero(film.rn)) - 1, 0))
    use_iid = var_iid > var
    return np.where(use_iid, var_iid, var), np.where(use_iid, dof_iid, reps)


def welch_dof(va: np.ndarray, nua: np.ndarray, vb: np.ndarray, nub: np.ndarray) -> np.ndarray:
    """Welch-Satterthwaite degrees of freedom of va + vb, two independent variance estimates
    with nua and nub degrees of freedom (broadcast): (va + vb)^2 / (va^2 / nua + vb^2 / nub);
    _DOF_INF where both variances are 0."""
    den = np.where(nua > 0, va * va / np.maximum(nua, 1e-300), np.where(va > 0, np.inf, 0.0)) \
        + np.where(nub > 0, vb * vb / np.maximum(nub, 1e-300), np.where(vb > 0, np.inf, 0.0))
    num = (va + vb) ** 2
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), _DOF_INF).clip(1.0, _DOF_INF)


def compare_images(a, b, alpha: float = 0.01, block: int = 1, trim: float = 0.05):
    """Two independent renders of the same view (``b`` the reference): per-pixel two-sample
    tests with both variance images, at a per-channel level Sidak-corrected to ``alpha`` over
    all pixel channels (Mitsuba 3's render tests), and a global Z-test of the image means.

    Per pixel channel, t = |a - b| / sqrt(var_a + var_b) is compared with Student's t at the
    Welch-Satterthwaite degrees of freedom of the two variance estimates
    (:func:`variance_for_test`: R - 1 for the Sobol sampler's R replicates, n - 1 for n
    independent samples, where t is the normal Z-test), so a 16-replicate reference is not
    held to normal thresholds.

    block: compare b x b block means instead of pixels (for heavy-tailed estimators whose
    per-pixel variance estimates are unreliable at test sample counts; a block's degrees of
    freedom by Welch-Satterthwaite over its pixels). trim: the fraction of pixel channels with
    the largest *reference* variance (light edges, where one sample is 0 or Le) left out of the
    global test; chosen from the reference alone, so the test stays valid (its sum of variances
    has hundreds of degrees of freedom or more: normal).
    Returns (fraction of pixel channels passing, largest per-channel global z, the per-pixel
    threshold at the smallest degrees of freedom).
    """
    ma, mb = a.mean.astype(np.float64), b.mean.astype(np.float64)
    va, nua = variance_for_test(a)
    vb, nub = variance_for_test(b)
    if block > 1:
        def block_dof(v, nu):  # Welch-Satterthwaite of a sum of b^2 pixel variances
            s = _blocks(v, block, False) * block * block
            d = _blocks(np.where(nu > 0, v * v / np.maximum(nu, 1e-300), 0.0), block, False) * block * block
            return np.where(d > 0, s * s / np.where(d > 0, d, 1.0), _DOF_INF)

        nua, nub = block_dof(va, nua), block_dof(vb, nub)
        ma, mb, va, vb = _blocks(ma, block, False), _blocks(mb, block, False), _blocks(va, block, True), _blocks(vb, block, True)
    n = ma.size
    alpha_px = 1.0 - (1.0 - alpha) ** (1.0 / n)
    nu = welch_dof(va, nua, vb, nub)
    thr_px = stats.t.ppf(1.0 - alpha_px / 2, nu)
    thr = float(thr_px.max())
    diff = np.abs(ma - mb)
    sd = np.sqrt(va + vb)
    z = np.where(sd > 0, diff / np.maximum(sd, 1e-300), np.where(diff <= 1e-6 * (np.abs(mb) + 1e-12), 0.0, np.inf))
    frac = float(np.mean(z <= thr_px))
    gz = 0.0
    for c in range(3):
        vbc = vb[..., c].ravel()
        keep = vbc <= np.quantile(vbc, 1.0 - trim)
        d = (ma[..., c].ravel() - mb[..., c].ravel())[keep].sum()
        s = np.sqrt((va[..., c].ravel() + vbc)[keep].sum())
        gz = max(gz, abs(d) / s if s > 0 else (0.0 if abs(d) < 1e-9 else np.inf))
    return frac, float(gz), thr


def assert_images_agree(a, b, alpha: float = 0.01, block: int = 1):
    """Assert :func:`compare_images` passes: >= 99.75% of pixel channels and the global test."""
    frac, gz, thr = compare_images(a, b, alpha, block)
    zcrit = stats.norm.ppf(1 - (1 - (1 - alpha) ** (1 / 3)) / 2)
    assert frac >= 0.9975, f"only {frac:.4f} of pixel channels pass the Z-test (threshold {thr:.2f})"
    assert gz < zcrit, f"image means differ: global z = {gz:.2f} >= {zcrit:.2f} (alpha {alpha})"




def caustic_scene(light_half: float = 0.2):
    """scenes/glass_caustic.yaml built in code: glass ball (r 0.5, ior 1.5) over a floor of
    albedo 0.6 under a 0.4 x 0.4 source of radiance 100 at z = 3 (other sizes: side
    2 light_half at the same power); its camera at 64 x 64."""
    from render.scene import Dielectric

    ball = trimesh.creation.icosphere(3, 0.5)
    ball.apply_translation([0, 0, 0.8])
    sc = Scene("glass_caustic", [SceneObject("floor", quad((0, 0, 0), 3, 3), Lambertian(0.6)),
                                 SceneObject("ball", ball, Dielectric(1.5)),
                                 SceneObject("light", quad((0, 0, 3.0), light_half, light_half, normal_sign=-1.0),
                                             Emissive(np.full(3, 100.0 * (0.2 / light_half) ** 2)))])
    cam = Camera(Intrinsics.from_fov(64, 64, 45.0),
                 look_at(np.array([0, -3.2, 2.2]), np.array([0, 0, 0.4]), np.array([0.0, 0.0, 1.0])), "c")
    return sc, cam


def caustic_region(ps, cam: Camera, radius: float = 0.3) -> np.ndarray:
    """(H, W) bool: pixels whose first hit is the floor (object 0) within ``radius`` of the spot
    under the ball (the caustic of :func:`caustic_scene`)."""
    o, d = cam.pixel_rays()
    h = ps.accel.intersect(o, d)
    p = o + np.where(np.isfinite(h.t), h.t, 0.0)[:, None] * d
    k = cam.intrinsics
    return ((h.tri >= 0) & (ps.geom.obj[np.maximum(h.tri, 0)] == 0)
            & (np.hypot(p[:, 0], p[:, 1]) < radius)).reshape(k.height, k.width)
