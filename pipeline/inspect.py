"""``lumigraph inspect DIR``: what a stage folder holds, as a terminal table and a contact sheet."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from rich.console import Console
from rich.table import Table

from render.image_io import atomic_path

from .artifacts import MANIFEST, BadInput, read_manifest, sha256_file

__all__ = ["inspect_folder", "contact_sheet", "CONTACT_SHEET"]

CONTACT_SHEET = "contact_sheet.png"


def _thumbnail(path: Path, size: tuple[int, int]) -> Image.Image:
    """``path`` decoded and shrunk to fit ``size``; BadInput naming the file when it is not a
    readable image (random bytes, truncated), so nothing is written."""
    try:
        with Image.open(path) as im:
            im = im.convert("RGB")
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:  # UnidentifiedImageError is an OSError
        reason = (str(exc).splitlines()[0] if str(exc) else type(exc).__name__).replace(f"'{path}'", "file")
        raise BadInput(f"{path}: unreadable PNG preview ({reason}); --no-sheet skips the contact sheet") from None
    im.thumbnail(size)
    return im


def contact_sheet(images: list[Path], out: Path, thumb: int = 160, columns: int = 8) -> Path:
    """Tile PNG previews into one labelled sheet (row-major, names under each thumbnail).

    Every preview is decoded before the sheet is written: an unreadable one is BadInput naming it,
    and no sheet is written."""
    if not images:
        raise BadInput("no PNG images to put on a contact sheet")
    rows = (len(images) + columns - 1) // columns
    label_h = 14
    first = _thumbnail(images[0], (thumb, thumb * 4))  # cells take the first image's aspect ratio
    cell_h = max(1, round(thumb * first.height / first.width))
    thumbs = [_thumbnail(p, (thumb, cell_h)) for p in images]
    sheet = Image.new("RGB", (columns * thumb, rows * (cell_h + label_h)), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    for i, (path, im) in enumerate(zip(images, thumbs)):
        x, y = (i % columns) * thumb, (i // columns) * (cell_h + label_h)
        sheet.paste(im, (x + (thumb - im.width) // 2, y + (cell_h - im.height) // 2))
        draw.text((x + 3, y + cell_h), path.stem[:24], fill=(220, 220, 220))
    with atomic_path(out) as tmp:
        sheet.save(tmp, format="PNG")
    return out


def _inside(folder: Path, rel: str) -> bool:
    """``rel`` names a path inside ``folder`` (relative, no '..' component)."""
    p = Path(rel)
    return bool(rel) and not p.is_absolute() and ".." not in p.parts


def _preview_images(folder: Path) -> list[Path]:
    for sub in ("images", "renders", ""):
        found = sorted(p for p in (folder / sub).glob("*.png") if p.name != CONTACT_SHEET) if (folder / sub).is_dir() else []
        if found:
            return found
    return []


def inspect_folder(folder: Path, console: Console | None = None, sheet: bool = True) -> dict:
    """Print a summary table of a stage folder; check its files against the manifest; write the
    contact sheet. Returns a summary dict (also what the tests look at)."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    console = console or Console()
    outputs: dict[str, str] = manifest.get("outputs", {})
    escaping = [p for p in outputs if not _inside(folder, p)]
    if escaping:
        raise BadInput(f"{folder / MANIFEST}: field 'outputs': {escaping[0]!r} is not a path inside the folder")
    missing = [p for p in outputs if not (folder / p).is_file()]
    changed = [p for p in outputs if p not in missing and sha256_file(folder / p) != outputs[p]]
    kinds = Counter(str(Path(p).parent) if Path(p).parent != Path(".") else Path(p).suffix or p for p in outputs)

    table = Table(title=f"{folder}  —  stage '{manifest.get('stage')}'", show_lines=False)
    table.add_column("item", style="bold")
    table.add_column("value")
    for k, v in manifest.get("params", {}).items():
        table.add_row(f"param {k}", str(v))
    for k, v in sorted(kinds.items()):
        table.add_row(f"files {k}", str(v))
    for k, v in manifest.get("metrics", {}).items():
        table.add_row(f"metric {k}", f"{v:.6g}" if isinstance(v, float) else str(v))
    table.add_row("wall time", f"{manifest.get('wall_time_s', float('nan')):.2f} s")
    table.add_row("inputs", str(len(manifest.get("inputs", {}))))
    integrity = "ok" if not (missing or changed) else f"{len(missing)} missing, {len(changed)} changed"
    table.add_row("integrity", integrity)
    summary = {"stage": manifest.get("stage"), "files": dict(kinds), "missing": missing, "changed": changed,
               "metrics": manifest.get("metrics", {})}
    previews = _preview_images(folder)
    if sheet and previews:
        path = contact_sheet(previews, folder / CONTACT_SHEET)
        table.add_row("contact sheet", str(path))
        summary["contact_sheet"] = str(path)
    console.print(table)
    return summary
