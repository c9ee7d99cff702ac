"""Is a NeRF unique? (issue 19, part 1): the exact claims of recon.nerf.uniqueness.

- the three-camera triangulation's ghost points at their closed-form positions;
- two voxel fields whose training renders are bitwise identical but differ at a held-out view;
- the linear map colour -> images: full column rank for constant sigma with enough views, a null
  space of the predicted dimension (empty plus occluded cells) for an opaque block.
Everything is deterministic (no sampling); small grids keep the file at a few seconds.
"""
import json
import math
import subprocess
import sys

import numpy as np
import pytest
import torch

from recon.nerf.uniqueness import (ThreeCameraScene, blob_centroids, colour_matrix, cup_field, ghost_points_closed_form,
                                   hidden_cells, numerical_rank, ortho_views_of_box, pair_triangulations, render_field,
                                   render_spheres, replace_hidden, ring_cameras, sphere_directions,
                                   triangulate_orthographic)
from recon.nerf.volume import VoxelField, render_voxels_exact


def _rays(cams):
    o, d = zip(*(c.pixel_rays() for c in cams))
    return torch.as_tensor(np.concatenate(o)), torch.as_tensor(np.concatenate(d))


# ---------------------------------------------------------------- 1. three orthographic cameras


def test_ghost_points_of_three_camera_triangulation_at_closed_form():
    """The slide's case: B seen by blue, red, green, the red camera's azimuth off by delta.
    Triangulating B's exact projections with the nominal poses: blue+red -> purple, red+green ->
    yellow, blue+green -> B, least squares -> B + (2/3) Delta r_R (cameras 120 deg apart), each
    at the closed form B - Delta / sin(theta_R - theta_k) (cos theta_k, sin theta_k, 0)
    written out here from the angles; A, on the rotation axis, triangulates exactly."""
    scene = ThreeCameraScene()
    A, B = scene.points()
    true_cams, nominal = scene.cameras(True), scene.cameras(False)
    uv = np.stack([c.project(scene.points()) for c in true_cams])               # (3, 2, 2)
    got = pair_triangulations(nominal, uv[:, 1])
    rho, phi = math.hypot(B[0], B[1]), math.atan2(B[1], B[0])
    tb, tr, tg = np.radians(scene.azimuths)
    shift = rho * (math.sin(phi - tr - math.radians(scene.red_error_deg)) - math.sin(phi - tr))
    expected = {"purple": B - shift / math.sin(tr - tb) * np.array([math.cos(tb), math.sin(tb), 0.0]),
                "yellow": B - shift / math.sin(tr - tg) * np.array([math.cos(tg), math.sin(tg), 0.0]),
                "blue_green": B,
                "least_squares": B + 2.0 / 3.0 * shift * np.array([-math.sin(tr), math.cos(tr), 0.0])}
    for name, point in expected.items():
        np.testing.assert_allclose(got[name], point, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(ghost_points_closed_form(scene)[name], point, atol=1e-12, err_msg=name)
    # the ghosts are real ghosts here: an equilateral triangle of side |Delta| / sin 60 around B's corner
    side = abs(shift) / math.sin(math.radians(60))
    for a, b in (("purple", "yellow"), ("purple", "blue_green"), ("yellow", "blue_green")):
        assert np.linalg.norm(got[a] - got[b]) == pytest.approx(side, rel=1e-12)
    assert side > 2 * scene.radius                                              # distinct from B's sphere
    np.testing.assert_allclose(triangulate_orthographic(nominal, uv[:, 0]), A, atol=1e-12)


def test_sphere_images_match_the_exact_chord_and_blobs_match_projections():
    """render_spheres against the closed form c (1 - exp(-sigma 2 sqrt(r^2 - b^2))) for a ray at
    offset b from a centre, and the study's colour matching finds each sphere within 0.5 px."""
    scene = ThreeCameraScene()
    b = 0.03
    o = torch.tensor([[b, -2.0, 0.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64)
    rgb = render_spheres(o, d, torch.zeros(1, 3, dtype=torch.float64), scene.radius, scene.sigma,
                         torch.tensor([[0.5, 0.25, 1.0]], dtype=torch.float64))
    alpha = -math.expm1(-scene.sigma * 2 * math.sqrt(scene.radius ** 2 - b ** 2))
    np.testing.assert_allclose(rgb[0].numpy(), alpha * np.array([0.5, 0.25, 1.0]), rtol=1e-12)
    for cam in scene.cameras(True):
        found = blob_centroids(scene.image(cam), np.array([scene.colour_a, scene.colour_b]))
        assert np.abs(found - cam.project(scene.points())).max() < 0.5


# ---------------------------------------------------------------- 2. different fields, same images


def test_fields_differing_in_hidden_cells_render_training_views_identically():
    """A cup (opaque block with a well) seen from a 25-degree ring of 8 views: cells every training
    ray reaches with transmittance exactly 0 get a dense magenta fog (the well's hidden bottom) or
    lose their density (the block's inside). The training renders are bitwise identical; a
    held-out view from straight above looks into the well and differs. The renders are the
    project's exact voxel quadrature (render_voxels_exact)."""
    field = cup_field(12)
    train = ring_cameras(25.0, 8, 16, 45.0)
    o, d = _rays(train)
    hidden = hidden_cells(field, o, d)
    well_air = hidden & (field.sigma == 0)
    assert int(well_air.sum()) > 0 and int((hidden & (field.sigma > 0)).sum()) > 0
    other = replace_hidden(field, hidden, 200.0, (1.0, 0.0, 1.0))
    other = VoxelField(torch.where(hidden & (field.sigma > 0), torch.zeros_like(field.sigma), other.sigma),
                       other.rgb, field.lo, field.hi)
    assert float((other.sigma - field.sigma).abs().max()) >= 1e9                # "large norm"
    a, b = render_field(field, o, d), render_field(other, o, d)
    assert torch.equal(a, b)
    np.testing.assert_allclose(a.numpy(), render_voxels_exact(field, o, d).rgb.numpy(), rtol=0, atol=1e-12)
    assert float(a.max()) > 0.2                                                  # the views do see the cup
    ho, hd = _rays(ring_cameras(90.0, 1, 16, 45.0))
    held_a, held_b = render_field(field, ho, hd), render_field(other, ho, hd)
    assert torch.isfinite(held_b).all()
    assert float((held_a - held_b).abs().max()) > 0.5


def test_hidden_set_shrinks_when_views_are_added():
    """Adding the 50-degree ring to the 25-degree one can only reveal cells: the hidden set of the
    union is the intersection of the hidden sets, and here strictly smaller in the well."""
    field = cup_field(12)
    sets = [ring_cameras(25.0, 8, 16, 45.0), ring_cameras(50.0, 8, 16, 45.0, azimuth_offset_deg=22.5)]
    h25 = hidden_cells(field, *_rays(sets[0]))
    h50 = hidden_cells(field, *_rays(sets[1]))
    both = hidden_cells(field, *_rays(sets[0] + sets[1]))
    assert torch.equal(both, h25 & h50)
    air = field.sigma == 0
    assert int((both & air).sum()) < int((h25 & air).sum())


# ---------------------------------------------------------------- 3. tomography's linear case


def test_linear_map_full_rank_for_constant_sigma_and_predicted_null_space_for_occluded_cells():
    """colour -> pixels is A c with A from the fixed density. (a) A reproduces the renders
    (linearity, 1e-12). (b) Constant sigma (optical depth 0.5 per cell) on a 4^3 grid seen by 6
    orthographic views: full column rank 64, smallest singular value above 1e-4 of the largest.
    (c) An opaque 4^3 block in a 6^3 grid seen along the six axes and four oblique directions: every column of an empty cell
    (alpha = 0) or an interior block cell (T = 0) is zero, and the shell's 4^3 - 2^3 = 56 cells are
    each first hit by some ray: rank 56, null space 216 - 56 = 160 exactly."""
    n = 4
    const = VoxelField(torch.full((n, n, n), 0.5 * n, dtype=torch.float64),
                       torch.rand(n, n, n, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)),
                       (-0.5,) * 3, (0.5,) * 3)
    o, d = _rays(ortho_views_of_box(sphere_directions(6), 12))
    A = colour_matrix(const, o, d)
    np.testing.assert_allclose(A @ const.rgb.reshape(-1, 3).numpy(), render_field(const, o, d).numpy(), atol=1e-12)
    rank, s = numerical_rank(A)
    assert rank == n ** 3 and s[-1] / s[0] > 1e-4
    m, n = 4, 6
    sigma = torch.zeros(n, n, n, dtype=torch.float64)
    sigma[1:5, 1:5, 1:5] = 1e12
    block = VoxelField(sigma, torch.zeros(n, n, n, 3, dtype=torch.float64), (-0.5,) * 3, (0.5,) * 3)
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
    # six axis views alone cannot tell a leak through the shell (each interior line repeats one
    # row pattern): four oblique views make the occluded cells' columns identifiable if nonzero
    A = colour_matrix(block, *_rays(ortho_views_of_box(np.concatenate([axes, sphere_directions(4)]), 18)))
    rank, _ = numerical_rank(A)
    assert rank == m ** 3 - (m - 2) ** 3
    assert n ** 3 - rank == 160


# ---------------------------------------------------------------- the study's entry point


def test_study_entry_point_quick_run_and_bad_input(tmp_path):
    """``python -m recon.nerf.uniqueness OUT --quick`` writes every figure and a summary whose
    exact claims hold; bad input is exit 2 with one stderr line naming the option or folder."""
    out = tmp_path / "study"
    run = subprocess.run([sys.executable, "-m", "recon.nerf.uniqueness", str(out), "--quick", "--minutes", "0.1"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    for name in ("ghost_points.csv", "three_cameras.csv", "three_cameras.png", "same_images.csv", "same_images.png",
                 "linear_rank.csv", "linear_rank.png", "summary.json"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert all(r["train_bitwise_identical"] for r in summary["same_images"]["rows"])
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())          # no partial folder left
    bad = subprocess.run([sys.executable, "-m", "recon.nerf.uniqueness", str(tmp_path / "x"), "--minutes", "0"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--minutes" in bad.stderr
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "keep.txt").write_text("user data")
    bad = subprocess.run([sys.executable, "-m", "recon.nerf.uniqueness", str(tmp_path / "foreign")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "foreign" in bad.stderr
    assert (tmp_path / "foreign" / "keep.txt").read_text() == "user data"
