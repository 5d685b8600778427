"""Train the grey-box of a project on a recording (the ``train`` command)."""

from __future__ import annotations

import dataclasses
import functools
import threading
import time
from collections.abc import Mapping, Sequence

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.errors import ConfigError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.integrator import whitebox_facts
from fmu_greybox.fmi.kinds import one_instance_per_process
from fmu_greybox.model.chain import GreyBoxChain, RecordedRun
from fmu_greybox.model.domain import training_ranges
from fmu_greybox.model.fit_cache import FitCache
from fmu_greybox.model.stage_data import estimate_noise, prepare
from fmu_greybox.model.store import GreyBoxModel, file_sha256
from fmu_greybox.model.terms import Term
from fmu_greybox.model.training import TrainingRecord
from fmu_greybox.model.whitebox import check_terms
from fmu_greybox.progress import Progress, announce
from fmu_greybox.project.config import BEST, ProjectConfig
from fmu_greybox.project.data import check_sample_time, split_row, whitebox_path
from fmu_greybox.project.fingerprint import (
    copy_message,
    data_rows,
    find_copy,
    fingerprint,
    recorded_rows,
)
from fmu_greybox.side_by_side import run_side_by_side
from fmu_greybox.workflow.parts import (
    FittedModel,
    PartsComparison,
    check_ship,
    compare_fitted,
    has_corrector,
    has_terms,
)

#: Fewest rows a model is trained on: fewer cannot pin down a corrector's hyperparameters, and
#: the free-run checks of training need a tail of them.
MIN_TRAIN_ROWS = 100


def with_inducing(
    config: ProjectConfig, inducing: int | None, max_iter: int | None = None
) -> ProjectConfig:
    """The project with another number of inducing points and, if given, another iteration
    cap (``None`` keeps the project's)."""
    changes = {k: v for k, v in (("inducing", inducing), ("max_iter", max_iter)) if v is not None}
    return dataclasses.replace(config, gp=dataclasses.replace(config.gp, **changes))


def train_model(
    config: ProjectConfig,
    recording: Recording,
    progress: bool = False,
    target_mode: str | None = None,
    terms: Sequence[Term] = (),
    ship: str = "best",
    calibration_recordings: Sequence[Recording] = (),
) -> GreyBoxModel:
    """Simulate the white-box over the recording and fit every stage's corrector.

    The leading ``config.train_fraction`` of the recording trains; the rest stays held out for
    ``validate``. The uncertainty is calibrated on ``calibration_recordings`` when given, else
    on the two halves of the training rows
    (:meth:`~fmu_greybox.model.chain.GreyBoxChain.fit`). With named ``terms``, the
    white-box, the terms, the correctors and both are first compared stage by stage, forward
    in time (:func:`compare_parts_forward`); the model ships on each stage the part ``ship``
    names, by default the stage's best (:func:`~fmu_greybox.workflow.parts.choose_stage_part`),
    trained on all the training rows, and ``training.parts`` keeps the comparison.

    Parameters
    ----------
    config : ProjectConfig
    recording : Recording
    progress : bool
        Show progress bars (simulation, then one per stage's optimisation).
    target_mode : str, optional
        Overrides ``config.gp.target``.
    terms : sequence of Term
        Named correction terms (from a diagnosis) folded into the white-box first: the
        correctors then learn what white-box + terms leave, and the model carries the terms.
    ship : str
        One of :data:`~fmu_greybox.workflow.parts.SHIP_CHOICES` (used with ``terms`` only).
    calibration_recordings : sequence of Recording
        Recordings no corrector is trained on, each free-run whole by the model that ships to
        calibrate its σ. Their rows are not scored by ``validate`` (``trained_rows``).

    Returns
    -------
    GreyBoxModel

    Raises
    ------
    ConfigError
        Fewer than :data:`MIN_TRAIN_ROWS` training rows, or more inducing points than
        training rows per stage (the message names the field to change), or an unknown
        ``ship``, a calibration recording of fewer than :data:`MIN_TRAIN_ROWS` rows, or one
        that is the training recording, or another calibration recording, again
        (:func:`check_independent_calibration`).
    RecordingError
        A calibration recording sampled at another step than the training recording.
    """
    check_ship(ship)
    for other in calibration_recordings:
        check_calibration_recording(recording, other)
    check_independent_calibration(recording, calibration_recordings)
    if not terms:
        return fit_model(
            config,
            recording,
            progress,
            target_mode,
            terms,
            calibrate_on=calibration_recordings,
            correct=stage_correctors(config),
        ).model
    fits = FitCache()  # the passes share the fits that nothing tells apart
    comparison, seconds, compared = compare_parts_forward(
        config, recording, progress, target_mode, terms, ship, fits
    )
    names = list(comparison.shipped)
    parts = [comparison.shipped[name] for name in names]
    announce(
        "Training pass 3 of 3: the model that ships ("
        + ", ".join(f"{name} {part}" for name, part in zip(names, parts, strict=True))
        + f"), on all the training rows, with the compared chains' choice of targets (about "
        f"{seconds:.0f} s left)",
        progress,
    )
    fitted = fit_model(
        config,
        recording,
        progress,
        target_mode,
        terms_per_stage(terms, parts),
        calibrate_on=calibration_recordings,
        targets_from={
            name: compared["terms" if has_terms(part) else "correctors"].model.chain
            for name, part in zip(names, parts, strict=True)
        },
        correct=[has_corrector(part) for part in parts],
        fits=fits,
    )
    model = fitted.model
    model.training = dataclasses.replace(
        model.training,
        parts=comparison.to_dict(),
        seconds=round(model.training.seconds + seconds, 2),
    )
    return model


def stage_correctors(config: ProjectConfig) -> list[bool]:
    """Per stage, whether its corrector may be used when no named terms are given: unless its
    ``ship`` setting names a part without one.

    Raises
    ------
    ConfigError
        A stage ships named terms, and there are none (naming the stage's field).
    """
    for i, stage in enumerate(config.stages):
        if has_terms(stage.ship):
            raise ConfigError(
                f"stage {stage.name} ships {stage.ship!r}, but no named terms were given; train "
                "with --terms DIAGNOSIS.json, or set its ship to 'correctors' or 'white-box'",
                field=f"stages[{i}].ship",
                path=str(config.path) if config.path else None,
            )
    return [stage.ship in (BEST, "correctors") for stage in config.stages]


def terms_per_stage(terms: Sequence[Term], parts: Sequence[str]) -> list[Term]:
    """The named terms as a model whose stages ship ``parts`` carries them: each term off on
    the stages whose part has no terms (``stages_off``); none at all when no stage has them.

    Parameters
    ----------
    terms : sequence of Term
    parts : sequence of str
        Per stage, the part shipped (:data:`~fmu_greybox.workflow.parts.STAGE_PARTS`).

    Returns
    -------
    list of Term
    """
    off = tuple(q for q, part in enumerate(parts) if not has_terms(part))
    if len(off) == len(parts):
        return []
    return [dataclasses.replace(t, stages_off=tuple(q for q in off if q >= t.entry)) for t in terms]


def compare_parts_forward(
    config: ProjectConfig,
    recording: Recording,
    progress: bool,
    target_mode: str | None,
    terms: Sequence[Term],
    ship: str,
    fits: FitCache | None = None,
) -> tuple[PartsComparison, float, dict[str, FittedModel]]:
    """Correctors alone, ``terms`` alone and both, compared forward in time: correctors
    trained on the first half of the training rows (:func:`comparison_config`), every part
    free-run from the first row and scored on every later row
    (:func:`~fmu_greybox.workflow.parts.compare_fitted`), judged in noise units and whitened
    against the drift the inputs' noise drives
    (:func:`~fmu_greybox.model.stage_data.estimate_noise`). ``fits``: shared by the two chains
    (and with the model that ships), so that a stage both see alike is fitted once.

    Returns
    -------
    PartsComparison
        ``shipped``: the part ``ship`` names (one of
        :data:`~fmu_greybox.workflow.parts.SHIP_CHOICES`; for ``best``, ``terms+correctors``
        when the data cannot decide).
    float
        Seconds the two comparison chains took to train (side by side).
    dict of str to FittedModel
        The two chains: ``"terms"`` (correctors on the white-box with ``terms``) and
        ``"correctors"`` (on the plain white-box); the model shipped takes the target modes of one
        of them (``fit_model``'s ``targets_from``).
    """
    early = comparison_config(config, GreyBoxChain(config, target_mode), recording.n_samples)
    with open_fmu(whitebox_path(config)) as archive:
        # each pass runs the white-box: one after the other where it allows one instance only
        once = one_instance_per_process(archive.model_description, archive.kind)
        announce(
            "Training passes 1 and 2 of 3, "
            + ("one after the other" if once else "side by side")
            + ", on the first half of the training rows (to compare the parts): correctors on "
            "the white-box with named terms (1), and on the plain white-box (2)",
            progress,
        )
        # the parts are compared by their means: no σ to calibrate
        named, plain = run_side_by_side(
            [
                functools.partial(
                    fit_model,
                    early,
                    recording,
                    progress,
                    target_mode,
                    chosen,
                    calibrate=False,
                    fade=False,  # stand-ins for the chain trained on all the rows
                    stand_in=True,
                    pass_=pass_,
                    fits=fits,
                )
                for chosen, pass_ in ((terms, "pass 1"), ((), "pass 2"))
            ],
            workers=1 if once else None,
        )
        noise = estimate_noise(config, named.model.chain, archive, named.data, terms)
    seconds = max(named.model.training.seconds, plain.model.training.seconds)
    judge = None if noise is None else noise.judge()
    comparison = compare_fitted(named, plain, ship, judge)
    return comparison, seconds, {"terms": named, "correctors": plain}


def comparison_config(config: ProjectConfig, chain: GreyBoxChain, n: int) -> ProjectConfig:
    """The project the parts are compared with: training on the first half of the training
    rows, with no more inducing points than those rows hold per stage. When half of them is
    fewer than :data:`MIN_TRAIN_ROWS`, the project itself (the parts are then compared on the
    rows it holds out)."""
    half = dataclasses.replace(config, train_fraction=config.train_fraction / 2)
    rows = split_row(half, n) + 1
    if rows < MIN_TRAIN_ROWS:
        return config
    per_stage = min(rows - chain.history, config.gp.max_train_samples)
    return with_inducing(half, min(config.gp.inducing, per_stage))


def fit_model(
    config: ProjectConfig,
    recording: Recording,
    progress: bool,
    target_mode: str | None,
    terms: Sequence[Term],
    calibrate: bool = True,
    calibrate_on: Sequence[Recording] = (),
    targets_from: Mapping[str, GreyBoxChain] | None = None,
    correct: Sequence[bool] | None = None,
    fade: bool = True,
    pass_: str = "",
    fits: FitCache | None = None,
    stand_in: bool = False,
) -> FittedModel:
    """One chain of correctors on the white-box with ``terms`` (see :func:`train_model`);
    without ``calibrate``, its σ is the propagated variance (a chain used for its mean only).
    ``calibrate_on``: the calibration recordings (``train_model``'s
    ``calibration_recordings``); ``targets_from``: per stage, a chain fitted on part of the
    same rows whose target mode of that stage the fit takes; ``correct``: per stage, whether its
    corrector may be used (:meth:`~fmu_greybox.model.chain.GreyBoxChain.fit`); ``fade``:
    whether its correctors fade out of their domain
    (:class:`~fmu_greybox.model.chain.GreyBoxChain`); ``pass_``: which training pass this is,
    in words, for the progress lines; ``fits``: fits shared with the other passes
    (:class:`~fmu_greybox.model.fit_cache.FitCache`); ``stand_in``: the chain only chooses
    (its fits optimise on at most ``[gp] optimise_rows`` rows; ``GreyBoxChain``)."""
    started = time.perf_counter()
    fmu_path = whitebox_path(config)
    chain = GreyBoxChain(
        config, target_mode, calibrate=calibrate, fade=fade, fits=fits, stand_in=stand_in
    )
    check_training_size(config, chain, recording)
    with open_fmu(fmu_path) as archive:
        config.check_against_fmu(archive)
        check_terms(terms, archive, len(chain.stages))
        data = prepare(config, chain, archive, recording, progress, terms)
        calibration = [prepare(config, chain, archive, r, progress, terms) for r in calibrate_on]
    runs = [RecordedRun(d.exo, d.y_wb, d.outputs) for d in calibration]
    split = split_row(config, data.n_samples)
    rows = slice(0, split + 1)
    report = FitProgress(config.gp.max_iter, progress, pass_)
    chain.fit(
        data.exo[rows],
        data.y_wb[rows],
        data.outputs[rows],
        progress=report,
        calibration_runs=runs,
        targets_from=targets_from,
        correct=correct,
    )
    report.close()
    training = TrainingRecord(
        recording_sha256=recording.sha256(),
        recording_source=str(recording.source),
        n_samples=data.n_samples,
        train_rows=split + 1,
        dt=recording.dt,
        # the exported FMU's input domain is built from these (fmu_greybox/model/domain.py)
        input_ranges=training_ranges(data.binding.inputs, data.binding.matrix(recording)[rows]),
        target_std={
            name: float(np.std(data.outputs[rows, q])) for q, name in enumerate(chain.stage_names)
        },
        target_unit={s.name: config.signals[s.config.target].unit for s in chain.stages},
        bounds={
            s.name: float(c.bound_)
            for s, c in zip(chain.stages, chain.correctors_, strict=True)
            if c is not None
        },
        free_run_check=chain.free_run_check_,
        target_selection=chain.selection_,
        calibration_check=chain.calibration_check_,
        calibration_recordings=[
            {"sha256": r.sha256(), "source": str(r.source), "n_samples": r.n_samples}
            for r in calibrate_on
        ],
        whitebox_source=str(fmu_path),
        whitebox_sha256=file_sha256(fmu_path),
        # its kind, and how a model-exchange white-box was integrated (fmi/integrator.py)
        whitebox=whitebox_facts(archive.kind),
        seconds=round(time.perf_counter() - started, 2),
    )
    model = GreyBoxModel(
        config=config,
        chain=chain,
        whitebox_fmu=fmu_path,
        dt=recording.dt,
        training=training,
        terms=list(terms),
        trained_rows=fingerprint(
            np.concatenate([data_rows(d) for d in calibration] + [data_rows(data)[rows]])
        ),
    )
    return FittedModel(model, data, split)


class FitProgress:
    """The progress of a chain's fits, one :class:`~fmu_greybox.progress.Progress` per fit,
    for :meth:`~fmu_greybox.model.chain.GreyBoxChain.fit`'s ``progress`` (fits that run side
    by side each keep their own).

    Parameters
    ----------
    max_iter : int
        Iterations a fit takes at most.
    enabled : bool
        Show anything.
    pass_ : str
        Which training pass the fits belong to, in words (shown after each fit's label).
    """

    def __init__(self, max_iter: int, enabled: bool, pass_: str = "") -> None:
        self.max_iter = max_iter
        self.enabled = enabled
        self.pass_ = pass_
        self._open: dict[str, Progress] = {}
        self._lock = threading.Lock()

    def __call__(self, corrector: str, iteration: int, bound: float) -> None:
        label = f"Fitting the {corrector}" + (f" [{self.pass_}]" if self.pass_ else "")
        with self._lock:
            if iteration == 0:  # the fit is done
                shown = self._open.pop(label, None)
                if shown is not None:
                    shown.close()
                return
            shown = self._open.get(label)
            if shown is None:
                shown = Progress(label, self.max_iter, self.enabled, "iteration")
                self._open[label] = shown
            shown.update(bound=f"{bound:.4g}")

    def close(self) -> None:
        """Close what is still shown."""
        with self._lock:
            for shown in self._open.values():
                shown.close()
            self._open.clear()


def check_calibration_recording(training: Recording, other: Recording) -> None:
    """A calibration recording must be sampled as the training one and long enough.

    Raises
    ------
    RecordingError
        Another sample time (both named, and how to resample).
    ConfigError
        Fewer than :data:`MIN_TRAIN_ROWS` rows.
    """
    check_sample_time(other, training.dt, f"the training recording {training.source}")
    if other.n_samples < MIN_TRAIN_ROWS:
        raise ConfigError(
            f"calibration recording {other.source} has {other.n_samples} rows; a calibration "
            f"free run needs at least {MIN_TRAIN_ROWS}. Give a longer recording",
            field="--calibrate-on",
        )


def check_independent_calibration(training: Recording, others: Sequence[Recording]) -> None:
    """Calibration recordings must be other recordings than the training one and each other:
    a copy (also rounded, or with other time stamps) is recognised by its rows
    (:func:`~fmu_greybox.project.fingerprint.find_copy`).

    Raises
    ------
    ConfigError
        Naming the copy and the recording it copies.
    """
    if not others:
        return
    found = find_copy(recorded_rows([training, *others]))
    if found is not None:
        raise ConfigError(
            f"calibration recording {copy_message(*found)}: σ calibrated on the rows it was "
            "trained on claims a coverage it does not have. Calibrate on recordings made "
            "apart from the training one (another flight or test run), each given once",
            field="--calibrate-on",
        )


def check_training_size(config: ProjectConfig, chain: GreyBoxChain, recording: Recording) -> None:
    """Enough training rows for a model, and no more inducing points than rows.

    Raises
    ------
    ConfigError
        Naming ``split.train_fraction`` or ``gp.inducing`` and the numbers.
    """
    where = str(config.path) if config.path else None
    n = recording.n_samples
    rows = split_row(config, n) + 1
    if rows < MIN_TRAIN_ROWS:
        raise ConfigError(
            f"{config.train_fraction:g} of the {n} rows of {recording.source} leaves {rows} "
            f"training rows; a model needs at least {MIN_TRAIN_ROWS}. Raise train_fraction or "
            "train on a longer recording",
            field="split.train_fraction",
            path=where,
        )
    per_stage = min(rows - chain.history, config.gp.max_train_samples)
    if config.gp.inducing > per_stage:
        raise ConfigError(
            f"{config.gp.inducing} inducing points per stage, but a stage is trained on "
            f"{per_stage} rows ({rows} training rows less {chain.history} of history, at most "
            f"gp.max_train_samples = {config.gp.max_train_samples}); set gp.inducing (or "
            f"--inducing) to at most {per_stage}, or train on more rows",
            field="gp.inducing",
            path=where,
        )
