"""The lecture studies' home: ``lumigraph study uniqueness`` through the real process, and the
report's lecture section (pipeline.report_lecture) on a finished study folder and on absent ones.

The study runs at the ``tiny`` size (``LUMIGRAPH_UNIQUENESS_SIZE=tiny``: untrained NeRFs, small
grids); what is checked is exact at any size: the ghost points' closed form, the bitwise identical
training renders of the two fields, the opaque block's predicted null space.
"""
import base64
import json
import math
import os
import subprocess
import sys

import numpy as np
from PIL import Image

from pipeline.artifacts import Manifest
from pipeline.plot import Series, svg_plot
from pipeline.report_lecture import lecture_section
from pipeline.stages.lecture import LECTURE_STUDIES, lecture_dir

UNIQUENESS_FILES = ("ghost_points.csv", "three_cameras.csv", "three_cameras.png", "nerf_masses.svg", "same_images.csv",
                    "same_images.png", "same_images.svg", "linear_rank.csv", "linear_rank.svg", "summary.json",
                    "manifest.json")


def _lumigraph(*args, env=None):
    return subprocess.run([sys.executable, "-m", "pipeline", *args], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYOPENGL_PLATFORM": "egl", **(env or {})})


def test_study_uniqueness_cli_writes_the_study_and_its_exact_figures(tmp_path):
    """``lumigraph study uniqueness --root R`` writes R/lecture/uniqueness: every file, a manifest
    of stage lecture_uniqueness, a summary with title / claim / headline / figures (each figure a
    file of the folder). Exact figures: B's purple ghost at B - Delta / sin(theta_R - theta_B)
    (cos theta_B, sin theta_B, 0) with Delta = rho [sin(phi - theta_R - delta) - sin(phi - theta_R)]
    (written out here from the scene's numbers: B at 0.4 (cos 45, sin 45), cameras at 90 / 210 /
    330 deg, delta = -15 deg), the triangle's side |Delta| / sin 60; the two fields' training renders
    bitwise identical; the opaque block's null space at its prediction. A bad size variable is exit 2
    with one stderr line naming it, and leaves no folder."""
    run = _lumigraph("study", "uniqueness", "--root", str(tmp_path), "-q", env={"LUMIGRAPH_UNIQUENESS_SIZE": "tiny"})
    assert run.returncode == 0, run.stderr
    out = tmp_path / "lecture" / "uniqueness"
    for name in UNIQUENESS_FILES:
        assert (out / name).is_file(), name
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["stage"] == "lecture_uniqueness" and manifest["params"]["profile"] == "quick"
    assert manifest["metrics"]["size"] == "tiny" and manifest["metrics"]["same_images_train_max_abs_diff"] == 0.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["title"] and summary["claim"] and len(summary["headline"]) >= 8
    assert all({"figure", "value", "unit", "note"} <= set(r) for r in summary["headline"])
    assert summary["figures"] and all((out / f).is_file() for f in summary["figures"])

    rho, phi = 0.4, math.radians(45.0)
    tb, tr, delta = math.radians(90.0), math.radians(210.0), math.radians(-15.0)
    shift = rho * (math.sin(phi - tr - delta) - math.sin(phi - tr))
    b = np.array([rho * math.cos(phi), rho * math.sin(phi), 0.0])
    purple = b - shift / math.sin(tr - tb) * np.array([math.cos(tb), math.sin(tb), 0.0])
    np.testing.assert_allclose(summary["three_cameras"]["ghost_points"]["purple"], purple, atol=1e-5)
    side = next(r["value"] for r in summary["headline"] if r["figure"].startswith("ghost triangle side"))
    assert abs(side - abs(shift) / math.sin(math.radians(60.0))) < 1e-4
    rows = summary["same_images"]["rows"]
    assert all(r["train_bitwise_identical"] and r["train_max_abs_diff"] == 0.0 for r in rows)
    assert rows[0]["held_out_max_abs_diff"] > 0.1                            # and they do differ held out
    block = [r for r in summary["linear"]["rows"] if r["field"].startswith("opaque")]
    assert block[-1]["null_dim"] == block[-1]["predicted_null_dim"]

    bad = _lumigraph("study", "uniqueness", "--root", str(tmp_path / "other"), "-q",
                     env={"LUMIGRAPH_UNIQUENESS_SIZE": "huge"})
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "LUMIGRAPH_UNIQUENESS_SIZE" in bad.stderr
    assert not (tmp_path / "other").exists()


def _finished_study(root, name, summary, files):
    """A finished lecture folder as run_lecture_study leaves it: files, summary.json, a manifest
    written by the real Manifest class."""
    folder = lecture_dir(name, root)
    folder.mkdir(parents=True)
    for fname, data in files.items():
        (folder / fname).write_bytes(data)
    (folder / "summary.json").write_text(json.dumps(summary))
    Manifest(f"lecture_{name}", params={"study": name, "profile": "quick", "seed": 0}).write(folder)
    return folder


def test_lecture_section_shows_a_finished_study_and_hints_for_absent_ones(tmp_path):
    """A finished uniqueness folder: its title, claim, headline values and both figures (the
    PNG's and the SVG's exact bytes as data URIs) appear; a figure named outside the folder is not
    read; caching (absent) and bias (summary but no manifest: unfinished) show the command that
    makes them, and nothing of the unfinished summary."""
    import io

    buf = io.BytesIO()
    Image.fromarray(np.full((4, 6, 3), 200, np.uint8)).save(buf, format="PNG")
    png = buf.getvalue()
    svg = svg_plot([Series("rank", [1, 2, 3], [10, 20, 27], line=True)], "views", "rank").encode()
    (tmp_path / "secret.png").write_bytes(png + b"secret")
    _finished_study(tmp_path, "uniqueness", {
        "title": "Is a NeRF unique? <test>", "claim": "Images do not determine a field.",
        "headline": [{"figure": "ghost triangle side", "value": 0.111395, "unit": "world units", "note": "closed form"},
                     {"figure": "held-out PSNR", "value": "3.0 -> 21.0", "unit": "dB", "note": "rings"}],
        "figures": ["fig.png", "plot.svg", "../../secret.png", "missing.svg"]}, {"fig.png": png, "plot.svg": svg})
    bias = lecture_dir("bias", tmp_path)
    bias.mkdir(parents=True)
    (bias / "summary.json").write_text(json.dumps({"title": "UNFINISHED BIAS", "claim": "x", "headline": [],
                                                   "figures": []}))
    page = lecture_section(tmp_path)
    assert "Is a NeRF unique? &lt;test&gt;" in page and "Images do not determine a field." in page
    assert "0.1114" in page and "3.0 -&gt; 21.0" in page and "world units" in page
    assert "data:image/png;base64," + base64.b64encode(png).decode() in page
    assert "data:image/svg+xml;base64," + base64.b64encode(svg).decode() in page
    assert base64.b64encode(png + b"secret").decode() not in page and "secret.png" not in page
    assert "missing.svg: missing" in page
    assert "lumigraph study caching" in page and "lumigraph study bias" in page
    assert "UNFINISHED BIAS" not in page
    assert page.count("Not run yet") == 2 == len(LECTURE_STUDIES) - 1
