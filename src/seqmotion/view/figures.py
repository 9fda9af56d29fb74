"""Small raster figures for paths in a plane (y–z of the spatula, x–y of the object on the pan).

Time series go to the page as data (uPlot draws them in the browser); a path is not a function of
one axis, so it is drawn here, with Pillow, into an RGB array (a few milliseconds for 500 points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

BLUE, GREY, ORANGE, GREEN, RED, PURPLE = (31, 119, 180), (140, 140, 140), (230, 120, 20), (44, 160, 44), \
    (214, 39, 40), (148, 103, 189)


@dataclass
class Line:
    """One polyline ``xy`` ``(N, 2)`` in data units; ``dashed`` draws every other segment; ``band`` ``(N,)`` a
    half-width (data units) drawn as a light tube around it."""

    xy: np.ndarray
    rgb: tuple[int, int, int]
    label: str
    width: int = 2
    dashed: bool = False
    band: np.ndarray | None = None


def _nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    span = max(hi - lo, 1e-12)
    step = 10 ** math.floor(math.log10(span / n))
    for m in (1, 2, 5, 10):
        if span / (m * step) <= n:
            step *= m
            break
    return np.arange(math.ceil(lo / step) * step, hi + 1e-12, step)


def _tick(value: float) -> str:
    return f"{0.0 if abs(value) < 1e-9 else value:.4g}"


def path_figure(lines: list[Line], xlabel: str, ylabel: str, size: tuple[int, int] = (440, 330),
                markers: list[tuple[tuple[float, float], tuple[int, int, int], str]] = (), scale: float = 1000.0,
                unit: str = "mm", title: str = "") -> np.ndarray:
    """An RGB image ``(H, W, 3)`` uint8 of ``lines`` with equal axis scales, ticks in ``unit`` (data × ``scale``),
    a legend, and ``markers`` (point, colour, label)."""
    w, h = size
    img = Image.new("RGB", (w, h), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    left, right, top, bottom = 52, 10, 24 if title else 10, 34
    pts = [ln.xy for ln in lines if len(ln.xy)] + [np.array([m[0]]) for m in markers]
    allxy = np.concatenate(pts) if pts else np.zeros((1, 2))
    lo, hi = allxy.min(0), allxy.max(0)
    pad = np.maximum(0.08 * (hi - lo).max(), 1e-3)
    lo, hi = lo - pad, hi + pad
    pw, ph = w - left - right, h - top - bottom
    k = min(pw / (hi[0] - lo[0]), ph / (hi[1] - lo[1]))  # equal scales
    cx, cy = (lo + hi) / 2
    lo = np.array([cx - pw / k / 2, cy - ph / k / 2])
    hi = np.array([cx + pw / k / 2, cy + ph / k / 2])

    def px(xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        return np.column_stack([left + (xy[:, 0] - lo[0]) * k, top + ph - (xy[:, 1] - lo[1]) * k])

    for t in _nice_ticks(lo[0], hi[0]):
        x = left + (t - lo[0]) * k
        draw.line([(x, top), (x, top + ph)], fill=(235, 235, 235))
        draw.text((x - 10, top + ph + 4), _tick(t * scale), fill=(60, 60, 60))
    for t in _nice_ticks(lo[1], hi[1]):
        y = top + ph - (t - lo[1]) * k
        draw.line([(left, y), (left + pw, y)], fill=(235, 235, 235))
        draw.text((4, y - 6), _tick(t * scale), fill=(60, 60, 60))
    draw.rectangle([left, top, left + pw, top + ph], outline=(120, 120, 120))
    draw.text((left + pw / 2 - 30, h - 14), f"{xlabel} [{unit}]", fill=(30, 30, 30))
    if title:
        draw.text((left, 4), f"{title}   ({ylabel} vs {xlabel} [{unit}])", fill=(30, 30, 30))
    else:
        draw.text((4, 0), f"{ylabel} [{unit}]", fill=(30, 30, 30))
    for ln in lines:
        if ln.band is not None and len(ln.xy) > 1:
            light = tuple(int(c + (255 - c) * 0.8) for c in ln.rgb)
            step = max(1, len(ln.xy) // 60)
            for (x, y), r in zip(px(ln.xy[::step]), ln.band[::step] * k, strict=False):
                r = min(r, 40)
                draw.ellipse([x - r, y - r, x + r, y + r], fill=light)
    for ln in lines:
        p = px(ln.xy)
        if len(p) < 2:
            continue
        if ln.dashed:
            seg = max(1, len(p) // 40)
            for i in range(0, len(p) - 1, 2 * seg):
                draw.line([tuple(q) for q in p[i : i + seg + 1]], fill=ln.rgb, width=ln.width)
        else:
            draw.line([tuple(q) for q in p], fill=ln.rgb, width=ln.width, joint="curve")
        x0, y0 = p[0]
        draw.ellipse([x0 - 3, y0 - 3, x0 + 3, y0 + 3], outline=ln.rgb)
    for (x, y), rgb, _ in markers:
        (mx, my), = px(np.array([x, y]))
        draw.line([(mx - 6, my - 6), (mx + 6, my + 6)], fill=rgb, width=2)
        draw.line([(mx - 6, my + 6), (mx + 6, my - 6)], fill=rgb, width=2)
    ly = top + 4
    for label, rgb in [(ln.label, ln.rgb) for ln in lines] + [(m[2], m[1]) for m in markers]:
        draw.line([(left + 8, ly + 6), (left + 26, ly + 6)], fill=rgb, width=3)
        draw.text((left + 30, ly), label, fill=(30, 30, 30))
        ly += 14
    return np.asarray(img)
