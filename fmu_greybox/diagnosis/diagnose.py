"""The diagnosis of a project on a recording: locate, name, model, show.

:class:`Diagnosis` composes the steps, scikit-learn style (``fit`` returns ``self``, fitted
attributes end in ``_``):

1. simulate the white-box over the recorded inputs and measure its residuals
   (:class:`~.locate.Locator`);
2. if a stage departs from the recording beyond noise, generate the hypotheses the project's
   roles allow (:func:`~.hypotheses.generate_hypotheses`) and keep the few the data support
   (:class:`~.select.ForwardSelection`);
3. fold the kept terms into the white-box
   (:func:`~fmu_greybox.model.simulate.simulate_with_terms`) and train the grey-box correctors
   (:class:`~fmu_greybox.model.chain.GreyBoxChain`) on what remains;
4. compare white-box, white-box + named terms and grey-box on held-out rows.

The held-out part is the project's (``split.train_fraction``), but at least the last 20 % of
the recording, so that the selection's held-out test has data to judge on.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable

import numpy as np

from fmu_greybox.data.noise import ResidualJudge
from fmu_greybox.data.recording import Recording
from fmu_greybox.diagnosis.findings import (
    Finding,
    named_findings,
    none_finding,
    stage_structure,
    unexplained_finding,
)
from fmu_greybox.diagnosis.hypotheses import DataScales, generate_hypotheses
from fmu_greybox.diagnosis.locate import Locator, regime_signals
from fmu_greybox.diagnosis.runner import Experiment, SimulationCluster, Simulator
from fmu_greybox.diagnosis.select import ForwardSelection
from fmu_greybox.diagnosis.signals import SignalMap
from fmu_greybox.diagnosis.window import MAX_ROWS, most_excited
from fmu_greybox.errors import ConfigError, RecordingError
from fmu_greybox.fmi.archive import FmuArchive, open_fmu, real_outputs
from fmu_greybox.model.chain import GreyBoxChain
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.model.terms import ViscousForce
from fmu_greybox.project.config import ProjectConfig
from fmu_greybox.project.data import check_step, whitebox_path
from fmu_greybox.side_by_side import run_side_by_side
from fmu_greybox.workflow.metrics import improvement, rmse
from fmu_greybox.workflow.parts import compare_parts

#: Largest share of a recording used for training in a diagnosis.
MAX_TRAIN_FRACTION = 0.8
#: Fewest rows a diagnosis runs on: its held-out part (at least the last 20 %) then has 200
#: rows, enough for the spectra and for a finding to be tested rather than fitted to noise.
MIN_ROWS = 1000

Progress = Callable[[str], None]


@dataclasses.dataclass(frozen=True)
class GreyBoxSettings:
    """Corrector settings of the diagnosis' grey-box (smaller than a full ``train``).

    The diagnosis trains the chain to show how much the correctors add to the named terms;
    ``fmu-greybox train`` builds the production model with the project's own settings. Each
    field caps the project's value.
    """

    inducing: int = 60
    max_iter: int = 40
    max_train_samples: int = 4000


class Diagnosis:
    """Locate, name, model and show what a white-box misses on a recording.

    Parameters
    ----------
    config : ProjectConfig
    workers : int
        Simulation worker processes.
    screen_rows : int
        Rows of the screening window.
    max_findings : int
        Most named effects kept.
    greybox : GreyBoxSettings or None
        Settings of the grey-box trained on top of the named terms; ``None`` skips it.
    progress : callable, optional
        Called with a short message at each step.
    cluster : SimulationCluster, optional
        Run the hypothesis simulations on this cluster's workers instead of ``workers`` local
        processes (``diagnose --scheduler``).
    max_rows : int
        Most rows diagnosed: a longer recording is diagnosed on its stretch of this many rows
        with the most input excitation (:mod:`~fmu_greybox.diagnosis.window`).

    Attributes
    ----------
    window_ : Window or None
        The stretch diagnosed, when the recording is longer than ``max_rows`` (``None``: all
        of it). Every row index below counts from its first row.
    signals_ : SignalMap
    experiment_ : Experiment
    locator_ : Locator
    selection_ : ForwardSelection or None
        ``None`` when nothing departs beyond noise.
    hypotheses_ : list of Hypothesis
        The hypotheses generated (empty when nothing departs beyond noise).
    simulations_ : int
        Simulations run.
    findings_ : list of Finding
        Best first.
    origin_stage_ : str or None
    simulated_ : dict[str, ndarray]
        ``whitebox`` and ``named`` predictions of the observed signals, shape (n, n_observed);
        with the grey-box, ``greybox``: its free run of the stage targets over the held-out
        rows, shape (n_heldout, Q).
    fit_ : dict[str, dict[str, float]]
        Stage -> ``wb_rmse``, ``named_rmse`` and its improvement, on held-out rows; with the
        grey-box also ``gb_rmse``, ``gb_improvement``, ``correctors_rmse`` (correctors on the
        plain white-box) and ``best`` (of the three parts, :mod:`fmu_greybox.workflow.parts`).
    parts_ : PartsComparison or None
        The correctors alone, the named terms alone and both on the held-out rows (``None``
        without the grey-box or without named terms).
    timings_ : dict[str, float]
        Seconds per step.
    """

    def __init__(
        self,
        config: ProjectConfig,
        workers: int = 2,
        screen_rows: int = 4000,
        max_findings: int = 5,
        greybox: GreyBoxSettings | None = GreyBoxSettings(),
        progress: Progress | None = None,
        cluster: SimulationCluster | None = None,
        max_rows: int = MAX_ROWS,
    ) -> None:
        self.config = config
        self.workers = workers
        self.screen_rows = screen_rows
        self.max_findings = max_findings
        self.greybox = greybox
        self.progress = progress or (lambda message: None)
        self.cluster = cluster
        self.max_rows = max_rows

    # ------------------------------------------------------------------ fit
    def fit(self, recording: Recording) -> Diagnosis:
        """Diagnose the white-box on ``recording``.

        Returns
        -------
        Diagnosis
            ``self``.

        Raises
        ------
        ConfigError
            If no recorded signal corresponds to an FMU output (nothing to compare).
        RecordingError
            If the recording has fewer than :data:`MIN_ROWS` rows.
        """
        started = time.perf_counter()
        self.timings_: dict[str, float] = {}
        config = self.config
        check_step(config, recording)
        if recording.n_samples < MIN_ROWS:
            raise RecordingError(
                f"holds {recording.n_samples} rows; a diagnosis needs at least {MIN_ROWS} (it "
                "holds out the last 20 % to test what it finds). Diagnose a longer recording",
                path=recording.source,
            )
        self.fmu_path_ = whitebox_path(config)
        with open_fmu(self.fmu_path_) as archive:
            config.check_against_fmu(archive)
            targets = [config.signals[s.target].column for s in config.stages]
            recording.require(targets, context=f"project {config.name}")
            recording = self._window(recording)
            signals = SignalMap.from_project(config, archive, recording)
            if not signals.observed:
                raise ConfigError(
                    "no recorded signal corresponds to an output of the white-box FMU; declare "
                    "the recorded outputs under [signals] with their FMU 'variable'",
                    field="signals",
                    path=str(config.path) if config.path else None,
                )
            n = recording.n_samples
            train = max(2, min(n - 2, int(min(config.train_fraction, MAX_TRAIN_FRACTION) * n)))
            experiment = Experiment.from_project(config, archive, recording, signals, train)
            self.progress("estimating the noise and simulating the white-box")
            wb = experiment.estimate_noise()
            if wb is None:
                raise ConfigError("the white-box FMU fails on this recording's inputs")
            signals.assign_stages(wb, experiment.dt)
            experiment.stages = signals.observed_stages
            self.signals_, self.experiment_ = signals, experiment
            self._locate(recording, wb)
            self._tick("locate", started)
            named = wb
            self.selection_ = None
            self.hypotheses_ = []
            self.simulations_ = 1
            if self.locator_.origin_ is not None:
                named = self._name(archive, signals, experiment)
            self._tick("name", started)
        self.simulated_ = {"whitebox": wb, "named": named}
        self.findings_ = self._verdicts(named)
        self.origin_stage_ = (
            None if self.locator_.origin_ is None else signals.stage_names[self.locator_.origin_]
        )
        self._show(recording)
        self._tick("model", started)
        self.timings_["total"] = round(time.perf_counter() - started, 2)
        return self

    def _window(self, recording: Recording) -> Recording:
        """The recording, or its most excited stretch of :attr:`max_rows` rows (sets
        :attr:`window_`)."""
        columns = sorted(
            {self.config.signals[i].column for s in self.config.stages for i in s.inputs}
        )
        present = [c for c in columns if c in recording.names]
        self.window_ = (
            most_excited([recording[c] for c in present], self.max_rows) if present else None
        )
        if self.window_ is None:
            return recording
        self.progress(
            f"diagnosing rows {self.window_.first}-{self.window_.last} of {recording.n_samples} "
            f"(the stretch whose inputs vary most; {self.window_.share_of_excitation:.0%} of the "
            "recording's excitation)"
        )
        time = recording.time
        return recording.slice_time(time[self.window_.first], time[self.window_.last])

    def _tick(self, step: str, started: float) -> None:
        done = sum(v for k, v in self.timings_.items())
        self.timings_[step] = round(time.perf_counter() - started - done, 2)

    # ------------------------------------------------------------------ steps
    def _locate(self, recording: Recording, wb: np.ndarray) -> None:
        self.progress("locating the residual")
        columns = {c: recording[c] for c in recording.names}
        self.regimes_ = regime_signals(self.signals_, columns, recording.dt)
        self.locator_ = Locator().fit(self.experiment_, self.signals_, wb, self.regimes_)

    def _name(self, archive: FmuArchive, signals: SignalMap, experiment: Experiment) -> np.ndarray:
        self.progress("generating hypotheses")
        scales = data_scales(archive, signals, experiment, self.screen_rows)
        self.hypotheses_ = generate_hypotheses(signals, archive, scales, experiment.parameters)
        self.progress(f"testing {len(self.hypotheses_)} hypotheses")
        with Simulator(experiment, self.workers, self.cluster) as simulator:
            selection = ForwardSelection(
                screen_rows=self.screen_rows, max_findings=self.max_findings
            ).fit(simulator, self.hypotheses_)
            selected = selection.selected_
            prefixes = [selection.baseline_.simulated]
            if selected.hypotheses:
                pairs = list(zip(selected.hypotheses, selected.split(), strict=True))
                partial = [
                    [t for h, th in pairs[:i] for t in h.terms(th)] for i in range(1, len(pairs))
                ]
                prefixes += [*simulator.run(partial), selected.simulated]
            self.simulations_ += simulator.runs
        self.selection_ = selection
        self.prefixes_ = prefixes
        return selected.simulated if selected.hypotheses else prefixes[0]

    def _verdicts(self, named: np.ndarray) -> list[Finding]:
        stages = self.locator_.stages_
        if self.locator_.origin_ is None:
            return [none_finding(stages)]
        experiment = self.experiment_
        found: list[Finding] = []
        if self.selection_ is not None and self.selection_.selected_.hypotheses:
            units = {s.column: s.unit for s in self.config.signals.values()}
            found = named_findings(
                experiment, self.selection_, self.prefixes_, stages, self.regimes_, units
            )
        rest = experiment.residual(named[experiment.train_rows :], experiment.train_rows)
        wb = self.simulated_["whitebox"]
        for stage in stages:
            cols = [j for j, s in enumerate(experiment.stages) if s == stage.index]
            if not cols or not stage.significant:
                continue
            ratio = float(np.max(np.sqrt(np.mean(rest[:, cols] ** 2, axis=0))))
            before, after = stage_structure(experiment, wb, named, stage.index)
            remaining = after / before if before else 0.0
            if not found or (ratio > 2.0 and remaining > 0.2):
                j = cols[0]
                sig = self.signals_.observed[j]
                held = slice(experiment.train_rows, None)
                rms = rmse(named[held, j], experiment.recorded[held, j])
                why = self._nothing_tested()
                found.append(unexplained_finding(stage, ratio, remaining, sig.unit, rms, why))
                break
        return found

    def _nothing_tested(self) -> str:
        """Why no hypothesis was fitted although a stage departs, when that is the reason the
        verdict is "unexplained" (else empty): the rows fitted agree with the white-box within
        noise, and the departure lies in the held-out rows only."""
        if self.selection_ is None or self.selection_.rounds_:
            return ""
        experiment = self.experiment_
        fitted = experiment.train_rows * experiment.dt
        return (
            f"No hypothesis could be tested: the first {fitted:.3g} s of the recording (the rows "
            "hypotheses are fitted to) agree with the white-box within its noise, and the "
            f"departure lies in the last {experiment.n_samples * experiment.dt - fitted:.3g} s, "
            "held out to test what is found. Diagnose a recording that shows it over more of "
            "its length."
        )

    def _show(self, recording: Recording) -> None:
        """Grey-box on the named terms, and the held-out fit table."""
        experiment = self.experiment_
        targets = [j for j, s in enumerate(self.signals_.observed) if s.is_target]
        names = self.signals_.stage_names
        train = experiment.train_rows
        self.fit_ = {}
        recorded = experiment.recorded[:, targets]
        wb = self.simulated_["whitebox"][:, targets]
        named = self.simulated_["named"][:, targets]
        gb = None
        self.parts_ = None
        both = self.simulated_["named"] is not self.simulated_["whitebox"]
        if self.greybox is not None:
            self.progress(
                "training the grey-box on the named model"
                + (" and, side by side, on the white-box (correctors alone)" if both else "")
            )
            on = [named, wb] if both else [named]
            runs = run_side_by_side(
                [functools.partial(self._greybox, recording, y, recorded, train) for y in on]
            )
            gb = self.simulated_["greybox"] = runs[0]
        if gb is not None and both:
            alone = runs[1]
            self.parts_ = compare_parts(
                names,
                recorded[train:],
                {"correctors": alone, "terms": named[train:], "terms+correctors": gb},
                {name: float(np.std(recorded[:train, q])) for q, name in enumerate(names)},
                train,
                judge=ResidualJudge(
                    experiment.sigma[targets],
                    None if experiment.whitening is None else experiment.whitening.columns(targets),
                ),
            )
        for q, name in enumerate(names):
            rec = recorded[train:, q]
            row = {
                "wb_rmse": rmse(wb[train:, q], rec),
                "named_rmse": rmse(named[train:, q], rec),
                "noise": float(experiment.sigma[targets[q]]),
                "unit": self.signals_.observed[targets[q]].unit,
            }
            row["named_improvement"] = improvement(row["wb_rmse"], row["named_rmse"])
            if gb is not None:
                row["gb_rmse"] = rmse(gb[:, q], rec)
                row["gb_improvement"] = improvement(row["wb_rmse"], row["gb_rmse"])
            if self.parts_ is not None:
                row["correctors_rmse"] = self.parts_.stages[name]["correctors_rmse"]
                row["best"] = self.parts_.stages[name]["best"]
            self.fit_[name] = row

    def _greybox(
        self, recording: Recording, named: np.ndarray, recorded: np.ndarray, train: int
    ) -> np.ndarray:
        """The grey-box on ``named`` (shape (n, Q)) trained on the first ``train`` rows, free-run
        over the rest: its means, shape (n - train, Q). No band is shown, so its σ is not
        calibrated (a free run's means do not depend on the calibration)."""
        config = self.config
        settings = self.greybox
        gp = dataclasses.replace(
            config.gp,
            inducing=min(config.gp.inducing, settings.inducing),
            max_iter=min(config.gp.max_iter, settings.max_iter),
            max_train_samples=min(config.gp.max_train_samples, settings.max_train_samples),
        )
        chain = GreyBoxChain(dataclasses.replace(config, gp=gp), calibrate=False)
        exo = np.column_stack([recording[config.signals[s].column] for s in chain.exo_names])
        chain.fit(exo[:train], named[:train], recorded[:train])
        mean, _ = chain.free_run(exo, named, recorded, train - 1)
        return mean


def data_scales(
    archive: FmuArchive, signals: SignalMap, experiment: Experiment, rows: int
) -> DataScales:
    """Typical signal sizes: recorded inputs, and every FMU output simulated over a window.

    Also finds, for every force input and velocity output (and position output, through its
    rate), whether a positive input force opposes positive velocity (a small viscous probe
    through the FMU).
    """
    rows = min(rows, experiment.n_samples)
    outputs = real_outputs(archive)
    u = experiment.u[:rows]

    def run(terms: list) -> np.ndarray:
        return simulate_with_terms(
            archive,
            experiment.inputs,
            u,
            experiment.dt,
            outputs,
            terms,
            experiment.parameters,
            start_time=experiment.start_time,
        )

    y = run([])
    output_rms = {name: float(np.sqrt(np.mean(y[:, j] ** 2))) for j, name in enumerate(outputs)}
    rates = {
        name: np.gradient(y[:, outputs.index(name)], experiment.dt)
        for name in signals.outputs_with_role("position")
        if name in outputs
    }
    input_rms = {
        name: float(np.sqrt(np.mean(experiment.u[:, j] ** 2)))
        for j, name in enumerate(experiment.inputs)
    }
    sense: dict[tuple[str, str], float] = {}
    sources = [(v, y[:, outputs.index(v)], False) for v in signals.outputs_with_role("velocity")]
    sources += [(p, rate, True) for p, rate in rates.items()]
    for force in signals.inputs_with_role("force"):
        for source, velocity, rate in sources:
            v_rms = float(np.sqrt(np.mean(velocity**2)))
            if v_rms <= 0:
                continue
            c = 0.05 * max(input_rms.get(force, 0.0), 1e-12) / v_rms
            probe = run([ViscousForce(input=force, source=source, coefficient=c, rate=rate)])
            j = outputs.index(source)
            moved = probe[:, j] - y[:, j]
            change = float(np.dot(velocity, np.gradient(moved, experiment.dt) if rate else moved))
            sense[(force, source)] = 1.0 if change <= 0 else -1.0
    return DataScales(
        input_rms,
        output_rms,
        experiment.dt,
        sense,
        input_span={
            name: (float(np.min(experiment.u[:, j])), float(np.max(experiment.u[:, j])))
            for j, name in enumerate(experiment.inputs)
        },
        output_start={name: float(y[0, j]) for j, name in enumerate(outputs)},
        rate_rms={name: float(np.sqrt(np.mean(rate**2))) for name, rate in rates.items()},
    )
