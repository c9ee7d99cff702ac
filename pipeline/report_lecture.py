"""The report's lecture section: the lecture's open questions (``lumigraph study uniqueness |
caching | bias``), one block per study.

:func:`lecture_section` reads ``<root>/lecture/<name>/`` for every name of
:data:`pipeline.stages.lecture.LECTURE_STUDIES` (``root`` is the artifacts root, the parent of a
scene's artifacts folder). A finished study (``manifest.json`` present) shows its
``summary.json``: title, claim, the headline table (figure, value, unit, note) and the figures it
lists (PNG and SVG files of the folder, embedded as data URIs: the report stays self-contained,
and an SVG shown through ``<img>`` runs nothing). An absent or unfinished study shows one line
with the command that makes it; a study whose summary cannot be read shows one line saying why.

This module does not import :mod:`pipeline.report` (which calls it): the import graph has no
cycles (``tests/test_import_graph.py``), so the few lines of HTML helpers it needs are its own.
"""
from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

from .artifacts import MANIFEST

__all__ = ["lecture_section", "MAX_FIGURE_BYTES"]

#: figures larger than this are listed by name, not embedded (the report stays a readable size)
MAX_FIGURE_BYTES = 4_000_000

_MIME = {".png": "image/png", ".svg": "image/svg+xml"}
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _figure_uri(path: Path) -> str | None:
    """A data URI of a study's PNG or SVG file (its bytes as they are), or None when the file is
    missing, of another kind, too large, or not what its suffix says."""
    mime = _MIME.get(path.suffix.lower())
    if mime is None or not path.is_file() or path.stat().st_size > MAX_FIGURE_BYTES:
        return None
    data = path.read_bytes()
    if mime == "image/png" and not data.startswith(_PNG_MAGIC):
        return None
    if mime == "image/svg+xml" and b"<svg" not in data[:512]:
        return None
    return f"data:{mime};base64," + base64.b64encode(data).decode("ascii")


def _cell(v) -> str:
    """A headline value as text: numbers to 4 significant digits, strings as they are."""
    if isinstance(v, bool) or v is None:
        return "–" if v is None else ("yes" if v else "no")
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}" if math.isfinite(v) else "–"
    return str(v)


def _headline_table(rows: list) -> str:
    e = html.escape
    body = "".join(
        "<tr>" + "".join(f"<td>{e(_cell(r.get(k)))}</td>" for k in ("figure", "value", "unit", "note")) + "</tr>"
        for r in rows if isinstance(r, dict))
    return f"<table><tr><th>figure</th><th>value</th><th>unit</th><th>note</th></tr>{body}</table>"


def _study_block(name: str, folder: Path, what: str) -> str:
    e = html.escape
    command = f"lumigraph study {name}"
    if not (folder / MANIFEST).is_file():
        return (f'<h3>{e(name)}</h3><p class="note">Not run yet ({e(what)}): <code>{e(command)}</code> writes '
                f"<code>{e(folder.as_posix())}</code>.</p>")
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        if not isinstance(summary, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc).splitlines()[0]
        return (f'<h3>{e(name)}</h3><p class="note">{e((folder / "summary.json").as_posix())}: unreadable '
                f"({e(reason)}); run <code>{e(command)} --overwrite</code> again.</p>")
    parts = [f"<h3>{e(str(summary.get('title', name)))}</h3>",
             f"<p>{e(str(summary.get('claim', '')))}</p>"]
    head = summary.get("headline", [])
    if isinstance(head, list) and head:
        parts.append(_headline_table(head))
    profile = summary.get("profile")
    parts.append(f'<p class="note"><code>{e(command)}</code>'
                 + (f" (profile {e(str(profile))})" if profile else "")
                 + f": <code>{e(folder.as_posix())}</code></p>")
    figures = summary.get("figures", [])
    imgs = []
    for fig in figures if isinstance(figures, list) else []:
        rel = Path(str(fig))
        if rel.is_absolute() or ".." in rel.parts:  # a summary names files of its own folder only
            continue
        uri = _figure_uri(folder / rel)
        if uri is None:
            imgs.append(f'<p class="note">{e(rel.as_posix())}: missing or not a PNG/SVG file</p>')
        else:
            imgs.append(f'<figure style="display:inline-block;margin:4px;vertical-align:top">'
                        f'<img src="{uri}" alt="{e(rel.name)}" style="max-width:100%">'
                        f'<figcaption class="cap">{e(rel.name)}</figcaption></figure>')
    parts.append('<div class="views">' + "".join(imgs) + "</div>")
    return "\n".join(parts)


def lecture_section(root: Path) -> str:
    """HTML of the lecture's open questions for the artifacts root ``root``: one block per lecture
    study, in :data:`~pipeline.stages.lecture.LECTURE_STUDIES` order (see the module docstring)."""
    from .stages.lecture import LECTURE_STUDIES, lecture_dir

    blocks = [_study_block(name, lecture_dir(name, Path(root)), what) for name, (_, what) in LECTURE_STUDIES.items()]
    return "<h2>The lecture's open questions</h2>\n" + "\n".join(blocks)
