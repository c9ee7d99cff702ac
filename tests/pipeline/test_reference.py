"""The reference stage: path-traced views with variance images, agreeing with the rig's capture."""
import numpy as np
import pytest

from pipeline.artifacts import read_manifest
from pipeline.cli import main
from render.camera_io import read_cameras_json
from render.image_io import read_exr

from .conftest import TINY_SCENE, write_scene


# The independent sampler: test_reference_agrees_with_the_rasterized_capture judges the two
# renderers' edge differences (MSAA against the box filter) in units of i.i.d. noise. The stage's
# default Sobol reference is several times less noisy at 64 spp (16 points per replicate), and
# against it those systematic differences exceed 4 sigma on 11% of lit channels (89% within).
REFERENCE_ARGS = ["--spp", "64", "--sampler", "independent"]


@pytest.fixture(scope="module")
def tiny_dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("ref")
    scene = write_scene(root / "scenes", TINY_SCENE)
    assert main(["capture", str(scene), "--out", str(root / "capture"), "--quiet"]) == 0
    assert main(["reference", str(scene), *REFERENCE_ARGS, "--out", str(root / "reference"), "--quiet"]) == 0
    return scene, root


def test_reference_writes_mean_variance_and_cameras(tiny_dirs):
    _, root = tiny_dirs
    ref = root / "reference"
    m = read_manifest(ref)
    assert m["params"]["integrator"] == "direct"  # direct + shadows only: pruned to `direct`
    cams, splits = read_cameras_json(ref / "cameras.json")
    assert splits == ["test", "test"]
    for cam in cams:
        mean = read_exr(ref / "linear" / f"{cam.name}.exr")
        var = read_exr(ref / "variance" / f"{cam.name}.exr")
        assert mean.shape == var.shape == (96, 128, 3)
        assert np.isfinite(mean).all() and np.isfinite(var).all() and var.min() >= 0
        assert (var > 0).any()


# Pixels judged by the reference-vs-capture test: lit in either image (max over RGB, linear).
# 92% of the tiny scene is black background, which agrees exactly and would pass any renderer.
LIT = 0.01


def test_reference_agrees_with_the_rasterized_capture(tiny_dirs):
    """Same light units in both renderers, judged on lit pixels only (radiance > LIT in either
    image: 7.9% and 8.2% of each view): their mean radiance within 1% (measured +0.29%, +0.18%),
    and at least 93% of their channels within 4 sigma of the reference's noise (measured 96.9%
    and 96.2%; at 128x96 many lit pixels straddle an edge or the board's pattern, where MSAA's 4
    subsamples and the path tracer's box filter differ). Over all pixels the former test passed
    with 99.7% (the background). The spot light 2% too bright in the path tracer's kernels fails it
    (lit mean +2.3%); the former test, with 3% over all pixels, passed that."""
    _, root = tiny_dirs
    for cam in read_cameras_json(root / "reference" / "cameras.json")[0]:
        ref = read_exr(root / "reference" / "linear" / f"{cam.name}.exr").astype(np.float64)
        var = read_exr(root / "reference" / "variance" / f"{cam.name}.exr").astype(np.float64)
        cap = read_exr(root / "capture" / "linear" / f"{cam.name}.exr").astype(np.float64)
        lit = np.maximum(ref.max(axis=2), cap.max(axis=2)) > LIT
        assert lit.mean() > 0.05, f"{cam.name}: only {lit.mean():.3f} of the pixels are lit"
        assert abs(ref[lit].mean() / cap[lit].mean() - 1) < 0.01, (cam.name, ref[lit].mean() / cap[lit].mean())
        z = np.abs(ref[lit] - cap[lit]) / np.sqrt(var[lit] + 1e-6)
        assert (z < 4).mean() > 0.93, (cam.name, (z < 4).mean())


def test_same_seed_same_bytes(tiny_dirs, tmp_path):
    scene, root = tiny_dirs
    assert main(["reference", str(scene), *REFERENCE_ARGS, "--out", str(tmp_path / "again"), "--quiet"]) == 0
    assert read_manifest(tmp_path / "again")["outputs"] == read_manifest(root / "reference")["outputs"]


@pytest.mark.parametrize("args, words", [
    (["--views", "scene"], "no 'scene' views"),
    (["--integrator", "bogus"], "--integrator"),
    (["--spp", "0"], "--spp"),
])
def test_bad_reference_options_exit_2(tiny_dirs, tmp_path, capsys, args, words):
    scene, _ = tiny_dirs
    out = tmp_path / "ref"
    assert main(["reference", str(scene), "--out", str(out), "--quiet", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]
    assert not out.exists()


def test_cornell_needs_path_and_refuses_direct(tmp_path, capsys):
    assert main(["reference", "cornell", "--views", "scene", "--integrator", "direct", "--quiet",
                 "--out", str(tmp_path / "r")]) == 2
    assert "interreflection" in capsys.readouterr().err
