"""The main job end to end on the built-in default (the ``demo`` command).

On the reference actuator, with nothing but this repository:

1. build the white-box and truth FMUs from their C sources, and check that the truth FMU
   offers the effects asked for (before anything is said or written);
2. record the truth actuator in closed loop with a concealed effect (drawn by the seed from
   :data:`~fmu_greybox.synth.actuator.TYPICAL_MAGNITUDES` unless given), plus an independent
   validation
   recording of the same actuator;
3. diagnose the training recording, given only the white-box FMU and the project file (without
   the diagnosis' quick grey-box check of the parts: step 4 compares the same parts with the
   project's settings, and decides what ships);
4. fold the diagnosis' named terms into the white-box, train the grey-box correctors on what
   remains, and validate the whole corrected model, free-running, on the validation recording;
5. export the grey-box FMU and run it on an SSP bench in fmpy and in libcosim, checking both
   against the in-process master;
6. write ``report.html`` (:mod:`fmu_greybox.report.main`), ``diagnosis.json``, ``metrics.json``
   and ``summary.json``.

Every file is written atomically; ``summary.json`` and ``report.html`` are written last, so a
folder without them is an interrupted run.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.data.recording import Recording, save_recording
from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.diagnosis.findings import named_physics
from fmu_greybox.diagnosis.report import diagnosis_payload, write_json
from fmu_greybox.export.fmu import export_greybox
from fmu_greybox.export.ssp import BenchAgreement, compare_with_master, make_bench, run_benches
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import reference_fmus, reference_project, sources_digest
from fmu_greybox.model.store import GreyBoxModel, file_sha256, load_model, save_model
from fmu_greybox.model.whitebox import terms_from_findings
from fmu_greybox.project.config import ProjectConfig, load_config
from fmu_greybox.report.provenance import (
    command_line,
    environment_rows,
    project_row,
    tool_rows,
)
from fmu_greybox.synth.actuator import (
    TYPICAL_MAGNITUDES,
    FlightTestProfile,
    SynthRequest,
    check_effects,
    synthesise,
)
from fmu_greybox.workflow.train import train_model, with_inducing
from fmu_greybox.workflow.validate import Validation, validate_model, write_metrics

Log = Callable[[str], None]

#: What each file of the traceability block is.
FILE_ROLES = {
    "recording.csv": "the training recording, as written",
    "validation.csv": "the independent validation recording, as written",
    "HydraulicActuator.fmu": "the white-box FMU, as built",
    "HydraulicActuatorTruth.fmu": "the truth FMU that made the recordings",
    "model/model.json": "the model manifest, which holds the SHA-256 of every model file",
    "greybox.fmu": "the exported grey-box FMU",
    "bench.ssp": "the SSP bench",
}

#: Bench runs cover this many 1 ms steps of the validation recording (a power of two keeps the
#: recording's mean step exactly libcosim's integer-nanosecond step).
BENCH_STEPS = 4096


#: The independent validation recording's seed is the demo's seed plus this.
VALIDATION_SEED_OFFSET = 1_000_003


@dataclass(frozen=True)
class DemoSettings:
    """What the demo does.

    Attributes
    ----------
    out_dir : Path
        Folder for everything produced.
    effects : dict[str, float] or None
        Concealed truth effects; ``None`` draws one from the seed.
    seed : int
        Seed of the effect draw and of the recordings.
    duration : float
        Training recording length [s].
    validation_duration : float
        Independent validation recording length [s].
    inducing : int
        Inducing points per stage.
    max_iter : int
        Optimiser iterations per stage.
    engines : tuple of str
        Bench engines to run the exported FMU in.
    """

    out_dir: Path
    effects: dict[str, float] | None = None
    seed: int = 0
    duration: float = 30.0
    validation_duration: float = 8.0
    inducing: int = 150
    max_iter: int = 100
    engines: tuple[str, ...] = ("fmpy", "libcosim")


@dataclass
class DemoResult:
    """What the demo produced (the report's content).

    Attributes
    ----------
    settings : DemoSettings
    effects : dict[str, float]
        The concealed effects.
    config : ProjectConfig
    diagnosis : Diagnosis
    payload : dict
        ``diagnosis.json``.
    validation : Validation
        Free run of the grey-box on the validation recording.
    model_dir, fmu, ssp : Path
        Model folder, exported FMU, SSP bench.
    bench : list of BenchAgreement
        Per engine: the exported FMU against the in-process master.
    files : dict[str, Path]
        Inputs and outputs to hash in the traceability block (label: the file's name in the
        output folder, or of a built-in FMU).
    timings : dict[str, float]
        Seconds per step.
    command : str
        The command line.
    parts : dict
        With named terms, the training's comparison of its parts and the part shipped
        (``model.json``'s ``training.parts``); empty without terms.
    effect_units : dict[str, str]
        Each concealed effect's unit, as the truth FMU declares it (empty when it declares
        none, or for an effect around the FMU).
    model : GreyBoxModel or None
        The model exported (its named terms, the stages whose corrector is switched off).
    """

    settings: DemoSettings
    effects: dict[str, float]
    config: ProjectConfig
    diagnosis: Diagnosis
    payload: dict[str, Any]
    validation: Validation
    model_dir: Path
    fmu: Path
    ssp: Path
    bench: list[BenchAgreement]
    files: dict[str, Path] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    command: str = ""
    parts: dict[str, Any] = field(default_factory=dict)
    effect_units: dict[str, str] = field(default_factory=dict)
    model: GreyBoxModel | None = None

    def top_finding_correct(self) -> bool:
        """The diagnosis' top finding names one of the concealed effects."""
        findings = self.payload["findings"]
        if not findings:
            return False
        return named_physics(findings[0]) in self.effects

    def traceability(self) -> list[tuple[str, str, str]]:
        """Rows ``(item, what it covers, value)``: the tool, the project file, the white-box
        sources, every file's SHA-256, the recordings' data hashes, versions, the command."""
        rows = tool_rows()
        rows.append(project_row(reference_project()))
        rows.append(
            (
                "white-box sources",
                "SHA-256 of the C sources, variable tables and builder the FMUs were built "
                "from (fmu_sources/)",
                sources_digest(),
            )
        )
        rows += [
            (label, f"SHA-256 of the file: {FILE_ROLES.get(label, label)}", file_sha256(path))
            for label, path in self.files.items()
        ]
        rows.append(
            (
                "training recording data",
                "SHA-256 of recording.csv's time, signals and units as read (independent of "
                "the file format; model.json and diagnosis.json record this one)",
                self.payload["recording"]["sha256"],
            )
        )
        rows.append(
            ("seed", "seed of the effect draw and of the recordings", str(self.settings.seed))
        )
        return rows + environment_rows(self.command)


def choose_effect(seed: int) -> dict[str, float]:
    """One truth effect and a magnitude in the upper half of its typical range, by seed.

    Parameters
    ----------
    seed : int

    Returns
    -------
    dict[str, float]
        ``{effect: value}``, the value rounded to two significant figures.
    """
    rng = np.random.default_rng(seed)
    names = sorted(TYPICAL_MAGNITUDES)
    name = names[int(rng.integers(len(names)))]
    low, high = TYPICAL_MAGNITUDES[name][0], TYPICAL_MAGNITUDES[name][-1]
    value = low + (high - low) * rng.uniform(0.5, 1.0)
    return {name: float(f"{value:.2g}")}


def run_demo(settings: DemoSettings, log: Log | None = None, progress: bool = False) -> DemoResult:
    """Run the main job; see the module docstring.

    Parameters
    ----------
    settings : DemoSettings
    log : callable, optional
        Called with one line per step.
    progress : bool
        Show progress bars.

    Returns
    -------
    DemoResult

    Raises
    ------
    ConfigError
        For an effect the truth actuator does not offer, before anything is said or written.
    """
    say = log or (lambda _message: None)
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def step(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = round(now - clock, 2)
        clock = now

    effects = dict(settings.effects) if settings.effects else choose_effect(settings.seed)
    fmus = reference_fmus()
    with (
        open_fmu(fmus["HydraulicActuatorTruth"]) as truth,
        open_fmu(fmus["HydraulicActuator"]) as whitebox,
    ):
        check_effects(effects, truth, whitebox)  # before a step is said or a folder made
        effect_units = {
            name: truth.variables[name].unit for name in effects if name in truth.variables
        }
    out = Path(settings.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say("[1/6] the reference FMUs, built from fmu_sources/ (once: they are cached)")
    config = load_config(reference_project())
    step("build")

    label = ", ".join(f"{k}={v:g}" for k, v in effects.items())
    say(f"[2/6] recording the truth actuator with a concealed effect ({label})")
    training, validation_rec = _record(fmus, effects, settings, progress)
    save_recording(training, out / "recording.csv")
    save_recording(validation_rec, out / "validation.csv")
    step("record")

    say("[3/6] diagnosing the recording (given only the white-box FMU and the project)")
    # no quick grey-box check of the parts here: training compares them next, and decides
    diagnosis = Diagnosis(config, greybox=None, progress=lambda m: say(f"      {m}")).fit(training)
    payload = diagnosis_payload(diagnosis, training)
    write_json(payload, out / "diagnosis.json")
    step("diagnose")

    terms = terms_from_findings(payload["findings"])
    on = f"the white-box + {len(terms)} named term(s)" if terms else "the white-box"
    say(f"[4/6] training the grey-box on {on} ({settings.inducing} inducing points per stage)")
    model_dir = out / "model"
    trained = train_model(
        with_inducing(config, settings.inducing, settings.max_iter), training, progress, terms=terms
    )
    save_model(trained, model_dir)
    model = load_model(model_dir)
    validation = validate_model(model, validation_rec, progress)
    write_metrics(validation, model, out / "metrics.json")
    step("train")

    say("[5/6] exporting the grey-box FMU and running it on an SSP bench")
    fmu = export_greybox(model_dir, out / "greybox.fmu", author="fmu-greybox demo").path
    bench_rec = validation_rec.slice_time(
        validation_rec.time[0], validation_rec.time[0] + BENCH_STEPS * model.dt
    )
    ssp = make_bench(fmu, bench_rec, out / "bench.ssp")
    agreements = []
    for engine, (result, seconds) in zip(
        settings.engines, run_benches(ssp, settings.engines), strict=True
    ):
        save_recording(result, out / f"bench_{engine}.csv")
        agreements.append(compare_with_master(model, bench_rec, result, engine, seconds))
    step("export and bench")

    say("[6/6] writing the report")
    files = {
        "recording.csv": out / "recording.csv",
        "validation.csv": out / "validation.csv",
        "HydraulicActuator.fmu": fmus["HydraulicActuator"],
        "HydraulicActuatorTruth.fmu": fmus["HydraulicActuatorTruth"],
        "model/model.json": model_dir / "model.json",
        "greybox.fmu": fmu,
        "bench.ssp": ssp,
    }
    return DemoResult(
        settings=settings,
        effects=effects,
        config=config,
        diagnosis=diagnosis,
        payload=payload,
        validation=validation,
        model_dir=model_dir,
        fmu=fmu,
        ssp=ssp,
        bench=agreements,
        files=files,
        timings=timings,
        command=command_line(),
        parts=model.training.parts or {},
        effect_units=effect_units,
        model=model,
    )


def _record(
    fmus: dict[str, Path], effects: dict[str, float], settings: DemoSettings, progress: bool
) -> tuple[Recording, Recording]:
    """Training and validation recordings of the truth actuator (different seeds)."""
    recordings = []
    with (
        open_fmu(fmus["HydraulicActuatorTruth"]) as truth,
        open_fmu(fmus["HydraulicActuator"]) as whitebox,
    ):
        for seed, duration in (
            (settings.seed, settings.duration),
            (settings.seed + VALIDATION_SEED_OFFSET, settings.validation_duration),
        ):
            request = SynthRequest(
                effects=effects, seed=seed, profile=FlightTestProfile(duration=duration)
            )
            recordings.append(synthesise(truth, whitebox, request, progress=progress))
    return recordings[0], recordings[1]
