"""A white-box with Windows binaries only, run on Linux through fmpy's remoting over Wine.

fmpy ships, for FMI 2.0, a Linux client library (``fmpy/remoting/linux64/client_tcp.so``) and
a Windows server (``fmpy/remoting/win64/server_tcp.exe``). :func:`add_wine_remoting` copies
both into an extracted FMU (fmpy's ``add_remoting``): the client takes the place of the missing
``binaries/linux64/<identifier>.so``, so everything that steps the FMU with fmpy
(:mod:`fmu_greybox.fmi.instance`) runs unchanged; on ``fmi2Instantiate`` the client starts
``wine64 server_tcp.exe <identifier>.dll`` and forwards every FMI call to it over TCP.

What the remoting cannot do, and so what the FMU's kind (:data:`FMI2_WINE`) refuses:

- the C paths load a Linux binary in their own process (:attr:`FmuKind.native` is false):
  the native grey-box export refuses such a white-box, and the diagnosis's simulations run
  in the C runner cross-compiled for win64 instead, a Windows program under Wine
  (:mod:`fmu_greybox.model.native_run`, ``native/simulate_main.c``), not through the
  remoting;
- fmpy's server listens on one fixed TCP port (8080) and the client keeps its connection in
  a process-wide variable: one instance runs at a time in a process, and one on the machine
  (:class:`RemoteSlot`: a second in the same process is refused, one in another process, such
  as a diagnosis worker, waits its turn);
- every FMI call is a round trip to the server (about 7 ms a step of the reference actuator,
  against 24 us for its linux64 build: ``docs/bench.md``), too slow for the diagnosis's
  hundreds of simulations, which is why they take the C runner's road above: one Wine
  process per thread of a Python process, one job per simulation, no limit on how many run
  at once.

And what it gets wrong under Wine: the server is to stop when the client dies, which it learns
by opening the client's lock file with exclusive access every 0.5 s; the client holds that file
with a POSIX lock, which Wine does not see, so the server stops 0.5 s after it started
(it prints "Lock file ... open. Exiting."). :func:`keep_server_alive` turns the lock file into
a folder as soon as the client names it (before it starts the server): the server cannot open a
folder as a file, so it runs until it is stopped, and :func:`remove_lock_folder` removes the
folder after. The client's ``fmi2FreeInstance`` stops the server and then waits for every child
of the process (a diagnosis's worker processes too: forever); so an instance is closed by
:func:`stop_server` instead, which stops and waits for the server's process only.

Debian's ``wine64`` installs ``/usr/lib/wine/wine64``, off the ``PATH`` the client searches:
:func:`add_wine_remoting` puts that folder on this process's ``PATH`` (and quiets Wine's
diagnostics with ``WINEDEBUG=-all`` unless set) and prepares the Wine prefix once, as the
client waits only 10 s for the server to answer.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import BinaryIO

from fmu_greybox.errors import FmuArchiveError
from fmu_greybox.fmi.kinds import CO_SIMULATION, FMI2_CS, FmuKind

#: The Windows platform whose binary the remoting runs.
REMOTE_PLATFORM = "win64"
#: An FMI 2.0 co-simulation FMU whose win64 binary runs through fmpy's remoting over Wine.
FMI2_WINE = FmuKind("2.0", CO_SIMULATION, remote=REMOTE_PLATFORM)
#: The Debian package that installs ``wine64``.
WINE_PACKAGE = "wine64"
#: Where Debian's ``wine64`` package puts the program.
DEBIAN_WINE_FOLDER = Path("/usr/lib/wine")
#: Longest wait for a new Wine prefix to be made [s].
PREFIX_TIMEOUT = 300.0

#: The client's message naming its lock file (``client_tcp.cpp``).
LOCK_FILE_MESSAGE = re.compile(r"Lock file: (/.+)\.$")

#: The client's message naming the server's process (its process group).
SERVER_MESSAGE = re.compile(r"Server process id is (\d+)\.")
#: The file whose lock gives the machine's one place for a remoted instance.
SLOT_FILE = Path(tempfile.gettempdir()) / "fmu_greybox_wine_remoting.lock"
#: Longest wait for the place, while another process holds it [s].
SLOT_TIMEOUT = 1800.0

_PREFIX_READY = threading.Lock()
_REMOTE_SLOT = threading.Lock()


def runs_through_wine(unzip_dir: Path, identifier: str, kind: FmuKind, host_folder: str) -> bool:
    """Whether an extracted FMU lacks a binary for this machine but has a win64 DLL that fmpy's
    remoting can run here (FMI 2.0 co-simulation, on linux64).

    Parameters
    ----------
    unzip_dir : Path
        The extracted FMU.
    identifier : str
        Its co-simulation model identifier.
    kind : FmuKind
        Its kind, as the model description declares it.
    host_folder : str
        This machine's FMI 2.0 binary folder, e.g. ``"linux64"``.
    """
    binaries = unzip_dir / "binaries"
    return (
        kind == FMI2_CS
        and host_folder == "linux64"
        and not (binaries / host_folder).is_dir()
        and (binaries / REMOTE_PLATFORM / f"{identifier}.dll").is_file()
    )


def wine_program() -> str:
    """The ``wine64`` program, on the ``PATH`` or where Debian installs it.

    Raises
    ------
    FmuArchiveError
        If Wine is not installed; the message names the package.
    """
    found = shutil.which("wine64") or shutil.which("wine64", path=str(DEBIAN_WINE_FOLDER))
    if found is None:
        raise FmuArchiveError(
            "Wine is not installed, so a white-box with Windows binaries only cannot run on "
            f"this Linux machine: apt-get install {WINE_PACKAGE} (Debian), or give the FMU a "
            "linux64 binary"
        )
    return found


def add_wine_remoting(path: Path, unzip_dir: Path) -> FmuKind:
    """Make an extracted win64-only FMI 2.0 co-simulation FMU steppable here through fmpy's
    remoting over Wine (see the module docstring).

    Parameters
    ----------
    path : Path
        The ``.fmu`` file (for messages).
    unzip_dir : Path
        The extracted FMU; receives fmpy's client and server binaries.

    Returns
    -------
    FmuKind
        :data:`FMI2_WINE`.

    Raises
    ------
    FmuArchiveError
        If Wine is not installed, its prefix cannot be made, or fmpy refuses the remoting.
    """
    program = wine_program()
    folder = str(Path(program).parent)
    if shutil.which("wine64") is None:
        os.environ["PATH"] = folder + os.pathsep + os.environ.get("PATH", "")
    os.environ.setdefault("WINEDEBUG", "-all")
    _prepare_prefix(path, program)
    from fmpy.util import add_remoting

    try:
        add_remoting(str(unzip_dir), host_platform="linux64", remote_platform=REMOTE_PLATFORM)
    except Exception as exc:  # fmpy raises bare Exceptions
        raise FmuArchiveError(
            f"{path}: fmpy's remoting cannot run its win64 binary here ({exc}); give the FMU "
            "a linux64 binary"
        ) from exc
    return FMI2_WINE


def _prepare_prefix(path: Path, program: str) -> None:
    """Make the Wine prefix (``$WINEPREFIX`` or ``~/.wine``) if it is missing, once per
    process, without the Mono and Gecko installers (an FMU needs neither)."""
    prefix = Path(os.environ.get("WINEPREFIX", Path.home() / ".wine"))
    with _PREFIX_READY:
        if (prefix / "system.reg").is_file():
            return
        env = {**os.environ, "WINEDLLOVERRIDES": "mscoree,mshtml="}
        try:
            subprocess.run(
                [program, "wineboot", "--init"],
                env=env,
                capture_output=True,
                timeout=PREFIX_TIMEOUT,
                check=True,
            )
        except (OSError, subprocess.SubprocessError) as exc:
            raise FmuArchiveError(
                f"{path}: Wine could not make its prefix {prefix} ({exc}); run "
                f"'{program} wineboot --init' to see why"
            ) from exc


class RemoteSlot:
    """The one place for a running remoted instance: in this process (a thread lock, not
    waited for) and on this machine (a lock on :data:`SLOT_FILE`, waited for up to
    :data:`SLOT_TIMEOUT`). Call :meth:`release` when the instance is stopped.

    Parameters
    ----------
    path : Path
        The ``.fmu`` file (for messages).

    Raises
    ------
    FmuArchiveError
        If another remoted instance runs in this process, or another process holds the place
        longer than :data:`SLOT_TIMEOUT`.
    """

    def __init__(self, path: Path) -> None:
        if not _REMOTE_SLOT.acquire(blocking=False):
            raise FmuArchiveError(
                f"{path}: another instance of a win64 white-box runs through Wine in this "
                "process, and fmpy's remoting serves one at a time (its server listens on one "
                "fixed TCP port); free it first, or give the FMU a linux64 binary"
            )
        try:
            self._file = _locked(path)
        except BaseException:
            _REMOTE_SLOT.release()
            raise

    def release(self) -> None:
        """Free the place (idempotent)."""
        if self._file is not None:
            self._file.close()  # closing drops the flock
            self._file = None
            _REMOTE_SLOT.release()


def _locked(path: Path) -> BinaryIO:
    """:data:`SLOT_FILE`, open and exclusively locked (waiting while another process holds it)."""
    stream = open(SLOT_FILE, "a+b")  # held until RemoteSlot.release
    waited = 0.0
    while True:
        try:
            fcntl.flock(stream, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return stream
        except BlockingIOError:
            if waited >= SLOT_TIMEOUT:
                stream.close()
                raise FmuArchiveError(
                    f"{path}: another process has run a win64 white-box through Wine for "
                    f"{SLOT_TIMEOUT:.0f} s (it holds {SLOT_FILE}); fmpy's remoting serves one "
                    "at a time on a machine. Stop that process, or give the FMU a linux64 binary"
                ) from None
            time.sleep(0.1)
            waited += 0.1


def server_pid(message: str) -> int | None:
    """The server's process id in a client log message, or ``None``."""
    named = SERVER_MESSAGE.match(message)
    return int(named.group(1)) if named else None


def stop_server(pid: int | None) -> None:
    """Stop a remoting server's process group and wait for that process alone (never raises)."""
    if pid is None:
        return
    try:
        os.killpg(pid, signal.SIGKILL)
    except OSError:
        pass
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


def keep_server_alive(message: str) -> Path | None:
    """Replace the lock file a client log message names by a folder (see the module docstring).

    Parameters
    ----------
    message : str
        A message the remoting client logged.

    Returns
    -------
    Path or None
        The folder, or ``None`` for another message.
    """
    named = LOCK_FILE_MESSAGE.match(message)
    if named is None:
        return None
    lock = Path(named.group(1))
    lock.unlink(missing_ok=True)  # the client holds it open: its lock stays on the open file
    lock.mkdir()
    return lock


def remove_lock_folder(lock: Path | None) -> None:
    """Remove a folder :func:`keep_server_alive` made (never raises)."""
    if lock is not None:
        shutil.rmtree(lock, ignore_errors=True)
