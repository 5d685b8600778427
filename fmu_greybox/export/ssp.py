"""SSP benches for a grey-box FMU, and running them in fmpy or libcosim (the ``cosim`` command).

:func:`make_bench` writes an ``.ssp`` archive from the template ``bench_configs/
bench_template.ssd``: a recording-playback FMU (:mod:`fmu_greybox.export.playback`) drives the
grey-box FMU and, side by side, the white-box FMU it corrects (taken from the grey-box's
resources), input by input as the project maps recorded columns to FMU inputs.

:func:`run_bench` co-simulates such an archive (or any SSP of FMI 2.0 co-simulation FMUs with a
fixed step) and returns every FMU output as a :class:`~fmu_greybox.data.recording.Recording`:

* ``fmpy`` -- :func:`fmpy.ssp.simulation.simulate_ssp`. It starts every connection at 0 and
  passes values along only after each step, so during the first communication step every
  connected input is 0; the connected inputs are therefore also initialised at 0, which keeps
  the start consistent. Rows come at the end of each step (fmpy labels them with its start).
* ``libcosim`` -- the Open Simulation Platform through libcosimpy: connections are passed on
  during initialisation and after every step, so the first step already sees the recording.
  It runs in a child process (:mod:`fmu_greybox.export.libcosim_run`): an FMU error during
  libcosim's initialisation would otherwise abort this one.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import json
import tempfile
import threading
import uuid
import zipfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from time import perf_counter

import numpy as np
from lxml import etree

from fmu_greybox import __version__
from fmu_greybox.atomic import atomic_write
from fmu_greybox.data.recording import Recording
from fmu_greybox.errors import BenchError
from fmu_greybox.export.fmu import (
    REQUIRES_PYTHON,
    fix_model_description,
    login_name,
    package_python_fmu,
)
from fmu_greybox.export.slave import MODEL_FOLDER, Port
from fmu_greybox.model.store import MANIFEST, WHITEBOX, file_sha256
from fmu_greybox.project.config import parse_config
from fmu_greybox.project.data import check_fixed_inputs, check_sample_time
from fmu_greybox.resources import data_path
from fmu_greybox.side_by_side import run_side_by_side

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"
NS = {"ssd": SSD, "ssc": SSC, "ssv": SSV, "osp": OSP}
#: The system structure inside an ``.ssp`` archive.
SSD_FILE = "SystemStructure.ssd"
#: Co-simulation engines of :func:`run_bench`.
ENGINES = ("fmpy", "libcosim")
#: Held while an fmpy run points :data:`tempfile.tempdir` at its private folder.
_TEMPDIR_LOCK = threading.Lock()
#: Module name of the playback entry in the playback FMU's resources.
PLAYBACK_ENTRY = "playback_fmu"


def template_path() -> Path:
    """The SSD template (``FMU_GREYBOX_BENCH_TEMPLATE`` overrides the packaged one)."""
    return data_path("bench_configs", "bench_template.ssd", env="FMU_GREYBOX_BENCH_TEMPLATE")


# ---------------------------------------------------------------------------- playback FMU
def build_playback_fmu(recording: Recording, out: str | Path, author: str | None = None) -> Path:
    """Write an FMU that plays ``recording`` back, one Real output per signal.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ExportError
        If pythonfmu cannot build it or the FMU fails validation.
    """
    from fmu_greybox.export.playback import RECORDING_FILE, PlaybackSlave

    out = Path(out)
    names = list(recording.names)
    units = [recording.units.get(n, "") for n in names]
    with tempfile.TemporaryDirectory(prefix="fmu_greybox_playback_") as tmp:
        src = Path(tmp) / "src"
        src.mkdir()
        table = np.column_stack([recording.time, *(recording[n] for n in names)])
        csv = src / RECORDING_FILE
        np.savetxt(
            csv, table, delimiter=",", fmt="%.17g", header=",".join(["time", *names]), comments=""
        )
        settings = {
            "kind": "playback",
            "exported_with": __version__,
            "install": f"fmu-greybox=={__version__}",
            "requires_python": list(REQUIRES_PYTHON),
            "model_identifier": "recording_playback",
            "description": f"Playback of {Path(recording.source).name or 'a recording'}: "
            f"{len(names)} signals, {recording.n_samples} samples every {recording.dt:g} s, "
            "sample and hold",
            "author": author or login_name(),
            "version": recording.sha256()[:12],
            "signals": names,
            "units": units,
            "recording_sha256": file_sha256(csv),
        }
        ports = [
            Port(n, "Real", "output", "continuous", u, f"Recorded {n} (sample and hold)")
            for n, u in zip(names, units, strict=True)
        ]
        guid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"playback:{settings['recording_sha256']}"))
        package_python_fmu(
            src,
            [csv],
            PLAYBACK_ENTRY,
            PlaybackSlave,
            settings,
            lambda root: fix_model_description(root, ports, guid, None, True, None),
            out,
        )
    return out


# ---------------------------------------------------------------------------- the bench
@dataclass(frozen=True)
class _Component:
    """An FMU on the bench: its name, file, model description and inputs fed by the playback."""

    name: str
    fmu: Path
    description: object
    fed: Mapping[str, str]
    fixed: Mapping[str, float]


def require_bench_fmi(fmi_version: str, what: str) -> None:
    """Refuse an FMU of another FMI version than the benches carry (FMI 2.0: the fmpy and
    libcosim runs here are made and tested for it).

    Parameters
    ----------
    fmi_version : str
        ``"2"``, ``"3"``, or a model description's ``fmiVersion``.
    what : str
        The FMU or the option, for the message.

    Raises
    ------
    BenchError
    """
    if not fmi_version.startswith("2"):
        raise BenchError(
            f"{what}: an FMI {fmi_version[0]}.0 FMU; an SSP bench carries FMI 2.0 FMUs (its "
            "fmpy and libcosim runs take no FMI 3.0): export the bench's FMU with --fmi 2"
        )


def make_bench(
    greybox_fmu: str | Path,
    recording: Recording,
    out: str | Path,
    *,
    side_by_side: bool = True,
    template: str | Path | None = None,
) -> Path:
    """Write an ``.ssp`` bench: the recording played back into the grey-box (and white-box).

    Parameters
    ----------
    greybox_fmu : str or Path
        An FMU written by :func:`fmu_greybox.export.fmu.export_greybox`.
    recording : Recording
        Supplies the inputs, mapped to FMU inputs as in the model's project (``[signals]``
        columns and variables); inputs the project holds fixed get parameter bindings.
    out : str or Path
        The ``.ssp`` file (written atomically).
    side_by_side : bool
        Also run the white-box FMU on the same inputs.
    template : str or Path, optional
        SSD template (default :func:`template_path`).

    Returns
    -------
    Path

    Raises
    ------
    BenchError
        A grey-box input has no recorded column, the template is missing or invalid, or the FMU
        is not FMI 2.0.
    RecordingError
        The recording is not sampled at the grey-box's step.
    ConfigError
        The recording records an input the project holds constant.
    """
    from fmpy import read_model_description

    greybox_fmu, out = Path(greybox_fmu), Path(out)
    template = Path(template) if template is not None else template_path()
    if not template.is_file():
        raise BenchError(
            f"SSD template {template} not found; set FMU_GREYBOX_BENCH_TEMPLATE to an SSD "
            "template such as the packaged fmu_greybox/_data/bench_configs/bench_template.ssd"
        )
    config = _project(greybox_fmu)
    description = read_model_description(str(greybox_fmu))
    require_bench_fmi(description.fmiVersion, str(greybox_fmu))
    step = description.defaultExperiment.stepSize if description.defaultExperiment else None
    if step is not None:
        check_sample_time(recording, float(step), "the grey-box FMU (its default step)")
    check_fixed_inputs(config, recording)
    fixed = dict(config.fixed_inputs)
    mapping = config.input_mapping()
    fed = {}
    for variable in description.modelVariables:
        if variable.causality != "input" or variable.name in fixed:
            continue
        column = mapping.get(variable.name, variable.name)
        if column not in recording.signals:
            raise BenchError(
                f"grey-box input {variable.name!r} needs the recorded column {column!r}, which "
                f"{recording.source or 'the recording'} lacks (it has "
                f"{', '.join(recording.names)}); record it or hold the input fixed in the project"
            )
        fed[variable.name] = column
    with tempfile.TemporaryDirectory(prefix="fmu_greybox_bench_") as tmp:
        tmp = Path(tmp)
        playback = build_playback_fmu(recording, tmp / "playback.fmu")
        components = [
            _Component("playback", playback, read_model_description(str(playback)), {}, {}),
            _Component("greybox", greybox_fmu, description, fed, fixed),
        ]
        if side_by_side:
            whitebox = tmp / "whitebox.fmu"
            with zipfile.ZipFile(greybox_fmu) as archive:
                whitebox.write_bytes(archive.read(f"resources/{MODEL_FOLDER}/{WHITEBOX}"))
            components.append(
                _Component("whitebox", whitebox, read_model_description(str(whitebox)), fed, fixed)
            )
        ssd = _system_structure(template, components, recording)
        with atomic_write(out, "wb") as f, zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr(SSD_FILE, ssd)
            for component in components:
                z.write(component.fmu, f"resources/{component.name}.fmu")
    return out


def _project(greybox_fmu: Path):
    """The project stored in a grey-box FMU's model copy."""
    try:
        with zipfile.ZipFile(greybox_fmu) as archive:
            manifest = json.loads(archive.read(f"resources/{MODEL_FOLDER}/{MANIFEST}"))
        return parse_config(manifest["project"], None)
    except (KeyError, OSError, ValueError, zipfile.BadZipFile) as exc:
        raise BenchError(
            f"{greybox_fmu}: not a grey-box FMU written by 'fmu-greybox export' ({exc})"
        ) from exc


def _system_structure(template: Path, components: list[_Component], recording: Recording) -> bytes:
    """The filled-in SSD."""
    try:
        tree = etree.parse(str(template), etree.XMLParser(remove_blank_text=True))
    except etree.XMLSyntaxError as exc:
        raise BenchError(f"{template}: not an XML file ({exc})") from exc
    root = tree.getroot()
    system = root.find("ssd:System", NS)
    elements = system.find("ssd:Elements", NS) if system is not None else None
    connections = system.find("ssd:Connections", NS) if system is not None else None
    step = root.find(".//osp:FixedStepAlgorithm", NS)
    experiment = root.find("ssd:DefaultExperiment", NS)
    if elements is None or connections is None or step is None or experiment is None:
        raise BenchError(
            f"{template}: an SSD template needs System/Elements, System/Connections and a "
            "DefaultExperiment with an osp:FixedStepAlgorithm annotation"
        )
    experiment.set("startTime", repr(float(recording.time[0])))
    experiment.set("stopTime", repr(float(recording.time[-1])))
    step.set("baseStepSize", repr(recording.dt))
    units: dict[str, object] = {}
    for component in components:
        elements.append(_component_element(component, units))
        for variable, column in component.fed.items():
            etree.SubElement(
                connections,
                _q("ssd", "Connection"),
                startElement="playback",
                startConnector=column,
                endElement=component.name,
                endConnector=variable,
            )
    used = {u.get("unit") for u in root.iterfind(".//ssc:Real[@unit]", NS)}
    units = {name: unit for name, unit in units.items() if name in used}
    if units:
        root.insert(root.index(system) + 1, _units_element(units))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _component_element(component: _Component, units: dict[str, object]) -> etree._Element:
    element = etree.Element(
        _q("ssd", "Component"),
        name=component.name,
        source=f"resources/{component.name}.fmu",
        type="application/x-fmu-sharedlibrary",
    )
    connectors = etree.SubElement(element, _q("ssd", "Connectors"))
    for unit in component.description.unitDefinitions:
        known = units.get(unit.name)
        if known is None or known.baseUnit is None:  # the playback's units are bare names
            units[unit.name] = unit
    for v in component.description.modelVariables:
        if not ((v.causality == "input" and v.name in component.fed) or v.causality == "output"):
            continue
        connector = etree.SubElement(
            connectors, _q("ssd", "Connector"), name=v.name, kind=v.causality
        )
        kind = etree.SubElement(connector, _q("ssc", v.type))
        if v.type == "Real" and v.unit:
            kind.set("unit", v.unit)
    if component.fixed:
        bindings = etree.SubElement(element, _q("ssd", "ParameterBindings"))
        values = etree.SubElement(
            etree.SubElement(bindings, _q("ssd", "ParameterBinding")), _q("ssd", "ParameterValues")
        )
        parameter_set = etree.SubElement(
            values, _q("ssv", "ParameterSet"), version="1.0", name="fixed_inputs"
        )
        parameters = etree.SubElement(parameter_set, _q("ssv", "Parameters"))
        for name, value in component.fixed.items():
            parameter = etree.SubElement(parameters, _q("ssv", "Parameter"), name=name)
            etree.SubElement(parameter, _q("ssv", "Real"), value=repr(float(value)))
    return element


def _units_element(units: Mapping[str, object]) -> etree._Element:
    element = etree.Element(_q("ssd", "Units"))
    for name, unit in sorted(units.items()):
        node = etree.SubElement(element, _q("ssc", "Unit"), name=name)
        base = etree.SubElement(node, _q("ssc", "BaseUnit"))
        for key in ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset"):
            value = getattr(unit.baseUnit, key, None) if unit.baseUnit is not None else None
            if value not in (None, 0, 0.0) and not (key == "factor" and value == 1.0):
                base.set(key, repr(value) if isinstance(value, float) else str(value))
    return element


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


# ---------------------------------------------------------------------------- running
@dataclass(frozen=True)
class BenchLayout:
    """What :func:`run_bench` needs from an SSP: its components and their outputs.

    Attributes
    ----------
    components : dict[str, str]
        Component name -> FMU path inside the archive.
    outputs : dict[str, list[str]]
        Component name -> output connectors, in SSD order.
    fed : dict[str, list[str]]
        Component name -> input connectors that a connection feeds.
    start, stop : float
        DefaultExperiment times [s].
    step : float or None
        The OSP fixed-step annotation [s], if any.
    """

    components: dict[str, str]
    outputs: dict[str, list[str]]
    fed: dict[str, list[str]]
    start: float
    stop: float | None
    step: float | None


def read_layout(ssp: str | Path) -> BenchLayout:
    """Read the layout of an ``.ssp`` archive.

    Raises
    ------
    BenchError
        The file is not an SSP archive with a SystemStructure.ssd.
    """
    ssp = Path(ssp)
    try:
        with zipfile.ZipFile(ssp) as archive:
            root = etree.fromstring(archive.read(SSD_FILE))
    except (OSError, KeyError, zipfile.BadZipFile, etree.XMLSyntaxError) as exc:
        raise BenchError(
            f"{ssp}: not an SSP archive with {SSD_FILE} ({exc}); write one with "
            "'fmu-greybox export MODEL --out gb.fmu --ssp bench.ssp --recording REC'"
        ) from exc
    components, outputs, fed = {}, {}, {}
    for c in root.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
        name = c.get("name")
        components[name] = c.get("source")
        connectors = list(c.iterfind("ssd:Connectors/ssd:Connector", NS))
        outputs[name] = [k.get("name") for k in connectors if k.get("kind") == "output"]
        fed[name] = []
    for link in root.iterfind("ssd:System/ssd:Connections/ssd:Connection", NS):
        fed.setdefault(link.get("endElement"), []).append(link.get("endConnector"))
    experiment = root.find("ssd:DefaultExperiment", NS)
    step = root.find(".//osp:FixedStepAlgorithm", NS)
    start = float(experiment.get("startTime", 0.0)) if experiment is not None else 0.0
    stop = experiment.get("stopTime") if experiment is not None else None
    return BenchLayout(
        components=components,
        outputs=outputs,
        fed=fed,
        start=start,
        stop=float(stop) if stop is not None else None,
        step=float(step.get("baseStepSize")) if step is not None else None,
    )


def run_bench(
    ssp: str | Path,
    engine: str = "fmpy",
    stop_time: float | None = None,
    step: float | None = None,
) -> Recording:
    """Co-simulate an SSP bench and collect every FMU output.

    Parameters
    ----------
    ssp : str or Path
        The ``.ssp`` archive.
    engine : {"fmpy", "libcosim"}
    stop_time : float, optional
        Default: the SSD's DefaultExperiment stopTime.
    step : float, optional
        Communication step [s]; default: the SSD's OSP fixed-step annotation.

    Returns
    -------
    Recording
        Signals ``<component>.<output>`` (Booleans as 0/1) at the end of every step, with units.

    Raises
    ------
    BenchError
        Unknown engine, no step or stop time, or an FMU failed (the message says which).
    """
    if engine not in ENGINES:
        raise BenchError(f"engine {engine!r} is not one of {', '.join(ENGINES)}")
    ssp = Path(ssp)
    layout = read_layout(ssp)
    step = step if step is not None else layout.step
    stop = stop_time if stop_time is not None else layout.stop
    if step is None or step <= 0 or stop is None:
        raise BenchError(
            f"{ssp}: give the communication step (--step) and the stop time (--stop-time); the "
            "SSD declares no OSP fixed step or no DefaultExperiment stopTime"
        )
    n_steps = round((stop - layout.start) / step)
    if n_steps < 1:
        raise BenchError(f"stop time {stop} s leaves no step of {step} s after {layout.start} s")
    units = _units(ssp, layout)
    runner = _run_fmpy if engine == "fmpy" else _run_libcosim
    columns = runner(ssp, layout, step, n_steps)
    time = layout.start + step * np.arange(1, n_steps + 1)
    return Recording(
        time=time,
        signals=columns,
        units={name: units.get(name, "") for name in columns},
        source=f"{ssp.name} in {engine}",
        metadata={"engine": engine, "step": repr(step)},
    )


def run_benches(ssp: str | Path, engines: Sequence[str]) -> list[tuple[Recording, float]]:
    """:func:`run_bench` in each engine, side by side (libcosim runs in a child process, fmpy
    in this one), each over the SSD's step and stop time.

    Returns
    -------
    list of (Recording, float)
        Per engine, in the order given: its run and the wall time it took [s].

    Raises
    ------
    BenchError
        As :func:`run_bench`, for the first engine that failed.
    """

    def timed(engine: str) -> tuple[Recording, float]:
        started = perf_counter()
        result = run_bench(ssp, engine)
        return result, perf_counter() - started

    return run_side_by_side([functools.partial(timed, engine) for engine in engines])


def _units(ssp: Path, layout: BenchLayout) -> dict[str, str]:
    """``<component>.<output>`` -> unit, from the FMUs' model descriptions."""
    from fmpy import read_model_description

    units = {}
    with zipfile.ZipFile(ssp) as archive:
        for name, source in layout.components.items():
            description = read_model_description(io.BytesIO(archive.read(source)))
            for v in description.modelVariables:
                if v.name in layout.outputs[name]:
                    unit = v.unit or (v.declaredType.unit if v.declaredType else None)
                    units[f"{name}.{v.name}"] = unit or ("1" if v.type == "Boolean" else "")
    return units


@contextmanager
def _unpacked_within() -> Iterator[None]:
    """Let fmpy unpack the SSP and its FMUs into a private folder, removed at the end even when
    the run fails (fmpy's ``simulate_ssp`` removes them only after a successful run).

    fmpy extracts with :func:`tempfile.mkdtemp`, so :data:`tempfile.tempdir` points at the
    private folder for the block and is restored after it; one block at a time, and
    :func:`_run_libcosim` reads the temporary folder outside any block (:data:`_TEMPDIR_LOCK`).
    """
    with _TEMPDIR_LOCK, tempfile.TemporaryDirectory(prefix="fmu_greybox_cosim_") as private:
        kept = tempfile.tempdir
        tempfile.tempdir = private
        try:
            yield
        finally:
            tempfile.tempdir = kept


def _run_fmpy(ssp: Path, layout: BenchLayout, step: float, n_steps: int) -> dict[str, np.ndarray]:
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import Parameter, ParameterSet, read_ssd

    ssd = read_ssd(str(ssp))
    parameters = ParameterSet(name="bench")
    for component in ssd.system.elements:
        for binding in getattr(component, "parameterBindings", []):
            for values in binding.parameterValues:
                for p in values.parameters:
                    value = float(p.value) if p.type == "Real" else p.value
                    parameters.parameters.append(
                        Parameter(name=f"{component.name}.{p.name}", type=p.type, value=value)
                    )
        for name in layout.fed.get(component.name, []):
            parameters.parameters.append(
                Parameter(name=f"{component.name}.{name}", type="Real", value=0.0)
            )
    try:
        with _unpacked_within():
            result = simulate_ssp(
                str(ssp),
                start_time=layout.start,
                stop_time=layout.start + (n_steps - 0.5) * step,
                step_size=step,
                parameter_set=parameters,
            )
    except Exception as exc:
        raise BenchError(f"{ssp.name} failed in fmpy: {type(exc).__name__}: {exc}") from exc
    wanted = [f"{c}.{o}" for c, outs in layout.outputs.items() for o in outs]
    return {name: np.asarray(result[name], dtype=np.float64) for name in wanted}


def _run_libcosim(
    ssp: Path, layout: BenchLayout, step: float, n_steps: int
) -> dict[str, np.ndarray]:
    from fmu_greybox.export.libcosim_run import run_libcosim

    with _TEMPDIR_LOCK:  # the temporary folder, not an fmpy run's private one
        scratch = tempfile.gettempdir()
    return run_libcosim(ssp, layout.outputs, layout.start, step, n_steps, scratch)


@dataclass(frozen=True)
class BenchAgreement:
    """A bench run of a grey-box FMU against the in-process master on the same inputs.

    Attributes
    ----------
    engine : str
    steps : int
        Communication steps run.
    seconds : float
        Wall time of the bench run (all its FMUs).
    max_relative_difference : dict[str, float]
        Output (``name``, ``name_std``, ``name_wb``) -> largest absolute difference over the
        run divided by the master's scale (its largest magnitude or range).
    """

    engine: str
    steps: int
    seconds: float
    max_relative_difference: dict[str, float]

    @property
    def worst(self) -> float:
        """The largest relative difference of any output."""
        return max(self.max_relative_difference.values())


def engine_inputs(recording: Recording, engine: str, inputs: list[str]) -> Recording:
    """The recording as an engine feeds it to the grey-box (see the module docstring).

    fmpy's SSP simulation feeds 0 to every connected input during the first step, so for
    ``fmpy`` the first row of ``inputs`` is set to 0; libcosim feeds the recording as it is.
    """
    if engine != "fmpy":
        return recording
    signals = {name: np.array(values) for name, values in recording.signals.items()}
    for name in inputs:
        signals[name][0] = 0.0
    return dataclasses.replace(recording, signals=signals)


def compare_with_master(
    model, recording: Recording, result: Recording, engine: str, seconds: float = float("nan")
) -> BenchAgreement:
    """Compare a bench run of a model's grey-box FMU with the in-process master.

    Parameters
    ----------
    model : GreyBoxModel
        The model the FMU was exported from.
    recording : Recording
        The recording the bench played back, from its first row.
    result : Recording
        :func:`run_bench`'s output; its ``greybox.<output>`` columns are compared.
    engine : str
        The engine that ran it.
    seconds : float
        Wall time of the run.

    Returns
    -------
    BenchAgreement
    """
    from fmu_greybox.fmi.archive import open_fmu
    from fmu_greybox.model.stage_data import prepare
    from fmu_greybox.workflow.master import run_master

    steps = result.n_samples
    played = recording.slice_time(recording.time[0], recording.time[0] + steps * model.dt)
    columns = [model.config.signals[n].column for n in model.chain.exo_names]
    fed = engine_inputs(played, engine, [c for c in columns if c in played.signals])
    with open_fmu(model.whitebox_fmu) as archive:
        data = prepare(model.config, model.chain, archive, fed)
    run = run_master(model, data, 0, memory_from="whitebox")
    if run.rows.size != steps:
        raise BenchError(
            f"the bench ran {steps} steps, the master {run.rows.size}; the bench's step differs "
            "from the model's"
        )
    differences = {}
    for q, signal in enumerate(model.chain.target_signals):
        name = model.config.signals[signal].variable
        for suffix, ref in (
            ("", run.mean[:, q]),
            ("_std", run.std[:, q]),
            ("_wb", run.whitebox[:, q]),
        ):
            got = result[f"greybox.{name}{suffix}"]
            scale = max(float(np.ptp(ref)), float(np.max(np.abs(ref))), np.finfo(float).tiny)
            differences[name + suffix] = float(np.max(np.abs(got - ref))) / scale
    return BenchAgreement(engine, steps, seconds, differences)
