"""Capture, slab and NeRF renders on the engine: one view / one row of slab cameras per unit of work.

Each stage runs in process (no Dask) and on a local cluster of two worker processes (one cluster
shared by the module, started once), on the tiny scene of conftest.py; the outputs must be the
same bytes (the manifest's sha256 of every file; metrics.json compared without its timings).
"""
import copy
import json

import numpy as np
import pytest

from pipeline.artifacts import read_manifest
from pipeline.cli import main
from pipeline.distributed import ClusterConfig, LocalEngine, engine, local_cluster, map_units
from pipeline.stages.capture import run_capture
from pipeline.stages.slab import SlabStageConfig, run_slab
from recon.slab import LayoutConfig

from .conftest import TINY_SCENE, write_scene

SMALL = LayoutConfig(count=4, uv_res=4, st_res=24)
MIRROR = copy.deepcopy(TINY_SCENE)  # the rasterizer cannot: capture path traces it
MIRROR["materials"]["chrome"] = {"type": "mirror", "reflectance": [0.9, 0.9, 0.9]}
MIRROR["objects"][0]["face_materials"][1] = "chrome"


@pytest.fixture(scope="module")
def two_workers():
    """A local cluster of 2 single-threaded worker processes, as a config naming its scheduler."""
    with local_cluster(2, dashboard=False) as cluster:
        yield ClusterConfig(scheduler=cluster.scheduler_address)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    from rig.build import load_scene

    root = tmp_path_factory.mktemp("stages")
    paths = {"raster": write_scene(root / "scenes", TINY_SCENE), "pathtracer": write_scene(root / "scenes", MIRROR, "mirror.yaml")}
    return root, {k: (load_scene(p), p) for k, p in paths.items()}


@pytest.fixture(scope="module")
def captured(scenes):
    """The in-process capture of each scene (the reference bytes; the slab tests' input)."""
    root, rigs = scenes
    out = {}
    for kind, (rig, path) in rigs.items():
        m = run_capture(rig, path, root / kind / "capture", seed=3, quiet=True)
        assert m["params"]["renderer"] == kind and m["metrics"]["engine"] == "in process"
        out[kind] = root / kind / "capture"
    return out


@pytest.mark.parametrize("kind", ["raster", "pathtracer"])
def test_capture_same_bytes_in_process_and_on_2_workers(scenes, captured, two_workers, kind):
    root, rigs = scenes
    rig, path = rigs[kind]
    out = root / kind / "capture-dask"
    m = run_capture(rig, path, out, seed=3, quiet=True, cluster=two_workers)
    assert m["metrics"]["engine"] == "dask cluster" and m["metrics"]["workers"] == 2
    assert m["params"]["renderer"] == kind
    assert len(m["outputs"]) > 4 * 6 and m["outputs"] == read_manifest(captured[kind])["outputs"]


def test_capture_cli_takes_the_scheduler_from_the_environment(scenes, captured, two_workers, monkeypatch):
    root, rigs = scenes
    monkeypatch.setenv("LUMIGRAPH_SCHEDULER", two_workers.scheduler)
    out = root / "cli-capture"
    assert main(["capture", str(rigs["raster"][1]), "--out", str(out), "--seed", "3", "--quiet"]) == 0
    m = read_manifest(out)
    assert m["metrics"]["engine"] == "dask cluster" and m["outputs"] == read_manifest(captured["raster"])["outputs"]


#: metrics.json's readings of the machine at run time (the slab stage's fit check and peak memory)
_MACHINE_STATE = ("render_s_per_view", "peak_rss_mb", "available_memory_bytes", "free_disk_bytes")


def _timeless(node):
    """metrics.json without its timings (keys ending in _s) and the machine's state at run time."""
    if isinstance(node, dict):
        return {k: _timeless(v) for k, v in node.items() if not (k.endswith("_s") or k in _MACHINE_STATE)}
    return node


def test_slab_same_bytes_in_process_and_on_2_workers(captured, two_workers, tmp_path):
    """Direct acquisition (rows of uv cameras), held-out renders in every mode and the VQ renders
    (one view per unit): every file the same bytes; metrics.json equal but for its timings and machine readings."""
    results = {}
    for tag, cluster in (("local", None), ("dask", two_workers)):
        out = tmp_path / tag
        m = run_slab(captured["raster"], None, out, SlabStageConfig(layout=SMALL), quiet=True, cluster=cluster)
        assert m["metrics"]["engine"] == ("in process" if cluster is None else "dask cluster")
        results[tag] = ({k: v for k, v in m["outputs"].items() if k != "metrics.json"},
                        _timeless(json.loads((out / "metrics.json").read_text())))
    (files, metrics), (files_d, metrics_d) = results["local"], results["dask"]
    assert any(k.startswith("slabs/") and k.endswith(".radiance.npy") for k in files)
    assert any(k.startswith("renders_vq/") for k in files) and any(k.startswith("modes/") for k in files)
    assert files_d == files
    assert metrics_d == metrics and metrics["build"]["renders"] > 0


def test_slab_rows_in_any_order_match_the_plain_acquisition(captured, tmp_path):
    """acquire_direct through rows= (the stage's path) writes what its plain loop writes."""
    from recon.slab import DirectConfig, acquire_direct, acquire_row, content_bounds
    from rig.build import load_scene
    from rig.raster import RasterRenderer

    from pipeline.stages.slab import _cameras, _content_points, _layout, load_views

    cams, splits = _cameras(captured["raster"])
    train = [c for c, s in zip(cams, splits) if s == "train"]
    bounds = content_bounds(_content_points(load_views(captured["raster"], train), 0.05))
    rig = load_scene(str(captured["raster"].parent.parent / "scenes" / "tiny.yaml"))
    geoms = _layout(SlabStageConfig(layout=SMALL), bounds, train, np.asarray(rig.scene.up, float))[:1]
    cfg = DirectConfig(uv_supersample=2)  # even K: the extra centre render for depth
    renderers = {}

    def render(cam):
        k = cam.intrinsics
        r = renderers.setdefault((k.width, k.height), RasterRenderer(rig.scene, k.width, k.height))
        f = r.render(cam)
        return f.rgb, f.depth

    def rows(units, put):  # in reverse, as a cluster may finish them
        for k in reversed(range(len(units))):
            put(k, *acquire_row(*units[k], render, cfg))

    try:
        plain = acquire_direct(geoms, render, tmp_path / "a", cfg)
        mapped = acquire_direct(geoms, None, tmp_path / "b", cfg, rows=rows)
        assert len(plain) == len(mapped) == 1
        for a, b in zip(plain, mapped):
            assert np.asarray(a.radiance).tobytes() == np.asarray(b.radiance).tobytes()
            assert np.asarray(a.depth).tobytes() == np.asarray(b.depth).tobytes()
    finally:
        for r in renderers.values():
            r.close()


def test_nerf_held_out_views_same_bytes_in_process_and_on_2_workers(tmp_path, two_workers):
    """The NeRF stage's unit (one held-out view, the model shared once) gives the same renders
    and scores on workers as in process: torch is pinned to the training's thread count (a
    different count changes the last bits of its reductions)."""
    from dataclasses import replace

    from recon.nerf.data import load_data
    from recon.nerf.models import MODELS, make_model

    from pipeline.stages.nerf import nerf_view
    from tests.recon.nerf_fixtures import FAST_SMALL, make_tiny_capture

    data = load_data(make_tiny_capture(tmp_path / "cap"), None, None, 1)
    model = make_model("fast", data.lo, data.hi, 0, replace(MODELS["fast"][1], **dict(FAST_SMALL)))
    got = {}
    for tag, cluster in (("local", None), ("dask", two_workers)):
        done = [None] * len(data.test)
        with engine(cluster, quiet=True) as eng:
            assert isinstance(eng, LocalEngine) == (cluster is None)
            shared = eng.share(model)
            map_units(eng, nerf_view, [(v, False, 2) for v in data.test], shared=[shared], on_result=done.__setitem__)
        got[tag] = done
    for (row, r), (row_d, r_d) in zip(got["local"], got["dask"]):
        assert row == row_d and np.isfinite(row["display_psnr"])
        assert r["rgb"].tobytes() == r_d["rgb"].tobytes() and r["depth"].tobytes() == r_d["depth"].tobytes()


def test_run_passes_one_engine_to_every_stage(scenes, monkeypatch, tmp_path):
    """`lumigraph run` reads --scheduler / LUMIGRAPH_SCHEDULER, opens one engine and hands that
    same engine to the stages (stubbed here after capture: the whole pipeline is too slow)."""
    import pipeline.pipeline_run as pr
    import pipeline.stages.capture as cap
    import pipeline.stages.reference as ref

    seen = {}

    class Stop(Exception):
        pass

    def fake_capture(rig, scene_file, out, seed=None, quiet=False, cluster=None, **kw):
        seen["capture"] = cluster
        return {"metrics": {"views": 0}, "params": {"renderer": "raster"}, "wall_time_s": 0.0}

    def fake_reference(*args, cluster=None, **kw):
        seen["reference"] = cluster
        raise Stop

    monkeypatch.setattr(cap, "run_capture", fake_capture)
    monkeypatch.setattr(ref, "run_reference", fake_reference)
    monkeypatch.setattr(pr, "inspect_folder", lambda folder: None)
    rig, path = scenes[1]["raster"]
    with pytest.raises(Stop):
        pr.run_pipeline(rig, path, tmp_path, quiet=True, cluster=ClusterConfig(workers=0))
    assert isinstance(seen["capture"], LocalEngine) and seen["reference"] is seen["capture"]

    calls = {}
    monkeypatch.setattr(pr, "run_pipeline", lambda *a, **kw: calls.setdefault("cluster", kw["cluster"]) and [])
    monkeypatch.setenv("LUMIGRAPH_SCHEDULER", "tcp://127.0.0.1:1")
    assert main(["run", str(path), "--root", str(tmp_path), "--quiet"]) == 0
    assert calls["cluster"] == ClusterConfig(scheduler="tcp://127.0.0.1:1")
