"""``lumigraph report``: one self-contained HTML page judging every model of a scene.

``write_report(artifacts_dir)`` reads the scene's artifacts (``artifacts/<scene>``: every stage's
manifest, the ``validate`` stage's metrics and error maps, the reference and model renders, the
poses' metrics, NeRF ``curve.csv`` files and the ``study`` folder when present) and writes
``validate/report.html``. The page needs nothing else: images are PNG data URIs, plots are inline
SVG drawn here (no plotting library), styles are inline, there is no script. Sections:

1. at a glance: the best model at the held-out views, its time, the Pareto-optimal models;
2. models: display PSNR, SSIM, ꟻLIP first (whole image and the subject's pixels, the all-black
   image's row beside), linear PSNR, truth estimates, reference noise share, Z-test, time; how
   each NeRF stage spent its ``--minutes`` budget;
3. accuracy versus time: every model on one plot, NeRF training curves, the study's fronts;
4. side-by-side views: reference (and its noise), each model's render, error map, Z-map and
   ꟻLIP error map;
5. pose accuracy; 6. per stage what it produced (manifest: time, outputs, headline metrics).

Plots are :mod:`pipeline.plot`'s, shared with the studies.
"""
from __future__ import annotations

import base64
import csv
import html
import io
import math
import os
from pathlib import Path

import numpy as np
from PIL import Image

from render.color import to_srgb8
from render.image_io import atomic_path, read_exr

from .artifacts import MANIFEST, BadInput, read_json
from .plot import Series, pareto_mask, svg_plot
from .report_lecture import lecture_section
from .report_poses import pose_tolerance_section

__all__ = ["write_report", "REPORT", "GENERATOR_TAG"]

REPORT = "report.html"
#: marks a file as a report this module wrote: ``--out`` replaces such a file, no other
GENERATOR_TAG = '<meta name="generator" content="lumigraph report">'


# ------------------------------------------------------------------------------------- images


def _png_uri(img: np.ndarray, max_width: int) -> str:
    """A data URI of a uint8 (H, W) / (H, W, 3) image, downscaled (box filter) to ``max_width``."""
    im = Image.fromarray(img)
    if im.width > max_width:
        im = im.resize((max_width, max(1, round(im.height * max_width / im.width))), Image.BOX)
    buf = io.BytesIO()
    im.save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _exr_uri(path: Path, max_width: int) -> str | None:
    if not path.is_file():
        return None
    a = read_exr(path)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if not np.all(np.isfinite(a)):
        return None
    return _png_uri(to_srgb8(a), max_width)


def _file_uri(path: Path, max_width: int) -> str | None:
    if not path.is_file():
        return None
    with Image.open(path) as im:
        return _png_uri(np.asarray(im.convert("RGB")), max_width)


def _noise_uri(path: Path, gain: float, max_width: int) -> str | None:
    """The reference's standard deviation sqrt(var), grey, on the error maps' scale."""
    if not path.is_file():
        return None
    v = read_exr(path)
    sd = np.sqrt(np.maximum(v if v.ndim == 2 else v.mean(axis=2), 0.0))
    return _png_uri(to_srgb8(np.repeat(sd[..., None], 3, axis=2), gain), max_width)


# ------------------------------------------------------------------------------------- reading


def _stage_folders(root: Path, max_depth: int = 3) -> list[Path]:
    """Folders under ``root`` holding a manifest, or a metrics.json with a status (failed poses)."""
    found = []
    for dirpath, dirnames, files in os.walk(root):
        rel = Path(dirpath).relative_to(root)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".")) if len(rel.parts) < max_depth else []
        if rel.parts and (MANIFEST in files or "metrics.json" in files):
            found.append(Path(dirpath))
    return sorted(found)


def _read_curve(path: Path) -> tuple[list[float], list[float]] | None:
    """(training seconds, held-out PSNR) from a NeRF ``curve.csv``, whose columns are
    :data:`pipeline.stages.nerf.CURVE_FIELDS` (:data:`~pipeline.stages.nerf.CURVE_TIME` and
    :data:`~pipeline.stages.nerf.CURVE_PSNR` are read); None when unreadable or lacking them.
    Rows with a non-finite value or a time of 0 are left out (the log time axis)."""
    from .stages.nerf import CURVE_PSNR, CURVE_TIME

    try:
        rows = list(csv.DictReader(path.open()))
    except (OSError, csv.Error):
        return None
    if not rows or CURVE_TIME not in rows[0] or CURVE_PSNR not in rows[0]:
        return None
    xs, ys = [], []
    for r in rows:
        try:
            t, p = float(r[CURVE_TIME]), float(r[CURVE_PSNR])
        except (TypeError, ValueError):
            continue
        if math.isfinite(t) and math.isfinite(p) and t > 0:
            xs.append(t)
            ys.append(p)
    return (xs, ys) if xs else None


def _fmt(v, digits: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "–"
        if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
            return f"{v:.{digits}g}"
        return f"{v:.{digits}f}".rstrip("0").rstrip(".") if abs(v) < 10 else f"{v:.{max(digits - 1, 1)}f}"
    return str(v)


def _duration(s: float | None) -> str:
    if s is None or not math.isfinite(s):
        return "–"
    return f"{s:.1f} s" if s < 120 else f"{s / 60:.1f} min"


# ------------------------------------------------------------------------------------- page


_CSS = """
body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1500px}
h1{margin-bottom:4px} h2{border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:36px}
table{border-collapse:collapse;font-size:13px;margin:8px 0}
th,td{border:1px solid #ddd;padding:3px 8px;text-align:right} th{background:#f3f3f3}
td:first-child,th:first-child{text-align:left}
tr.best td{background:#e8f5e9;font-weight:bold} tr.failed td{color:#b00} tr.black td{color:#666;font-style:italic}
.glance{background:#f6f8fa;border:1px solid #d0d7de;padding:10px 16px;border-radius:6px;font-size:15px}
.views{overflow-x:auto} .grid{border-collapse:collapse} .grid td{border:none;padding:2px;vertical-align:top;text-align:center}
.grid img{display:block;image-rendering:pixelated} .cap{font-size:11px;color:#555}
.grid td.rowcap{width:90px;text-align:right;vertical-align:middle;padding-right:6px}
.note{font-size:12px;color:#555} .plots svg{margin:6px 6px 6px 0;border:1px solid #eee;max-width:48%;height:auto}
"""


def _table(header: list[str], rows: list[list], classes: list[str] | None = None) -> str:
    e = html.escape
    h = "".join(f"<th>{e(c)}</th>" for c in header)
    body = []
    for i, r in enumerate(rows):
        cls = f' class="{classes[i]}"' if classes and classes[i] else ""
        body.append(f"<tr{cls}>" + "".join(f"<td>{e(_fmt(c))}</td>" for c in r) + "</tr>")
    return f"<table><tr>{h}</tr>{''.join(body)}</table>"


def _db(v) -> str:
    return "–" if v is None else f"{v:.2f} dB"


def _glance(models: dict, best: dict | None, ref: dict, front: list[str]) -> str:
    e = html.escape
    if not best:
        return '<p class="glance">No model could be scored.</p>'
    b = models[best["model"]]
    lines = [f"<b>Best at the held-out views: {e(best['model'])}</b> — display PSNR {_db(b['display_psnr_mean'])} "
             f"(subject {_db(b.get('display_psnr_subject_mean'))}), SSIM {_fmt(b['display_ssim_mean'], 4)}, "
             f"ꟻLIP {_fmt(b.get('flip_ldr_mean'))} (HDR {_fmt(b.get('flip_hdr_mean'))}), linear PSNR "
             f"{_db(b['linear_psnr_mean'])}; {e(_duration(b['end_to_end_s']))} end to end "
             f"({e(_duration(b['time_s']))} for the model stage itself)."]
    cheaper = [n for n in front if n != best["model"] and models[n]["end_to_end_s"] < b["end_to_end_s"]]
    if cheaper:
        lines.append("Cheaper, on the Pareto front: " + "; ".join(
            f"{e(n)} {_db(models[n]['display_psnr_mean'])} in {e(_duration(models[n]['end_to_end_s']))}"
            for n in cheaper) + ".")
    ceil, dceil = ref.get("psnr_noise_ceiling_mean"), ref.get("display_psnr_noise_ceiling_mean")
    if ceil is not None:
        lines.append(f"The reference ({e(str(ref.get('spp')))} spp, {e(str(ref.get('integrator')))}) limits what can be "
                     f"measured to about {_db(dceil)} display PSNR ({ceil:.1f} dB linear: its own noise); the best "
                     f"model's linear difference is {100 * (b.get('noise_share_mean') or 0):.1f}% reference noise.")
    black = ref.get("black") or {}
    if black.get("display_psnr_mean") is not None:
        lines.append(f"For scale: an empty (black) image scores display PSNR {_db(black['display_psnr_mean'])} "
                     f"(subject {_db(black.get('display_psnr_subject_mean'))}), ꟻLIP "
                     f"{_fmt(black.get('flip_ldr_mean'))}, linear PSNR {_db(black.get('linear_psnr_mean'))} "
                     "against this reference.")
    return '<div class="glance">' + "<br>".join(lines) + "</div>"


#: the models table's figures (validate's ``<key>_mean``), headline first, and their column titles
MODEL_COLUMNS = (("display_psnr", "display PSNR dB"), ("display_psnr_subject", "subject display PSNR dB"),
                 ("display_ssim", "SSIM"), ("display_ssim_subject", "subject SSIM"), ("flip_ldr", "ꟻLIP"),
                 ("flip_ldr_subject", "subject ꟻLIP"), ("flip_hdr", "HDR-ꟻLIP"), ("linear_psnr", "linear PSNR dB"),
                 ("linear_psnr_subject", "subject linear PSNR dB"), ("display_psnr_truth_est", "display PSNR vs truth (est.)"),
                 ("psnr_truth_est", "linear PSNR vs truth (est.)"), ("noise_share", "ref. noise share"),
                 ("z_within_fraction", "Z-test within noise"))


def _models_section(models: dict, best: str | None, front: list[str], ref: dict | None = None) -> str:
    ref = ref or {}
    key = lambda n: -(models[n]["display_psnr_mean"] if models[n]["display_psnr_mean"] is not None else -1e9)  # noqa: E731
    names = sorted(models, key=key)
    header = ["model", "poses", *[t for _, t in MODEL_COLUMNS], "stage time", "end to end", "Pareto"]
    rows = [[n, models[n]["poses"], *[models[n].get(f"{k}_mean") for k, _ in MODEL_COLUMNS],
             _duration(models[n]["time_s"]), _duration(models[n]["end_to_end_s"]), n in front] for n in names]
    classes = ["best" if n == best else "" for n in names]
    black = ref.get("black") or {}
    if black:  # the floor every figure is read against
        rows.append(["all-black image", "–", *[black.get(f"{k}_mean") for k, _ in MODEL_COLUMNS], "–", "–", "–"])
        classes.append("black")
    if ref.get("display_psnr_noise_ceiling_mean") is not None:
        ceiling = {"display_psnr": ref["display_psnr_noise_ceiling_mean"], "linear_psnr": ref.get("psnr_noise_ceiling_mean")}
        rows.append(["reference noise ceiling", "–", *[ceiling.get(k) for k, _ in MODEL_COLUMNS], "–", "–", "–"])
        classes.append("black")
    note = ('<p class="note">Means over the held-out views. Display figures score the 8-bit sRGB images (as NeRF, '
            'TensoRF and Instant-NGP report PSNR/SSIM); ꟻLIP is NVIDIA\'s perceptual error (0 identical, 1 largest; '
            'LDR on the display images, HDR on linear radiance); linear PSNR scores linear radiance clipped to [0, 1]. '
            '"subject": on the capture\'s subject mask only. "all-black image": what an empty render scores, the floor '
            'every figure is read against. "vs truth (est.)" removes the reference\'s own noise (the MSE minus the '
            'noise\'s expected MSE, display: delta method and 8-bit rounding; – when the difference is within that '
            'noise). "ref. noise share": the fraction of the linear squared error the reference noise explains. '
            '"Z-test within noise": fraction of pixel channels within the two-sided per-pixel Z-test. End to end = '
            'capture + poses (when estimated) + the model stage.</p>')
    return _table(header, rows, classes) + note + _budget_table(models)


def _budget_table(models: dict) -> str:
    """How each NeRF stage spent its ``--minutes`` budget (its metrics.json ``time``), when recorded."""
    rows = []
    for n in sorted(models):
        t = models[n].get("budget")
        if not t:
            continue
        a = t.get("actual", {})
        rows.append([n, _duration(t.get("budget_s")), _duration(a.get("load_s")), _duration(a.get("train_total_s")),
                     _duration(a.get("render_s")), _duration(a.get("write_s")), _duration(a.get("stage_s")),
                     a.get("stopped_by"), t.get("planned", {}).get("eval_factor")])
    if not rows:
        return ""
    return ("<h3>How the NeRF stages spent their --minutes budget</h3>"
            + _table(["model", "budget", "load", "train", "held-out renders", "write", "stage total", "training stopped by",
                      "evaluation scale 1/k"], rows))


def _plots_section(models: dict, ref: dict, root: Path, validate_dir: Path) -> str:
    parts = []
    ceil = ref.get("display_psnr_noise_ceiling_mean")
    hl = [(ceil, "reference noise ceiling")] if ceil is not None else []
    black = (ref.get("black") or {}).get("display_psnr_mean")
    if black is not None:
        hl.append((black, "empty (black) image"))
    series = [Series(n, [m["end_to_end_s"]], [m["display_psnr_mean"]], [n], annotate=True)
              for n, m in sorted(models.items()) if m["display_psnr_mean"] is not None and m["end_to_end_s"] > 0]
    parts.append(svg_plot(series, "end-to-end time (s)", "display PSNR at held-out views (dB)",
                          "Every model: accuracy against time", logx=True, hlines=hl))
    curves = []
    for f in sorted(root.glob("nerf/*/curve.csv")):
        c = _read_curve(f)
        if c:
            curves.append(Series(f.parent.relative_to(root).as_posix(), c[0], c[1], line=True))
    if curves:
        parts.append(svg_plot(curves, "training time (s)", "held-out PSNR (dB)", "NeRF training curves",
                              logx=True, hlines=hl))
    study = root / "study"
    svgs = sorted(study.glob("*.svg")) if (study / MANIFEST).is_file() else []
    for s in svgs:
        text = s.read_text()
        if text.lstrip().startswith("<svg"):
            parts.append(text)
    out = '<div class="plots">' + "".join(parts) + "</div>"
    if (study / "pareto.csv").is_file():
        rows = list(csv.DictReader((study / "pareto.csv").open()))
        if rows:
            cols = list(rows[0])
            out += "<h3>Study: Pareto-optimal settings</h3>" + _table(cols, [[r[c] for c in cols] for r in rows])
    elif not svgs:
        out += '<p class="note">No study folder: run <code>lumigraph study SCENE</code> for per-stage fronts.</p>'
    return out


def _views_section(root: Path, validate_dir: Path, models: dict, views: list[str], gain: float, max_views: int,
                   thumb: int) -> str:
    e = html.escape
    from .stages.validate import model_subfolder

    blocks = []
    for v in views[:max_views]:
        cols = [("reference", _exr_uri(root / "reference" / "linear" / f"{v}.exr", thumb),
                 _noise_uri(root / "reference" / "variance" / f"{v}.exr", gain, thumb), None, None)]
        for n in sorted(models):
            cols.append((n, _exr_uri(root / n / "renders" / f"{v}.exr", thumb),
                         _file_uri(validate_dir / "errors" / model_subfolder(n) / f"{v}.png", thumb),
                         _file_uri(validate_dir / "zmaps" / model_subfolder(n) / f"{v}.png", thumb),
                         _file_uri(validate_dir / "flip_ldr" / model_subfolder(n) / f"{v}.png", thumb)))
        rows = []
        for k, what in ((1, "render"), (2, "|error| ×%g (reference: its noise σ, same scale)" % gain), (3, "Z-map"),
                        (4, "ꟻLIP error (LDR)")):
            cells = []
            for c in cols:
                uri = c[k]
                if uri:
                    cells.append(f'<td><img src="{uri}" alt="{e(c[0])} {e(what)} {e(v)}" width="{thumb}"></td>')
                else:
                    cells.append("<td></td>")
            rows.append(f'<tr><td class="cap rowcap">{e(what)}</td>{"".join(cells)}</tr>')
        head = "".join(f'<td class="cap">{e(c[0])}'
                       + (f"<br>{_view_figures(models[c[0]]['per_view'][v])}" if c[0] in models else "")
                       + "</td>" for c in cols)
        blocks.append(f"<h3>{e(v)}</h3><div class='views'><table class='grid'><tr><td></td>{head}</tr>{''.join(rows)}</table></div>")
    if len(views) > max_views:
        blocks.append(f'<p class="note">{len(views) - max_views} more held-out views are scored in the tables '
                      f'(validate/errors, validate/zmaps hold all of them).</p>')
    blocks.append('<p class="note">Captions: display PSNR (whole image, then the subject), LDR-ꟻLIP, linear PSNR. '
                  'Z-map: grey where the difference is within the reference\'s noise (darker = smaller), red where it '
                  'exceeds it. ꟻLIP error: magma, black 0 to pale yellow 1 (validate/flip_hdr holds the HDR maps).</p>')
    return "".join(blocks)


def _view_figures(m: dict) -> str:
    """A render's caption: display PSNR (subject), ꟻLIP, linear PSNR of one view."""
    parts = [f"{m['display_psnr']:.2f} dB" if m.get("display_psnr") is not None else "",
             f"subject {m['display_psnr_subject']:.2f} dB" if m.get("display_psnr_subject") is not None else "",
             f"ꟻLIP {m['flip_ldr']:.3f}" if m.get("flip_ldr") is not None else "",
             f"linear {m['linear_psnr']:.2f} dB" if m.get("linear_psnr") is not None else ""]
    return html.escape(" · ".join(p for p in parts if p))


def _poses_section(poses: dict) -> str:
    if not poses:
        return '<p class="note">No poses stage.</p>'
    header = ["method", "status", "registered", "rotation error mean (deg)", "rotation error max (deg)",
              "centre error mean (rel.)", "reprojection (px)", "time"]
    rows, cls = [], []
    for m, p in sorted(poses.items()):
        reg = f"{p.get('views_registered', '–')}/{p.get('views_total', '–')}"
        rows.append([m, p.get("status", "ok") + (f": {p['reason']}" if p.get("reason") else ""), reg,
                     p.get("rotation_error_deg_mean"), p.get("rotation_error_deg_max"), p.get("center_error_rel_mean"),
                     p.get("reprojection_error_px"), _duration(p.get("wall_time_s"))])
        cls.append("failed" if p.get("status") == "failed" else "")
    return _table(header, rows, cls)


def _stages_section(root: Path) -> str:
    rows, cls = [], []
    for f in _stage_folders(root):
        rel = f.relative_to(root).as_posix()
        if (f / MANIFEST).is_file():
            m = read_json(f / MANIFEST)
            outs = m.get("outputs", {})
            size = sum((f / o).stat().st_size for o in outs if (f / o).is_file())
            kinds = sorted({Path(o).parts[0] if len(Path(o).parts) > 1 else Path(o).name for o in outs})
            head = {k: v for k, v in m.get("metrics", {}).items()
                    if isinstance(v, (int, float, str)) and not isinstance(v, bool)}
            heads = ", ".join(f"{k} {_fmt(v)}" for k, v in list(head.items())[:6])
            rows.append([rel, m.get("stage", "?"), _duration(m.get("wall_time_s")), len(outs),
                         f"{size / 1e6:.1f} MB", ", ".join(kinds)[:90], heads[:160]])
            cls.append("")
        else:
            mt = read_json(f / "metrics.json")
            if mt.get("status") == "failed":
                rows.append([rel, "failed", _duration(mt.get("wall_time_s")), 0, "–", "metrics.json",
                             str(mt.get("reason", ""))[:160]])
                cls.append("failed")
    return _table(["folder", "stage", "wall time", "files", "size", "produced", "headline metrics"], rows, cls)


def _check_report_out(path: Path, overwrite: bool) -> None:
    """BadInput unless ``path`` may be (over)written: absent, or a report this module wrote (its
    generator tag), or any file when ``overwrite``; never a folder."""
    from .artifacts import OVERWRITE_HINT

    if path.is_dir():
        raise BadInput(f"{path}: is a folder; --out names the report file to write")
    if overwrite or not (path.exists() or path.is_symlink()):
        return
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise BadInput(f"{path}: cannot read the existing file ({exc.strerror})") from None
    if GENERATOR_TAG.encode() not in head:
        raise BadInput(f"{path}: exists and is not a lumigraph report; refusing to replace it ({OVERWRITE_HINT})")


def write_report(artifacts_dir: Path, out: Path | None = None, max_views: int = 4, thumb: int = 320,
                 overwrite: bool = False) -> Path:
    """Write the scene's report (default ``artifacts_dir/validate/report.html``) from its finished
    ``validate`` stage and the other stage folders; returns its path. BadInput when the validate
    stage is missing or unfinished, or when ``out`` is an existing file that is not a report
    (tagged :data:`GENERATOR_TAG`) and not ``overwrite``. Images are embedded, downscaled to
    ``thumb`` pixels wide; side-by-side views show the first ``max_views`` held-out views."""
    from .artifacts import read_manifest

    if out is not None:
        _check_report_out(Path(out), overwrite)  # before any work
    root = Path(artifacts_dir)
    vdir = root / "validate"
    vman = read_manifest(vdir)
    met = read_json(vdir / "metrics.json")
    models, ref, best = met.get("models", {}), met.get("reference", {}), met.get("best")
    if not isinstance(models, dict):
        raise BadInput(f"{vdir / 'metrics.json'}: 'models' is not an object")
    stale = sorted(n for n, m in models.items() if not isinstance(m, dict) or "display_psnr_mean" not in m)
    if stale:  # written before the display metrics: say so instead of a KeyError
        raise BadInput(f"{vdir / 'metrics.json'}: models {', '.join(stale)} have no display_psnr_mean "
                       "(an older validate stage): rerun `lumigraph validate --overwrite`")
    names = sorted(models)
    mask = pareto_mask([models[n]["end_to_end_s"] for n in names],
                       [models[n]["display_psnr_mean"] if models[n]["display_psnr_mean"] is not None else float("nan")
                        for n in names])
    for n in names:  # the NeRF stages' time budgets, for the models table
        f = root / n / "metrics.json"
        t = read_json(f).get("time") if n.startswith("nerf") and f.is_file() else None
        if isinstance(t, dict):
            models[n]["budget"] = t
    front = sorted((n for n, k in zip(names, mask) if k), key=lambda n: models[n]["end_to_end_s"])
    views = list(vman.get("params", {}).get("views", []))
    gain = float(vman.get("params", {}).get("error_gain", 8.0))
    e = html.escape
    scene = root.resolve().name
    body = [f"<h1>lumigraph report: {e(scene)}</h1>",
            f'<p class="note">{len(models)} models judged on {len(views)} held-out views against the path-traced '
            f"reference ({e(str(ref.get('spp')))} spp, {e(str(ref.get('integrator')))}). "
            f"lumigraph {e(str(vman.get('lumigraph', '')))}.</p>",
            _glance(models, best, ref, front),
            "<h2>Models at the held-out views</h2>", _models_section(models, best and best["model"], front, ref),
            "<h2>Accuracy against time</h2>", _plots_section(models, ref, root, vdir),
            "<h2>Side by side</h2>", _views_section(root, vdir, models, views, gain, max_views, thumb),
            "<h2>Pose accuracy</h2>", _poses_section(met.get("poses", {})), pose_tolerance_section(root),
            "<h2>Stages: what each produced</h2>", _stages_section(root),
            lecture_section(root.parent)]
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>lumigraph report: {e(scene)}</title>{GENERATOR_TAG}"
            '<meta http-equiv="Content-Security-Policy" content="default-src \'none\'; img-src data:; '
            "style-src 'unsafe-inline'\">"
            f"<style>{_CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    path = Path(out) if out is not None else vdir / REPORT
    with atomic_path(path) as tmp:
        Path(tmp).write_text(page, encoding="utf-8")
    return path

