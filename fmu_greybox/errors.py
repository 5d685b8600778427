"""Every exception fmu-greybox raises on purpose.

All derive from :class:`FmuGreyboxError`, so a caller (the CLI in particular) can tell a user
error with a clear message from a bug. Each message says what was wrong and how to mend it.
"""

from __future__ import annotations


class FmuGreyboxError(Exception):
    """Base class of all errors raised on purpose by fmu-greybox."""


class RecordingError(FmuGreyboxError):
    """A recording file cannot be used as it is.

    Parameters
    ----------
    message : str
        What is wrong and how to mend it.
    path : str or None
        The recording file.
    column : str or None
        The offending column (signal), if any.
    row : int or None
        The offending row (0-based data row), if any.
    """

    def __init__(
        self,
        message: str,
        path: str | None = None,
        column: str | None = None,
        row: int | None = None,
    ) -> None:
        self.path = path
        self.column = column
        self.row = row
        where = []
        if path is not None:
            where.append(str(path))
        if column is not None:
            where.append(f"column {column!r}")
        if row is not None:
            where.append(f"row {row}")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class ConfigError(FmuGreyboxError):
    """A project configuration field is missing or invalid.

    Parameters
    ----------
    message : str
        What is wrong and how to mend it.
    field : str or None
        Dotted path of the field, e.g. ``"stages[1].target"``.
    path : str or None
        The configuration file.
    """

    def __init__(self, message: str, field: str | None = None, path: str | None = None) -> None:
        self.field = field
        self.path = path
        where = ": ".join(p for p in (str(path) if path else None, field) if p)
        super().__init__(f"{where}: {message}" if where else message)


class UnitMismatchError(ConfigError):
    """A recorded signal's unit differs from the unit the FMU declares for it."""


class FmuBuildError(FmuGreyboxError):
    """Compiling or packaging an FMU from C sources failed."""


class FmuArchiveError(FmuGreyboxError):
    """An FMU archive is corrupt, hostile, of the wrong kind or lacks this platform's binary."""


class FmuError(FmuGreyboxError):
    """An FMI call returned an error status.

    Parameters
    ----------
    call : str
        The FMI function, e.g. ``"fmi2DoStep"``.
    status : str
        The status it returned, e.g. ``"fmi2Error"``.
    time : float or None
        Simulation time [s] at which the call was made.
    detail : str
        Any message the FMU logged.
    """

    def __init__(self, call: str, status: str, time: float | None = None, detail: str = "") -> None:
        self.call = call
        self.status = status
        self.time = time
        at = f" at t = {time:.6g} s" if time is not None else ""
        extra = f": {detail}" if detail else ""
        super().__init__(f"{call} returned {status}{at}{extra}")


class ModelFormatError(FmuGreyboxError):
    """A saved model directory is corrupt, tampered with, or of an unknown format version."""


class DiagnosisFormatError(FmuGreyboxError):
    """A saved ``diagnosis.json`` holds what no diagnosis writes (damaged or edited), so it cannot
    be reused as it is."""


class NumericalError(FmuGreyboxError):
    """A numerical procedure failed (e.g. a Cholesky factorisation beyond the jitter limit)."""


class ExportError(FmuGreyboxError):
    """A trained model cannot be exported as an FMU as it is (the message says why, what to do)."""


class BenchError(FmuGreyboxError):
    """A bench (SSP system structure) cannot be built or co-simulated as asked."""


class ClusterError(FmuGreyboxError):
    """A Dask cluster cannot be reached or started as asked (the message says which address)."""


class OutputError(FmuGreyboxError):
    """An output cannot be written where asked: its folder cannot be made, or another run is
    writing it."""
