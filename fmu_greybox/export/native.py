"""The native grey-box FMU: a C binary compiled at export, no Python in the bench's process.

Layout of the FMU::

    modelDescription.xml
    binaries/<platform>/<identifier>.so   compiled here from sources/ (gcc, buildDescription.xml);
                                          FMI 2.0: linux64, FMI 3.0: x86_64-linux
    binaries/win64/<identifier>.dll       when the white-box has a win64 binary, or C sources
                                          that mingw-w64 cross-compiles into one: the same
                                          sources cross-compiled with mingw-w64 (FMI 3.0:
                                          x86_64-windows)
    documentation/binaries.txt            each binary above and below, and how it was made
    sources/                              the C sources, the FMI headers, greybox_config.h,
                                          fmi_shell_config.h and buildDescription.xml: a bench
                                          rebuilds from them
    resources/greybox.dat                 the trained numbers (native_data.py), checked against
                                          the SHA-256 compiled into the binary
    resources/whitebox/                   the white-box FMU, unpacked: the binary dlopens it;
                                          its binaries/win64/<id>.dll cross-compiled here
                                          from its sources/ when it had none
    resources/greybox_model/              the model folder (provenance, the SSP benches)

The C sources live in ``fmu_greybox/native/``: ``chain_core.c`` (the chain step, the very file
the Python package's extension compiles), ``whitebox.c`` (the white-box and its named terms,
as :class:`~fmu_greybox.model.whitebox.NamedModel`), ``terms.c`` (every term kind),
``rules.c`` (what a step must satisfy and the words of its refusals, the very file the
extension compiles for the Python FMU), ``greybox_fmu.c`` (the FMI 2.0 core) on
``fmi2_shell.c`` (the FMI 2.0 shell the reference FMUs share), ``greybox_data.c`` and
``sha256.c``; an FMI 3.0 export adds ``fmi3_shell.c``, the FMI 3.0 face the reference FMUs use
too, over the same FMI 2.0 functions. Only ``greybox_config.h`` (the FMU's identifier and
GUID, the data file's hash and the C kind table of the term kinds,
:mod:`fmu_greybox.model.native_terms`) and ``fmi_shell_config.h`` are generated.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
import warnings
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from lxml import etree

from fmu_greybox import __version__
from fmu_greybox.atomic import atomic_write
from fmu_greybox.errors import ExportError, FmuBuildError
from fmu_greybox.export.description3 import fmi3_description
from fmu_greybox.export.slave import MODEL_FOLDER, STEP_RTOL
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.build import LOG_CATEGORIES, fmi2_headers
from fmu_greybox.fmi.build_description import BUILD_DESCRIPTION, sources_build
from fmu_greybox.fmi.build_description import build_description as description_text
from fmu_greybox.fmi.builtin import cache_dir
from fmu_greybox.fmi.compiler import (
    NATIVE_DIR,
    SHELL_CONFIG,
    CBuild,
    compile_cached,
    compile_library,
    library_name,
    native_flags,
    shell_config,
)
from fmu_greybox.fmi.kinds import FMI2_CS, FMI3_CS, FmuKind, require_native
from fmu_greybox.fmi.platforms import WIN64, BinaryPlatform, compiler_of, host_platform
from fmu_greybox.model.native_data import data_file_bytes
from fmu_greybox.model.native_terms import kind_code, kind_defines
from fmu_greybox.model.native_whitebox import whitebox_sections
from fmu_greybox.model.store import file_sha256
from fmu_greybox.model.whitebox import part_layouts
from fmu_greybox.side_by_side import run_side_by_side

if TYPE_CHECKING:
    from fmu_greybox.export.fmu import ExportPlan

#: The package's C sources of the native FMU (both FMI versions).
SOURCES = (
    "greybox_fmu.c",
    "fmi2_shell.c",
    "fmi2_shell.h",
    "whitebox.c",
    "whitebox.h",
    "dynlib.h",
    "terms.c",
    "terms.h",
    "chain_core.c",
    "chain_core.h",
    "rules.c",
    "rules.h",
    "greybox_data.c",
    "greybox_data.h",
    "sha256.c",
    "sha256.h",
)
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: What an FMI 3.0 export adds: the FMI 3.0 face and its headers.
FMI3_SOURCES = ("fmi3_shell.c",)
FMI3_HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
#: The FMI versions an export is made for, and their kinds.
FMI_KINDS = {"2": FMI2_CS, "3": FMI3_CS}
LIBRARIES = ("m", "dl")
DATA_FILE = "greybox.dat"
CONFIG_HEADER = "greybox_config.h"
WHITEBOX_FOLDER = "whitebox"
#: The FMU's note of where each of its binaries comes from.
BINARIES_NOTE = "documentation/binaries.txt"


def package_native(plan: ExportPlan, archive: FmuArchive, out: Path) -> None:
    """Write the native FMU of an export plan (see the module docstring), atomically.

    Parameters
    ----------
    plan : ExportPlan
        Its ``settings["fmi_version"]`` (``"2"`` or ``"3"``) says which FMI the FMU offers.
    archive : FmuArchive
        The white-box FMU, open.
    out : Path

    Raises
    ------
    ExportError
        The white-box is not FMI 2.0 co-simulation (``native/whitebox.c`` loads that kind
        only), a term has no native implementation, compiling fails, or the FMU fails
        validation.
    """
    from fmu_greybox.export.fmu import check_valid

    require_native(
        archive.kind,
        archive.path,
        "the native grey-box export",
        "export with --runtime python (it steps the white-box with fmpy), or give an FMI 2.0 "
        "co-simulation white-box",
        ExportError,
    )
    kind = FMI_KINDS[plan.settings["fmi_version"]]
    identifier = plan.settings["model_identifier"]
    with tempfile.TemporaryDirectory(prefix="fmu_greybox_native_") as tmp:
        root = Path(tmp) / "fmu"
        resources = root / "resources"
        plan.copy_model(resources / MODEL_FOLDER)
        whitebox = resources / WHITEBOX_FOLDER
        shutil.copytree(archive.unzip_dir, whitebox)
        host = host_platform()
        win64 = not host.windows and whitebox_win64(archive, whitebox, host)
        data = data_file_bytes(data_sections(plan, archive, whitebox))
        (resources / DATA_FILE).write_bytes(data)
        description = model_description(plan, kind)
        sources = root / "sources"
        write_sources(sources, plan, kind, file_sha256(resources / DATA_FILE))
        builds = [lambda: compile_sources(sources, root / binary_path(identifier, kind, host))]
        if win64:  # the two compilers side by side, each in its own process
            builds.append(
                lambda: add_win64_binary(sources, root / binary_path(identifier, kind, WIN64))
            )
        run_side_by_side(builds)
        cross_compiled = win64 and not has_win64_binary(archive)
        write_binaries_note(root / BINARIES_NOTE, archive.path.name, kind, cross_compiled)
        (root / "modelDescription.xml").write_bytes(description)
        staged = Path(tmp) / "staged.fmu"
        _zip_folder(root, staged)
        check_valid(staged)
        with atomic_write(out, "wb") as f, open(staged, "rb") as source:
            shutil.copyfileobj(source, f)


def binary_path(identifier: str, kind: FmuKind, target: BinaryPlatform) -> str:
    """The binary's member, e.g. ``binaries/x86_64-linux/<identifier>.so`` for FMI 3.0."""
    return f"binaries/{kind.folder_of(target)}/{library_name(identifier, target)}"


# ---------------------------------------------------------------------------- the data file
def data_sections(plan: ExportPlan, archive: FmuArchive, whitebox: Path) -> dict[str, Any]:
    """Everything the binary reads from ``greybox.dat`` (``greybox_fmu.c``, ``whitebox.c``);
    ``whitebox`` is the white-box's copy in the resources, whose binaries' hashes it holds
    (a win64 binary cross-compiled at export included).

    The chain's plan and parameters are stored as :class:`ChainPlan` lays them out, untouched:
    whatever per-stage numbers a plan carries reach the compiled step without new plumbing.
    """
    model, iface = plan.model, plan.interface
    chain_plan, params = model.chain.plan().arrays
    outputs = iface.wb_outputs
    layouts = part_layouts(
        outputs, model.terms, model.output_stages(outputs), model.config.parameters, model.substeps
    )
    for term in model.terms:
        kind_code(term)  # refuse a kind without native implementation before anything else
    stages = [len(model.chain.stages), iface.exo_index.size]
    return {
        **whitebox_sections(
            archive, iface.input_names, layouts, model.dt, len(outputs), stages, whitebox
        ),
        "plan": chain_plan,
        "params": params,
        "stage_output": iface.stage_output.astype(np.int64),
        "exo_index": iface.exo_index.astype(np.int64),
        "input_names": "\n".join(iface.input_names),
        "input_start": np.array([p.start for p in iface.reals[: iface.n_inputs]], dtype=float),
        "input_low": plan.domain.low,
        "input_high": plan.domain.high,
        "settings": np.array([model.dt, plan.settings["ood_threshold"], STEP_RTOL]),
    }


# ---------------------------------------------------------------------------- sources, binary
def write_sources(folder: Path, plan: ExportPlan, kind: FmuKind, data_sha256: str) -> None:
    """Fill ``sources/``: the C sources, the FMI headers, the generated configuration headers
    and the build description."""
    identifier = plan.settings["model_identifier"]
    folder.mkdir(parents=True)
    for name in source_names(kind):
        shutil.copyfile(NATIVE_DIR / name, folder / name)
    for name in (*FMI2_HEADERS, *(FMI3_HEADERS if kind == FMI3_CS else ())):
        shutil.copyfile(fmi2_headers() / name, folder / name)
    (folder / CONFIG_HEADER).write_text(
        "/* Generated by fmu-greybox at export: this FMU's identity, the SHA-256 of its data\n"
        " * file (resources/" + DATA_FILE + ") and the kind table of the term kinds\n"
        " * (native_terms.py). */\n"
        "#ifndef GREYBOX_CONFIG_H\n#define GREYBOX_CONFIG_H\n"
        f'#define GREYBOX_IDENTIFIER "{identifier}"\n'
        f'#define GREYBOX_GUID "{{{plan.guid}}}"\n'
        f'#define GREYBOX_DATA_FILE "{DATA_FILE}"\n'
        f'#define GREYBOX_DATA_SHA256 "{data_sha256}"\n'
        f"{kind_defines()}#endif\n",
        encoding="ascii",
    )
    time_vr = len(plan.interface.ports)
    (folder / SHELL_CONFIG).write_text(shell_config(identifier, time_vr), encoding="ascii")
    (folder / BUILD_DESCRIPTION).write_bytes(build_description(identifier, kind))


def source_names(kind: FmuKind) -> tuple[str, ...]:
    """The files of ``native/`` an FMU of ``kind`` is built from (headers included)."""
    return (*SOURCES, *(FMI3_SOURCES if kind == FMI3_CS else ()))


def build_description(identifier: str, kind: FmuKind) -> bytes:
    """``sources/buildDescription.xml`` (the FMI build description, read by fmpy as well)."""
    files = [name for name in source_names(kind) if name.endswith(".c")]
    flags = [*native_flags(), *host_platform().flags]
    return description_text(identifier, files, flags, LIBRARIES)


def compile_sources(sources: Path, library: Path, target: BinaryPlatform | None = None) -> None:
    """Compile a ``sources/`` folder into the shared library, as its build description says.

    Parameters
    ----------
    sources : Path
    library : Path
    target : BinaryPlatform or None
        This machine when ``None`` (:func:`fmu_greybox.fmi.compiler.compile_library` adds the
        target's options and leaves out what a Windows DLL does without).

    Raises
    ------
    ExportError
        The compiler is missing or fails (its output is quoted).
    """
    try:
        build = sources_build(sources, library.stem, "the native grey-box")
        compile_library(build, library, target)
    except FmuBuildError as exc:
        raise ExportError(
            f"{exc}\n(install the compiler, or export with --runtime python)"
        ) from exc


def has_win64_binary(archive: FmuArchive) -> bool:
    """Whether the white-box FMU carries a win64 binary (``binaries/win64/<identifier>.dll``)."""
    folder = archive.unzip_dir / "binaries" / WIN64.folder
    return (folder / f"{archive.model_identifier}.dll").is_file()


def whitebox_win64(archive: FmuArchive, whitebox: Path, host: BinaryPlatform) -> bool:
    """Whether the white-box's copy ``whitebox`` has a win64 binary, cross-compiled here from
    its C sources (``sources/``, as its build description says) when it has none.

    Without mingw-w64 warn (naming its package); when the sources do not compile for win64,
    warn naming the white-box FMU and quoting the compiler's first errors: either way the
    grey-box FMU is for this machine only, and the export goes on.
    """
    if has_win64_binary(archive):
        return True
    if not (whitebox / "sources").is_dir():
        return False
    identifier = archive.model_identifier
    library = whitebox / "binaries" / WIN64.folder / library_name(identifier, WIN64)
    try:
        compiler_of(WIN64)
    except FmuBuildError as exc:
        warnings.warn(
            f"{archive.path}: the white-box has C sources but no win64 binary, and the grey-box "
            f"FMU gets none (it is for {host.folder} only): {exc}",
            stacklevel=3,
        )
        return False
    try:
        what = f"{archive.path.name} for win64"
        listed = listed_sources(archive)
        build = sources_build(whitebox / "sources", identifier, what, listed, (fmi2_headers(),))
        cross_compiled_once(build, library)
    except FmuBuildError as exc:
        library.unlink(missing_ok=True)
        warnings.warn(
            f"{archive.path}: the white-box has C sources but no win64 binary, and its sources "
            f"were not cross-compiled for win64:\n{first_errors(str(exc), whitebox)}\n"
            f"The grey-box FMU is for {host.folder} only; mend the white-box's sources/ or "
            "give it a win64 binary (binaries/win64), and export again",
            stacklevel=3,
        )
        return False
    return True


def cross_compiled_once(build: CBuild, library: Path) -> None:
    """Cross-compile ``build`` for win64 into ``library``, once per distinct build: a copy is
    kept in the cache (``FMU_GREYBOX_CACHE``), keyed by the content of its sources and headers
    and by its options, so that exporting many models of one white-box compiles it once.

    Raises
    ------
    FmuBuildError
        As :func:`fmu_greybox.fmi.compiler.compile_library`.
    """
    key = hashlib.sha256(repr((build.flags, build.defines, build.libraries)).encode())
    compiler = Path(compiler_of(WIN64)).resolve()  # an upgraded compiler builds again
    key.update(f"{compiler} {compiler.stat().st_size} {compiler.stat().st_mtime_ns}".encode())
    headers = (h for folder in build.include_dirs for h in sorted(folder.rglob("*.h")))
    for path in (*build.sources, *headers):
        key.update(path.name.encode() + b"\0" + path.read_bytes())
    cached = cache_dir().parent / "win64-whitebox" / key.hexdigest()[:16] / library.name
    if not cached.is_file():
        compile_cached(build, cached, target=WIN64)
    library.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(cached, library)


def listed_sources(archive: FmuArchive) -> list[str]:
    """The source files an FMI 2.0 model description lists (``<SourceFiles>``, as fmpy reads
    them), for an FMU without a build description."""
    return [
        name
        for configuration in archive.model_description.buildConfigurations
        for file_set in configuration.sourceFileSets
        for name in file_set.sourceFiles
    ]


def first_errors(message: str, folder: Path, count: int = 3) -> str:
    """The first ``count`` error lines of a compiler failure's message, their files named
    from ``folder`` (its first lines when none says error: a missing compiler, an unreadable
    build description)."""
    for prefix in (folder.resolve(), folder):
        message = message.replace(f"{prefix}{os.sep}", "")
    lines = message.splitlines()
    errors = [line for line in lines[2:] if "error" in line.lower()]  # after the command
    return "\n".join((errors or lines)[:count])


def add_win64_binary(sources: Path, library: Path) -> None:
    """Cross-compile ``sources/`` for win64 with mingw-w64 into ``library``; without mingw-w64
    warn (naming its package) and leave the FMU for this machine only.

    Raises
    ------
    ExportError
        mingw-w64 fails on the sources (its output is quoted).
    """
    try:
        compiler_of(WIN64)
    except FmuBuildError as exc:
        warnings.warn(
            f"the white-box has a win64 binary but the grey-box gets none: {exc}", stacklevel=2
        )
        return
    compile_sources(sources, library, WIN64)


def write_binaries_note(
    note: Path, whitebox_name: str, kind: FmuKind, cross_compiled: bool
) -> None:
    """Write ``documentation/binaries.txt``: each binary of the FMU (``note``'s FMU folder) and
    how it was made; ``cross_compiled``: the white-box's win64 DLL was compiled at export."""
    root = note.parent.parent
    windows = kind.folder_of(WIN64)
    lines = []
    for path in sorted(root.glob("binaries/*/*")):
        compiler = WIN64.compiler if path.parent.name == windows else "this machine's C compiler"
        lines.append(f"{path.relative_to(root)}: compiled at export from sources/ with {compiler}")
    for path in sorted((root / "resources" / WHITEBOX_FOLDER).glob("binaries/*/*")):
        how = f"as in the white-box FMU {whitebox_name}"
        if cross_compiled and path.parent.name == WIN64.folder:
            how = f"cross-compiled at export from the white-box's sources/ with {WIN64.compiler}"
        lines.append(f"{path.relative_to(root)}: {how}")
    note.parent.mkdir(parents=True, exist_ok=True)
    note.write_text("\n".join(lines) + "\n", encoding="utf-8")


# ---------------------------------------------------------------------------- description
def model_description(plan: ExportPlan, kind: FmuKind = FMI2_CS) -> bytes:
    """The FMU's ``modelDescription.xml``: the variables, completed as the Python FMU's is;
    for FMI 3.0 derived from that (:func:`~fmu_greybox.export.description3.fmi3_description`)."""
    settings = plan.settings
    root = etree.Element(
        "fmiModelDescription",
        fmiVersion="2.0",
        modelName=settings["model_identifier"],
        guid="{" + plan.guid + "}",
        description=settings["description"],
        author=settings["author"],
        version=settings["version"],
        generationDateAndTime=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        numberOfEventIndicators="0",
    )
    etree.SubElement(root, "CoSimulation", modelIdentifier=settings["model_identifier"])
    categories = etree.SubElement(root, "LogCategories")
    for name, text in LOG_CATEGORIES:
        etree.SubElement(categories, "Category", name=name, description=text)
    etree.SubElement(root, "DefaultExperiment", stepSize=repr(plan.model.dt))
    variables = etree.SubElement(root, "ModelVariables")
    for reference, port in enumerate(plan.interface.ports):
        variable = etree.SubElement(
            variables,
            "ScalarVariable",
            name=port.name,
            valueReference=str(reference),
            causality=port.causality,
            variability=port.variability,
        )
        if port.initial:
            variable.set("initial", port.initial)
        value = etree.SubElement(variable, port.type)
        if port.type == "Boolean" and port.start is not None:
            value.set("start", str(bool(port.start)).lower())
    plan.fix(root, f"fmu-greybox {__version__} (native)", needs_execution_tool=False)
    if kind == FMI3_CS:
        root = fmi3_description(root)
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _zip_folder(folder: Path, archive: Path) -> None:
    """Zip a staged FMU (binaries executable)."""
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                info = zipfile.ZipInfo(path.relative_to(folder).as_posix())
                info.compress_type = zipfile.ZIP_DEFLATED
                executable = "binaries" in path.relative_to(folder).parts
                info.external_attr = (0o755 if executable else 0o644) << 16
                z.writestr(info, path.read_bytes())
