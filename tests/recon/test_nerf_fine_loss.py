"""The fast NeRF's loss on the pyramid levels finer than the working scale: the tangent loss
(``FastConfig.fine_loss``: the display error linearised at the prediction, unbiased in linear light),
and its value checked where the config is made (the config, the study's ``--set``)."""
from dataclasses import replace

import numpy as np
import pytest
import torch

from recon.nerf.data import load_data
from recon.nerf.models import MODELS, FastConfig
from recon.nerf.study import parse_run, parse_settings
from recon.nerf import train as train_mod
from recon.nerf.train import TrainConfig, fit_loss, srgb_encode, srgb_slope, train

from .nerf_fixtures import FAST_SMALL, make_tiny_capture


@pytest.fixture(scope="module")
def full_data(tmp_path_factory):
    return load_data(make_tiny_capture(tmp_path_factory.mktemp("fine_loss") / "capture"), downsample=4, train_full=True)


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
    take the tangent one; "display": every step the display one."""
    kinds = []
    orig = train_mod.fit_loss
    monkeypatch.setattr(train_mod, "fit_loss", lambda preds, t, kind: kinds.append(kind) or orig(preds, t, kind))
    small = replace(full_data, train=full_data.train[:2], test=full_data.test[:1])
    ov = FAST_SMALL + (("pixel_schedule", ((0.5, 2), (0.75, 1))),)
    train(small, TrainConfig(model="fast", minutes=30, max_steps=12, eval_every_s=1e9, overrides=ov))
    assert kinds == ["display"] * 6 + ["tangent"] * 6          # the default
    kinds.clear()
    train(small, TrainConfig(model="fast", minutes=30, max_steps=4, eval_every_s=1e9,
                             overrides=ov + (("fine_loss", "display"),)))
    assert kinds == ["display"] * 4


def test_a_bad_fine_loss_is_refused_where_the_config_is_made(tmp_path, capsys):
    """An unknown fine_loss: a ValueError naming the field from the config itself (and so from
    ``replace`` and ``train``'s overrides, before any data is read); the study's ``--set`` parses
    it as text, refuses it the same way, and its command prints one line and exits 2."""
    assert MODELS["fast"][1].fine_loss == "tangent"
    with pytest.raises(ValueError, match="fine_loss must be one of 'display', 'tangent', got 'l1'"):
        FastConfig(fine_loss="l1")
    with pytest.raises(ValueError, match="fine_loss"):
        replace(MODELS["fast"][1], fine_loss="Tangent")
    runs = [parse_run("fast"), parse_run("vanilla")]
    assert parse_settings(["fine_loss=display"], runs) == {"fast": (("fine_loss", "display"),), "vanilla": ()}
    with pytest.raises(ValueError, match="fine_loss"):
        parse_settings(["fine_loss=l1"], runs)
    from pipeline.stages.nerf_study import main
    code = main([str(tmp_path / "no_capture"), "--out", str(tmp_path / "out"), "--run", "fast",
                 "--set", "fine_loss=l1"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "fine_loss" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
