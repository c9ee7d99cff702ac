"""render.metrics: the project's one PSNR convention and the hard case of identical images."""
import json
import math

import numpy as np
import pytest

from render import metrics
from render.metrics import MSE_FLOOR, PSNR_MAX_DB, mse_to_psnr, psnr, rmse, ssim

#: the documented value of every image metric (render.metrics.__all__'s functions of two images)
#: on identical images
IDENTICAL = {"psnr": PSNR_MAX_DB, "ssim": 1.0, "rmse": 0.0}


def _images():
    rng = np.random.default_rng(5)
    return {"black": np.zeros((12, 16, 3), np.float32), "constant": np.full((12, 16, 3), 0.25, np.float32),
            "random": rng.random((12, 16, 3)).astype(np.float32), "grey 2-D": rng.random((12, 16)),
            "over-range": rng.uniform(-1.0, 3.0, (12, 16, 3))}


def test_identical_images_through_every_metric():
    """Hard case: identical images through every metric of render.metrics (black, constant,
    random, 2-D, out of [0, 1]) give finite, documented values: psnr PSNR_MAX_DB = 100 dB (MSE
    floored at MSE_FLOOR = 1e-10 of peak^2), ssim 1, rmse 0; and those values are valid JSON
    (allow_nan=False, as stages write metrics.json). A metric added to render.metrics without
    a documented identical-image value here fails the first assertion."""
    image_metrics = {n for n in metrics.__all__ if callable(getattr(metrics, n)) and n != "mse_to_psnr"}
    assert image_metrics == set(IDENTICAL)
    assert PSNR_MAX_DB == 100.0 and 10 * math.log10(1 / MSE_FLOOR) == pytest.approx(PSNR_MAX_DB)
    for label, img in _images().items():
        for name, expected in IDENTICAL.items():
            got = getattr(metrics, name)(img, img.copy())
            assert math.isfinite(got) and got == pytest.approx(expected, abs=1e-6), (label, name, got)
        json.dumps({name: getattr(metrics, name)(img, img) for name in IDENTICAL}, allow_nan=False)
    assert psnr(np.full((4, 4, 3), 2.0), np.full((4, 4, 3), 2.0), max_val=2.0) == PSNR_MAX_DB


def test_psnr_follows_its_closed_form_up_to_the_cap():
    """10 log10(peak^2 / MSE) below the cap, the cap at and beyond MSE = 1e-10 peak^2 (training's
    mse_to_psnr is the same function), never above it."""
    ref = np.full((8, 8, 3), 0.5)
    for d in (0.1, 1e-3, 1e-5 + 1e-9):
        assert psnr(ref + d, ref) == pytest.approx(-20 * math.log10(d), rel=1e-9)
    assert psnr(ref + 1e-6, ref) == pytest.approx(PSNR_MAX_DB, abs=1e-6)  # MSE 1e-12: capped
    assert mse_to_psnr(0.0) == mse_to_psnr(1e-300) == PSNR_MAX_DB
    assert mse_to_psnr(0.25, peak=2.0) == pytest.approx(10 * math.log10(16.0))
    from recon.nerf.train import mse_to_psnr as training_psnr
    assert training_psnr is mse_to_psnr
    assert rmse(ref + 0.1, ref) == pytest.approx(0.1) and ssim(ref + 0.1, ref) < 1.0
