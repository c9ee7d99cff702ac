"""NeRF: encodings, sampling, data loading, models, training, checkpoints, the stage.

Everything runs on the tiny exact fog-cube capture of nerf_fixtures (32x24, 8 train + 2 test
views) with step-bounded training, so results are deterministic and the file stays fast.
"""
import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
import torch

from pipeline.artifacts import BadInput
from pipeline.stages.nerf import NerfStageConfig, run_nerf
from recon.nerf.data import NerfInputError, area_downsample, camera_rays, load_data, scene_box
from recon.nerf.encoding import PositionalEncoding, sh_encoding
from recon.nerf.models import MODELS, FastConfig, FastNeRF, make_model
from recon.nerf.sampling import sample_pdf, stratified
from recon.nerf.train import TrainConfig, render_view, srgb_encode, train
from render.color import linear_to_srgb
from render.image_io import read_exr

from .nerf_fixtures import FAST_SMALL, SIZE, make_tiny_capture, tiny_cameras

# small grids and batches: the tiny scene needs no more, and the file stays fast
VANILLA_SMALL = (("width", 32), ("n_coarse", 8), ("n_fine", 8), ("batch_rays", 64), ("curve_pixels", 64))


@pytest.fixture(scope="session")
def tiny_capture(tmp_path_factory):
    return make_tiny_capture(tmp_path_factory.mktemp("nerf") / "capture")


@pytest.fixture(scope="session")
def tiny_data(tiny_capture):
    return load_data(tiny_capture, downsample=1)


# ---------------------------------------------------------------- encodings


def test_positional_encoding_matches_formula():
    pe = PositionalEncoding(3, 4)
    x = torch.tensor([[0.1, -0.5, 0.9]])
    y = pe(x)
    assert y.shape == (1, pe.out_dim) == (1, 27)
    k = 3
    assert torch.allclose(y[0, 3 + 3 * k: 3 + 3 * (k + 1)], torch.sin(2.0 ** k * np.pi * x[0]))
    assert torch.allclose(PositionalEncoding(3, 0)(x), x)  # the "no PE" ablation is the identity


def test_sh_basis_is_orthonormal_on_the_sphere():
    """Monte Carlo Gram matrix of the 16 SH functions: 4 pi E[Y_i Y_j] = delta_ij. With 2e5
    uniform directions (seed 0) the standard error of each entry is below 0.01; tolerance 0.05."""
    g = torch.Generator().manual_seed(0)
    d = torch.randn(200_000, 3, generator=g, dtype=torch.float64)
    d /= d.norm(dim=1, keepdim=True)
    Y = sh_encoding(d)
    gram = 4 * np.pi * (Y.T @ Y) / d.shape[0]
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=0.05)


# ---------------------------------------------------------------- sampling


def test_stratified_samples_one_per_bin():
    t0, t1 = torch.tensor([1.0, 2.0]), torch.tensor([3.0, 2.5])
    t, edges = stratified(t0, t1, 8, True, torch.Generator().manual_seed(0))
    assert ((t >= edges[:, :-1]) & (t <= edges[:, 1:])).all()


def test_sample_pdf_follows_the_weights():
    """All weight on bin 5: every sample lands in it (up to the 1e-5 floor). Uniform weights: a
    Kolmogorov-Smirnov test against U(0, 1) at alpha = 0.01 (n = 4000, seed 1)."""
    from scipy.stats import kstest

    edges = torch.linspace(0, 1, 11)[None].repeat(2, 1)
    w = torch.zeros(2, 10)
    w[0, 5] = 1.0
    w[1] = 1.0
    s = sample_pdf(edges, w, 4000, True, torch.Generator().manual_seed(1))
    assert ((s[0] >= 0.5) & (s[0] <= 0.6)).float().mean() > 0.99
    assert kstest(s[1].numpy(), "uniform").pvalue > 0.01
    assert (s[:, 1:] >= s[:, :-1]).all()


# ---------------------------------------------------------------- data


def test_area_downsample_averages_blocks_and_rejects_odd_sizes():
    img = np.arange(4 * 6 * 3, dtype=np.float32).reshape(4, 6, 3)
    small = area_downsample(img, 2)
    assert small.shape == (2, 3, 3)
    assert small[0, 0, 0] == pytest.approx(img[:2, :2, 0].mean())
    with pytest.raises(NerfInputError, match="divisible"):
        area_downsample(img, 4)


def test_scene_box_contains_the_common_target_and_fits_every_view():
    cams, _ = tiny_cameras()
    lo, hi = scene_box(cams)
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-9)
    r = (hi - lo)[0] / 2
    # a ball of radius r about the centre is seen by every camera: its edge projects inside
    for c in cams:
        axis = c.cam_to_world[:3, 0]  # sideways
        uv, z = c.project(np.array([r * axis]))
        assert z[0] > 0 and 0 <= uv[0, 0] <= c.intrinsics.width


def test_downsampled_camera_rays_hit_block_centres(tiny_capture):
    data = load_data(tiny_capture, downsample=2)
    v = data.test[0]
    assert v.rgb.shape == (SIZE[1] // 2, SIZE[0] // 2, 3)
    # the small pixel (0, 0) centre is the full-res point (1, 1): the corner of 4 pixels
    o, d = v.camera.pixel_rays(np.array([[0.5, 0.5]]))
    o2, d2 = v.full_camera.pixel_rays(np.array([[1.0, 1.0]]))
    np.testing.assert_allclose(d, d2, atol=1e-12)


def test_camera_rays_of_chosen_pixels_are_the_whole_views_rays(tiny_capture):
    """camera_rays(camera, pixels) computes only those pixels' rays (a render probe of a few rows of a
    capture-size view must not pay for the whole view's): bit-identical to the whole view's rays at
    those indices, in the order given."""
    cam = tiny_cameras()[0][0]
    o, d = camera_rays(cam)
    px = torch.randperm(o.shape[0], generator=torch.Generator().manual_seed(3))[:50]
    o2, d2 = camera_rays(cam, px)
    assert torch.equal(o2, o[px]) and torch.equal(d2, d[px])


def test_poses_folder_replaces_train_cameras(tiny_capture, tmp_path):
    poses = tmp_path / "poses" / "gt"
    poses.mkdir(parents=True)
    shutil.copy(tiny_capture / "cameras.json", poses / "cameras.json")
    a = load_data(tiny_capture, downsample=1)
    b = load_data(tiny_capture, poses, downsample=1)
    assert [v.name for v in a.train] == [v.name for v in b.train]
    for va, vb in zip(a.train, b.train):
        np.testing.assert_array_equal(va.camera.cam_to_world, vb.camera.cam_to_world)
    # an estimate that lost a view (not registered) trains on the rest
    doc = json.loads((poses / "cameras.json").read_text())
    doc["cameras"] = [c for c in doc["cameras"] if c["name"] != "view_000"]
    (poses / "cameras.json").write_text(json.dumps(doc))
    c = load_data(tiny_capture, poses, downsample=1)
    assert "view_000" not in [v.name for v in c.train] and len(c.train) == len(a.train) - 1


def test_bad_inputs_name_the_file(tiny_capture, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(tiny_capture, bad)
    (bad / "linear" / "view_001.exr").unlink()
    with pytest.raises(NerfInputError, match="view_001.exr"):
        load_data(bad, downsample=1)
    (bad / "cameras.json").write_text("{not json")
    with pytest.raises(NerfInputError, match="cameras.json"):
        load_data(bad, downsample=1)


# ---------------------------------------------------------------- models


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_model_renders_finite_bounded_colours(name, tiny_data):
    m = make_model(name, tiny_data.lo, tiny_data.hi, seed=0)
    out = render_view(m, tiny_data.test[0].camera)
    assert out["rgb"].shape == (SIZE[1], SIZE[0], 3)
    for a in out.values():
        assert np.all(np.isfinite(a))
    assert out["rgb"].min() >= 0 and out["rgb"].max() <= 1


def test_vm_dense_grid_equals_pointwise_field_at_vertices():
    m = FastNeRF(replace(FastConfig(), res_init=9), (-1, -1, -1), (1, 1, 1))
    v = m.density_vm.dense()
    idx = torch.tensor([[0, 0, 0], [8, 3, 5], [2, 7, 1], [4, 4, 8]])
    x = idx.float() / 8 * 2 - 1
    pointwise = m.density_vm.components(x).sum(dim=(0, 1))
    assert torch.allclose(v[idx[:, 0], idx[:, 1], idx[:, 2]], pointwise, atol=1e-5)


def test_occupancy_grid_is_conservative():
    """Any point whose density per step exceeds the threshold lies in an occupied cell."""
    cfg = replace(FastConfig(), res_init=24, occ_res=8)
    m = FastNeRF(cfg, (-1, -1, -1), (1, 1, 1), seed=3)
    with torch.no_grad():
        m.density_vm.planes.mul_(30.0)  # a structured field: blobs of high density
        tau = m._sigma(m.density_vm.dense()) * m.step
    cfg = replace(cfg, occ_tau=float(tau.quantile(0.995)))
    m.cfg = cfg
    m.update_occupancy()
    assert 0 < m.occupancy.float().mean() < 1
    x = torch.rand(20000, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with torch.no_grad():
        dense = m.density(x) * m.step > cfg.occ_tau
    assert m._occupied(x)[dense].all()


# ---------------------------------------------------------------- training


def _psnr_black(data):
    mse = np.mean([np.mean(np.clip(v.rgb, 0, 1) ** 2) for v in data.test])
    return -10 * np.log10(mse)


@pytest.fixture(scope="session")
def trained_fast(tiny_data):
    cfg = TrainConfig(model="fast", minutes=30, max_steps=150, eval_every_s=1e9, overrides=FAST_SMALL)
    return train(tiny_data, cfg)


def test_fast_model_learns_the_tiny_scene(trained_fast, tiny_data):
    """After 150 steps the held-out PSNR beats the all-black prediction by more than 8 dB."""
    final = trained_fast.curve[-1]["linear_psnr"]
    assert final > _psnr_black(tiny_data) + 8, (final, _psnr_black(tiny_data))
    assert trained_fast.steps == 150


def test_inference_render_equals_the_training_quadrature(trained_fast, tiny_data):
    """Held-out rendering (the compiled march: occupied box, empty-space jumps, dense density
    grid, early termination; colour in one batch) against the training render's quadrature on
    the same samples: the opacity equal to float rounding; with every sample above
    COLOUR_MIN_WEIGHT coloured, the colour within the skipped weights' bound; with the default
    COLOUR_INFERENCE_WEIGHT (weights of the uncoloured samples spread over the coloured ones) at
    display PSNR >= 45 dB against it (measured 58.2 dB; the tiny fog cube's colour varies along
    every ray), on fewer colour evaluations."""
    from render.metrics import psnr, to_display
    from recon.nerf.models import COLOUR_MIN_WEIGHT
    m = trained_fast.model
    assert bool(m.occ_active) and m.prepare_inference()  # the dense grid, as a whole view uses
    assert int(m.skip_distance().max()) >= 2  # the tiny scene has empty space to jump over
    o, d = camera_rays(tiny_data.test[0].camera)
    with torch.no_grad():
        ref = m.render(o, d, training=False)
    every = m.render_inference(o, d, colour_weight=COLOUR_MIN_WEIGHT)
    fast = m.render_inference(o, d)
    for got in (every, fast):
        assert torch.all(torch.isfinite(got.rgb)) and float(ref.opacity.max()) > 0.5
        assert float((got.opacity - ref.opacity).abs().max()) < 1e-5
        assert float((got.distance - ref.distance).abs().max()) < 1e-4
    # every skipped sample has weight <= COLOUR_MIN_WEIGHT and colour <= 1; at most steps_per_side * sqrt(3) of them
    assert float((every.rgb - ref.rgb).abs().max()) <= COLOUR_MIN_WEIGHT * 96 * 3 ** 0.5
    assert psnr(to_display(fast.rgb.numpy()), to_display(ref.rgb.numpy())) >= 45.0
    assert fast.n_points < every.n_points < ref.n_points


def test_march_keeps_the_heavy_samples_and_the_heaviest_with_the_listed_weight(trained_fast, tiny_data):
    """The march's colour samples against their definition, ray by ray: from every sample above
    COLOUR_MIN_WEIGHT (colour_weight None lists them all, in order), the default keeps those above
    COLOUR_INFERENCE_WEIGHT and each ray's heaviest, in order, their weights scaled to the listed
    ones' sum. And room for one sample a ray (the rest marched again, those rays only) returns
    what room for all does."""
    from recon.nerf.march_kernels import march
    from recon.nerf.models import COLOUR_INFERENCE_WEIGHT
    m = trained_fast.model
    o, d = camera_rays(tiny_data.test[0].camera)
    args = m.march_inputs(o, d)
    op_a, wt_a, n_a, t_a, w_a, ev_a = march(*args, colour_weight=None, threads=1)
    got = march(*args, colour_weight=COLOUR_INFERENCE_WEIGHT, threads=2)
    op, wt, n, t, w, ev = got
    assert np.array_equal(op, op_a) and np.array_equal(wt, wt_a) and np.array_equal(ev, ev_a)
    light_only = 0
    for r in range(o.shape[0]):
        tl, wl = t_a[r, :n_a[r]], w_a[r, :n_a[r]].astype(np.float64)
        keep = (wl > COLOUR_INFERENCE_WEIGHT) | (wl == wl.max()) if n_a[r] else np.zeros(0, bool)
        light_only += int(n_a[r] > 0 and not (wl > COLOUR_INFERENCE_WEIGHT).any())
        assert n[r] == keep.sum()
        assert np.array_equal(t[r, :n[r]], tl[keep])
        np.testing.assert_allclose(w[r, :n[r]], wl[keep] * wl.sum() / wl[keep].sum(), rtol=1e-6)
    assert light_only > 0 and n.max() >= 2  # both cases occur on the tiny scene
    narrow = march(*args, colour_weight=COLOUR_INFERENCE_WEIGHT, threads=2, capacity=1)
    for a, b in zip(got[:3] + got[5:], narrow[:3] + narrow[5:]):
        assert np.array_equal(a, b)
    for a, b in zip(got[3:5], narrow[3:5]):  # the samples, up to the columns past every count
        assert np.array_equal(a[:, :b.shape[1]], b[:, :a.shape[1]])


def test_skip_distance_is_the_chebyshev_distance_to_occupancy():
    """One occupied cell: every other cell's skip distance is its Chebyshev distance in cells to
    it, capped at SKIP_MAX_CELLS (closed form); occupied cells 0."""
    from recon.nerf.models import SKIP_MAX_CELLS
    m = make_model("fast", -np.ones(3), np.ones(3), 0, replace(FastConfig(), occ_res=24))
    m.occupancy.zero_()
    m.occupancy[5, 7, 9] = True
    i, j, k = torch.meshgrid(*(torch.arange(24),) * 3, indexing="ij")
    cheb = torch.stack([(i - 5).abs(), (j - 7).abs(), (k - 9).abs()]).amax(dim=0)
    assert torch.equal(m.skip_distance(), cheb.clamp(max=SKIP_MAX_CELLS))


def test_dense_density_grid_equals_the_factored_density(trained_fast):
    m = trained_fast.model
    x = torch.rand(2000, 3, generator=torch.Generator().manual_seed(3)) * 2 - 1
    assert m.prepare_inference()
    with torch.no_grad():
        a, b = m.density(x), m._density_from_grid(x)
    assert float((a - b).abs().max()) <= 1e-4 * float(a.abs().max()) + 1e-6


def test_pixel_sampler_pairs_each_ray_with_its_pixel(tiny_capture):
    """PixelSampler's rays are the capture's pixel-centre rays of the drawn view and pixel, and
    its colours that pixel's (float16): every sample is found among all pixels' (ray, colour)."""
    from recon.nerf.data import PixelSampler
    data = load_data(tiny_capture, downsample=2, train_full=True)
    sampler = PixelSampler(data.train)
    assert sampler.width == SIZE[0] and sampler.height == SIZE[1]
    o, d, c = sampler.sample(300, torch.Generator().manual_seed(0))
    rays = [camera_rays(v.full_camera) for v in data.train]
    all_o = torch.cat([r[0] for r in rays])
    all_d = torch.cat([r[1] for r in rays])
    all_c = torch.cat([torch.from_numpy(v.full_rgb.astype(np.float32).reshape(-1, 3)) for v in data.train])
    gap = torch.cdist(torch.cat([o, d], 1), torch.cat([all_o, all_d], 1), compute_mode="donot_use_mm_for_euclid_dist")
    best = gap.argmin(dim=1)
    assert float(gap.min(dim=1).values.max()) < 1e-5
    assert torch.equal(c, all_c[best])
    assert float(c.sum()) > 0  # some samples hit the cube


def test_training_is_deterministic_and_resumes_exactly(tiny_data, tmp_path):
    """Same seed, same result: 20 steps then a resume to 40 equal 40 straight (step-bounded, so
    the schedule, with an upsampling and occupancy updates in between, is deterministic)."""
    cfg = TrainConfig(model="fast", minutes=30, max_steps=40, eval_every_s=1e9, overrides=FAST_SMALL)
    small = replace(tiny_data, train=tiny_data.train[:2], test=tiny_data.test[:1])
    a = train(small, cfg)
    ck = tmp_path / "ck.pt"
    b1 = train(small, cfg, checkpoint=ck, stop_step=20)
    assert b1.steps == 20
    b = train(small, cfg, checkpoint=ck, resume=True)
    assert b.steps == 40
    for (k, va), vb in zip(a.model.state_dict().items(), b.model.state_dict().values()):
        assert torch.equal(va, vb), k


def _dark(data, scale: float = 0.05):
    """The tiny capture at 1/20 of its radiance: mean linear colour about 0.01, like the default
    scene's 0.03."""
    dim = lambda views: [replace(v, rgb=v.rgb * scale) for v in views]
    return replace(data, train=dim(data.train), test=dim(data.test))


def test_vanilla_keeps_its_density_on_a_dark_capture(tiny_data):
    """Hard case: a dark capture. From the paper's grey colour start, removing all density is
    the fastest way down the loss and the softplus density never returns (opacity 0, PSNR frozen
    at the all-black value); the colour heads start at the mean colour instead, so the cube is
    kept and learned."""
    dark = _dark(tiny_data)
    # the paper's width: a narrow (32 or 64) network is too slow to collapse within the steps
    small = (("n_coarse", 8), ("n_fine", 8), ("batch_rays", 64), ("curve_pixels", 64))
    cfg = TrainConfig(model="vanilla", minutes=30, max_steps=60, eval_every_s=1e9, overrides=small)
    res = train(dark, cfg)
    o, d = dark.test[0].camera.pixel_rays()
    with torch.no_grad():
        out = res.model.render(torch.from_numpy(o).float(), torch.from_numpy(d).float())
    target = torch.from_numpy(dark.test[0].rgb.reshape(-1, 3))
    hits = target.sum(-1) > 0
    opacity = float(out.opacity[hits].mean())
    mse_ratio = float(((out.rgb - target) ** 2).mean() / (target ** 2).mean())  # 1: as bad as all black
    print(f"opacity on the cube {opacity:.3f}, mse / mse(all black) {mse_ratio:.3f}")
    assert opacity > 0.5  # grey start: 0.0
    assert mse_ratio < 0.95  # grey start: 1.0, the all-black image


def test_vanilla_colour_heads_start_at_the_mean_colour(tiny_data):
    m = make_model("vanilla", tiny_data.lo, tiny_data.hi, seed=0, config=replace(MODELS["vanilla"][1], **dict(VANILLA_SMALL)))
    m.init_colour(torch.tensor([0.02, 0.5, 0.9]))
    for net in (m.coarse, m.fine):
        assert torch.allclose(torch.sigmoid(net.color[-1].bias), torch.tensor([0.02, 0.5, 0.9]), atol=1e-6)


def test_training_rejects_unknown_model():
    with pytest.raises(ValueError, match="unknown NeRF model"):
        TrainConfig(model="nope")
    with pytest.raises(ValueError, match="loss must be"):
        TrainConfig(loss="log")


def test_display_loss_encoding_is_srgb_with_finite_gradients():
    """The display loss's encoding equals the sRGB curve (render.color.linear_to_srgb) on [0, 1],
    is continuous at the knee, and its gradient is finite everywhere, zero included (the power's
    derivative is infinite at 0): no NaN reaches a loss."""
    x = torch.cat([torch.zeros(1), torch.logspace(-7, 0, 2001, dtype=torch.float64),
                   torch.tensor([0.0031308 * (1 + 1e-12), 2.0], dtype=torch.float64)])
    x.requires_grad_(True)
    y = srgb_encode(x)
    ref = linear_to_srgb(x.detach().numpy()[:-1])
    assert np.allclose(y.detach().numpy()[:-1], ref, rtol=0, atol=1e-12)
    assert float(y[-1].detach()) == pytest.approx(1.055 * 2.0 ** (1 / 2.4) - 0.055)  # unclipped above 1
    y.sum().backward()
    g = x.grad.numpy()
    assert np.all(np.isfinite(g)) and g[0] == pytest.approx(12.92)
    # just above the knee the power's slope, 1.055 / 2.4 * knee^(1/2.4 - 1) = 12.70: within 2% of the toe's
    assert g[-2] == pytest.approx(1.055 / 2.4 * 0.0031308 ** (1 / 2.4 - 1)) and g[-2] == pytest.approx(12.92, rel=0.02)


# ---------------------------------------------------------------- the stage


@pytest.fixture(scope="session")
def stage_out(tiny_capture, tmp_path_factory):
    out = tmp_path_factory.mktemp("stage") / "nerf" / "fast"
    run_nerf(tiny_capture, None, out,
             NerfStageConfig("fast", 30.0, downsample=1, max_steps=40,
                             overrides=dict(FAST_SMALL, render_full_res=True, train_full_res=True)), quiet=True)
    return out


def test_stage_writes_the_nerf_folder(stage_out, tiny_capture):
    names = ["view_003", "view_008"]
    for n in names:
        img = read_exr(stage_out / "renders" / f"{n}.exr")
        assert img.shape == (SIZE[1], SIZE[0], 3) and np.all(np.isfinite(img))
        assert (stage_out / "renders" / f"{n}.png").is_file()
        depth = read_exr(stage_out / "depth" / f"{n}.exr")
        assert depth.shape == (SIZE[1], SIZE[0]) and depth.min() >= 0
    metrics = json.loads((stage_out / "metrics.json").read_text())
    assert [r["view"] for r in metrics["views"]] == names
    assert all(np.isfinite(r["display_psnr"]) and 0 <= r["display_ssim"] <= 1 for r in metrics["views"])
    # opted in: held-out views rendered at every capture pixel, scored there
    assert metrics["time"]["planned"]["render_full_res"] is True and np.isfinite(metrics["display_psnr_full_mean"])
    lines = (stage_out / "curve.csv").read_text().splitlines()
    assert lines[0] == "step,train_s,wall_s,display_psnr,linear_psnr" and len(lines) >= 2
    manifest = json.loads((stage_out / "manifest.json").read_text())
    assert manifest["stage"] == "nerf" and "checkpoint.pt" in manifest["outputs"]
    assert not list(stage_out.parent.glob(".*"))  # no partial folder or resume file left behind


def test_stage_bad_input_exits_cleanly(tiny_capture, tmp_path):
    with pytest.raises(BadInput, match="nowhere: no such folder"):
        run_nerf(tmp_path / "nowhere", None, tmp_path / "out", NerfStageConfig("fast", 1.0), quiet=True)
    with pytest.raises(BadInput, match="unknown NeRF model"):
        run_nerf(tiny_capture, None, tmp_path / "out", NerfStageConfig("nope", 1.0), quiet=True)
    with pytest.raises(BadInput, match="--poses"):
        run_nerf(tiny_capture, tmp_path / "missing", tmp_path / "out", NerfStageConfig("fast", 1.0), quiet=True)
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------- the study


def test_study_parses_runs():
    from recon.nerf.study import parse_run

    r = parse_run("colmap=fast@/a/poses/colmap")
    assert (r.label, r.model, str(r.poses)) == ("colmap", "fast", "/a/poses/colmap")
    assert parse_run("vanilla_nope").label == "vanilla_nope"
    with pytest.raises(ValueError, match="unknown model"):
        parse_run("nerfacto")


def test_study_settings_apply_to_the_models_that_have_them():
    from recon.nerf.study import parse_run, parse_settings

    runs = [parse_run("fast"), parse_run("vanilla_nope")]
    got = parse_settings(["batch_rays=256", "curve_pixels=none", "lr_net=0.002"], runs)
    assert got["vanilla_nope"] == (("batch_rays", 256), ("curve_pixels", None))
    assert got["fast"] == (("curve_pixels", None), ("lr_net", 0.002))
    with pytest.raises(ValueError, match="no run's model config has a field 'widht'"):
        parse_settings(["widht=64"], runs)
    with pytest.raises(ValueError, match="FIELD=VALUE"):
        parse_settings(["batch_rays"], runs)


def test_auto_downsample_targets_a_160_pixel_width():
    from recon.nerf.data import auto_downsample

    assert auto_downsample(640, 480) == 4
    assert auto_downsample(1280, 960) == 8
    assert auto_downsample(32, 24) == 1
    assert auto_downsample(1000, 750) == 5  # 200x150: the largest common divisor keeping >= 160
