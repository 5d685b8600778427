"""Build FMI 2.0 co-simulation FMUs from the C sources in ``fmu_sources/`` (FMI 3.0, and
model exchange, with the framework's shells: :func:`build_fmu`'s ``kind``).

A model is a folder holding ``variables.toml`` (the variable table), ``config.h`` (state layout)
and ``model.c`` (physics); ``fmu_sources/framework/`` supplies the FMI plumbing and the
integrator. For one model identifier of the table the builder

1. reads and checks the variable table (:mod:`fmu_greybox.fmi.variables`),
2. generates ``fmu_variables.h`` / ``fmu_variables.c`` (value references, storage indices,
   start values, ranges) and ``modelDescription.xml`` (units, variables, model structure;
   :mod:`fmu_greybox.fmi.description`),
3. compiles everything with gcc into one shared library (``-O2``, IEEE arithmetic: no
   ``-ffast-math``, no floating-point contraction), and
4. zips ``modelDescription.xml``, ``binaries/<platform>/<identifier>.<ext>``,
   ``documentation/`` and ``sources/`` (the C files and headers, generated ones included, and
   ``buildDescription.xml``, :mod:`fmu_greybox.fmi.build_description`: a tool rebuilds the
   FMU for another platform, as the native export does for win64) into
   ``<out_dir>/<identifier>.fmu``, written atomically.

The FMI 2 headers are the ones fmpy ships (``fmpy/c-code``).
"""

from __future__ import annotations

import hashlib
import html
import tempfile
import uuid
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from fmu_greybox.atomic import atomic_write
from fmu_greybox.errors import FmuBuildError
from fmu_greybox.fmi.build_description import BUILD_DESCRIPTION, build_description
from fmu_greybox.fmi.compiler import (
    FRAMEWORK_FLAGS,
    NATIVE_DIR,
    SHELL_CONFIG,
    CBuild,
    compile_library,
    shell_config,
)
from fmu_greybox.fmi.description import (
    LOG_CATEGORIES,
    model_description,
    model_description_fmi3,
    model_exchange_description,
    number_text,
)
from fmu_greybox.fmi.kinds import ACCEPTED, FMI2_CS, MODEL_EXCHANGE, FmuKind
from fmu_greybox.fmi.platforms import (
    BinaryPlatform,
    host_platform,
)
from fmu_greybox.fmi.variables import (
    TYPES,
    ModelEntry,
    Variable,
    VariableTable,
    load_variable_table,
    time_reference,
)
from fmu_greybox.resources import data_path

__all__ = [
    "FMI3_SHELL",
    "FRAMEWORK_DIR",
    "GENERATORS",
    "LOG_CATEGORIES",
    "ME_SHELL_DIR",
    "REFERENCE_MODEL_DIR",
    "SHARED_SOURCES",
    "SOURCES_DIR",
    "build_fmu",
    "build_model_pair",
    "build_reference_fmus",
    "fmi2_headers",
    "load_variable_table",
    "variables_c_sources",
]

SOURCES_DIR = data_path("fmu_sources")
"""Root of the C sources: ``framework/`` and one folder per model."""

FRAMEWORK_DIR = SOURCES_DIR / "framework"
"""The generic FMI 2.0 co-simulation framework."""
FMI3_SHELL = NATIVE_DIR / "fmi3_shell.c"
"""The FMI 3.0 co-simulation face over an FMI 2.0 co-simulation core (the framework's here,
the native grey-box's at export)."""

ME_SHELL_DIR = FRAMEWORK_DIR / "me"
"""The model-exchange functions (FMI 2.0, and the FMI 3.0 shell over them), which the
framework's files include when compiled with ``-DFW_MODEL_EXCHANGE``."""
SHARED_SOURCES = tuple(
    NATIVE_DIR / n for n in ("fmi2_shell.c", "fmi2_shell.h", "sha256.c", "sha256.h")
)
"""What the framework shares with the native grey-box FMU: the FMI 2.0 shell (phases, logging,
serialised states, the unsupported calls) and the SHA-256 its serialised states carry."""

REFERENCE_MODEL_DIR = SOURCES_DIR / "HydraulicActuator"
"""The reference actuator: white-box ``HydraulicActuator`` and ``HydraulicActuatorTruth``."""

#: The modules whose code shapes a built FMU: its GUID, and the cache of the built-in FMUs,
#: change with any of them.
GENERATORS = tuple(
    Path(__file__).with_name(n)
    for n in ("build.py", "build_description.py", "variables.py", "description.py")
)

# The C names of the generated tables (fmu_framework.h)
_TYPE_PREFIX = {"Real": "R", "Integer": "I", "Boolean": "B", "String": "S"}
_C_TYPE = {
    "Real": "FW_REAL",
    "Integer": "FW_INTEGER",
    "Boolean": "FW_BOOLEAN",
    "String": "FW_STRING",
}
_C_CAUSALITY = {"parameter": "FW_PARAMETER", "input": "FW_INPUT", "output": "FW_OUTPUT"}
_C_VARIABILITY = {
    "fixed": "FW_FIXED",
    "tunable": "FW_TUNABLE",
    "discrete": "FW_DISCRETE",
    "continuous": "FW_CONTINUOUS",
}
_GUID_NAMESPACE = uuid.UUID("6f1c2a0e-5b7d-4e21-9a57-1f0c3d8e4b62")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed: same sources give the same archive


def _guid(table: VariableTable, identifier: str, source_files: list[Path]) -> str:
    """Deterministic GUID over identifier, builder, table and sources: changes with any."""
    digest = hashlib.sha256(identifier.encode())
    for file in [*GENERATORS, table.path, *source_files]:
        digest.update(file.name.encode())
        digest.update(file.read_bytes())
    digest.update(" ".join(FRAMEWORK_FLAGS).encode())
    return "{" + str(uuid.uuid5(_GUID_NAMESPACE, digest.hexdigest())) + "}"


def _c_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def variables_c_sources(table: VariableTable, identifier: str, guid: str) -> tuple[str, str]:
    """Generate ``fmu_variables.h`` and ``fmu_variables.c`` for one model of a table.

    The header defines ``MODEL_IDENTIFIER_STRING``, ``MODEL_GUID``, the counts per type,
    ``VR_<name>`` (value reference) and ``R_/I_/B_/S_<name>`` (index in the ``SimData`` array
    of its type) for every variable of the model, and ``FW_SOLVER_STEP``. The source holds the
    tables the framework reads: variable rows by value reference, start values and ranges.

    Parameters
    ----------
    table : VariableTable
        The variable table.
    identifier : str
        Model identifier.
    guid : str
        The model's GUID.

    Returns
    -------
    tuple of str
        Header text and source text.
    """
    variables = table.variables_of(identifier)
    n_vr = time_reference(table, identifier)
    index: dict[str, int] = {}
    counts = dict.fromkeys(TYPES, 0)
    for v in variables:
        index[v.name] = counts[v.type]
        counts[v.type] += 1

    notice = (
        f"/* Generated by fmu_greybox.fmi.build from {table.path.parent.name}/"
        f"{table.path.name} for {identifier}. Do not edit. */\n"
    )
    header = [
        notice,
        "#ifndef FMU_VARIABLES_H",
        "#define FMU_VARIABLES_H",
        "",
        f"#define MODEL_IDENTIFIER_STRING {_c_string(identifier)}",
        f"#define MODEL_GUID {_c_string(guid)}",
        "",
        f"#define N_VALUE_REFERENCES {n_vr}",
        f"#define N_REAL {counts['Real']}",
        f"#define N_INTEGER {counts['Integer']}",
        f"#define N_BOOLEAN {counts['Boolean']}",
        f"#define N_STRING {counts['String']}",
        "",
        "/* Value references */",
    ]
    header += [f"#define VR_{v.name} {v.value_reference}" for v in variables]
    header += ["", "/* Positions in the SimData array of each type */"]
    header += [f"#define {_TYPE_PREFIX[v.type]}_{v.name} {index[v.name]}" for v in variables]
    header += [
        "",
        "/* The framework's internal step (parameter solver_step) */",
        "#define FW_SOLVER_STEP R_solver_step",
        "",
        "/* States the table declares (a model-exchange build checks them against N_STATES) */",
        f"#define FW_DECLARED_STATES {len(table.states)}",
        "",
        "#endif",
        "",
    ]

    rows = []
    by_vr = {v.value_reference: v for v in variables}
    for vr in range(n_vr):
        v = by_vr.get(vr)
        if v is None:
            rows.append(f"    /* {vr}: not in this model */ {{0, FW_ABSENT, 0, 0, -1}},")
        else:
            rows.append(
                f"    /* {vr} */ {{{_c_string(v.name)}, {_C_TYPE[v.type]}, "
                f"{_C_CAUSALITY[v.causality]}, {_C_VARIABILITY[v.variability]}, "
                f"{index[v.name]}}},"
            )

    def array(ctype: str, name: str, vtype: str, value: Any) -> list[str]:
        items = [f"    {value(v)}, /* {v.name} */" for v in variables if v.type == vtype]
        items.append(f"    {value(None)}, /* keeps the array non-empty */")
        return [f"const {ctype} {name}[N_{vtype.upper()} + 1] = {{", *items, "};", ""]

    def real_start(v: Variable | None) -> str:
        return number_text(v.start) if v is not None and v.start is not None else "0.0"

    def bound(attribute: str, default: str) -> Any:
        def text(v: Variable | None) -> str:
            value = getattr(v, attribute) if v is not None else None
            return default if value is None else number_text(value)

        return text

    source = [
        notice,
        "#include <math.h>",
        "",
        '#include "fmu_framework.h"',
        "",
        "const FwVariable fw_variables[N_VALUE_REFERENCES] = {",
        *rows,
        "};",
        "",
    ]
    source += array("double", "fw_real_start", "Real", real_start)
    source += array("double", "fw_real_min", "Real", bound("min", "-HUGE_VAL"))
    source += array("double", "fw_real_max", "Real", bound("max", "HUGE_VAL"))
    source += array(
        "int",
        "fw_integer_start",
        "Integer",
        lambda v: str(v.start) if v is not None and v.start is not None else "0",
    )
    source += array(
        "int", "fw_boolean_start", "Boolean", lambda v: "1" if v is not None and v.start else "0"
    )
    source += array(
        "char *const",
        "fw_string_start",
        "String",
        lambda v: _c_string(str(v.start or "")) if v is not None else '""',
    )
    return "\n".join(header), "\n".join(source)


# ------------------------------------------------------------------------------------------------
# Compiling and packaging
# ------------------------------------------------------------------------------------------------


def fmi2_headers() -> Path:
    """Folder of the FMI 2.0 C headers shipped with fmpy.

    Raises
    ------
    FmuBuildError
        If fmpy is not installed or lacks ``c-code/fmi2Functions.h``.
    """
    try:
        import fmpy
    except ImportError as exc:
        raise FmuBuildError("fmpy is needed for the FMI 2.0 headers: pip install fmpy") from exc
    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise FmuBuildError(f"{folder} lacks fmi2Functions.h; reinstall fmpy.")
    return folder


def _framework_sources(kind: FmuKind) -> list[Path]:
    """The framework's C files for ``kind``: the FMI 2.0 framework, plus the FMI 3.0 shell
    (model exchange: and, included by them, the files of :data:`ME_SHELL_DIR`)."""
    shell = [FMI3_SHELL] if kind.fmi_version == "3.0" else []
    return [*sorted(FRAMEWORK_DIR.glob("*.c")), *shell]


def _model_build(model_dir: Path, entry: ModelEntry, generated: Path, kind: FmuKind) -> CBuild:
    """What one model's shared library is compiled from (``generated``: the generated files)."""
    sources = [
        *_framework_sources(kind),
        *(f for f in SHARED_SOURCES if f.suffix == ".c"),
        *sorted(model_dir.glob("*.c")),
        generated / "fmu_variables.c",
    ]
    defines = [*entry.defines, *(["FW_MODEL_EXCHANGE"] if kind.interface == MODEL_EXCHANGE else [])]
    return CBuild(
        what=entry.identifier,
        sources=tuple(sources),
        flags=FRAMEWORK_FLAGS,
        include_dirs=(generated, model_dir, FRAMEWORK_DIR, NATIVE_DIR, fmi2_headers()),
        defines=tuple(defines),
    )


def _source_member(path: Path) -> str:
    """A C file's member under ``sources/``: flat, but for the framework's sub-folders
    (``me/``, which its files include by that path)."""
    inside = path.relative_to(FRAMEWORK_DIR) if path.is_relative_to(FRAMEWORK_DIR) else path.name
    return f"sources/{Path(inside).as_posix()}"


def _zip_sources(
    archive: zipfile.ZipFile, build: CBuild, files: list[Path], identifier: str
) -> None:
    """Pack ``sources/``: every C file and header of the build but the FMI headers (the
    importing tool has them), and ``buildDescription.xml``: a tool rebuilds the FMU for its
    platform, as the native export does for win64 (:mod:`fmu_greybox.export.native`)."""
    for path in files:
        _zip_write(archive, _source_member(path), path.read_bytes())
    text = build_description(
        identifier,
        [_source_member(p).removeprefix("sources/") for p in build.sources],
        build.flags,
        build.libraries,
        build.defines,
    )
    _zip_write(archive, f"sources/{BUILD_DESCRIPTION}", text)


def _zip_write(archive: zipfile.ZipFile, name: str, data: bytes, executable: bool = False) -> None:
    info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = (0o755 if executable else 0o644) << 16
    archive.writestr(info, data)


def _index_html(entry: ModelEntry, readme: str) -> bytes:
    """``documentation/index.html`` (the FMI entry point): the README as preformatted text."""
    title = html.escape(entry.identifier)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{title}'
        f"</title></head>\n<body><h1>{title}</h1><p>{html.escape(entry.description)}</p>"
        f"\n<pre>{html.escape(readme)}</pre></body></html>\n"
    ).encode()


def build_fmu(
    model_dir: Path,
    out_dir: Path,
    identifier: str | None = None,
    kind: FmuKind = FMI2_CS,
    target: BinaryPlatform | None = None,
) -> Path:
    """Build one co-simulation FMU from a model folder.

    Parameters
    ----------
    model_dir : Path
        Folder with ``variables.toml``, ``config.h`` and ``model.c`` (and optionally
        ``README.md``, packed as ``documentation/README.md`` and ``index.html``).
    out_dir : Path
        Where ``<identifier>.fmu`` is written (created if missing).
    identifier : str or None
        Which model of the table to build; the first one if ``None``.
    kind : FmuKind
        :data:`~fmu_greybox.fmi.kinds.FMI2_CS` (the framework) or
        :data:`~fmu_greybox.fmi.kinds.FMI3_CS` (the framework with its FMI 3.0 shell, the
        same numbers); :data:`~fmu_greybox.fmi.kinds.FMI2_ME` or
        :data:`~fmu_greybox.fmi.kinds.FMI3_ME` for model exchange (the framework's
        model-exchange functions, ``framework/me``: the model's states and derivatives, no
        integrator; the table must declare the states, ``[[state]]``).
    target : BinaryPlatform or None
        The platform of its binary: this machine's when ``None``, or
        :data:`~fmu_greybox.fmi.platforms.WIN64` (FMI 2.0 only: cross-compiled with mingw-w64
        into ``binaries/win64/<identifier>.dll``).

    Returns
    -------
    Path
        The FMU, replaced atomically if it existed.

    Raises
    ------
    FmuBuildError
        If the table is invalid, the platform unsupported, gcc missing or compilation fails
        (the message holds the compiler output).
    """
    model_dir = Path(model_dir).resolve()
    out_dir = Path(out_dir)
    table = load_variable_table(model_dir / "variables.toml")
    entry = table.model(identifier)
    if kind not in ACCEPTED:
        raise FmuBuildError(f"the builder makes no {kind.label} FMUs")
    me = kind.interface == MODEL_EXCHANGE
    if me and not table.states:
        raise FmuBuildError(
            f"{table.path}: a model-exchange build declares the model's continuous states; "
            "list them as [[state]] rows in the order of config.h (see "
            "HydraulicActuator/variables.toml)"
        )
    target = target or host_platform()
    if target.windows and kind != FMI2_CS:
        raise FmuBuildError(f"the {target.folder} build makes FMI 2.0 FMUs, not {kind.label}")
    extension = target.extension
    folder = target.folder if target.windows else kind.binary_folder
    c_files = sorted(
        [
            *FRAMEWORK_DIR.glob("*.h"),
            *_framework_sources(kind),
            *(ME_SHELL_DIR.glob("*.c") if me else ()),
            *SHARED_SOURCES,
            *model_dir.glob("*.[ch]"),
        ]
    )
    guid = _guid(table, entry.identifier, c_files)
    header, source = variables_c_sources(table, entry.identifier, guid)
    describe = model_description_fmi3 if kind.fmi_version == "3.0" else model_description
    description = describe(table, entry.identifier, guid)
    if me:
        description = model_exchange_description(description, table, entry.identifier, kind)

    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f"fmu-build-{entry.identifier}-") as tmp:
        generated = Path(tmp)
        (generated / "fmu_variables.h").write_text(header, encoding="utf-8")
        (generated / "fmu_variables.c").write_text(source, encoding="utf-8")
        time = time_reference(table, entry.identifier)
        (generated / SHELL_CONFIG).write_text(shell_config(entry.identifier, time), "ascii")
        library = generated / f"{entry.identifier}{extension}"
        build = _model_build(model_dir, entry, generated, kind)
        compile_library(build, library, target)
        packed = [*c_files, *(generated / n for n in ("fmu_variables.c", "fmu_variables.h"))]
        packed += [generated / SHELL_CONFIG] if kind.fmi_version == "3.0" else []
        target = out_dir / f"{entry.identifier}.fmu"
        with atomic_write(target, "wb") as stream, zipfile.ZipFile(stream, "w") as archive:
            _zip_write(archive, "modelDescription.xml", description)
            _zip_write(
                archive, f"binaries/{folder}/{library.name}", library.read_bytes(), executable=True
            )
            _zip_sources(archive, build, packed, entry.identifier)
            readme = model_dir / "README.md"
            if readme.is_file():
                text = readme.read_text(encoding="utf-8")
                _zip_write(archive, "documentation/README.md", text.encode())
                _zip_write(archive, "documentation/index.html", _index_html(entry, text))
    return target


def build_reference_fmus(
    out_dir: Path, kind: FmuKind = FMI2_CS, target: BinaryPlatform | None = None
) -> dict[str, Path]:
    """Build the reference actuator FMUs (white-box and truth), in parallel.

    Parameters
    ----------
    out_dir : Path
        Where the FMUs are written.
    kind : FmuKind
        Their kind (see :func:`build_fmu`).
    target : BinaryPlatform or None
        Their binaries' platform (see :func:`build_fmu`).

    Returns
    -------
    dict of str to Path
        ``{"HydraulicActuator": ..., "HydraulicActuatorTruth": ...}``.

    Raises
    ------
    FmuBuildError
        As :func:`build_fmu`.
    """
    return build_model_pair(REFERENCE_MODEL_DIR, out_dir, kind, target)


def build_model_pair(
    model_dir: Path, out_dir: Path, kind: FmuKind = FMI2_CS, target: BinaryPlatform | None = None
) -> dict[str, Path]:
    """Build every model a folder's table declares (white-box and truth), in parallel.

    Parameters
    ----------
    model_dir : Path
        Model folder (see :func:`build_fmu`); its ``variables.toml`` lists the white-box first
        and then the truth model, whose truth-only variables carry ``models``.
    out_dir : Path
        Where the FMUs are written.
    kind : FmuKind
        Their kind (see :func:`build_fmu`).
    target : BinaryPlatform or None
        Their binaries' platform (see :func:`build_fmu`).

    Returns
    -------
    dict of str to Path
        Model identifier -> ``.fmu`` path, in the table's order.

    Raises
    ------
    FmuBuildError
        As :func:`build_fmu`.
    """
    table = load_variable_table(Path(model_dir) / "variables.toml")
    identifiers = [m.identifier for m in table.models]
    with ThreadPoolExecutor(max_workers=len(identifiers)) as pool:
        paths = pool.map(lambda i: build_fmu(model_dir, out_dir, i, kind, target), identifiers)
        return dict(zip(identifiers, paths, strict=True))
