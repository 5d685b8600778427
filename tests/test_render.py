"""Figures rendered aside in forked processes (``fmu_greybox/evidence/render.py``): the same
page byte for byte, rendered in place where forking is not safe or a child fails."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

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
        return text, len(render._aside.renders)


def in_a_fresh_process(children_fail: bool = False) -> dict:
    """The page of :func:`report` in place and aside, built in a fresh Python process (where
    this one, a test worker, may run other threads): the children forked, whether the pages
    are equal, and the figures left open."""
    code = f"""
import json, os, sys
sys.path.insert(0, {str(Path(__file__).parent)!r})
import matplotlib.pyplot as plt
from test_render import forked_in, report
from fmu_greybox.evidence import render
in_place = report()
if {children_fail}:
    render._render_into = lambda fig, send: os._exit(3)
aside, forked = forked_in(report)
print(json.dumps({{"forked": forked, "same": aside == in_place, "open": plt.get_fignums(),
                  "pngs": aside.count("data:image/png;base64,iVBOR"), "tokens": "\\0" in aside}}))
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def test_a_page_rendered_aside_is_the_page_rendered_in_place() -> None:
    outcome = in_a_fresh_process()
    assert outcome == {"forked": 3, "same": True, "open": [], "pngs": 3, "tokens": False}


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


def test_a_child_that_fails_leaves_its_figure_to_this_process() -> None:
    outcome = in_a_fresh_process(children_fail=True)
    assert outcome == {"forked": 3, "same": True, "open": [], "pngs": 3, "tokens": False}


def test_a_figure_token_outside_the_block_is_refused() -> None:
    with pytest.raises(OutputError, match="rendering_aside"):
        render.resolve("<img src='data:image/png;base64," + render.TOKEN.format(0) + "'>")
