"""Write files and directories so that a reader never sees half of them.

A crashed or failed run must leave the previous result in place. Both helpers build the new
content under a hidden temporary name beside the target (same folder, so the same file system)
and move it over the target only when the ``with`` block ends without an exception; on an
exception the temporary is removed and the target is untouched.

A run killed outright cannot remove its temporary. Each writer therefore holds an advisory lock
(``flock``) on its temporary while it writes; the next write of the same target removes the
temporaries nobody holds (the kernel drops a killed process's locks). :func:`output_lock` uses
the same mechanism to keep two runs from writing one output at once, and
:func:`prepare_output` makes an output's folder before anything is written.
"""

from __future__ import annotations

import fcntl
import logging
import os
import secrets
import shutil
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any

from fmu_greybox.errors import OutputError

_MODES = ("w", "wb")
#: A temporary younger than this is left alone even when unlocked: its writer may be between
#: creating it and locking it.
STALE_AFTER_SECONDS = 2.0
_log = logging.getLogger(__name__)


def prepare_output(path: str | os.PathLike[str], what: str) -> Path:
    """Make the folder an output goes into (with its parents), before anything is written.

    Parameters
    ----------
    path : str or path-like
        The output file or folder.
    what : str
        What it is, for the message (e.g. ``"--ssp"``).

    Returns
    -------
    Path

    Raises
    ------
    OutputError
        If the folder cannot be made (a file in the way, no permission); the message names it.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(
            f"{what} {target}: cannot make its folder {target.parent} "
            f"({error.strerror or error}); choose another path"
        ) from error
    return target


@contextmanager
def output_lock(path: str | os.PathLike[str], what: str) -> Iterator[None]:
    """Hold ``path`` for this run: a second run writing it meanwhile is refused.

    The lock is the hidden file ``.NAME.lock`` beside ``path``, locked with ``flock`` and
    naming its holder; it is removed at the end. A lock file left by a killed run is not
    locked by anyone and is taken over (with a note in the log).

    Raises
    ------
    OutputError
        If another run holds ``path``; the message names it and the holder.
    """
    target = prepare_output(path, what)
    lock = target.with_name(f".{target.name}.lock")
    fd = _locked_file(lock, target, what)
    try:
        previous = os.read(fd, 200).decode("utf-8", errors="replace").strip()
        if previous:
            _log.warning(
                "%s: took over the lock of a run that ended without releasing it (%s)",
                target,
                previous,
            )
        os.ftruncate(fd, 0)
        holder = f"process {os.getpid()} on {socket.gethostname()} since {time.strftime('%X')}"
        os.pwrite(fd, holder.encode(), 0)
        yield
    finally:
        with suppress(FileNotFoundError):
            lock.unlink()
        os.close(fd)


def _locked_file(lock: Path, target: Path, what: str) -> int:
    """Open and ``flock`` the lock file, making sure it is still the file at ``lock``."""
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 200).decode("utf-8", errors="replace").strip() or "another run"
            os.close(fd)
            raise OutputError(
                f"{what} {target} is being written by {holder}; wait for that run to finish, "
                "or write elsewhere"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False  # its holder removed it between our open and our lock
        if same:
            return fd
        os.close(fd)


def _hold(path: Path) -> int:
    """Open ``path`` (a file or a folder) and lock it for as long as the descriptor is open."""
    fd = os.open(path, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


def remove_stale_temporaries(path: Path) -> list[Path]:
    """Remove the temporaries of ``path`` left by killed runs.

    A temporary ``.NAME.<hex>.tmp`` is stale when no process holds its lock and it is older
    than :data:`STALE_AFTER_SECONDS`.

    Returns
    -------
    list of Path
        The temporaries removed.
    """
    removed = []
    for tmp in path.parent.glob(f".{path.name}.*.tmp"):
        try:
            fd = _hold(tmp)
        except OSError:
            continue  # held by a running writer, or gone
        try:
            if time.time() - os.fstat(fd).st_mtime < STALE_AFTER_SECONDS:
                continue
            if tmp.is_dir():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)
            removed.append(tmp)
        finally:
            os.close(fd)
    if removed:
        _log.warning("%s: removed %d temporaries left by killed runs", path, len(removed))
    return removed


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
    remove_stale_temporaries(target)
    tmp, fd = _create_exclusive(target)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
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
    remove_stale_temporaries(target)
    tmp = _make_fresh_dir(target)
    fd = _hold(tmp)
    try:
        try:
            yield tmp
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        _swap_in(tmp, target)
    finally:
        os.close(fd)


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
