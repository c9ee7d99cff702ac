"""Volume-rendering quadrature: closed forms, gradients, and the hard numerical cases (named)."""
import numpy as np
import pytest
import torch

from recon.nerf.volume import (TAU_MAX, VoxelField, alpha_from_tau, composite, composite_constant,
                           exclusive_transmittance, ray_aabb, render_voxels_exact, render_voxels_quadrature,
                           voxel_segments)

DTYPES = [torch.float32, torch.float64]


def _check_bounded(out, sigma=None):
    w = out.weights
    assert torch.isfinite(w).all() and torch.isfinite(out.rgb).all() and torch.isfinite(out.distance).all()
    assert (w >= 0).all() and (w <= 1).all()
    eps = 1e-6 if w.dtype == torch.float32 else 1e-12
    assert (w.sum(-1) <= 1 + eps).all()
    assert (out.opacity >= 0).all() and (out.opacity <= 1).all()


# ---------------------------------------------------------------- closed forms


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("sigma,length", [(0.3, 2.0), (5.0, 1.0), (50.0, 0.1), (1e-4, 3.0)])
def test_constant_sigma_and_colour_matches_closed_form(dtype, sigma, length):
    """Constant sigma and c: the quadrature is exact for any segmentation, c (1 - exp(-sigma T))."""
    c = torch.tensor([0.2, 0.5, 0.9], dtype=dtype)
    bg = torch.tensor([0.1, 0.0, 0.3], dtype=dtype)
    for n in (1, 7, 128):
        delta = torch.full((1, n), length / n, dtype=dtype)
        out = composite(torch.full((1, n), sigma, dtype=dtype), c.expand(1, n, 3), delta, background=bg,
                        stop_transmittance=0.0)
        want = composite_constant(sigma, c.numpy(), length, bg.numpy())
        tol = 1e-6 if dtype == torch.float32 else 1e-13
        np.testing.assert_allclose(out.rgb[0].double().numpy(), want, rtol=tol, atol=tol)
        np.testing.assert_allclose(float(out.opacity[0]), -np.expm1(-sigma * length), rtol=tol, atol=tol)


def test_expected_distance_of_constant_medium():
    """Constant sigma on [0, L]: E[t | absorbed] = 1/sigma - L e^{-sigma L} / (1 - e^{-sigma L})."""
    s, L, n = 2.0, 3.0, 20000
    delta = torch.full((1, n), L / n, dtype=torch.float64)
    out = composite(torch.full((1, n), s, dtype=torch.float64), torch.ones(1, n, 3, dtype=torch.float64), delta,
                    stop_transmittance=0.0)
    want = 1 / s - L * np.exp(-s * L) / (1 - np.exp(-s * L))
    assert abs(float(out.distance[0]) - want) < 1e-4


def test_transmittance_is_exclusive_cumsum():
    tau = torch.tensor([[0.5, 1.0, 2.0]], dtype=torch.float64)
    T = exclusive_transmittance(tau)
    np.testing.assert_allclose(T[0].numpy(), np.exp(-np.array([0.0, 0.5, 1.5])), rtol=1e-15)


def test_alpha_has_no_cancellation_for_tiny_tau():
    tau = torch.tensor([1e-12, 1e-30], dtype=torch.float64)
    np.testing.assert_allclose(alpha_from_tau(tau).numpy(), [1e-12, 1e-30], rtol=1e-10)


# ---------------------------------------------------------------- gradients


def test_gradcheck_float64():
    g = torch.Generator().manual_seed(0)
    sigma = (torch.rand(3, 6, generator=g, dtype=torch.float64) * 4).requires_grad_()
    rgb = torch.rand(3, 6, 3, generator=g, dtype=torch.float64).requires_grad_()
    delta = (torch.rand(3, 6, generator=g, dtype=torch.float64) * 0.5 + 0.01).requires_grad_()
    bg = torch.rand(3, dtype=torch.float64)

    def f(s, c, d):
        out = composite(s, c, d, background=bg, stop_transmittance=0.0)
        return out.rgb, out.opacity, out.distance

    assert torch.autograd.gradcheck(f, (sigma, rgb, delta), eps=1e-6, atol=1e-7)


# ---------------------------------------------------------------- hard cases (named)


@pytest.mark.parametrize("dtype", DTYPES)
def test_hard_case_huge_and_zero_densities(dtype):
    """Densities of 1e6 next to zeros, with zero, 1e-9 and ordinary segment lengths."""
    sigma = torch.tensor([[0.0, 1e6, 0.0, 1e6], [1e6, 1e6, 1e6, 1e6], [0.0, 0.0, 0.0, 0.0]], dtype=dtype,
                         requires_grad=True)
    delta = torch.tensor([[0.0, 1e-9, 0.1, 0.1], [0.0, 0.0, 1e-9, 1.0], [1.0, 0.0, 1e-9, 1.0]], dtype=dtype)
    rgb = torch.rand(3, 4, 3, dtype=dtype, generator=torch.Generator().manual_seed(1)).requires_grad_()
    out = composite(sigma, rgb, delta, background=0.5)
    _check_bounded(out)
    (out.rgb.sum() + out.distance.sum() + out.opacity.sum()).backward()
    assert torch.isfinite(sigma.grad).all() and torch.isfinite(rgb.grad).all()
    # row 0: 1e6 * 1e-9 = 1e-3 of absorption, then the 1e6 * 0.1 wall absorbs the rest
    assert float(out.opacity[0].detach()) == pytest.approx(1.0, abs=1e-6)
    assert float(out.weights[0, 1].detach()) == pytest.approx(-np.expm1(-1e-3), rel=1e-3)


@pytest.mark.parametrize("dtype", DTYPES)
def test_hard_case_zero_length_segments_contribute_nothing(dtype):
    sigma = torch.full((2, 5), 1e6, dtype=dtype)
    delta = torch.zeros(2, 5, dtype=dtype)
    out = composite(sigma, torch.ones(2, 5, 3, dtype=dtype), delta, background=torch.tensor([0.2, 0.3, 0.4], dtype=dtype))
    _check_bounded(out)
    assert (out.weights == 0).all() and (out.opacity == 0).all() and (out.distance == 0).all()
    np.testing.assert_allclose(out.rgb.double().numpy(), [[0.2, 0.3, 0.4]] * 2, rtol=1e-6)


@pytest.mark.parametrize("dtype", DTYPES)
def test_hard_case_all_transparent_ray_shows_background(dtype):
    sigma = torch.zeros(4, 64, dtype=dtype, requires_grad=True)
    out = composite(sigma, torch.ones(4, 64, 3, dtype=dtype), torch.full((4, 64), 0.01, dtype=dtype), background=0.25)
    _check_bounded(out)
    assert torch.allclose(out.rgb, torch.full_like(out.rgb, 0.25))
    out.rgb.sum().backward()
    assert torch.isfinite(sigma.grad).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_hard_case_all_opaque_ray_takes_first_colour(dtype):
    sigma = torch.full((4, 64), 1e6, dtype=dtype, requires_grad=True)
    rgb = torch.rand(4, 64, 3, dtype=dtype, generator=torch.Generator().manual_seed(2))
    out = composite(sigma, rgb, torch.full((4, 64), 0.01, dtype=dtype), background=0.9)
    _check_bounded(out)
    assert torch.allclose(out.rgb, rgb[:, 0], atol=1e-6)
    assert torch.allclose(out.opacity, torch.ones_like(out.opacity))
    out.rgb.sum().backward()
    assert torch.isfinite(sigma.grad).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_hard_case_infinite_optical_depth_is_clamped(dtype):
    """sigma * delta beyond TAU_MAX (even inf) behaves as an opaque wall, with finite gradients."""
    sigma = torch.tensor([[1.0, float("inf"), 1.0]], dtype=dtype, requires_grad=True)
    out = composite(sigma, torch.ones(1, 3, 3, dtype=dtype), torch.full((1, 3), 0.5, dtype=dtype))
    _check_bounded(out)
    out.rgb.sum().backward()
    assert torch.isfinite(sigma.grad).all()
    assert TAU_MAX * 0.5 > 100  # opaque to both precisions


def test_early_termination_changes_colour_by_at_most_the_threshold():
    g = torch.Generator().manual_seed(3)
    sigma = torch.rand(256, 128, generator=g, dtype=torch.float64) * 50
    rgb = torch.rand(256, 128, 3, generator=g, dtype=torch.float64)
    delta = torch.full((256, 128), 0.02, dtype=torch.float64)
    full = composite(sigma, rgb, delta, stop_transmittance=0.0)
    cut = composite(sigma, rgb, delta, stop_transmittance=1e-4)
    assert (cut.weights == 0).any()
    assert float((full.rgb - cut.rgb).abs().max()) <= 1e-4


def test_composite_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="shapes"):
        composite(torch.zeros(2, 3), torch.zeros(2, 4, 3), torch.zeros(2, 3))


# ---------------------------------------------------------------- voxel fields: exact vs quadrature


@pytest.fixture(scope="module")
def voxel_case():
    g = torch.Generator().manual_seed(4)
    res = (6, 5, 7)
    field = VoxelField(torch.rand(res, generator=g, dtype=torch.float64) * 4,
                       torch.rand(*res, 3, generator=g, dtype=torch.float64), (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    n = 64
    origins = torch.randn(n, 3, generator=g, dtype=torch.float64)
    origins = 3.0 * origins / origins.norm(dim=1, keepdim=True)
    target = (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * 1.5
    dirs = target - origins
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    # an axis-parallel ray and one that misses the box
    origins = torch.cat([origins, torch.tensor([[0.1, 0.2, -3.0], [5.0, 5.0, 5.0]], dtype=torch.float64)])
    dirs = torch.cat([dirs, torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)])
    return field, origins, dirs


def test_voxel_segments_tile_the_box_interval(voxel_case):
    field, o, d = voxel_case
    ts, te, cells = voxel_segments(field, o, d)
    t0, t1 = ray_aabb(o, d, field.lo, field.hi)
    length = (te - ts).sum(1)
    np.testing.assert_allclose(length.numpy(), (t1 - t0).clamp(min=0).numpy(), atol=1e-12)
    assert (te >= ts).all()
    assert float(length[-1]) == 0.0  # the miss


def test_voxel_exact_integral_of_uniform_field_is_closed_form(voxel_case):
    _, o, d = voxel_case
    res = (4, 4, 4)
    field = VoxelField(torch.full(res, 1.7, dtype=torch.float64), torch.full((*res, 3), 0.6, dtype=torch.float64),
                       (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    out = render_voxels_exact(field, o, d, background=0.1)
    t0, t1 = ray_aabb(o, d, field.lo, field.hi)
    L = (t1 - t0).clamp(min=0).numpy()
    want = np.stack([composite_constant(1.7, [0.6] * 3, li, 0.1) for li in L])
    np.testing.assert_allclose(out.rgb.numpy(), want, atol=1e-12)


def test_voxel_quadrature_converges_to_exact_integral(voxel_case):
    """Midpoint quadrature of a piecewise-constant field errs only in segments straddling a cell
    boundary: the max error over rays falls roughly as 1/n and is small at n = 4096."""
    field, o, d = voxel_case
    exact = render_voxels_exact(field, o, d, background=0.2).rgb
    errs = [float((render_voxels_quadrature(field, o, d, n, background=0.2).rgb - exact).abs().max())
            for n in (16, 256, 4096)]
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] < 5e-3
    assert errs[0] / errs[2] > 30


def test_voxel_exact_is_differentiable_in_the_field(voxel_case):
    field, o, d = voxel_case
    sigma = field.sigma.clone().requires_grad_()
    rgb = field.rgb.clone().requires_grad_()
    out = render_voxels_exact(VoxelField(sigma, rgb, field.lo, field.hi), o, d)
    out.rgb.sum().backward()
    assert torch.isfinite(sigma.grad).all() and torch.isfinite(rgb.grad).all()
    assert sigma.grad.abs().sum() > 0 and rgb.grad.abs().sum() > 0
