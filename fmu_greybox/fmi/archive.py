"""Open an FMU archive safely and read what it declares.

An FMU is a zip file from a supplier, a tool or a colleague: treat it as untrusted. Before any
byte is written to disk the archive is checked for paths escaping the extraction folder,
absolute paths, links, encryption, compression methods FMI does not allow, absurd declared sizes
(per member, in total, and as a compression ratio) and a missing ``modelDescription.xml``; then
the model must be of a kind fmu-greybox runs (:mod:`fmu_greybox.fmi.kinds`) with a binary for
this platform, or a win64 binary that runs here through Wine (:mod:`fmu_greybox.fmi.wine`).
"""

from __future__ import annotations

import math
import shutil
import stat
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from fmpy import platform as fmi2
from fmpy import read_model_description

from fmu_greybox.errors import FmuArchiveError
from fmu_greybox.fmi.kinds import FmuKind, binary_path, fmu_kind, interface
from fmu_greybox.fmi.wine import add_wine_remoting, runs_through_wine
from fmu_greybox.suggest import did_you_mean

#: Largest total uncompressed size accepted [bytes].
MAX_UNCOMPRESSED_BYTES = 2 * 1024**3
#: Largest uncompressed size accepted for one member [bytes].
MAX_MEMBER_BYTES = 1024**3
#: Largest number of members accepted.
MAX_MEMBERS = 100_000
#: Largest compression ratio accepted for a member (zip bombs have ratios of 1000s).
MAX_COMPRESSION_RATIO = 1000.0
#: Compression methods the FMI standard allows in an FMU: stored and deflate.
FMI_COMPRESSION = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}
#: FMI 3.0 types read as the FMI 2.0 type they exchange the same values as.
FMI2_TYPE = {"Float64": "Real", "Int32": "Integer"}


@dataclass(frozen=True)
class FmuVariable:
    """One scalar variable declared in ``modelDescription.xml``.

    Attributes
    ----------
    name, causality, variability, unit, description : str
        As declared (``unit`` is ``""`` when none is declared).
    value_reference : int
        The FMI value reference.
    type : str
        ``"Real"``, ``"Integer"``, ``"Boolean"``, ``"String"`` or ``"Enumeration"``; FMI 3.0
        scalar ``Float64`` and ``Int32`` read as ``"Real"`` and ``"Integer"`` (the other FMI 3.0
        types keep their names, an array variable reads e.g. ``"Float64 array"``: no scalar
        role, binding or term takes it).
    start : float or None
        Start value when declared and numeric.
    minimum, maximum : float or None
        Declared range (on the variable or its declared type), when numeric.
    """

    name: str
    value_reference: int
    type: str
    causality: str
    variability: str
    unit: str
    description: str
    start: float | None
    minimum: float | None = None
    maximum: float | None = None


@dataclass
class FmuArchive:
    """An FMU extracted into a private temporary folder.

    Use :func:`open_fmu` to make one; call :meth:`close` (or use it as a context manager) to
    remove the folder.

    Attributes
    ----------
    path : Path
        The ``.fmu`` file.
    unzip_dir : Path
        Folder it was extracted to.
    model_description : fmpy.model_description.ModelDescription
        The parsed model description.
    kind : FmuKind
        Its FMI version and interface.
    variables : dict[str, FmuVariable]
        Every scalar variable by name.
    """

    path: Path
    unzip_dir: Path
    model_description: object
    kind: FmuKind
    variables: dict[str, FmuVariable] = field(default_factory=dict)

    @property
    def model_identifier(self) -> str:
        """The model identifier of the interface run (name of the shared library)."""
        return interface(self.model_description, self.kind).modelIdentifier

    @property
    def model_name(self) -> str:
        """The model name from the model description."""
        return self.model_description.modelName

    @property
    def guid(self) -> str:
        """The FMU's GUID."""
        return self.model_description.guid

    def names(self, causality: str) -> list[str]:
        """Names of the variables with the given causality, in declaration order.

        Parameters
        ----------
        causality : str
            ``"input"``, ``"output"``, ``"parameter"``, ``"local"``, ...
        """
        return [v.name for v in self.variables.values() if v.causality == causality]

    @property
    def inputs(self) -> list[str]:
        """Input names."""
        return self.names("input")

    @property
    def outputs(self) -> list[str]:
        """Output names."""
        return self.names("output")

    @property
    def parameters(self) -> list[str]:
        """Parameter names."""
        return self.names("parameter")

    def variable(self, name: str) -> FmuVariable:
        """Look up a variable, with a helpful error when the name is unknown.

        Raises
        ------
        FmuArchiveError
            If the FMU declares no variable of that name; the message lists close names.
        """
        try:
            return self.variables[name]
        except KeyError:
            raise FmuArchiveError(
                f"{self.path.name} declares no variable {name!r}"
                + did_you_mean(name, self.variables)
            ) from None

    def close(self) -> None:
        """Remove the extraction folder (idempotent)."""
        shutil.rmtree(self.unzip_dir, ignore_errors=True)

    def __enter__(self) -> FmuArchive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def real_outputs(archive: FmuArchive) -> list[str]:
    """Names of the FMU's Real outputs, in declaration order."""
    return [
        v.name for v in archive.variables.values() if v.causality == "output" and v.type == "Real"
    ]


def open_fmu(path: str | Path) -> FmuArchive:
    """Check, extract and describe a white-box FMU of an accepted kind
    (:data:`fmu_greybox.fmi.kinds.ACCEPTED`).

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` file.

    Returns
    -------
    FmuArchive
        The extracted FMU; the caller owns it and must close it.

    Raises
    ------
    FmuArchiveError
        If the file is missing, not a zip archive, hostile (a path escaping the folder, a link,
        an absurd declared size or compression ratio), encrypted or compressed in a way FMI does
        not allow, damaged, of a kind not accepted, lacks a binary for this platform (an FMI
        2.0 co-simulation FMU with a win64 binary only runs through Wine, when Wine is
        installed: :mod:`fmu_greybox.fmi.wine`), or is a pythonfmu FMU without the slave module
        its binary loads.
    """
    path = Path(path)
    if path.is_dir():
        raise FmuArchiveError(
            f"{path}: a folder, not an FMU file; give the .fmu archive (an extracted FMU can "
            "be zipped back into one)"
        )
    if not path.is_file():
        raise FmuArchiveError(f"{path}: no such FMU file; check the path")
    if not zipfile.is_zipfile(path):
        raise FmuArchiveError(f"{path}: not a zip archive, so not an FMU; re-export it")
    unzip_dir = Path(tempfile.mkdtemp(prefix=f"fmu_greybox_{path.stem}_"))
    try:
        _extract_checked(path, unzip_dir)
        description = _read_description(path, unzip_dir)
        kind = fmu_kind(path, description)
        identifier = interface(description, kind).modelIdentifier
        if runs_through_wine(unzip_dir, identifier, kind, fmi2):
            kind = add_wine_remoting(path, unzip_dir)
        _check_binary(path, unzip_dir, description, kind)
        _check_python_runtime(path, unzip_dir, description)
    except BaseException:
        shutil.rmtree(unzip_dir, ignore_errors=True)
        raise
    archive = FmuArchive(path=path, unzip_dir=unzip_dir, model_description=description, kind=kind)
    archive.variables = _variables(description)
    return archive


def _extract_checked(path: Path, unzip_dir: Path) -> None:
    """Extract ``path`` into ``unzip_dir`` after checking every member."""
    try:
        with zipfile.ZipFile(path) as zf:
            members = zf.infolist()
            _check_members(path, members)
            names = {m.filename for m in members}
            if "modelDescription.xml" not in names:
                raise FmuArchiveError(
                    f"{path}: no modelDescription.xml at the archive root; not an FMU. Export the "
                    "model as an FMU, or zip an extracted FMU from inside its folder"
                )
            for member in members:
                _extract_member(path, zf, member, unzip_dir)
    except zipfile.BadZipFile as exc:
        raise FmuArchiveError(f"{path}: corrupt zip archive ({exc}); re-export the FMU") from exc


def _extract_member(path: Path, zf: zipfile.ZipFile, member: zipfile.ZipInfo, into: Path) -> None:
    """Extract one checked member; a damaged stream or a full disk names the member.

    The bytes written never exceed the member's declared size (checked against the limits
    beforehand): :mod:`zipfile` stops at it and then checks the CRC.
    """
    try:
        zf.extract(member, into)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
        if isinstance(exc, OSError) and exc.errno is not None:
            mend = f"check the free space and permissions of {into.parent}"
        else:
            mend = "the archive is damaged; re-export the FMU"
        raise FmuArchiveError(
            f"{path}: member {member.filename!r} cannot be extracted ({exc}); {mend}"
        ) from exc


def _check_members(path: Path, members: list[zipfile.ZipInfo]) -> None:
    """Refuse members that would escape the folder, links, encrypted or oddly compressed
    members and absurd declared sizes, naming the member and the limit."""
    if len(members) > MAX_MEMBERS:
        raise FmuArchiveError(
            f"{path}: {len(members)} members is more than an FMU needs (limit {MAX_MEMBERS}); "
            "refused as corrupt or hostile"
        )
    total = 0
    seen: set[str] = set()
    for member in members:
        name = member.filename
        if name in seen:
            raise FmuArchiveError(
                f"{path}: member {name!r} appears twice; tools disagree on which copy counts, "
                "so the archive was refused. Re-export the FMU"
            )
        seen.add(name)
        pure = PurePosixPath(name)
        if not pure.parts:
            raise FmuArchiveError(
                f"{path}: a member has the empty name {name!r}; the archive is malformed or "
                "hostile and was not extracted. Re-export the FMU"
            )
        if "\\" in name or pure.is_absolute() or ":" in name or ".." in pure.parts:
            raise FmuArchiveError(
                f"{path}: member {name!r} would be written outside the extraction folder; "
                "the archive is malformed or hostile and was not extracted"
            )
        mode = member.external_attr >> 16
        if stat.S_ISLNK(mode):
            raise FmuArchiveError(
                f"{path}: member {name!r} is a symbolic link; refused, as an FMU holds plain "
                "files only. Re-export the FMU"
            )
        if member.flag_bits & 0x1:
            raise FmuArchiveError(
                f"{path}: member {name!r} is encrypted; an FMU must be readable without a "
                "password. Re-export it without encryption"
            )
        if member.compress_type not in FMI_COMPRESSION:
            raise FmuArchiveError(
                f"{path}: member {name!r} uses zip compression method {member.compress_type}; "
                f"the FMI standard allows only {' and '.join(FMI_COMPRESSION.values())}. "
                "Re-export the FMU"
            )
        if member.file_size > MAX_MEMBER_BYTES:
            raise FmuArchiveError(
                f"{path}: member {name!r} declares {_gib(member.file_size)} uncompressed, over "
                f"the {_gib(MAX_MEMBER_BYTES)} limit per member; refused before extraction as "
                "corrupt or hostile"
            )
        ratio = member.file_size / max(member.compress_size, 1)
        if ratio > MAX_COMPRESSION_RATIO:
            raise FmuArchiveError(
                f"{path}: member {name!r} expands {ratio:.0f} times; refused as a likely zip "
                f"bomb (the limit is {MAX_COMPRESSION_RATIO:.0f} times)"
            )
        total += member.file_size
    if total > MAX_UNCOMPRESSED_BYTES:
        raise FmuArchiveError(
            f"{path}: uncompressed size {_gib(total)} (all members) exceeds the "
            f"{_gib(MAX_UNCOMPRESSED_BYTES)} limit; refused before extraction"
        )


def _gib(size: int) -> str:
    """A byte count in GiB for a message, e.g. ``"2.0 GiB"``."""
    return f"{size / 1024**3:.1f} GiB"


def _read_description(path: Path, unzip_dir: Path) -> object:
    """Parse the model description."""
    try:
        description = read_model_description(str(unzip_dir / "modelDescription.xml"))
    except Exception as exc:  # fmpy raises bare Exceptions for schema problems
        raise FmuArchiveError(
            f"{path}: unreadable modelDescription.xml: {exc}. It must be valid FMI XML; "
            "re-export the FMU"
        ) from exc
    return description


def _check_binary(path: Path, unzip_dir: Path, description: object, kind: FmuKind) -> None:
    """Require the shared library for this platform."""
    library = binary_path(unzip_dir, kind, interface(description, kind).modelIdentifier)
    if not library.is_file():
        binaries = unzip_dir / "binaries"
        found = sorted(p.name for p in binaries.iterdir()) if binaries.is_dir() else []
        raise FmuArchiveError(
            f"{path}: no binary for this platform ({kind.binary_folder}, {kind.label}); the "
            f"FMU has {found or 'no binaries'}. Rebuild or re-export it for "
            f"{kind.binary_folder}"
        )


def _check_python_runtime(path: Path, unzip_dir: Path, description: object) -> None:
    """Require, in a pythonfmu FMU (its generation tool or its ``resources/pythonfmu``), the
    member ``resources/slavemodule.txt`` naming a module under ``resources/``: pythonfmu's
    binary reads it at instantiation and crashes the host without it."""
    resources = unzip_dir / "resources"
    tool = (getattr(description, "generationTool", None) or "").lower()
    if "pythonfmu" not in tool and not (resources / "pythonfmu").is_dir():
        return
    member = resources / "slavemodule.txt"
    if not member.is_file():
        raise FmuArchiveError(
            f"{path}: a pythonfmu FMU without its member 'resources/slavemodule.txt' (the name "
            "of the Python module its binary loads); refused, as pythonfmu crashes without it. "
            "Re-export the FMU"
        )
    module = member.read_text(encoding="utf-8", errors="replace").strip()
    if not module or not (resources / f"{module}.py").is_file():
        raise FmuArchiveError(
            f"{path}: member 'resources/slavemodule.txt' names the module {module!r}, but the "
            f"FMU holds no 'resources/{module}.py'; the FMU is incomplete. Re-export it"
        )


def _variables(description: object) -> dict[str, FmuVariable]:
    """Collect the scalar variables with their units."""
    result: dict[str, FmuVariable] = {}
    for v in description.modelVariables:
        declared = v.declaredType
        unit = v.unit or (declared.unit if declared is not None else None) or ""
        result[v.name] = FmuVariable(
            name=v.name,
            value_reference=int(v.valueReference),
            type=f"{v.type} array" if v.dimensions else FMI2_TYPE.get(v.type, v.type),
            causality=v.causality,
            variability=v.variability,
            unit=unit,
            description=v.description or "",
            start=_number(v.start),
            minimum=_number(_declared(v, declared, "min")),
            maximum=_number(_declared(v, declared, "max")),
        )
    return result


def _declared(variable: object, declared: object | None, name: str) -> object | None:
    """An attribute of a variable, or of its declared type when the variable has none."""
    value = getattr(variable, name, None)
    if value is None and declared is not None:
        value = getattr(declared, name, None)
    return value


def _number(text: object | None) -> float | None:
    """A declared attribute as a finite float, or ``None``."""
    try:
        value = float(text) if text is not None else None
    except (TypeError, ValueError):
        return None
    return value if value is not None and math.isfinite(value) else None
