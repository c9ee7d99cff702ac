"""Image I/O and metrics: linear EXR round trips bit-exactly, previews follow the sRGB standard,
writes are atomic and refuse non-finite data, PSNR and SSIM match their closed forms."""
from __future__ import annotations

import numpy as np
import pytest

import OpenEXR

from render.image_io import read_exr, read_png, write_depth_exr, write_exr, write_preview
from render.metrics import psnr, rmse, ssim


def test_exr_round_trip_is_bit_exact_for_rgb_and_depth(tmp_path):
    rng = np.random.default_rng(0)
    rgb = (rng.random((7, 5, 3)) * 10.0 ** rng.uniform(-6, 4, (7, 5, 3))).astype(np.float32)
    depth = rng.random((7, 5)).astype(np.float32)
    write_exr(tmp_path / "rgb.exr", rgb)
    write_exr(tmp_path / "depth.exr", depth[..., None])
    assert np.array_equal(read_exr(tmp_path / "rgb.exr"), rgb)
    assert np.array_equal(read_exr(tmp_path / "depth.exr"), depth)


def test_depth_is_written_in_channel_z_and_the_old_y_is_still_read(tmp_path):
    """Depth tools look for OpenEXR's depth channel ``Z`` (``Y`` is luminance): depth is written there;
    captures written before (depth in ``Y``) still read back, bit-exactly, through the same reader."""
    depth = np.random.default_rng(1).random((6, 9)).astype(np.float32) * 3.0
    write_depth_exr(tmp_path / "new.exr", depth)
    with OpenEXR.File(str(tmp_path / "new.exr")) as f:
        assert sorted(f.channels()) == ["Z"]
        assert np.array_equal(f.channels()["Z"].pixels, depth)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"Y": depth}) as f:  # an old capture's depth, written as before
        f.write(str(tmp_path / "old.exr"))
    assert np.array_equal(read_exr(tmp_path / "new.exr"), depth)
    assert np.array_equal(read_exr(tmp_path / "old.exr"), depth)
    with pytest.raises(ValueError, match="single channel"):
        write_exr(tmp_path / "x.exr", depth, channel="D")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_images_are_refused_and_nothing_is_written(tmp_path, bad):
    img = np.zeros((4, 4, 3), np.float32)
    img[1, 2, 0] = bad
    with pytest.raises(ValueError, match="non-finite"):
        write_exr(tmp_path / "x.exr", img)
    assert list(tmp_path.iterdir()) == []


def test_preview_follows_the_srgb_transfer_function(tmp_path):
    """IEC 61966-2-1: 12.92 c below 0.0031308, 1.055 c^(1/2.4) - 0.055 above; values above 1 clip."""
    lin = np.array([0.0, 0.002, 0.0031308, 0.18, 0.5, 1.0, 4.0])
    img = np.repeat(lin[None, :, None], 3, axis=2)
    write_preview(tmp_path / "p.png", img)
    got = read_png(tmp_path / "p.png")[0, :, 0].astype(int)
    c = np.minimum(lin, 1.0)
    expected = np.round(255 * np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)).astype(int)
    assert np.array_equal(got, expected)
    assert got[3] == 118 and got[4] == 188  # mid grey 0.18 -> 118, 0.5 -> 188 (published sRGB values)


def test_linear_to_srgb_is_the_closed_form_bit_for_bit_on_any_shape():
    """The encoder skips the power on the linear segment (a dark scene's background): the values must
    stay exactly IEC 61966-2-1's, for an image, a scalar and values outside [0, 1]."""
    from render.color import linear_to_srgb

    rng = np.random.default_rng(3)
    lin = np.concatenate([rng.random(500) ** 4, [-1.0, 0.0, 0.0031308, 0.00313081, 1.0, 7.0]]).reshape(2, 253, 1) * [1, 1, 1]
    c = np.clip(lin, 0.0, 1.0)
    expected = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    got = linear_to_srgb(lin)
    assert got.shape == lin.shape and got.dtype == np.float64 and np.array_equal(got, expected)
    assert float(linear_to_srgb(0.18)) == 1.055 * 0.18 ** (1 / 2.4) - 0.055 and float(linear_to_srgb(-2.0)) == 0.0


def test_psnr_matches_its_closed_form_and_ssim_ranks_degradations():
    rng = np.random.default_rng(1)
    ref = rng.random((32, 32, 3)) * 0.8 + 0.1
    shifted = ref + 0.01
    assert np.isclose(psnr(shifted, ref), 10 * np.log10(1.0 / 1e-4), atol=1e-6)  # MSE 1e-4 -> 40 dB
    assert np.isclose(rmse(shifted, ref), 0.01)
    assert psnr(ref, ref) == 100.0  # render.metrics.PSNR_MAX_DB (tests/render/test_metrics.py)
    assert np.isclose(ssim(ref, ref), 1.0, atol=1e-6)
    mild = ref + rng.normal(0, 0.02, ref.shape)
    strong = ref + rng.normal(0, 0.1, ref.shape)
    assert 1.0 > ssim(mild, ref) > ssim(strong, ref) > 0.0
    with pytest.raises(ValueError, match="shape"):
        psnr(ref[:8], ref)
