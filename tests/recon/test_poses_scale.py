"""Posing at scale without COLMAP runs: what ``auto`` resolves to at the benchmark's view counts,
the benchmark's growth exponents (closed form), and the stoppable child process's error
protocol (the child's exception re-raised in the parent, a bug's with the child's traceback)."""
import math
from pathlib import Path

import pytest

from bench.bench_poses import LAYOUTS, colmap_config, growth
from recon.poses import ColmapConfig, ReconstructionError
from recon.poses.colmap import resolve_first_octave, resolve_mapper, resolve_matcher
from recon.poses.colmap_process import estimate_colmap_stoppable


def test_auto_resolves_by_view_count():
    """56 views: every pair, the incremental mapper; from 150 views on: the capture's order
    (sequential by name without it), the global mapper; SIFT on the doubled image at every count
    (octave 0 doubled the rotation error at 224 views). A given option is kept whatever the count."""
    cfg = ColmapConfig()
    assert [sum(n for _, n in LAYOUTS[v][0]) + LAYOUTS[v][1][1] for v in LAYOUTS] == [56, 224, 1000]
    table = {v: (resolve_matcher(cfg, v, True), resolve_mapper(cfg, v), resolve_first_octave(cfg, v)) for v in LAYOUTS}
    assert table == {56: ("exhaustive", "incremental", -1), 224: ("capture_order", "global", -1),
                     1000: ("capture_order", "global", -1)}
    assert resolve_matcher(cfg, 224, False) == "sequential"
    assert resolve_first_octave(ColmapConfig(first_octave=-1), 1000) == -1
    assert resolve_first_octave(ColmapConfig(first_octave=0), 56) == 0
    with pytest.raises(ValueError, match="first_octave"):
        ColmapConfig(first_octave=2)
    assert colmap_config("capture_order+global+o-1").first_octave == -1
    assert colmap_config("exhaustive+incremental").first_octave is None


def test_growth_exponents_are_the_log_log_slopes():
    """Times proportional to views give exponent 1, to views squared 2; per-view seconds as given."""
    rows = [{"config": "c", "views": v, "failure": None, "pairs": 21 * v, "extract_s": 0.5 * v,
             "match_s": 0.01 * v * v, "map_s": 3.0 * v ** 1.5, "poses_wall_s": 0.5 * v + 0.01 * v * v + 3.0 * v ** 1.5}
            for v in (56, 224, 1000)]
    rows.append({"config": "c", "views": 2000, "failure": "did not finish"})  # failed runs are left out
    g = growth(rows)
    assert [e["views"] for e in g] == [[56, 224], [224, 1000]]
    for e in g:
        assert e["pairs_exponent"] == e["extract_s_exponent"] == 1.0
        assert e["match_s_exponent"] == 2.0 and e["map_s_exponent"] == 1.5
        assert 1.0 < e["poses_wall_s_exponent"] < 2.0
    assert g[0]["extract_s_per_view"] == [0.5, 0.5]
    assert g[1]["match_s_per_view"] == [2.24, 10.0]
    assert math.isclose(g[0]["map_s_per_view"][0], round(3.0 * 56 ** 0.5, 3))


def test_the_child_process_hands_back_its_errors(tmp_path):
    """A ReconstructionError raised in the child (one image: nothing to reconstruct) reaches the
    caller as itself, its one-line message intact; a bug (a missing image file) as its own type
    with the child's traceback attached as a note."""
    img = tmp_path / "a.png"
    img.write_bytes(b"not an image")
    with pytest.raises(ReconstructionError, match="at least 2 images, got 1") as info:
        estimate_colmap_stoppable({"a": img}, None, tmp_path / "work1", ColmapConfig(known_intrinsics=False))
    assert str(info.value) == "structure from motion needs at least 2 images, got 1"
    with pytest.raises(FileNotFoundError) as info:
        estimate_colmap_stoppable({"a": img, "b": tmp_path / "missing.png"}, None, tmp_path / "work2",
                                  ColmapConfig(known_intrinsics=False))
    assert any("in the COLMAP child process" in n and "Traceback" in n for n in info.value.__notes__)
    assert not (tmp_path / "work2" / "result").exists()
