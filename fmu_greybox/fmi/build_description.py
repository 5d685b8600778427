"""An FMU's ``sources/buildDescription.xml``: written for every FMU the package builds, read to
compile an FMU's C sources for another platform.

The build description is FMI 3.0's (FMI 2.0 FMUs may carry it too, as the Modelica
Association's Reference FMUs do): the source files, their compiler options and preprocessor
definitions, the include folders and the libraries of each model identifier. The reference
FMUs (:mod:`fmu_greybox.fmi.build`) and the native grey-box FMU
(:mod:`fmu_greybox.export.native`) write one; the native export reads the grey-box's own to
compile it, and a white-box's to cross-compile the white-box for win64. An FMI 2.0 FMU without
one lists its source files in its model description (``<SourceFiles>``), with no options.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from lxml import etree

from fmu_greybox.errors import FmuBuildError
from fmu_greybox.fmi.compiler import CBuild

BUILD_DESCRIPTION = "buildDescription.xml"
#: The compiler options a read build description may give (it may come with a supplier's FMU:
#: no plugins, wrappers, spec files, other tool folders or options passed to the assembler,
#: linker or preprocessor, which would run other programs or read other files at export).
SAFE_OPTION = re.compile(
    r"-(O[0-3sgz]?|std=[\w+]+|g[0-3]?|ansi|pedantic|W(?![alp],)[\w=+-]+|f(?!plugin)[\w=+.-]+"
    r"|m[\w=+.-]+|D\w+(=[\w.+-]*)?|U\w+)"
)
#: What a reader of the description does with the files.
HOW_TO_BUILD = (
    "a shared library: compile the source files with these options and -shared (-fPIC but on "
    "Windows), link the libraries"
)


def build_description(
    identifier: str,
    files: Sequence[str],
    flags: Sequence[str],
    libraries: Sequence[str],
    defines: Sequence[str] = (),
) -> bytes:
    """The text of ``sources/buildDescription.xml`` for one model identifier.

    Parameters
    ----------
    identifier : str
        The model identifier (the shared library's name).
    files : sequence of str
        The C files to compile, relative to ``sources/``.
    flags : sequence of str
        Their compiler options.
    libraries : sequence of str
        Linked as ``-l<name>``.
    defines : sequence of str
        Preprocessor definitions, ``NAME`` or ``NAME=VALUE``.
    """
    root = etree.Element("fmiBuildDescription", fmiVersion="3.0")
    configuration = etree.SubElement(
        root, "BuildConfiguration", modelIdentifier=identifier, description=HOW_TO_BUILD
    )
    standards = [f.removeprefix("-std=").upper() for f in flags if f.startswith("-std=")]
    file_set = etree.SubElement(
        configuration,
        "SourceFileSet",
        language=(standards or ["C99"])[-1],
        compiler="gcc",
        compilerOptions=" ".join(flags),
    )
    for name in files:  # FMI's schema: the files, the definitions, the include folders
        etree.SubElement(file_set, "SourceFile", name=name)
    for define in defines:
        name, _, value = define.partition("=")
        definition = etree.SubElement(file_set, "PreprocessorDefinition", name=name)
        if value:
            definition.set("value", value)
    etree.SubElement(file_set, "IncludeDirectory", name=".")
    for library in libraries:
        etree.SubElement(configuration, "Library", name=library)
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def sources_build(
    sources: Path,
    identifier: str,
    what: str,
    listed: Sequence[str] = (),
    headers: Sequence[Path] = (),
) -> CBuild:
    """What an FMU's ``sources/`` folder compiles into, as its build description says.

    Parameters
    ----------
    sources : Path
        The unpacked ``sources/`` folder.
    identifier : str
        The model identifier whose configuration is read (the first one when none names it).
    what : str
        Its name in the compiler's messages.
    listed : sequence of str
        The source files the model description lists (FMI 2.0 ``<SourceFiles>``), compiled
        with no options when the folder has no build description.
    headers : sequence of Path
        Folders searched for includes after the description's (the FMI headers, which an FMU
        need not carry).

    Raises
    ------
    FmuBuildError
        Neither a build description nor listed files; a build description that cannot be
        read, has no source file set, or several with different options; a compiler option
        outside :data:`SAFE_OPTION`; a file or folder outside ``sources``.
    """
    path = sources / BUILD_DESCRIPTION
    if not path.is_file():
        if not listed:
            raise FmuBuildError(
                f"{sources} has no {BUILD_DESCRIPTION} and the model description lists no "
                "<SourceFiles>: add either to the FMU to have it compiled"
            )
        where = "the model description's <SourceFiles>"
        files = tuple(_inside(sources, name, where) for name in listed)
        return CBuild(what, files, (), (sources, *headers))
    configuration = _configuration(path, identifier)
    file_sets = configuration.findall("SourceFileSet")
    if not file_sets:
        raise FmuBuildError(f"{path} has no SourceFileSet for {identifier}: list its C files")
    options = {_options(file_set) for file_set in file_sets}
    if len(options) != 1:
        raise FmuBuildError(
            f"{path}: {len(options)} different sets of options for {identifier}; the export "
            "compiles with one: give all its source files the same options"
        )
    flags, defines = options.pop()
    _check_options(path, flags)
    files = [f.get("name") for s in file_sets for f in s.findall("SourceFile")]
    folders = [d.get("name") for s in file_sets for d in s.findall("IncludeDirectory")]
    return CBuild(
        what=what,
        sources=tuple(_inside(sources, name, BUILD_DESCRIPTION) for name in files),
        flags=flags,
        include_dirs=(*(_inside(sources, name, BUILD_DESCRIPTION) for name in folders), *headers),
        defines=defines,
        libraries=tuple(x.get("name") for x in configuration.findall("Library")),
    )


def _check_options(path: Path, flags: Sequence[str]) -> None:
    """Refuse compiler options outside :data:`SAFE_OPTION`."""
    unsafe = [flag for flag in flags if not SAFE_OPTION.fullmatch(flag)]
    if unsafe:
        raise FmuBuildError(
            f"{path}: compiler options {' '.join(unsafe)} are not compiled from an FMU's build "
            "description (optimisation, standard, warning, code-generation and -D/-U options "
            "are); remove them from compilerOptions"
        )


def _inside(sources: Path, name: str | None, where: str) -> Path:
    """A file or folder ``where`` names, which must lie in ``sources``."""
    named = (sources / (name or "")).resolve()
    if not name or not named.is_relative_to(sources.resolve()):
        raise FmuBuildError(
            f"{sources}: {where} names {name!r}, not a path inside sources/; name files and "
            "folders relative to sources/, without '..'"
        )
    return named


def _configuration(path: Path, identifier: str) -> etree._Element:
    """The ``BuildConfiguration`` of ``identifier`` (or the first) in a build description."""
    try:
        root = etree.parse(str(path)).getroot()
    except etree.XMLSyntaxError as exc:
        raise FmuBuildError(f"{path} is not readable XML ({exc}): mend or remove it") from exc
    configurations = root.findall("BuildConfiguration")
    named = [c for c in configurations if c.get("modelIdentifier") == identifier]
    if not configurations:
        raise FmuBuildError(f"{path} has no BuildConfiguration: add one for {identifier}")
    return (named or configurations)[0]


def _options(file_set: etree._Element) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The compiler options and the preprocessor definitions of a source file set."""
    flags = tuple((file_set.get("compilerOptions") or "").split())
    defines = []
    for definition in file_set.findall("PreprocessorDefinition"):
        value = definition.get("value") or ""
        defines.append(definition.get("name") + (f"={value}" if value else ""))
    return flags, tuple(defines)
