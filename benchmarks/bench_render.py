"""A report page's figures rendered aside in forked processes (``fmu_greybox/evidence/render.py``)
against rendered in place, one after the other, as every page was before.

The page: F figures of 2 x 2 panels, each panel a noisy trace of P points with its title and
legend, built with ``evidence.html.figure`` and ``page`` as the reports build theirs. The two
pages are checked byte for byte.

Usage::

    .venv/bin/python benchmarks/bench_render.py [--figures 8] [--points 4000] [--repeat 3]

Prints the median time to build the page each way with its range, the ratio, and whether the
pages are the same.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
from collections.abc import Callable

import matplotlib.pyplot as plt
import numpy as np
from spread import alternated, print_against, yes

from fmu_greybox.evidence.html import figure, page
from fmu_greybox.evidence.render import rendering_aside


def report(figures: int, points: int) -> str:
    """The benchmark's page (see the module docstring)."""
    rng = np.random.default_rng(0)
    x = np.linspace(0.0, 10.0, points)
    sections = []
    for k in range(figures):
        fig, axes = plt.subplots(2, 2, figsize=(10, 6))
        for j, ax in enumerate(axes.flat):
            ax.plot(x, np.sin((k + j + 1) * x) + 0.1 * rng.standard_normal(points), label="trace")
            ax.set_title(f"figure {k}, panel {j}")
            ax.legend(loc="upper right")
        fig.tight_layout()
        sections.append(figure(f"figure {k}", fig, "a caption"))
    return page("bench_render", sections)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figures", type=int, default=8)
    parser.add_argument("--points", type=int, default=4000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    load_before = os.getloadavg()[0]

    def built(block: Callable[[], contextlib.AbstractContextManager]) -> str:
        with block():
            return report(args.figures, args.points)

    ways = {"in place": contextlib.nullcontext, "aside": rendering_aside}
    figures, pages = alternated(
        {way: functools.partial(built, block) for way, block in ways.items()}, args.repeat
    )
    print_against(
        f"a page of {args.figures} figures (2 x 2 panels of {args.points} points)",
        figures,
        "aside",
        "in place",
        f"the same page: {yes(pages['in place'] == pages['aside'])}",
        load_before,
        args.repeat,
    )


if __name__ == "__main__":
    main()
