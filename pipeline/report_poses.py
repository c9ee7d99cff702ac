"""The report's pose section, second half: what pose accuracy costs (``study pose_tolerance``).

:func:`pose_tolerance_section` reads ``<artifacts>/study_pose_tolerance/summary.json`` (written
by :mod:`pipeline.stages.pose_tolerance_study`) and returns HTML: the tolerance curves (the
study's SVGs inlined, the poses stage's reached accuracy marked on them) and a table of every
point's NeRF and slab display PSNR with its loss against the true cameras. A note when the
study has not been run.
"""
from __future__ import annotations

import html
import json
from pathlib import Path

__all__ = ["pose_tolerance_section", "STUDY_FOLDER"]

STUDY_FOLDER = "study_pose_tolerance"


def _fmt(v, digits: int = 2) -> str:
    return f"{v:.{digits}f}" if isinstance(v, (int, float)) else "–"


def pose_tolerance_section(artifacts_dir: Path) -> str:
    """HTML for the study in ``artifacts_dir / STUDY_FOLDER``, or a one-line note without it."""
    folder = Path(artifacts_dir) / STUDY_FOLDER
    e = html.escape
    try:
        summary = json.loads((folder / "summary.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return (f'<p class="note">What pose accuracy costs: no {STUDY_FOLDER}/ (run <code>lumigraph study '
                f"pose_tolerance --capture {e(str(Path(artifacts_dir) / 'capture'))}</code>).</p>")
    rows = summary.get("rows", [])
    truth = next((r for r in rows if r.get("kind") == "truth"), {})
    est = summary.get("estimate", {})
    out = [f"<h3>{e(summary.get('title', 'What pose accuracy costs'))}</h3>",
           f'<p class="note">{e(summary.get("claim", ""))} The poses stage reached '
           f"{_fmt(est.get('rotation_deg'), 3)} deg mean rotation error and {_fmt(est.get('focal_pct'), 2)} % focal "
           f"error ({e(str(est.get('poses', 'no --poses given')))}).</p>"]
    for name in summary.get("figures", []):
        svg = folder / name
        if svg.is_file() and svg.read_text().lstrip().startswith("<svg"):
            out.append(f'<div class="plot">{svg.read_text()}</div>')
    head = ["point", "NeRF display PSNR (dB)", "NeRF loss (dB)", "slab display PSNR (dB)", "slab loss (dB)"]
    body = []
    for r in rows:
        cells = [r.get("name", "")]
        for model in ("nerf", "slab"):
            v, t = r.get(f"{model}_display_psnr"), truth.get(f"{model}_display_psnr")
            cells += [_fmt(v), _fmt(t - v) if isinstance(v, (int, float)) and isinstance(t, (int, float)) else "–"]
        body.append("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in cells) + "</tr>")
    out.append("<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr>" + "".join(body) + "</table>")
    s = summary.get("settings", {})
    out.append(f'<p class="note">Settings: NeRF {e(str(s.get("nerf_steps")))} steps, rebinned slab uv '
               f'{e(str(s.get("uv_res")))}, st_per_pixel {e(str(s.get("st_per_pixel")))}.</p>')
    return "\n".join(out)
