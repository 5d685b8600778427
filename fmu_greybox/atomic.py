"""Write files and directories so that a reader never sees half of them.

A crashed or failed run must leave the previous result in place. Both helpers build the new
content under a hidden temporary name beside the target (same folder, so the same file system)
and move it over the target only when the ``with`` block ends without an exception; on an
exception the temporary is removed and the target is untouched.
"""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any

_MODES = ("w", "wb")


def _sibling(path: Path, tag: str) -> Path:
    """Return an unused hidden name beside ``path``, e.g. ``.result.csv.3f9a0c1b.tmp``."""
    return path.with_name(f".{path.name}.{secrets.token_hex(4)}.{tag}")


def _create_exclusive(path: Path) -> tuple[Path, int]:
    """Create a fresh temporary file beside ``path`` (honouring the umask) and open it."""
    while True:
        tmp = _sibling(path, "tmp")
        try:
            return tmp, os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue


def _make_fresh_dir(path: Path) -> Path:
    """Create a fresh temporary directory beside ``path`` (honouring the umask)."""
    while True:
        tmp = _sibling(path, "tmp")
        try:
            tmp.mkdir(mode=0o777)
        except FileExistsError:
            continue
        return tmp


@contextmanager
def atomic_write(
    path: str | os.PathLike[str],
    mode: str = "w",
    *,
    encoding: str = "utf-8",
    newline: str | None = None,
) -> Iterator[IO[Any]]:
    """Open a file for writing that replaces ``path`` only if the block succeeds.

    Parameters
    ----------
    path : str or path-like
        The file to write. Its folder must exist.
    mode : {"w", "wb"}
        Text or binary.
    encoding : str
        Text encoding (text mode only).
    newline : str or None
        As for :func:`open` (text mode only); pass ``""`` for the :mod:`csv` module.

    Yields
    ------
    file object
        Open on a temporary file in the same folder as ``path``.

    Raises
    ------
    ValueError
        If ``mode`` is not ``"w"`` or ``"wb"``.

    Examples
    --------
    >>> with atomic_write("model.json") as f:  # doctest: +SKIP
    ...     f.write("{}")
    """
    if mode not in _MODES:
        raise ValueError(f"atomic_write mode must be one of {_MODES}, not {mode!r}")
    target = Path(path)
    tmp, fd = _create_exclusive(target)
    try:
        text = {"encoding": encoding, "newline": newline} if mode == "w" else {}
        with os.fdopen(fd, mode, **text) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        with suppress(FileNotFoundError):
            tmp.unlink()
        raise


@contextmanager
def atomic_dir(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Build a directory under a temporary name and swap it in for ``path`` on success.

    The old directory (if any) is moved aside, the new one renamed into place and only then the
    old one deleted; if the final rename fails the old directory is put back.

    Parameters
    ----------
    path : str or path-like
        The directory to (re)create. Its parent must exist.

    Yields
    ------
    pathlib.Path
        The empty temporary directory to fill.

    Raises
    ------
    NotADirectoryError
        If ``path`` exists and is not a directory.
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise NotADirectoryError(f"{target} exists and is not a directory; remove it first")
    tmp = _make_fresh_dir(target)
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _swap_in(tmp, target)


def _swap_in(new: Path, target: Path) -> None:
    """Move directory ``new`` to ``target``, replacing (and then deleting) an old ``target``."""
    if not target.exists():
        os.replace(new, target)
        return
    old = _sibling(target, "old")
    os.replace(target, old)
    try:
        os.replace(new, target)
    except BaseException:
        os.replace(old, target)
        shutil.rmtree(new, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)
