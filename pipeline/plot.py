"""One plotting helper for the report and every study: dependency-free inline SVG.

:func:`svg_plot` draws series of (x, y) points (optionally joined, labelled, on a log x axis, with
dashed reference lines) as an ``<svg>`` element that can be inlined in HTML many times or written
as a file; :func:`pareto_mask` finds the points no other point beats in both cost and accuracy.
Used by :mod:`pipeline.report`, :mod:`pipeline.stages.study`, :mod:`pipeline.stages.slab_study`,
:mod:`pipeline.stages.nerf_study` and the benchmarks.
"""
from __future__ import annotations

import html
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from render.image_io import atomic_path

__all__ = ["Series", "svg_plot", "write_svg", "pareto_mask", "PALETTE"]

PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
           "#7f7f7f", "#bcbd22")



@dataclass
class Series:
    """One series of a plot: points (x, y) with an optional label each (shown beside the point
    when ``annotate``, always as a tooltip); ``line`` joins the points in the order given (a knob's
    order, or time order for a training curve)."""

    name: str
    x: list[float]
    y: list[float]
    labels: list[str] = field(default_factory=list)
    colour: str = ""
    line: bool = False
    annotate: bool = False
    dashed: bool = False


def pareto_mask(cost, accuracy) -> np.ndarray:
    """(N,) bool: points no other point dominates (no other has cost <= and accuracy >= with one
    strict). Lower cost and higher accuracy are better; non-finite entries are never optimal."""
    c, a = np.asarray(cost, float), np.asarray(accuracy, float)
    ok = np.isfinite(c) & np.isfinite(a)
    le_c = c[None, :] <= c[:, None]  # [i, j]: j costs no more than i
    ge_a = a[None, :] >= a[:, None]
    strict = (c[None, :] < c[:, None]) | (a[None, :] > a[:, None])
    dom = le_c & ge_a & strict & ok[None, :]
    return ok & ~dom.any(axis=1)


def _nice_ticks(lo: float, hi: float, n: int = 6) -> list[float]:
    span = hi - lo if hi > lo else 1.0
    raw = span / max(n - 1, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(s * mag for s in (1, 2, 2.5, 5, 10) if s * mag >= raw)
    start = math.ceil(lo / step - 1e-9) * step
    return [start + i * step for i in range(int((hi - start) / step + 1e-9) + 1)]


def _log_ticks(lo: float, hi: float) -> list[float]:
    ticks = []
    for e in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1):
        for m in (1, 2, 5):
            t = m * 10.0 ** e
            if lo <= t <= hi:
                ticks.append(t)
    return ticks if len(ticks) >= 2 else [t for t in _nice_ticks(lo, hi, 4) if lo <= t <= hi]


def _fmt_tick(v: float) -> str:
    if v == 0:
        return "0"
    if abs(v) >= 1000 or abs(v) < 0.01:
        return f"{v:.0e}".replace("e+0", "e").replace("e-0", "e-")
    return f"{v:.3g}"


def svg_plot(series: list[Series], xlabel: str, ylabel: str, title: str = "", logx: bool = False,
             hlines: list[tuple[float, str]] = (), width: int = 720, height: int = 400) -> str:
    """A dependency-free SVG scatter/line plot. Non-finite points are dropped; ``logx`` needs
    positive x. ``hlines``: (y, label) dashed reference lines (e.g. the reference noise ceiling).
    Returns the ``<svg>`` element text (no XML declaration, no ids: safe to inline many times)."""
    e = html.escape
    pts = [(x, y) for s in series for x, y in zip(s.x, s.y)
           if math.isfinite(x) and math.isfinite(y) and (x > 0 or not logx)]
    L, R, T, B = 64, 190, 30 if title else 14, 46
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" width="{width}" '
           f'height="{height}" font-family="sans-serif" font-size="11" role="img">',
           f'<rect width="{width}" height="{height}" fill="white"/>']
    if title:
        out.append(f'<text x="{width / 2:.0f}" y="18" text-anchor="middle" font-size="13" font-weight="bold">'
                   f'{e(title)}</text>')
    if not pts:
        out.append(f'<text x="{width / 2:.0f}" y="{height / 2:.0f}" text-anchor="middle">no data</text></svg>')
        return "\n".join(out) + "\n"
    xs = np.array([p[0] for p in pts])
    ys = np.array([p[1] for p in pts] + [h for h, _ in hlines if math.isfinite(h)])
    if logx:
        lx0, lx1 = math.log10(xs.min()), math.log10(xs.max())
        pad = max(0.08 * (lx1 - lx0), 0.1)
        x0, x1 = 10 ** (lx0 - pad), 10 ** (lx1 + pad)
        fx = lambda v: (math.log10(v) - math.log10(x0)) / (math.log10(x1) - math.log10(x0))  # noqa: E731
        xt = _log_ticks(x0, x1)
    else:
        pad = max(0.05 * (xs.max() - xs.min()), 1e-9 + 0.05 * abs(xs.max()))
        x0, x1 = xs.min() - pad, xs.max() + pad
        fx = lambda v: (v - x0) / (x1 - x0)  # noqa: E731
        xt = [t for t in _nice_ticks(x0, x1) if x0 <= t <= x1]
    ypad = max(0.06 * (ys.max() - ys.min()), 1e-9 + 0.02 * abs(ys.max()), 0.05)
    y0, y1 = ys.min() - ypad, ys.max() + ypad
    W, H = width - L - R, height - T - B
    X = lambda v: L + fx(v) * W  # noqa: E731
    Y = lambda v: T + H - (v - y0) / (y1 - y0) * H  # noqa: E731
    out.append(f'<rect x="{L}" y="{T}" width="{W}" height="{H}" fill="none" stroke="#444"/>')
    for t in xt:
        out.append(f'<line x1="{X(t):.1f}" y1="{T}" x2="{X(t):.1f}" y2="{T + H}" stroke="#e4e4e4"/>'
                   f'<text x="{X(t):.1f}" y="{T + H + 14}" text-anchor="middle">{_fmt_tick(t)}</text>')
    for t in _nice_ticks(y0, y1):
        if y0 <= t <= y1:
            out.append(f'<line x1="{L}" y1="{Y(t):.1f}" x2="{L + W}" y2="{Y(t):.1f}" stroke="#e4e4e4"/>'
                       f'<text x="{L - 5}" y="{Y(t) + 4:.1f}" text-anchor="end">{_fmt_tick(t)}</text>')
    out.append(f'<text x="{L + W / 2:.0f}" y="{height - 8}" text-anchor="middle">{e(xlabel)}'
               f'{" (log scale)" if logx else ""}</text>')
    out.append(f'<text x="14" y="{T + H / 2:.0f}" transform="rotate(-90 14 {T + H / 2:.0f})" '
               f'text-anchor="middle">{e(ylabel)}</text>')
    for h, label in hlines:
        if math.isfinite(h):
            out.append(f'<line x1="{L}" y1="{Y(h):.1f}" x2="{L + W}" y2="{Y(h):.1f}" stroke="#555" '
                       f'stroke-dasharray="5 4"/><text x="{L + W - 4}" y="{Y(h) - 4:.1f}" text-anchor="end" '
                       f'fill="#555">{e(label)}</text>')
    legend_y, placed = T + 4, []  # placed: label boxes (x0, y0, x1, y1); overlapping labels are left to tooltips
    for i, s in enumerate(series):
        c = s.colour or PALETTE[i % len(PALETTE)]
        labels = s.labels or [""] * len(s.x)
        good = [(x, y, lab) for x, y, lab in zip(s.x, s.y, labels)
                if math.isfinite(x) and math.isfinite(y) and (x > 0 or not logx)]
        if s.line and len(good) > 1:
            dash = ' stroke-dasharray="6 3"' if s.dashed else ""
            out.append(f'<polyline fill="none" stroke="{c}" stroke-width="1.8"{dash} points="'
                       + " ".join(f"{X(x):.1f},{Y(y):.1f}" for x, y, _ in good) + '"/>')
        for x, y, lab in good:
            tip = f"{s.name}{': ' + lab if lab else ''} ({_fmt_tick(x)}, {y:.3g})"
            out.append(f'<circle cx="{X(x):.1f}" cy="{Y(y):.1f}" r="3.5" fill="{c}" stroke="white" stroke-width="0.8">'
                       f'<title>{e(tip)}</title></circle>')
            if s.annotate and lab:
                box = (X(x) + 6, Y(y) - 15, X(x) + 6 + 6.2 * len(lab), Y(y) - 3)
                if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in placed):
                    placed.append(box)
                    out.append(f'<text x="{box[0]:.1f}" y="{Y(y) - 5:.1f}" fill="{c}">{e(lab)}</text>')
        out.append(f'<rect x="{L + W + 12}" y="{legend_y}" width="10" height="10" fill="{c}"/>'
                   f'<text x="{L + W + 27}" y="{legend_y + 9}">{e(s.name[:28])}</text>')
        legend_y += 16
    out.append("</svg>")
    return "\n".join(out) + "\n"


def write_svg(path: Path, svg: str) -> None:
    """Write an :func:`svg_plot` result to ``path`` atomically."""
    with atomic_path(Path(path)) as tmp:
        Path(tmp).write_text(svg)
