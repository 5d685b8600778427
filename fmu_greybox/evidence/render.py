"""Figures rendered to PNG aside, in forked processes, while a report goes on being built.

Most of a report's time goes into rendering its figures (matplotlib's Agg and the PNG
encoder: 2.5 s of the demo report's 4.2 s, ``docs/speed.md``), one after another on one core.
Inside :func:`rendering_aside`, :func:`png_base64` forks a process for each figure (at most one
per core at a time), which renders the figure it inherits and sends the PNG back, while this
process builds the next figure; :func:`resolve` then puts every PNG in its place. The PNG is
the one rendering here gives, byte for byte (the same code on the same figure).

Figures render in place, as outside the context, where ``fork`` is missing (Windows) or while
another thread runs (a fork copies only the thread that forks; a lock another thread holds
would stay held in the child), and when a child fails.
"""

from __future__ import annotations

import base64
import multiprocessing
import re
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

import matplotlib.pyplot as plt

from fmu_greybox.errors import OutputError
from fmu_greybox.evidence.plots import png_bytes
from fmu_greybox.side_by_side import available_cores

#: A figure not rendered yet, in the text of a page (a NUL never occurs in HTML text).
TOKEN = "\0figure {}\0"
_TOKEN_PATTERN = re.compile("\0figure (\\d+)\0")


@dataclass
class _Render:
    """One figure rendering in a child process."""

    figure: plt.Figure
    process: BaseProcess
    answer: Connection
    png: str | None = None


class _Renders:
    """The figures handed to child processes in one :func:`rendering_aside` block."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.renders: list[_Render] = []  # every figure handed to a child, in token order

    def submit(self, fig: plt.Figure) -> str:
        """Fork a child rendering ``fig``; its token."""
        while len(self.running()) >= self.limit:
            self.collect(self.running()[0])
        context = multiprocessing.get_context("fork")
        answer, send = context.Pipe(duplex=False)
        process = context.Process(target=_render_into, args=(fig, send), daemon=True)
        process.start()
        send.close()
        self.renders.append(_Render(fig, process, answer))
        return TOKEN.format(len(self.renders) - 1)

    def running(self) -> list[_Render]:
        """The renders not collected yet, oldest first."""
        return [r for r in self.renders if r.png is None]

    def collect(self, render: _Render) -> None:
        """Wait for ``render``'s PNG (rendered here if its child failed)."""
        try:
            data: bytes | None = render.answer.recv_bytes()
        except (EOFError, OSError):
            data = None
        render.process.join()
        render.answer.close()
        if data is None or render.process.exitcode != 0:
            data = png_bytes(render.figure)  # closes it
        else:
            plt.close(render.figure)
        render.png = base64.b64encode(data).decode("ascii")

    def png(self, index: int) -> str:
        """The base64 PNG of the figure of token ``index``, waiting for it if need be."""
        render = self.renders[index]
        if render.png is None:
            self.collect(render)
        return render.png or ""

    def stop(self) -> None:
        """End every child still running (a report that failed half-way)."""
        for render in self.running():
            render.process.terminate()
            render.process.join()
            render.answer.close()
            plt.close(render.figure)
            render.png = ""


_aside: _Renders | None = None


@contextmanager
def rendering_aside() -> Iterator[None]:
    """A block in which :func:`png_base64` renders figures in forked processes (see the
    module docstring); every child has ended when it ends."""
    global _aside
    if _aside is not None:  # nested: the outer block renders
        yield
        return
    _aside = _Renders(max(1, available_cores()))
    try:
        yield
    finally:
        _aside.stop()
        _aside = None


def png_base64(fig: plt.Figure) -> str:
    """``fig`` as base64 PNG text, or, inside :func:`rendering_aside`, a token that
    :func:`resolve` replaces with it (the figure is closed once rendered)."""
    if _aside is not None and _may_fork():
        return _aside.submit(fig)
    return base64.b64encode(png_bytes(fig)).decode("ascii")


def resolve(text: str) -> str:
    """``text`` with every figure token replaced by its base64 PNG (waiting for it)."""
    if "\0" not in text:
        return text
    if _aside is None:
        raise OutputError("a page holds figures rendered aside; build it inside rendering_aside()")
    renders = _aside
    return _TOKEN_PATTERN.sub(lambda match: renders.png(int(match.group(1))), text)


def _may_fork() -> bool:
    """Whether a child may be forked here: ``fork`` exists and no other thread runs."""
    return "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1


def _render_into(fig: plt.Figure, send: Connection) -> None:
    """The child's work: render ``fig`` and send the PNG."""
    send.send_bytes(png_bytes(fig))
    send.close()
