"""The fast NeRF's losses on the pyramid levels finer than the working scale: the tangent loss
(``fine_loss``: the display error linearised at the prediction, unbiased in linear light) and the
low-frequency supervision (``coarse_loss``, ``coarse_group``: pixels drawn in stratified groups inside
one working-scale pixel's footprint, ``PixelSampler.sample_blocks``, their rendered mean fitted to the
footprint's area average)."""
from dataclasses import replace

import numpy as np
import pytest
import torch

from recon.nerf.data import PixelSampler, area_downsample, camera_rays, load_data
from recon.nerf import train as train_mod
from recon.nerf.train import TrainConfig, fit_loss, srgb_encode, srgb_slope, train

from .nerf_fixtures import FAST_SMALL, SIZE, make_tiny_capture


@pytest.fixture(scope="module")
def full_data(tmp_path_factory):
    return load_data(make_tiny_capture(tmp_path_factory.mktemp("coarse") / "capture"), downsample=4, train_full=True)


def test_blocks_are_stratified_groups_with_their_area_average(full_data):
    """Capture pixels (level 1) in blocks of 4: each group of 4 has one pixel in each 2x2 cell of
    one block of one view, its rays the capture's pixel-centre rays and colours, and the block's
    target is the mean of its 16 pixels (linear, float16 images)."""
    s = PixelSampler(full_data.train, 1)
    o, d, c, block = s.sample_blocks(200, 4, 4, torch.Generator().manual_seed(0))
    assert o.shape == d.shape == c.shape == (800, 3) and block.shape == (200, 3)
    rays = [camera_rays(v.full_camera) for v in full_data.train]
    all_o, all_d = torch.cat([r[0] for r in rays]), torch.cat([r[1] for r in rays])
    imgs = [v.full_rgb.astype(np.float16).astype(np.float32) for v in full_data.train]
    all_c = torch.cat([torch.from_numpy(im.reshape(-1, 3)) for im in imgs])
    gap = torch.cdist(torch.cat([o, d], 1), torch.cat([all_o, all_d], 1), compute_mode="donot_use_mm_for_euclid_dist")
    assert float(gap.min(dim=1).values.max()) < 1e-5
    hit = gap.argmin(dim=1)
    assert torch.equal(c, all_c[hit])
    w, h = SIZE
    view, rest = (hit // (w * h)).reshape(200, 4), (hit % (w * h)).reshape(200, 4)
    row, col = rest // w, rest % w
    assert bool((view == view[:, :1]).all())                                    # one view per group
    assert bool((row // 4 == row[:, :1] // 4).all() and (col // 4 == col[:, :1] // 4).all())  # one block
    cell = (row % 4) // 2 * 2 + (col % 4) // 2
    assert bool((cell == torch.arange(4)[None, :]).all())                       # one pixel per 2x2 cell
    means = [area_downsample(im, 4) for im in imgs]
    expect = torch.stack([torch.from_numpy(means[int(v)][int(r) // 4, int(q) // 4])
                          for v, r, q in zip(view[:, 0], row[:, 0], col[:, 0])])
    assert torch.allclose(block, expect, atol=1e-6)
    assert float(block.sum()) > 0
    # every pixel as likely as with sample(): all 4 x 4 offsets inside the blocks are drawn
    assert len(set(((row % 4) * 4 + col % 4).reshape(-1).tolist())) == 16
    for bad in ((4, 3), (4, 9), (3, 4)):
        with pytest.raises(ValueError, match="coarse"):
            s.sample_blocks(10, *bad, torch.Generator())


def test_training_fits_the_group_means_on_the_fine_levels(full_data, monkeypatch):
    """With coarse_loss, the levels finer than the working scale draw their batches in groups
    (block = the working scale's factor over the level's); the working scale draws as before; the
    loss adds the groups' term (a larger weight: a larger loss on the same batch at the first fine
    step); a negative weight or a group that is not a square is refused."""
    drawn = []
    orig = PixelSampler.sample_blocks
    monkeypatch.setattr(PixelSampler, "sample_blocks",
                        lambda self, n, b, k, g: drawn.append((self.factor, b, k)) or orig(self, n, b, k, g))
    small = replace(full_data, train=full_data.train[:2], test=full_data.test[:1])
    ov = FAST_SMALL + (("pixel_schedule", ((0.5, 2), (0.75, 1))), ("coarse_loss", 1.0), ("coarse_group", 4))
    losses = {}
    for w in (0.0, 1.0, 8.0):
        seen = []
        ov_w = tuple(x for x in ov if x[0] != "coarse_loss") + (("coarse_loss", w),)
        train(small, TrainConfig(model="fast", minutes=30, max_steps=20, eval_every_s=1e9, overrides=ov_w),
              progress=lambda p: seen.append(p["loss"]))
        losses[w] = seen
        if w == 1.0:
            assert drawn == [(2, 2, 4)] * 5 + [(1, 4, 4)] * 5   # steps 10-14 at level 2, 15-19 at level 1
    assert losses[0.0][:10] == losses[1.0][:10] == losses[8.0][:10]   # the working scale: unchanged
    assert losses[8.0][10] > losses[1.0][10] > 0.0
    for bad in ((("coarse_loss", -1.0),), (("coarse_loss", 1.0), ("coarse_group", 3))):
        with pytest.raises(ValueError, match="coarse_"):
            train(small, TrainConfig(model="fast", minutes=30, max_steps=2, eval_every_s=1e9, overrides=ov + bad))


def test_srgb_slope_is_the_encodings_derivative():
    x = torch.cat([torch.linspace(0.0, 0.003, 50), torch.linspace(0.0032, 2.0, 500)]).double().requires_grad_()
    srgb_encode(x).sum().backward()
    assert torch.allclose(srgb_slope(x.detach()), x.grad, rtol=1e-9, atol=0)
    assert float(srgb_slope(torch.tensor([0.0]))) == pytest.approx(12.92)


def test_tangent_loss_is_minimised_by_the_linear_mean_and_the_display_one_is_darker():
    """Targets a ray cannot tell apart (one prediction for a dark and a bright pixel): the tangent
    loss's gradient vanishes at their linear mean; the display loss's minimiser is darker (its
    gradient there pushes down). Near the target both losses agree to first order."""
    target = torch.tensor([[0.002] * 3, [0.4] * 3], dtype=torch.float64)
    mean = target.mean(dim=0)

    def grad_at(value: torch.Tensor, kind: str) -> torch.Tensor:
        p = value.clone().requires_grad_()
        fit_loss([p.expand(2, 3)], target, kind).backward()
        return p.grad
    assert float(grad_at(mean, "tangent").abs().max()) < 1e-12
    assert float(grad_at(mean, "display").min()) > 0.0               # the display loss wants it darker
    assert float(grad_at(mean, "linear").abs().max()) < 1e-12
    grid = torch.linspace(0.01, 0.4, 3901, dtype=torch.float64)
    display = [float(fit_loss([g.expand(2, 3)], target, "display")) for g in grid]
    assert float(grid[int(np.argmin(display))]) < 0.75 * float(mean[0])
    pred = torch.full((4, 3), 0.2, dtype=torch.float64)
    near = pred * (1 + 1e-4 * torch.arange(1, 13, dtype=torch.float64).reshape(4, 3))
    assert float(fit_loss([near], pred, "tangent")) == pytest.approx(float(fit_loss([near], pred, "display")), rel=1e-3)
    with pytest.raises(ValueError, match="loss"):
        fit_loss([pred], pred, "huber")


def test_fine_loss_applies_to_the_levels_only(full_data, monkeypatch):
    """fine_loss "tangent": the working scale's steps keep the display loss, the pyramid levels'
    take the tangent one; an unknown fine_loss is refused naming the field."""
    kinds = []
    orig = train_mod.fit_loss
    monkeypatch.setattr(train_mod, "fit_loss", lambda preds, t, kind: kinds.append(kind) or orig(preds, t, kind))
    small = replace(full_data, train=full_data.train[:2], test=full_data.test[:1])
    ov = FAST_SMALL + (("pixel_schedule", ((0.5, 2), (0.75, 1))), ("fine_loss", "tangent"))
    train(small, TrainConfig(model="fast", minutes=30, max_steps=12, eval_every_s=1e9, overrides=ov))
    assert kinds == ["display"] * 6 + ["tangent"] * 6
    with pytest.raises(ValueError, match="fine_loss"):
        train(small, TrainConfig(model="fast", minutes=30, max_steps=2, eval_every_s=1e9,
                                 overrides=ov + (("fine_loss", "l1"),)))
