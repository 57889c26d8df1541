"""Inline SVG for the plant page: a state timeline and a sparkline, as strings.

Drawn on the server so the page needs no script library and no network: a plant network often has no
internet. Coordinates are in viewBox units (a timeline is 1000 wide whatever its pixel width), bands carry
their state as a CSS class and their epoch start/end as data attributes, so a browser test can check order
and widths in the DOM and a person can hover for the exact times.
"""

from __future__ import annotations

import html
from collections.abc import Callable, Sequence

from edge.service.trends import Band

TIMELINE_WIDTH = 1000.0
TIMELINE_HEIGHT = 22
TICK_HEIGHT = 14
SPARK_WIDTH = 240.0
SPARK_HEIGHT = 40.0


def duration_text(seconds: float) -> str:
    """1 h 05 min, 4 min 30 s, 12 s: how long, for people."""
    seconds = max(0, int(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours} h {minutes:02d} min"
    if minutes:
        return f"{minutes} min {secs:02d} s"
    return f"{secs} s"


def timeline_svg(element_id: str, runs: Sequence[tuple[float, float, Band]], start: float, end: float,
                 ticks: Sequence[tuple[float, str]], clock_text: Callable[[float], str]) -> str:
    """Bands for `runs` (start, end, band) over [start, end], with labelled ticks underneath."""
    span = max(end - start, 1e-9)
    scale = TIMELINE_WIDTH / span
    parts = []
    for begin, until, band in runs:
        x = (max(begin, start) - start) * scale
        width = (min(until, end) - max(begin, start)) * scale
        if width <= 0:
            continue
        title = f"{band.label} {clock_text(begin)} - {clock_text(until)} ({duration_text(until - begin)})"
        parts.append(f'<rect class="band {band.css}" x="{x:.3f}" y="0" width="{width:.3f}" '
                     f'height="{TIMELINE_HEIGHT}" data-start="{begin:.3f}" data-end="{until:.3f}">'
                     f"<title>{html.escape(title)}</title></rect>")
    for at, label in ticks:
        x = (at - start) * scale
        if 0 <= x <= TIMELINE_WIDTH:
            anchor = "start" if x < 30 else "end" if x > TIMELINE_WIDTH - 30 else "middle"
            parts.append(f'<line class="tick" x1="{x:.1f}" x2="{x:.1f}" y1="{TIMELINE_HEIGHT}" '
                         f'y2="{TIMELINE_HEIGHT + 3}"/><text x="{x:.1f}" y="{TIMELINE_HEIGHT + TICK_HEIGHT - 2}" '
                         f'text-anchor="{anchor}">{html.escape(label)}</text>')
    height = TIMELINE_HEIGHT + TICK_HEIGHT
    return (f'<svg id="{html.escape(element_id)}" class="timeline" viewBox="0 0 {TIMELINE_WIDTH:g} {height}" '
            f'preserveAspectRatio="none" width="100%" height="{height}" role="img" '
            f'data-start="{start:.3f}" data-end="{end:.3f}">' + "".join(parts) + "</svg>")


def sparkline_svg(element_id: str, points: Sequence[float | None],
                  peaks: Sequence[float | None] = ()) -> tuple[str, float | None, float | None]:
    """A line through `points` (None breaks it) and a faint one through `peaks`, scaled from 0 (or the
    lowest value) to the highest; the SVG and the (low, high) of its scale, None when there is no value."""
    values = [p for p in (*points, *peaks) if p is not None]
    if not values:
        return (f'<svg id="{html.escape(element_id)}" class="spark empty" viewBox="0 0 {SPARK_WIDTH:g} '
                f'{SPARK_HEIGHT:g}" width="{SPARK_WIDTH:g}" height="{SPARK_HEIGHT:g}"></svg>', None, None)
    low, high = min(0.0, min(values)), max(values)
    shapes = _polylines(peaks, low, high, "peak") + _polylines(points, low, high, "mean")
    return (f'<svg id="{html.escape(element_id)}" class="spark" viewBox="0 0 {SPARK_WIDTH:g} {SPARK_HEIGHT:g}" '
            f'width="{SPARK_WIDTH:g}" height="{SPARK_HEIGHT:g}" role="img">{shapes}</svg>', low, high)


def _polylines(points: Sequence[float | None], low: float, high: float, css: str) -> str:
    """Polylines through runs of values (a lone value is a dot)."""
    span = high - low or 1.0
    step = SPARK_WIDTH / max(len(points) - 1, 1)
    lines: list[list[tuple[float, float]]] = []
    previous = None
    for i, value in enumerate(points):
        if value is None:
            previous = None
            continue
        if previous is None:
            lines.append([])
        lines[-1].append((i * step, SPARK_HEIGHT - 1 - (value - low) / span * (SPARK_HEIGHT - 2)))
        previous = value
    return "".join(f'<polyline class="{css}" points="{" ".join(f"{x:.1f},{y:.1f}" for x, y in line)}"/>'
                   if len(line) > 1 else f'<circle class="{css}" r="1.5" cx="{line[0][0]:.1f}" cy="{line[0][1]:.1f}"/>'
                   for line in lines)
