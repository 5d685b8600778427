"""Export a trained grey-box as an FMI 2.0 (or 3.0) co-simulation FMU (the ``export`` command).

Two runtimes, the same variables and the same numbers:

``native`` (the default)
    A C binary compiled at export (:mod:`fmu_greybox.export.native`): the chain step shared with
    the Python package, the white-box FMU loaded from the resources with dlopen, the trained
    numbers in a data file. No Python in the bench's process.
``python``
    A pythonfmu FMU: pythonfmu's binary, the entry module (:mod:`fmu_greybox.export.runtime`,
    bound to :class:`~fmu_greybox.export.slave.GreyBoxSlave`), a copy of the model folder and
    the export settings in its resources. It runs in the Python of a Python-hosted master.

Both carry a copy of the model folder (``resources/greybox_model/``, for provenance and for
the SSP benches). :func:`fix_model_description` completes either model description (units and
their definitions, descriptions, ``initial``, ModelStructure, capability flags, the model's
hashes in the vendor annotations) so that ``fmpy.validation.validate_fmu`` finds no problem, and
the export fails if it does.
"""

from __future__ import annotations

import getpass
import json
import shutil
import sys
import tempfile
import uuid
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lxml import etree

from fmu_greybox import __version__
from fmu_greybox.atomic import atomic_write
from fmu_greybox.errors import ExportError
from fmu_greybox.export.slave import (
    MODEL_FOLDER,
    RUNTIME_FILE,
    GreyBoxInterface,
    GreyBoxSlave,
    greybox_interface,
)
from fmu_greybox.fmi.archive import FmuArchive, open_fmu
from fmu_greybox.fmi.integrator import recorded_integrator
from fmu_greybox.fmi.kinds import interface as kind_interface
from fmu_greybox.model.chain_step import DEFAULT_OOD_THRESHOLD
from fmu_greybox.model.domain import InputDomain
from fmu_greybox.model.store import (
    MANIFEST,
    GreyBoxModel,
    file_sha256,
    load_model,
    read_manifest,
)

#: Python the exported FMUs need in the simulation process (that of fmu-greybox itself).
REQUIRES_PYTHON = (3, 11)
#: Module name of the grey-box entry in the FMU's resources.
GREYBOX_ENTRY = "greybox_fmu"
#: The runtimes an FMU can be exported for; the first is the default.
RUNTIMES = ("native", "python")
#: The FMI versions an FMU can be exported for; the first is the default.
FMI_VERSIONS = ("2", "3")


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_greybox` wrote.

    Attributes
    ----------
    path : Path
        The FMU.
    interface : GreyBoxInterface
        Its variables.
    model_sha256 : str
        SHA-256 of the model's ``model.json`` (which holds the hash of every model file).
    guid : str
        The FMU's GUID.
    """

    path: Path
    interface: GreyBoxInterface
    model_sha256: str
    guid: str


@dataclass(frozen=True)
class ExportPlan:
    """What both runtimes' FMUs are made from, derived once from the model folder.

    Attributes
    ----------
    model : GreyBoxModel
    model_dir : Path
        The model folder (copied into the FMU's resources).
    manifest : dict
        Its ``model.json``.
    model_sha256 : str
        SHA-256 of ``model.json``.
    interface : GreyBoxInterface
        The FMU's variables.
    domain : InputDomain
        The inputs it accepts (:mod:`fmu_greybox.model.domain`).
    guid : str
    settings : dict
        Identity and text of the FMU (``model_identifier``, ``description``, ``author``,
        ``version``, ``ood_threshold``, ...).
    annotation : lxml element
        The model's provenance for the vendor annotations.
    units : lxml element or None
        The white-box's ``UnitDefinitions``.
    stateful : bool
        The white-box can get, set and serialise its state (so can the grey-box).
    instantiate_once : bool
        The white-box can be instantiated only once per process (so can the grey-box).
    """

    model: GreyBoxModel
    model_dir: Path
    manifest: dict[str, Any]
    model_sha256: str
    interface: GreyBoxInterface
    domain: InputDomain
    guid: str
    settings: dict[str, Any]
    annotation: etree._Element
    units: etree._Element | None
    stateful: bool
    instantiate_once: bool

    def fix(self, root: etree._Element, tool: str, needs_execution_tool: bool) -> None:
        """Complete a model description of this grey-box in place (see
        :func:`fix_model_description`)."""
        fix_model_description(
            root,
            self.interface.ports,
            self.guid,
            self.units,
            self.stateful,
            self.annotation,
            instantiate_once=self.instantiate_once,
            tool=tool,
            needs_execution_tool=needs_execution_tool,
        )

    def copy_model(self, folder: Path) -> None:
        """Copy the model folder's files (those ``model.json`` lists) into ``folder``."""
        folder.mkdir(parents=True)
        for name in [MANIFEST, *self.manifest["files"]]:
            shutil.copyfile(self.model_dir / name, folder / name)


def export_greybox(
    model_dir: str | Path,
    out: str | Path,
    *,
    runtime: str = RUNTIMES[0],
    fmi_version: str = FMI_VERSIONS[0],
    author: str | None = None,
    version: str = "1.0",
    ood_threshold: float = DEFAULT_OOD_THRESHOLD,
) -> ExportResult:
    """Write the grey-box FMU of a trained model.

    Parameters
    ----------
    model_dir : str or Path
        Model folder written by ``fmu-greybox train``.
    out : str or Path
        The ``.fmu`` file to write (atomically).
    runtime : {"native", "python"}
        A C binary with no Python in the bench's process, or a pythonfmu FMU.
    fmi_version : {"2", "3"}
        FMI 2.0 or FMI 3.0 co-simulation (FMI 3.0: native runtime only; pythonfmu writes FMI
        2.0).
    author : str, optional
        Author in the model description (default: the login name).
    version : str
        Model version in the model description.
    ood_threshold : float
        Default of the ``ood_threshold`` parameter, in (0, 1).

    Returns
    -------
    ExportResult

    Raises
    ------
    ModelFormatError
        The model folder is incomplete or was modified after training.
    ExportError
        The white-box interface cannot be exported, the native binary cannot be compiled, or
        the FMU fails validation.
    """
    model_dir = Path(model_dir)
    out = Path(out)
    if out.suffix.lower() != ".fmu":
        raise ExportError(f"{out}: an FMU file name must end in .fmu")
    if not 0.0 < ood_threshold < 1.0:
        raise ExportError(f"ood_threshold = {ood_threshold} must lie strictly between 0 and 1")
    if runtime not in RUNTIMES:
        raise ExportError(f"runtime {runtime!r} is not one of {', '.join(RUNTIMES)}")
    _check_fmi_version(fmi_version, runtime)
    model = load_model(model_dir)
    with open_fmu(model.whitebox_fmu) as archive:
        plan = _plan(
            model, model_dir, archive, (runtime, fmi_version), author, version, ood_threshold
        )
        if runtime == "native":
            from fmu_greybox.export.native import package_native

            package_native(plan, archive, out)
        else:
            _package_python(plan, out)
    return ExportResult(
        path=out, interface=plan.interface, model_sha256=plan.model_sha256, guid=plan.guid
    )


def _check_fmi_version(fmi_version: str, runtime: str) -> None:
    """Refuse an FMI version the runtime cannot write.

    Raises
    ------
    ExportError
    """
    if fmi_version not in FMI_VERSIONS:
        raise ExportError(f"FMI version {fmi_version!r} is not one of {', '.join(FMI_VERSIONS)}")
    if fmi_version != "2" and runtime == "python":
        raise ExportError(
            f"the Python runtime writes FMI 2.0 FMUs only (pythonfmu has no FMI {fmi_version}.0): "
            f"export with --runtime native --fmi {fmi_version}, or with --fmi 2"
        )


def _plan(
    model: GreyBoxModel,
    model_dir: Path,
    archive: FmuArchive,
    target: tuple[str, str],
    author: str | None,
    version: str,
    ood_threshold: float,
) -> ExportPlan:
    """Everything both runtimes need (see :class:`ExportPlan`); ``target`` is the runtime and
    the FMI version."""
    runtime, fmi_version = target
    manifest = read_manifest(model_dir)
    model_sha = file_sha256(model_dir / MANIFEST)
    interface = greybox_interface(model, archive, ood_threshold)
    cosim = kind_interface(archive.model_description, archive.kind)  # CS or ME flags
    units = etree.parse(str(archive.unzip_dir / "modelDescription.xml")).find("UnitDefinitions")
    identity = f"fmu-greybox:{__version__}:{runtime}:{model_sha}:{ood_threshold!r}"
    stages = "; ".join(f"{stage}: {what}" for stage, what in model.contents().items())
    settings = {
        "kind": "greybox",
        "runtime": runtime,
        "fmi_version": fmi_version,
        "exported_with": __version__,
        "model_sha256": model_sha,
        "model_identifier": _identifier(f"{model.config.name}_greybox"),
        "description": (
            f"{model.kind.capitalize()} of {archive.model_name} ({model.config.name}), stage by "
            f"stage {stages} (fmu-greybox); drop-in replacement with the stages' outputs, their "
            "standard deviations, the white-box outputs before the correctors and an "
            "out-of-domain flag" + _integration_note(model, archive)
        ),
        "author": author or login_name(),
        "version": version,
        "ood_threshold": ood_threshold,
    }
    return ExportPlan(
        model=model,
        model_dir=model_dir,
        manifest=manifest,
        model_sha256=model_sha,
        interface=interface,
        domain=InputDomain.of(archive, interface.input_names, model.training.input_ranges),
        guid=str(uuid.uuid5(uuid.NAMESPACE_URL, identity)),
        settings=settings,
        annotation=_annotation(model, manifest, model_sha, ood_threshold),
        units=units,
        stateful=bool(cosim.canGetAndSetFMUstate and cosim.canSerializeFMUstate),
        instantiate_once=bool(cosim.canBeInstantiatedOnlyOncePerProcess),
    )


def _package_python(plan: ExportPlan, out: Path) -> None:
    """The pythonfmu FMU (see the module docstring)."""
    import pythonfmu

    settings = {
        **plan.settings,
        "install": f"fmu-greybox=={__version__}",
        "requires_python": list(REQUIRES_PYTHON),
        "python_at_export": ".".join(map(str, sys.version_info[:3])),
    }
    tool = f"fmu-greybox {__version__} (pythonfmu {pythonfmu.__version__})"
    with tempfile.TemporaryDirectory(prefix="fmu_greybox_export_") as tmp:
        src = Path(tmp) / "src"
        plan.copy_model(src / MODEL_FOLDER)
        package_python_fmu(
            src,
            [src / MODEL_FOLDER],
            GREYBOX_ENTRY,
            GreyBoxSlave,
            settings,
            lambda root: plan.fix(root, tool, needs_execution_tool=True),
            out,
        )


# ---------------------------------------------------------------------------- building blocks
def package_python_fmu(
    src: Path,
    files: list[Path],
    entry: str,
    slave: type,
    settings: dict[str, Any],
    fix: Callable[[etree._Element], None],
    out: Path,
) -> None:
    """Build a pythonfmu FMU, complete its model description, validate it, write it atomically.

    Parameters
    ----------
    src : Path
        Staging folder holding ``files``; the entry module and the settings are written there.
    files : list of Path
        Files and folders to put in the FMU's resources.
    entry : str
        Module name of the entry in the resources (one per kind of FMU: pythonfmu imports it
        under that name, once per process).
    slave : type
        The slave class the entry loads.
    settings : dict
        Written to the resources as ``fmu_runtime.json``.
    fix : callable
        Completes the ``fmiModelDescription`` element in place.
    out : Path
        The ``.fmu`` file.

    Raises
    ------
    ExportError
        pythonfmu fails, or the FMU does not pass fmpy's validation.
    """
    (src / RUNTIME_FILE).write_text(json.dumps(settings, indent=2), encoding="utf-8")
    module = write_entry(src, entry, slave.__module__, slave.__name__)
    built = build_python_fmu(module, [*files, src / RUNTIME_FILE], src.parent / "built.fmu")
    fixed = src.parent / "fixed.fmu"
    rewrite_model_description(built, fixed, fix)
    check_valid(fixed)
    with atomic_write(out, "wb") as f, open(fixed, "rb") as source:
        shutil.copyfileobj(source, f)


def write_entry(folder: Path, module: str, slave_module: str, slave_class: str) -> Path:
    """Write the FMU's entry module: :mod:`fmu_greybox.export.runtime` bound to one slave class.

    Returns
    -------
    Path
        ``folder / f"{module}.py"``.
    """
    source = (Path(__file__).parent / "runtime.py").read_text(encoding="utf-8")
    entry = folder / f"{module}.py"
    entry.write_text(
        f"{source}\n\n{slave_class} = load_slave({slave_module!r}, {slave_class!r})\n",
        encoding="utf-8",
    )
    return entry


def build_python_fmu(entry: Path, project_files: list[Path], dest: Path) -> Path:
    """Build a pythonfmu FMU from an entry module and resource files.

    pythonfmu's builder instantiates the slave once (with the resources folder it assembles) to
    collect its variables, so the slave's own checks run at export too. The builder puts the
    entry's folder on ``sys.path``; it is taken off again here.

    Raises
    ------
    ExportError
        If pythonfmu cannot build the FMU (the slave's error is quoted).
    """
    from pythonfmu import FmuBuilder

    folder = str(entry.parent)
    added = folder not in sys.path
    try:
        return Path(FmuBuilder.build_FMU(entry, dest=dest, project_files=project_files))
    except Exception as exc:
        raise ExportError(f"building the FMU failed: {type(exc).__name__}: {exc}") from exc
    finally:
        if added and folder in sys.path:
            sys.path.remove(folder)


def rewrite_model_description(source: Path, dest: Path, fix) -> None:
    """Copy an FMU, passing its ``modelDescription.xml`` root element through ``fix``."""
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as zout:
        parser = etree.XMLParser(remove_blank_text=True)
        root = etree.fromstring(zin.read("modelDescription.xml"), parser)
        fix(root)
        zout.writestr(
            "modelDescription.xml",
            etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True),
        )
        for item in zin.infolist():
            if item.filename != "modelDescription.xml":
                zout.writestr(item, zin.read(item.filename))


def check_valid(fmu: Path) -> None:
    """Run fmpy's validation; raise :class:`ExportError` listing any problem."""
    from fmpy.validation import validate_fmu

    problems = validate_fmu(str(fmu))
    if problems:
        raise ExportError(
            "the FMU does not pass fmpy.validation.validate_fmu: " + "; ".join(problems)
        )


def fix_model_description(
    root: etree._Element,
    ports: list,
    guid: str,
    units: etree._Element | None,
    stateful: bool,
    annotation: etree._Element | None,
    instantiate_once: bool = False,
    tool: str | None = None,
    needs_execution_tool: bool = True,
) -> None:
    """Complete a model description (pythonfmu's, or the native exporter's) in place.

    Parameters
    ----------
    root : lxml element
        ``fmiModelDescription``.
    ports : list of Port
        The variables, in the order pythonfmu registered them (value-reference order).
    guid : str
    units : lxml element or None
        The white-box's ``UnitDefinitions`` (units are copied from it by name).
    stateful : bool
        The FMU can get, set and serialise its state.
    annotation : lxml element or None
        Child of ``VendorAnnotations/Tool[@name="fmu-greybox"]``.
    instantiate_once : bool
        The embedded white-box can be instantiated only once per process.
    tool : str, optional
        ``generationTool`` (default: fmu-greybox and its version).
    needs_execution_tool : bool
        The FMU needs the Python interpreter of the simulation process (the Python runtime).
    """
    root.set("guid", "{" + guid + "}")
    root.set("variableNamingConvention", "flat")
    root.set("generationTool", tool or f"fmu-greybox {__version__}")
    flags = {
        "needsExecutionTool": str(needs_execution_tool).lower(),
        "canHandleVariableCommunicationStepSize": "false",  # the correctors' step is fixed
        "canInterpolateInputs": "false",
        "canBeInstantiatedOnlyOncePerProcess": str(instantiate_once).lower(),
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": str(stateful).lower(),
        "canSerializeFMUstate": str(stateful).lower(),
        "providesDirectionalDerivative": "false",
    }
    for key, value in flags.items():
        root.find("CoSimulation").set(key, value)
    variables = root.find("ModelVariables")
    elements = variables.findall("ScalarVariable")
    if [e.get("name") for e in elements] != [p.name for p in ports]:
        raise ExportError("pythonfmu registered the variables in an unexpected order")
    for element, port in zip(elements, ports, strict=True):
        if port.description:
            element.set("description", port.description)
        value = element[0]
        if port.unit:
            value.set("unit", port.unit)
        if port.type == "Real" and port.start is not None:
            value.set("start", repr(float(port.start)))
    _replace(root, "UnitDefinitions", _unit_definitions(ports, units), before="LogCategories")
    if annotation is not None:
        vendor = etree.Element("VendorAnnotations")
        etree.SubElement(vendor, "Tool", name="fmu-greybox").append(annotation)
        _replace(root, "VendorAnnotations", vendor, before="ModelVariables")
    structure = etree.Element("ModelStructure")
    outputs = [str(i + 1) for i, p in enumerate(ports) if p.causality == "output"]
    for tag in ("Outputs", "InitialUnknowns"):
        node = etree.SubElement(structure, tag)
        for index in outputs:
            etree.SubElement(node, "Unknown", index=index)
    _replace(root, "ModelStructure", structure, before=None)


def _unit_definitions(ports: list, units: etree._Element | None) -> etree._Element:
    """``UnitDefinitions`` for the units the ports use, copied from the white-box's by name."""
    known = {u.get("name"): u for u in (units if units is not None else [])}
    definitions = etree.Element("UnitDefinitions")
    for name in sorted({p.unit for p in ports if p.unit}):
        unit = known.get(name)
        definitions.append(
            etree.fromstring(etree.tostring(unit))
            if unit is not None
            else etree.Element("Unit", name=name)
        )
    return definitions


#: Order of the children of ``fmiModelDescription`` (FMI 2.0 schema).
_ORDER = (
    "ModelExchange",
    "CoSimulation",
    "UnitDefinitions",
    "TypeDefinitions",
    "LogCategories",
    "DefaultExperiment",
    "VendorAnnotations",
    "ModelVariables",
    "ModelStructure",
)


def _replace(root: etree._Element, tag: str, element: etree._Element, before: str | None) -> None:
    """Put ``element`` in place of ``root``'s child ``tag``, keeping the schema's order."""
    old = root.find(tag)
    if old is not None:
        root.replace(old, element)
        return
    later = _ORDER[_ORDER.index(tag) + 1 :]
    for child in root:
        if child.tag in later:
            child.addprevious(element)
            return
    root.append(element)


def _integration_note(model: GreyBoxModel, archive: FmuArchive) -> str:
    """For a model-exchange white-box, how it is integrated (the model folder's record), as a
    sentence closing the FMU's description; else nothing."""
    facts = model.training.whitebox
    if "integrator" not in facts:
        return ""
    integrator = recorded_integrator(model.training.whitebox)
    return (
        f". The white-box is an {archive.kind.label} FMU, integrated at each step of "
        f"{model.dt:g} s by {integrator.summary()}"
    )


def _annotation(
    model, manifest: dict[str, Any], model_sha: str, ood_threshold: float
) -> etree._Element:
    """The model's provenance for the vendor annotations."""
    training = model.training
    node = etree.Element(
        "GreyBox",
        model_sha256=model_sha,
        whitebox_sha256=manifest["whitebox_sha256"],
        recording_sha256=str(training.recording_sha256),
        recording=str(training.recording_source),
        trained=str(manifest.get("created", "")),
        tool=str(manifest.get("tool", "")),
        target_mode=model.chain.target_mode,
        dt=repr(model.dt),
        ood_threshold=repr(ood_threshold),
    )
    facts = training.whitebox
    if facts:  # the white-box's kind and, for model exchange, its integrator
        whitebox = etree.SubElement(node, "WhiteBox", kind=str(facts.get("kind", "")))
        integrator = facts.get("integrator")
        if isinstance(integrator, dict):
            etree.SubElement(
                whitebox,
                "Integrator",
                step=repr(model.dt),
                **{k: str(integrator[k]) for k in ("method", "rtol", "atol", "max_steps")},
                summary=str(integrator.get("summary", "")),
            )
    for stage, corrector in zip(model.chain.stages, model.chain.correctors_, strict=True):
        etree.SubElement(
            node,
            "Stage",
            name=stage.name,
            output=stage.config.whitebox_output,
            features=" ".join(model.chain.feature_names(stage.stage_index)),
            inducing=str(0 if corrector is None else corrector.inducing_points_.shape[0]),
        )
    for term in model.terms:
        data = term.to_dict()
        etree.SubElement(
            node,
            "NamedTerm",
            effect=term.effect,
            stage=model.chain.stages[term.entry].name,
            **{k: str(v) for k, v in data.items() if k != "entry"},
        )
    return node


def _identifier(text: str) -> str:
    """A C identifier (the FMU's model identifier names its shared library)."""
    clean = "".join(c if c.isalnum() or c == "_" else "_" for c in text)
    return clean if clean[:1].isalpha() else f"m_{clean}"


def login_name() -> str:
    """The user's login name (the default author)."""
    try:
        return getpass.getuser()
    except Exception:
        return "unknown"
