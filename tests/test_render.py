"""Figures rendered aside in forked processes (``fmu_greybox/evidence/render.py``): the same
page byte for byte, rendered in place where forking is not safe or a child fails."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable

import matplotlib.pyplot as plt
import numpy as np
import pytest

from fmu_greybox.errors import OutputError
from fmu_greybox.evidence import render
from fmu_greybox.evidence.html import figure, page


def report(count: int = 3) -> str:
    """A page of ``count`` figures, each a noisy trace."""
    sections = []
    for k in range(count):
        fig, ax = plt.subplots(figsize=(4, 3))
        x = np.linspace(0.0, 1.0, 500)
        ax.plot(x, np.sin(7 * k * x) + 0.1 * np.random.default_rng(k).standard_normal(x.size))
        ax.set_title(f"figure {k}")
        sections.append(figure(f"figure {k}", fig, "a caption"))
    return page("report", sections)


def forked_in(block_report: Callable[[], str]) -> tuple[str, int]:
    """The page built inside :func:`render.rendering_aside` and the children forked."""
    with render.rendering_aside():
        text = block_report()
        return text, render._aside.forked


def test_a_page_rendered_aside_is_the_page_rendered_in_place() -> None:
    in_place = report()
    aside, forked = forked_in(report)
    assert forked == 3
    assert aside == in_place
    assert "\0" not in aside and aside.count("data:image/png;base64,iVBOR") == 3
    assert plt.get_fignums() == []  # every figure closed


def test_while_another_thread_runs_figures_render_in_place() -> None:
    in_place = report()
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        aside, forked = forked_in(report)
    finally:
        stop.set()
        other.join()
    assert forked == 0
    assert aside == in_place


def test_a_child_that_fails_leaves_its_figure_to_this_process(monkeypatch) -> None:
    in_place = report(2)
    monkeypatch.setattr(render, "_render_into", lambda fig, send: os._exit(3))
    aside, forked = forked_in(lambda: report(2))
    assert forked == 2
    assert aside == in_place


def test_a_figure_token_outside_the_block_is_refused() -> None:
    with pytest.raises(OutputError, match="rendering_aside"):
        render.resolve("<img src='data:image/png;base64," + render.TOKEN.format(0) + "'>")
