"""Checks on rendered matplotlib figures, shared by the report's tests."""

from __future__ import annotations

import matplotlib.pyplot as plt


def overlapping_tick_labels(fig: plt.Figure) -> list[tuple[str, str, str]]:
    """Pairs of visible tick labels of one axis whose rendered boxes intersect.

    The figure is drawn first (labels get their text and place only then).

    Returns
    -------
    list of (str, str, str)
        ``(axis, label, label)`` per overlapping pair, the axis as ``"panel 2 x"``; empty when
        every label stands clear of its neighbours.
    """
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    found = []
    for n, ax in enumerate(fig.axes):
        for name, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            labels = [
                t
                for t in axis.get_ticklabels(which="both")
                if t.get_visible() and t.get_text().strip()
            ]
            boxes = [t.get_window_extent(renderer) for t in labels]
            for i in range(len(labels)):
                for j in range(i + 1, len(labels)):
                    if boxes[i].overlaps(boxes[j]):
                        found.append(
                            (f"panel {n} {name}", labels[i].get_text(), labels[j].get_text())
                        )
    return found
