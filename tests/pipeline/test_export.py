"""Captures open unchanged in the field's tools, judged by those tools' own readers (issue 18).

One capture of the default scene's rig (its 48 train and 8 test views, images shrunk to 128x96)
is made and exported through the real CLI. Then:

* nerfstudio 1.1.5's own dataparsers (installed without dependencies by ``make setup``, run in a
  subprocess by ``nerfstudio_reader.py``: why is said there) read the capture folder: 48/8/8
  train/val/test views, one normalisation for every split, masks and depth attached, and the
  rays it generates pass through the ground-truth depth points within 0.01 px; its Blender
  parser opens ``transforms_train.json`` (no ``.png.png``); its depth loader reads the
  ``nerfstudio`` export's depth in metres at its default unit.
* instant-ngp's export is checked against the rules of its loader (``src/nerf_loader.cu``, master
  of 2024, and ``docs/nerf_dataset_tips.md``): what each rule is, is said where it is checked.
* pycolmap reads the capture's text model and the export's binary model with 3D points.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pycolmap
import pytest
import yaml
from PIL import Image

from render.camera_io import read_cameras_json
from render.image_io import read_exr, read_png

REPO = Path(__file__).resolve().parents[2]
READER = Path(__file__).with_name("nerfstudio_reader.py")


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], capture_output=True, text=True,
                          timeout=600, cwd=cwd)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The default scene's rig at 128x96: capture, then every export format, through the CLI."""
    root = tmp_path_factory.mktemp("export")
    spec = yaml.safe_load((REPO / "scenes" / "turntable.yaml").read_text())
    spec["cameras"]["intrinsics"].update(width=128, height=96)
    (root / "turntable.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    cap = root / "art" / "turntable" / "capture"
    r = _cli("capture", root / "turntable.yaml", "--out", cap, "--quiet")
    assert r.returncode == 0, r.stderr
    for fmt in ("nerfstudio", "instant-ngp", "colmap"):
        quiet = ["--quiet"] if fmt != "colmap" else []  # one format with its progress bar drawn, as a user sees it
        r = _cli("export", cap, "--format", fmt, *quiet)
        assert r.returncode == 0, r.stderr
        assert quiet or "export colmap" in r.stderr, r.stderr
    return cap


def _nerfstudio(tmp_path, request: dict) -> dict:
    req = tmp_path / "request.json"
    req.write_text(json.dumps(request))
    r = subprocess.run([sys.executable, str(READER), str(req)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _gt_points(cam, depth, pixels_rc):
    """World points of the ground-truth z-depth at (row, col) pixel centres: C + z d / d_z."""
    pix = np.array([[c + 0.5, r + 0.5] for r, c in pixels_rc])
    o, d = cam.pixel_rays(pix)
    z = np.array([depth[r, c] for r, c in pixels_rc], dtype=np.float64)
    return o + d * (z / (d @ cam.cam_to_world[:3, 2]))[:, None]


def test_nerfstudio_reads_the_capture_48_8_in_one_frame_with_rays_through_the_depth(exported, tmp_path):
    cams, splits = read_cameras_json(exported / "cameras.json")
    by_name = {c.name: c for c in cams}
    rng = np.random.default_rng(0)
    coords, truth = {}, {}
    for split in ("train", "test"):
        names = sorted(c.name for c, s in zip(cams, splits) if s == split)  # nerfstudio sorts frames by file name
        coords[split], truth[split] = [], []
        for i, n in enumerate(names):
            depth = read_exr(exported / "depth" / f"{n}.exr")
            rows, cols = np.nonzero(depth > 0)
            pick = rng.choice(len(rows), size=4, replace=False)
            rc = list(zip(rows[pick].tolist(), cols[pick].tolist()))
            coords[split] += [[i, r + 0.5, c + 0.5] for r, c in rc]
            truth[split].append(_gt_points(by_name[n], depth, rc))
    out = _nerfstudio(tmp_path, {"parser": "nerfstudio", "data": str(exported), "splits": ["train", "val", "test"],
                                 "coords": coords})
    assert out["nerfstudio"] == "1.1.5"
    train, val, test = out["train"], out["val"], out["test"]
    assert (len(train["images"]), len(val["images"]), len(test["images"])) == (48, 8, 8)
    assert {Path(p).stem for p in test["images"]} == {c.name for c, s in zip(cams, splits) if s == "test"}
    assert val["images"] == test["images"]
    # one normalisation for every split: the same transform and scale
    np.testing.assert_array_equal(train["transform"], test["transform"])
    assert train["scale"] == test["scale"]
    assert [Path(p).parent.name for p in train["masks"]] == ["masks"] * 48
    assert [Path(p).suffix for p in test["depth_files"]] == [".exr"] * 8
    T = np.vstack([np.array(train["transform"]), [0, 0, 0, 1]])
    for split in ("train", "test"):
        pts = np.concatenate(truth[split])
        pts_ns = (pts @ T[:3, :3].T + T[:3, 3]) * out[split]["scale"]  # our world -> nerfstudio's frame
        o, d = np.array(out[split]["origins"]), np.array(out[split]["directions"])
        along = np.sum((pts_ns - o) * d, axis=1)
        off_ray = np.linalg.norm(pts_ns - o - along[:, None] * d, axis=1)
        fx = np.array(out[split]["fx"])[[c[0] for c in coords[split]]]
        px = off_ray / along * fx  # distance from the ray, in pixels at the point's depth
        assert px.max() < 0.01, (split, px.max())


def test_nerfstudio_blender_parser_opens_the_split_files(exported, tmp_path):
    """transforms_{train,test}.json follow the Blender convention (file paths without extension,
    camera_angle_x): nerfstudio's blender-data parser adds '.png' and finds every image."""
    out = _nerfstudio(tmp_path, {"parser": "blender", "data": str(exported), "splits": ["train", "test"]})
    assert len(out["train"]["images"]) == 48 and len(out["test"]["images"]) == 8
    assert all(p.endswith(".png") and not p.endswith(".png.png") and Path(p).is_file()
               for p in out["train"]["images"] + out["test"]["images"])
    k = read_cameras_json(exported / "cameras.json")[0][0].intrinsics
    assert out["train"]["fx"][0] == pytest.approx(k.fx, rel=1e-6)


def test_nerfstudio_export_depth_reads_in_metres_at_nerfstudio_defaults(exported, tmp_path):
    ns = exported.parent / "export" / "nerfstudio"
    doc = json.loads((ns / "transforms.json").read_text())
    assert doc["depth_unit_scale_factor"] == 1e-3 and len(doc["train_filenames"]) == 48
    names = ["train_000", "test_003"]
    out = _nerfstudio(tmp_path, {"parser": "nerfstudio", "data": str(ns), "splits": ["test"],
                                 "depth_files": [str(ns / "depth" / f"{n}.png") for n in names]})
    assert len(out["test"]["images"]) == 8 and len(out["test"]["depth_files"]) == 8
    for n, d in zip(names, out["depth"]):
        truth = read_exr(exported / "depth" / f"{n}.exr")
        assert np.abs(np.array(d) - truth).max() <= 0.5e-3 + 1e-6  # millimetre steps, rounded


def test_instant_ngp_export_follows_its_loader(exported):
    ngp = exported.parent / "export" / "instant-ngp"
    cams, splits = read_cameras_json(exported / "cameras.json")
    by_name = {c.name: c for c in cams}
    assert sorted(p.name for p in ngp.iterdir() if p.is_dir()) == ["test", "test_linear", "train", "train_linear"]
    for folder in ("train", "test", "train_linear", "test_linear"):
        split = folder.split("_")[0]
        # the loader, given a folder, loads every *.json with "frames": a folder holds one split only
        jsons = [p for p in (ngp / folder).glob("*.json") if "frames" in json.loads(p.read_text())]
        assert [p.name for p in jsons] == ["transforms.json"]
        doc = json.loads(jsons[0].read_text())
        names = [Path(f["file_path"]).stem for f in doc["frames"]]
        assert sorted(names) == sorted(c.name for c, s in zip(cams, splits) if s == split)
        # aabb_scale: a power of two up to 128 (nerf_dataset_tips.md); scale/offset: p * scale + offset
        assert doc["aabb_scale"] in (1, 2, 4, 8, 16, 32, 64, 128)
        assert doc["scale"] > 0 and len(doc["offset"]) == 3
        # intrinsics: fl_x / fl_y / cx / cy / w / h at the top level (read_focal_length, read_lens)
        k = cams[0].intrinsics
        assert (doc["fl_x"], doc["cx"], doc["w"], doc["h"]) == (k.fx, k.cx, k.width, k.height)
        for f in doc["frames"]:
            name = Path(f["file_path"]).stem
            # file_path resolves against the json's folder (resolve_path)
            img_path = ngp / folder / f["file_path"]
            assert img_path.is_file()
            # transform_matrix: camera-to-world in NeRF's OpenGL axes (the loader's nerf_matrix_to_ngp input)
            np.testing.assert_allclose(np.array(f["transform_matrix"]),
                                       by_name[name].cam_to_world @ np.diag([1.0, -1, -1, 1]), atol=1e-12)
            # depth_path: 16-bit single-channel PNG of the image's size; value * integer_depth_scale = metres
            dimg = Image.open(ngp / folder / f["depth_path"])
            assert dimg.mode in ("I;16", "I") and dimg.size == (k.width, k.height)
            truth = read_exr(exported / "depth" / f"{name}.exr")
            np.testing.assert_allclose(np.asarray(dimg, dtype=np.float64) * doc["integer_depth_scale"], truth,
                                       atol=doc["integer_depth_scale"] / 2 + 1e-7)
            if folder.endswith("_linear"):  # EXR: read natively as HDR; dynamic masks apply to 8-bit images only
                assert img_path.suffix == ".exr"
                np.testing.assert_array_equal(read_exr(img_path), read_exr(exported / "linear" / f"{name}.exr"))
            else:
                # dynamic_mask_<basename>.png beside the image, same size; non-zero pixels are ignored
                mask = read_png(img_path.parent / f"dynamic_mask_{name}.png")
                assert mask.shape == (k.height, k.width)
                np.testing.assert_array_equal(mask > 0, read_png(exported / "masks" / f"{name}.png") == 0)
    # the framing puts the subject (the 0.16 m box on the turntable) inside the unit cube around 0.5
    doc = json.loads((ngp / "train" / "transforms.json").read_text())
    box = np.array([[-0.08, -0.08, 0.0005], [0.08, 0.08, 0.1605]])  # scenes/turntable.yaml's box
    mapped = box * doc["scale"] + np.array(doc["offset"])
    assert np.all(mapped >= -0.01) and np.all(mapped <= 1.01)
    # and fills most of it (0.68 here: at 128x96 silhouette pixels blur the box by ~2 px); instant-ngp's
    # default scale (0.33) gave it 0.05 of the cube
    assert np.max(mapped[1] - mapped[0]) > 0.6


def test_colmap_models_load_in_pycolmap(exported):
    cams, _ = read_cameras_json(exported / "cameras.json")
    text = pycolmap.Reconstruction(str(exported / "colmap"))
    assert text.num_reg_images() == 56
    model = exported.parent / "export" / "colmap"
    assert (model / "sparse" / "0" / "images.bin").is_file()
    rec = pycolmap.Reconstruction(str(model / "sparse" / "0"))
    assert rec.num_reg_images() == 56 and rec.num_points3D() > 1000
    assert rec.compute_mean_track_length() > 2.0
    assert rec.compute_mean_reprojection_error() < 1e-3  # points triangulated from exact depth
    for c in cams:
        im = rec.find_image_with_name(f"{c.name}.png")
        assert (model / "images" / im.name).is_file()
        np.testing.assert_allclose(np.asarray(im.cam_from_world().matrix()), c.world_to_cam[:3], atol=1e-9)
        text_im = text.find_image_with_name(f"{c.name}.png")
        np.testing.assert_allclose(np.asarray(text_im.cam_from_world().matrix()), c.world_to_cam[:3], atol=1e-12)


def test_export_refuses_bad_input_with_one_line_and_writes_nothing(exported, tmp_path):
    out = tmp_path / "out"
    cases = [(["export", exported, "--format", "obj", "--out", out], "--format: unknown format 'obj'"),
             (["export", tmp_path / "missing", "--format", "colmap", "--out", out], "no such capture folder"),
             (["export", exported.parent, "--format", "colmap", "--out", out], "manifest.json")]
    for args, needle in cases:
        r = _cli(*args)
        assert r.returncode == 2 and needle in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not out.exists()
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    r = _cli("export", exported, "--format", "colmap", "--out", out)
    assert r.returncode == 2 and "refusing to replace it" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    r = _cli("export", exported, "--format", "nerfstudio", "--out", out, "--overwrite", "--quiet")
    assert r.returncode == 0 and (out / "transforms.json").is_file() and not (out / "notes.txt").exists()
