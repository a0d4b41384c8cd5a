"""What makes a report figure readable at a glance, checked on the drawn figure.

``figure_problems(fig)`` lists what is wrong with a matplotlib figure as it will be saved
(``plots.save_figure``: 120 dpi, tight bounding box): wider than ``MAX_WIDTH_PX``, or two
pieces of visible text whose boxes overlap. The tests draw every report figure on crowded
inputs and require an empty list.
"""

from __future__ import annotations

import itertools

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.text import Text  # noqa: E402

from harness.report.plots import DPI  # noqa: E402  (plots.save_figure's resolution)

MAX_WIDTH_PX = 2000  # wider does not fit a laptop screen or a Markdown page at 1:1


def _texts(fig: plt.Figure) -> list[Text]:
    """The text ``fig`` draws: visible, non-empty, in a visible axes, and, for tick labels, only
    those of ticks inside the view (matplotlib keeps labels for ticks it does not draw)."""
    tick_labels, drawn = set(), set()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                tick_labels.update({id(tick.label1), id(tick.label2)})
            for tick in axis._update_ticks():  # the ticks matplotlib will draw
                drawn.update(id(lb) for lb in (tick.label1, tick.label2) if lb.get_visible())
    seen: set[int] = set()
    out = []
    for t in fig.findobj(Text):
        if id(t) in seen or not t.get_visible() or not t.get_text().strip():
            continue
        if t.axes is not None and not t.axes.get_visible():
            continue
        if id(t) in tick_labels and id(t) not in drawn:
            continue
        seen.add(id(t))
        out.append(t)
    return out


def figure_problems(fig: plt.Figure) -> list[str]:
    """Everything that makes ``fig`` hard to read: its saved width, overlapping text."""
    fig.set_dpi(DPI)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    problems = []
    width = fig.get_tightbbox(renderer).width * DPI  # inches at save time
    if width > MAX_WIDTH_PX:
        problems.append(f"{width:.0f} px wide (at most {MAX_WIDTH_PX})")
    boxes = [(t, t.get_window_extent(renderer)) for t in _texts(fig)]
    boxes = [(t, b) for t, b in boxes if b.width > 0 and b.height > 0]
    for (t1, b1), (t2, b2) in itertools.combinations(boxes, 2):
        # a shared pixel row or column is no overlap: boxes must intersect by more than a pixel
        dx = min(b1.x1, b2.x1) - max(b1.x0, b2.x0)
        dy = min(b1.y1, b2.y1) - max(b1.y0, b2.y0)
        if dx > 1 and dy > 1:
            problems.append(f"text {t1.get_text()!r} overlaps {t2.get_text()!r}")
    return problems
