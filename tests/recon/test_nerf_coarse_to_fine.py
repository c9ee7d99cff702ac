"""The fast NeRF's coarse-to-fine training: pyramid levels of training pixels (``pixel_schedule``,
``PixelSampler(views, factor)``) and appearance grids grown past the density's (``app_res_final``)."""
from dataclasses import replace

import numpy as np
import pytest
import torch

from recon.nerf.data import PixelSampler, area_downsample, camera_rays, load_data
from recon.nerf.models import FastConfig, FastNeRF
from recon.nerf.train import TrainConfig, pixel_samplers, pixel_schedule, sampler_at, train

from .nerf_fixtures import FAST_SMALL, SIZE, make_tiny_capture


@pytest.fixture(scope="module")
def full_data(tmp_path_factory):
    return load_data(make_tiny_capture(tmp_path_factory.mktemp("c2f") / "capture"), downsample=4, train_full=True)


def test_pyramid_level_pairs_each_ray_with_its_averaged_pixel(full_data):
    """A level of factor 2: the rays through the centres of the capture's 2x2 blocks (the camera
    scaled by 1/2) with those blocks' mean colour; every sample is found among them."""
    s = PixelSampler(full_data.train, 2)
    assert (s.width, s.height) == (SIZE[0] // 2, SIZE[1] // 2)
    o, d, c = s.sample(300, torch.Generator().manual_seed(0))
    cams = [replace(v.full_camera, intrinsics=v.full_camera.intrinsics.scaled(0.5)) for v in full_data.train]
    rays = [camera_rays(cam) for cam in cams]
    all_o, all_d = torch.cat([r[0] for r in rays]), torch.cat([r[1] for r in rays])
    all_c = torch.cat([torch.from_numpy(area_downsample(v.full_rgb, 2).astype(np.float16).astype(np.float32)
                                        .reshape(-1, 3)) for v in full_data.train])
    gap = torch.cdist(torch.cat([o, d], 1), torch.cat([all_o, all_d], 1), compute_mode="donot_use_mm_for_euclid_dist")
    assert float(gap.min(dim=1).values.max()) < 1e-5
    assert torch.equal(c, all_c[gap.argmin(dim=1)])
    assert float(c.sum()) > 0


def test_pixel_schedule_picks_the_level_reached_and_refuses_bad_ones(full_data):
    cfg = replace(FastConfig(), pixel_schedule=((0.5, 4), (0.75, 2), (0.9, 1)))
    levels = pixel_samplers(full_data, cfg)
    assert [(p, s.factor) for p, s in levels] == [(0.5, 4), (0.75, 2), (0.9, 1)]
    assert sampler_at(levels, 0.49) is None                     # the working scale's rays
    assert sampler_at(levels, 0.5).factor == 4
    assert sampler_at(levels, 0.8).factor == 2
    assert sampler_at(levels, 1.0).factor == 1
    # the former switch is one level: capture pixels from full_res_from on
    assert pixel_schedule(FastConfig(pixel_schedule=(), train_full_res=True, full_res_from=0.3)) == [(0.3, 1)]
    assert pixel_schedule(FastConfig(pixel_schedule=())) == []
    assert pixel_schedule(FastConfig()) == [(0.4, 4), (0.6, 2), (0.8, 1)]   # the default since session 32
    for bad in (((0.5, 2), (0.4, 1)), ((0.5, 0),), ((1.5, 1),), ((0.5, 1.5),)):
        with pytest.raises(ValueError, match="pixel_schedule"):
            pixel_schedule(replace(FastConfig(), pixel_schedule=bad))
    assert FastConfig(pixel_schedule=((0.5, 2),)).needs_full_images()
    assert not FastConfig(pixel_schedule=()).needs_full_images()


def test_training_draws_each_level_once_reached(full_data, monkeypatch):
    """Step-bounded training (progress = step / max_steps) draws its batches from the working
    scale until the first level's progress, then from each level in turn."""
    drawn = []
    orig = PixelSampler.sample
    monkeypatch.setattr(PixelSampler, "sample", lambda self, n, g: drawn.append(self.factor) or orig(self, n, g))
    small = replace(full_data, train=full_data.train[:2], test=full_data.test[:1])
    ov = FAST_SMALL + (("pixel_schedule", ((0.5, 2), (0.75, 1))),)
    train(small, TrainConfig(model="fast", minutes=30, max_steps=20, eval_every_s=1e9, overrides=ov))
    assert drawn == [2] * 5 + [1] * 5   # steps 10-14 at progress 0.5-0.7, steps 15-19 from 0.75


def test_appearance_grows_past_the_density_and_keeps_the_field():
    """After the shared upsamplings the appearance planes grow alone, geometrically to
    app_res_final; the density is untouched (bit for bit) and the colour field nearly so (bilinear
    resampling of a smooth field); param_bytes_final is the grown model's size."""
    cfg = FastConfig(res_init=16, res_final=24, upsample_at=(0.2,), app_res_final=96, app_upsample_at=(0.5, 0.7),
                     n_comp_app=6, n_comp_sigma=4, occ_start=10 ** 9)
    m = FastNeRF(cfg, [-1, -1, -1], [1, 1, 1], seed=0)
    with torch.no_grad():  # a smooth field, so that resampling it keeps it to a small tolerance
        for vm in (m.density_vm, m.app_vm):
            r = torch.linspace(-1, 1, vm.res)
            vm.planes.copy_(torch.sin(2 * r)[None, None, :, None] * torch.cos(r)[None, None, None, :]
                            * torch.linspace(0.5, 1.5, vm.planes.shape[1])[None, :, None, None])
            vm.lines.copy_(torch.cos(1.5 * r)[None, None, :, None].expand_as(vm.lines))
    assert m.on_progress(0.2)
    assert (m.density_vm.res, m.app_vm.res) == (24, 24)
    assert not m.on_progress(0.4)
    x = torch.rand(2000, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    sh = torch.zeros(2000, 16)
    with torch.no_grad():
        sig0, col0, feat0 = m.density(x), m.colour(x, sh), m.app_vm.components(x)
    assert m.on_progress(0.5)
    assert (m.density_vm.res, m.app_vm.res) == (24, 48)   # geometric: 24 * (96 / 24) ** (1 / 2)
    assert m.on_progress(0.9)
    assert (m.density_vm.res, m.app_vm.res) == (24, 96)
    assert not m.on_progress(1.0)
    with torch.no_grad():
        assert torch.equal(m.density(x), sig0)
        feat1 = m.app_vm.components(x)
        assert float((feat1 - feat0).abs().max()) < 0.02 * float(feat0.abs().max())
        assert float((m.colour(x, sh) - col0).abs().max()) < 0.01
    assert m.param_bytes_final() == sum(p.numel() * p.element_size() for p in m.parameters())
    # a checkpoint of the grown model loads into a fresh one
    fresh = FastNeRF(cfg, [-1, -1, -1], [1, 1, 1], seed=1)
    fresh.load_state_dict(m.state_dict())
    assert fresh.app_vm.res == 96 and int(fresh.app_stage) == 2


def test_working_scale_figure_of_a_capture_size_render_is_its_area_average(full_data):
    """With the capture-size render, the working scale's display PSNR scores that render
    area-averaged to the working size (as the reference is), display_psnr_point the working
    scale's own one ray per pixel."""
    from recon.nerf.train import evaluate_view, render_view
    from render.metrics import psnr, to_display

    small = replace(full_data, train=full_data.train[:2], test=full_data.test[:1])
    res = train(small, TrainConfig(model="fast", minutes=30, max_steps=30, eval_every_s=1e9, overrides=FAST_SMALL))
    v = small.test[0]
    row, out = evaluate_view(res.model, v, full_res=True)
    big = render_view(res.model, v.full_camera)["rgb"]
    f = v.full_camera.intrinsics.width // v.camera.intrinsics.width
    assert f == 4 and out["rgb"].shape == big.shape
    assert row["display_psnr"] == pytest.approx(psnr(to_display(area_downsample(big, f)), to_display(v.rgb)))
    point = render_view(res.model, v.camera)["rgb"]
    assert row["display_psnr_point"] == pytest.approx(psnr(to_display(point), to_display(v.rgb)))
    assert row["display_psnr_full"] == pytest.approx(psnr(to_display(big), to_display(v.full_rgb)))
