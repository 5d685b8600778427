"""The autoregressive grey-box: stage correctors chained in the paper's order.

:class:`GreyBoxChain` owns the stage layouts and their sparse-GP correctors. It is trained by
teacher forcing (:meth:`GreyBoxChain.fit`) and run one communication step at a time by its
compiled plan (:meth:`GreyBoxChain.plan`, :class:`~fmu_greybox.model.chain_step.ChainPlan`),
the same step serving the co-simulation master, the array-based free run used for validation,
and the exported FMU.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fmu_greybox.errors import ConfigError
from fmu_greybox.gp import SparseGPR
from fmu_greybox.model.calibration import (
    UNCALIBRATED,
    VarianceCalibration,
    calibration_rows,
    fit_calibration,
    left_out_shares,
)
from fmu_greybox.model.chain_step import ChainPlan, ChainState
from fmu_greybox.model.fit_cache import FitCache
from fmu_greybox.model.stage import TARGET_MODES, SourceLayout, StageLayout
from fmu_greybox.project.config import AUTO, ProjectConfig
from fmu_greybox.side_by_side import one_blas_thread, run_side_by_side

ProgressCallback = Callable[[str, int, float], None]
"""Called as ``progress(corrector, iteration, bound)`` after each optimiser iteration of a fit,
``corrector`` naming the fit in words, and once more with ``iteration = 0`` when that fit is
done. Fits may run side by side (:func:`~fmu_greybox.side_by_side.run_side_by_side`), so calls
for two fits can interleave, from two threads."""

#: Features are clipped to their training range widened by this share of the range.
RANGE_MARGIN = 0.05
#: Share of the training rows a stage with target "auto" is free-run over to choose.
SELECTION_TAIL = 0.2
#: Relative free-run RMSE gain that makes "increment" win over "residual".
SELECTION_MARGIN = 1e-3
#: The calibration's two folds: the first and the second half of the training rows.
CALIBRATION_HALVES = ("first", "second")


class GreyBoxChain:
    """The chain of stage correctors of a project.

    Parameters
    ----------
    config : ProjectConfig
        Stages, signals and GP settings.
    target_mode : str, optional
        Overrides ``config.gp.target``.
    check_tail : float or None
        Share of the training rows :meth:`fit` free-runs at its end to pass through the stages
        whose corrector loses to their white-box there (``None``: keep every corrector).
    calibrate : bool
        Estimate each stage's reported variance on rows its corrector was not fitted to
        (:attr:`calibration_`); ``False`` reports the propagated variance as it is.
    fade : bool
        Fade a corrector out where its features leave its domain
        (:mod:`~fmu_greybox.model.chain_step`). ``False`` for a chain trained on part of the
        rows to stand in for one trained on all of them, whose domain is larger: the
        calibration's halves (its free runs must err as the shipped chain would) and the
        comparison of the parts.
    fits : FitCache, optional
        Fits shared with the other chains of one training run: a corrector fitted to the same
        features and targets with the same settings is taken from there, not fitted again.
    stand_in : bool
        The chain is trained only to choose between alternatives (a stage's candidate targets,
        a part in ``train --terms``' comparison): its fits optimise their hyperparameters on at
        most ``[gp] optimise_rows`` rows, evenly spread. The chain that ships and the halves
        that calibrate its σ optimise on every row: its band holds on fewer recordings when
        they do not (measured in ``docs/greybox.md``).

    Attributes
    ----------
    stages : list of StageLayout
        In autoregressive order; derived from the settings, with the target mode each stage
        was fitted with once :meth:`fit` has chosen it (``"auto"`` resolved).
    exo_names : list of str
        Signals forming the chain's exogenous vector (union of the stages' inputs).
    correctors_ : list of SparseGPR or None
        Fitted correctors, one per stage (after :meth:`fit` or loading); ``None`` for a stage
        that :meth:`fit` was told to pass through (``correct``) and nothing else needs.
    active_ : ndarray of bool, shape (Q,)
        Stages whose corrector is used; a stage found to free-run worse than its white-box on
        the tail of its training data is passed through (see :meth:`fit`).
    free_run_check_ : dict
        Stage -> ``{"wb_rmse", "gb_rmse", "active"}`` of that check (empty without it).
    selection_ : dict
        Stage -> free-run RMSE of each candidate target and the one chosen, for stages whose
        target is ``"auto"``.
    feature_bounds_ : list of ndarray, each shape (2, D_q)
        Per stage, the training range of each feature (widened by :data:`RANGE_MARGIN`);
        features are clipped to it when the chain steps, so a free run never extrapolates.
    calibration_ : list of VarianceCalibration
        Per stage, the reported variance ``a V + b`` of its output (V: the propagated
        variance; see :mod:`fmu_greybox.model.calibration` and :meth:`fit`);
        :data:`~fmu_greybox.model.calibration.UNCALIBRATED` until fitted.
    calibration_check_ : dict
        Stage -> rows, the held-out residual's RMSE and the shipped chain's median propagated
        standard deviation on the rows the calibration was estimated on, what those rows are
        worth in independent ones, how many free runs they came from and their ``source``
        (``"halves"`` of the training rows or calibration ``"recordings"``), and each free
        run's share inside ±1.96σ with σ calibrated on the others
        (``free_run_shares``, :func:`~fmu_greybox.model.calibration.left_out_shares`); empty
        without it.
    """

    def __init__(
        self,
        config: ProjectConfig,
        target_mode: str | None = None,
        check_tail: float | None = SELECTION_TAIL,
        calibrate: bool = True,
        fade: bool = True,
        fits: FitCache | None = None,
        stand_in: bool = False,
    ) -> None:
        mode = target_mode or config.gp.target
        if mode not in (*TARGET_MODES, AUTO):
            raise ConfigError(
                f"{mode!r} is not one of {', '.join((*TARGET_MODES, AUTO))}", field="gp.target"
            )
        self.config = config
        self.target_mode = mode
        self.check_tail = check_tail
        self.calibrate = calibrate
        self.fade = fade
        self.fits = fits
        self.stand_in = stand_in
        self.exo_names: list[str] = []
        for stage in config.stages:
            self.exo_names += [s for s in stage.inputs if s not in self.exo_names]
        self.stages = self._layouts()
        self.layout = SourceLayout(
            n_exo=len(self.exo_names),
            n_stages=len(self.stages),
            depth=max(1, *(s.depth for s in self.stages)),
        )
        self.correctors_: list[SparseGPR | None] = []
        self.feature_bounds_: list[np.ndarray | None] = []
        self.active_ = np.ones(len(self.stages), dtype=bool)
        self.free_run_check_: dict[str, dict[str, float]] = {}
        self.selection_: dict[str, dict[str, float]] = {}
        self.calibration_: list[VarianceCalibration] = [UNCALIBRATED] * len(self.stages)
        self.calibration_check_: dict[str, dict[str, float]] = {}

    def _layouts(self) -> list[StageLayout]:
        """The stage layouts as the settings give them (target ``"auto"`` not yet chosen)."""
        names = [s.name for s in self.config.stages]
        return [
            StageLayout(
                config=s,
                target_mode=s.target_mode or self.target_mode,
                exo_index=np.array([self.exo_names.index(i) for i in s.inputs], dtype=int),
                stage_index=q,
                feed_index=np.array([names.index(f) for f in s.feeds_from], dtype=int),
            )
            for q, s in enumerate(self.config.stages)
        ]

    # ------------------------------------------------------------------ names
    @property
    def stage_names(self) -> list[str]:
        """Stage names in order."""
        return [s.name for s in self.stages]

    @property
    def passed_through(self) -> list[str]:
        """Names of the stages whose corrector is switched off (``active_`` false)."""
        return [n for n, on in zip(self.stage_names, self.active_, strict=True) if not on]

    @property
    def target_signals(self) -> list[str]:
        """Recorded signal of each stage."""
        return [s.config.target for s in self.stages]

    @property
    def whitebox_outputs(self) -> list[str]:
        """White-box FMU output of each stage."""
        return [s.config.whitebox_output for s in self.stages]

    @property
    def history(self) -> int:
        """Rows of known data :meth:`start` uses: the history of outputs and of the inputs
        before them, and the longest memory."""
        return max(self.layout.depth + 2, *(s.memory_length for s in self.stages))

    def feature_names(self, q: int) -> list[str]:
        """Feature names of stage ``q``."""
        return self.stages[q].feature_names(self.exo_names, self.stage_names)

    # ------------------------------------------------------------------ training
    def fit(
        self,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
        progress: ProgressCallback | None = None,
        calibration_runs: Sequence[RecordedRun] = (),
        targets_from: Mapping[str, GreyBoxChain] | None = None,
        correct: Sequence[bool] | None = None,
    ) -> GreyBoxChain:
        """Train every stage, in chain order.

        A stage's own memory and target come from the recorded outputs (teacher forcing). The
        earlier stages' outputs in its features come from the recording, or with ``[gp] feeds =
        "free_run"`` from the earlier (already trained) stages' own free run over the same rows, as
        the stage will see them when it runs. A stage whose target is ``"auto"`` is trained both as
        ``residual`` and ``increment`` on the leading rows, each free-run with the stages before it
        over the last :data:`SELECTION_TAIL` of the rows, and takes ``increment`` only where that
        free run's RMSE is lower by more than :data:`SELECTION_MARGIN`; then it is trained on all
        rows (from the usual start: a warm start at the chosen candidate's hyperparameters changes
        which corrector passes the free-run check below, measured in ``docs/speed.md``). The two
        candidates are trained side by side. Given ``targets_from``, per stage a chain already
        fitted to the same stage (on other rows of the same recording), every stage takes its target
        mode instead. Stages that ``correct`` says not to correct are passed through and get no
        corrector (a later stage fed by their free run sees their white-box, as it will when it
        runs). Last, unless ``check_tail`` is ``None``, the chain is free-run over that share of the
        rows and every stage that does not beat its white-box there is passed through too
        (:attr:`active_`), so the grey-box is never knowingly worse than the model it corrects.
        Then, with ``calibrate``, each stage's reported variance is estimated (:attr:`calibration_`)
        by two-fold cross-validation: each half of the rows is free-run by a chain whose correctors
        were trained (hyperparameters and all, the two halves side by side) on the other half only,
        so no corrector has seen the rows it predicts (hyperparameters taken from this chain instead
        make the held-out residuals too small: measured in ``docs/speed.md``), on at most half the
        rows this chain's correctors hold (``[gp] max_train_samples``), as on a recording short
        enough for every row to count: a half then stands for a chain trained on half the data
        however long the recording, and a 10-minute flight test calibrates at half the cost.
        Each of those residuals is paired with the propagated variance that this chain, trained on
        all rows, reports at the same row (its own free run over the half): that is the variance
        ``a`` will scale when the chain ships, and a corrector trained on half the rows usually
        reports a larger one. The pairs of both halves give ``a`` and ``b``
        (:func:`~fmu_greybox.model.calibration.fit_calibration`), stage by stage in chain order (a
        stage's propagated variance holds the calibrated variances of the stages feeding it). Given
        ``calibration_runs``, recordings no corrector is trained on, the calibration takes their
        residuals instead: each is free-run from its first rows by this chain, the one that ships,
        so its residuals and variances are those a bench will see and no half-trained corrector
        biases them; and every one is a separate free run, so a drift that lasts seconds is repeated
        once per recording. The settings given to the constructor are not changed: a refit chooses
        ``"auto"`` targets again.

        Parameters
        ----------
        exo : ndarray, shape (n, n_exo)
            Exogenous inputs per row (columns as :attr:`exo_names`).
        y_wb : ndarray, shape (n, Q)
            White-box predictions of the stage outputs.
        outputs : ndarray, shape (n, Q)
            Recorded stage outputs.
        progress : callable, optional
            Called as ``progress(corrector, iteration, bound)`` during optimisation;
            ``corrector`` names the fit in words (``"EHV corrector"``, or with what a fit on
            the leading rows is for).
        calibration_runs : sequence of RecordedRun
            Recordings to calibrate the uncertainty on, instead of the two halves of the
            training rows (each longer than :attr:`history` rows).
        targets_from : mapping of str to GreyBoxChain, optional
            Stage name -> a fitted chain of the same project whose target mode of that stage
            this fit takes.
        correct : sequence of bool, optional
            Per stage, whether its corrector may be used (default: every stage's).

        Returns
        -------
        GreyBoxChain
            ``self``, with :attr:`correctors_` set.
        """
        self.stages = self._layouts()
        q_count = len(self.stages)
        self.correctors_ = [None] * q_count
        self.feature_bounds_ = [None] * q_count
        self.active_ = np.ones(q_count, dtype=bool)
        self.selection_ = {}
        self.free_run_check_ = {}
        self.calibration_ = [UNCALIBRATED] * q_count
        self.calibration_check_ = {}
        allowed = np.ones(q_count, dtype=bool) if correct is None else np.asarray(correct, bool)
        with one_blas_thread():  # the parallelism is in the fits side by side
            for q, stage in enumerate(self.stages):
                if targets_from is not None:
                    source = targets_from[stage.name]
                    stage.target_mode = source.stages[q].target_mode
                    if stage.name in source.selection_:
                        self.selection_[stage.name] = source.selection_[stage.name]
                elif stage.target_mode == AUTO:
                    stage.target_mode = self._choose_target(q, exo, y_wb, outputs, progress)
                # a stage passed through from the start gets no corrector: it would never run
                label = f"{stage.name} corrector" if allowed[q] else None
                self._fit_stage(q, exo, y_wb, outputs, progress, label)
            self.active_[:] = allowed
            if self.check_tail is not None:
                self.free_run_check_ = self._check_free_run(exo, y_wb, outputs, self.check_tail)
            if self.calibrate:
                self._calibrate(RecordedRun(exo, y_wb, outputs), progress, calibration_runs)
        return self

    def _fit_stage(
        self,
        q: int,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
        progress: ProgressCallback | None,
        label: str | None,
        limit: int | None = None,
    ) -> None:
        """Fit stage ``q``'s corrector on the rows given (the stages before it are fitted),
        evenly thinned to at most ``limit`` rows (default ``[gp] max_train_samples``); with
        ``label`` ``None`` only its feature range is set and it keeps no corrector."""
        gp = self.config.gp
        stage = self.stages[q]
        fed = self._fed(q, exo, y_wb, outputs) if gp.feeds == "free_run" and q else None
        X, t = stage.teacher_forced(self.layout, exo, y_wb, outputs, fed)
        X, t = _thin(X, t, gp.max_train_samples if limit is None else limit)
        self.feature_bounds_[q] = _widened_range(X)
        if label is None:
            self.correctors_[q] = None
            return
        corrector = SparseGPR(
            n_inducing=min(gp.inducing, t.size),
            inducing=gp.inducing_method,
            max_iter=gp.max_iter,
            optimise_rows=gp.optimise_rows if self.stand_in else None,
            seed=gp.seed,
        )
        callback = _stage_progress(progress, label) if progress is not None else None
        if self.fits is None:
            self.correctors_[q] = corrector.fit(X, t, progress=callback)
        else:
            self.correctors_[q], reused = self.fits.fit(
                corrector, X, t, lambda: corrector.fit(X, t, progress=callback)
            )
            label += " (the same fit as another pass's)" if reused else ""
        if progress is not None:
            progress(label, 0, self.correctors_[q].bound_)  # this fit is done

    @contextlib.contextmanager
    def _correcting_first(self, count: int) -> Iterator[None]:
        """Run only the first ``count`` stages' correctors (the rest, and a stage without a
        corrector, pass the white-box through) inside the block; :attr:`active_` is restored
        after it. A later stage trained on an earlier one's free run (``[gp] feeds =
        "free_run"``) so sees it as it will run: a stage passed through from the start feeds
        its white-box."""
        kept = self.active_.copy()
        fitted = np.array([c is not None for c in self.correctors_], dtype=bool)
        self.active_[:] = (np.arange(len(self.stages)) < count) & fitted
        try:
            yield
        finally:
            self.active_[:] = kept

    def _fed(self, q: int, exo: np.ndarray, y_wb: np.ndarray, outputs: np.ndarray) -> np.ndarray:
        """The recorded outputs with the stages before ``q`` replaced by their free run."""
        start = self.history - 1
        with self._correcting_first(q):
            mean, _ = self.free_run(exo, y_wb, outputs, start)
        fed = outputs.copy()
        fed[start + 1 :, :q] = mean[:, :q]
        return fed

    def _choose_target(
        self,
        q: int,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
        progress: ProgressCallback | None,
    ) -> str:
        """``residual`` or ``increment`` for stage ``q`` (see :meth:`fit`)."""
        stage = self.stages[q]
        split = max(self.history + 2, int((1.0 - SELECTION_TAIL) * exo.shape[0]))
        modes = ("residual", "increment")
        tried = run_side_by_side(
            [
                functools.partial(self._candidate, q, mode, exo, y_wb, outputs, split, progress)
                for mode in modes
            ]
        )
        errors = dict(zip(modes, tried, strict=True))
        better = errors["increment"] < (1.0 - SELECTION_MARGIN) * errors["residual"]
        chosen = "increment" if better else "residual"
        self.selection_[stage.name] = {**errors, "chosen": chosen}
        return chosen

    def _candidate(
        self,
        q: int,
        mode: str,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
        split: int,
        progress: ProgressCallback | None,
    ) -> float:
        """Stage ``q`` with target ``mode`` trained on the rows before ``split`` and free-run
        with the stages before it over the rest: that free run's RMSE. Works on a copy of
        the chain, so candidates can run side by side."""
        chain = self._copy()
        chain.stand_in = True
        chain.stages = list(self.stages)
        chain.stages[q] = copy.copy(self.stages[q])
        chain.stages[q].target_mode = mode
        head = slice(0, split)
        label = f"{self.stages[q].name} corrector on the leading rows, {mode} target (to choose it)"
        chain._fit_stage(q, exo[head], y_wb[head], outputs[head], progress, label)
        with chain._correcting_first(q + 1):
            mean, _ = chain.free_run(exo, y_wb, outputs, split - 1)
        return float(np.sqrt(np.mean((mean[:, q] - outputs[split:, q]) ** 2)))

    def _copy(self) -> GreyBoxChain:
        """A copy whose correctors, feature ranges and active stages can change on their own
        (the fitted correctors themselves are shared, not copied), to be trained on part of the
        rows as a stand-in for this chain: it does not fade (``fade``)."""
        chain = copy.copy(self)
        chain.fade = False
        chain.correctors_ = list(self.correctors_)
        chain.feature_bounds_ = list(self.feature_bounds_)
        chain.active_ = self.active_.copy()
        return chain

    def _calibrate(
        self,
        training: RecordedRun,
        progress: ProgressCallback | None,
        calibration_runs: Sequence[RecordedRun] = (),
    ) -> None:
        """Set :attr:`calibration_` and :attr:`calibration_check_` (see :meth:`fit`).

        Parameters
        ----------
        training : RecordedRun
            The training rows, as given to :meth:`fit`.
        progress : callable, optional
        calibration_runs : sequence of RecordedRun
            As for :meth:`fit`.
        """
        if calibration_runs:
            folds = [(self, run, self.history, run.rows) for run in calibration_runs]
        else:
            folds = self._halves(training, progress)
        calibration = [UNCALIBRATED] * len(self.stages)
        # a free run's means do not depend on the calibration (the variances propagate to first
        # order beside them): each fold's held-out chain runs once; the folds' free runs go
        # side by side (the compiled run releases the GIL and has its own scratch)
        held_out = run_side_by_side([functools.partial(_fold_means, self, *fold) for fold in folds])
        for q, name in enumerate(self.stage_names):
            residual, latent_var, whitebox = [], [], []
            self.calibration_ = calibration  # the stages before q already calibrated
            runs = run_side_by_side(
                [
                    functools.partial(self.free_run_variances, *run.head(stop), first - 1)
                    for _, run, first, stop in folds
                ]
            )
            for (_, run, first, stop), means, shipped in zip(folds, held_out, runs, strict=True):
                means = shipped.mean if means is None else means
                residual.append(run.outputs[first:stop, q] - means[:, q])
                latent_var.append(shipped.latent_var[:, q])
                whitebox.append(run.outputs[first:stop, q] - run.y_wb[first:stop, q])
            shares = left_out_shares(residual, latent_var)
            residual, latent_var = np.concatenate(residual), np.concatenate(latent_var)
            whitebox = np.concatenate(whitebox)
            # what the stage reports where its corrector fades out: the white-box's residual,
            # calibrated as for a stage passed through
            faded = fit_calibration(whitebox, np.zeros_like(whitebox)).residual_variance
            calibration[q] = dataclasses.replace(
                fit_calibration(residual, latent_var), whitebox_variance=faded
            )
            std = np.sqrt(calibration[q].variance(latent_var))
            self.calibration_check_[name] = {
                "rows": int(residual.size),
                "rmse": float(np.sqrt(np.mean(residual**2))),
                "median_latent_std": float(np.median(np.sqrt(latent_var))),
                "independent_rows": calibration_rows(residual, std),
                "free_runs": len(folds),
                "source": "recordings" if calibration_runs else "halves",
                "free_run_shares": shares,
            }
        self.calibration_ = calibration

    def _halves(
        self, training: RecordedRun, progress: ProgressCallback | None
    ) -> list[tuple[GreyBoxChain, RecordedRun, int, int]]:
        """The two folds of a calibration on the training rows: each half, with a chain
        trained on the other half only (see :meth:`fit`).

        Returns
        -------
        list of (GreyBoxChain, RecordedRun, int, int)
            The chain that predicts the fold, the rows, its first and its stop row.
        """
        n = training.rows
        middle = max(self.history + 2, n // 2)
        halves = [(self.history, middle), (middle, n)]
        trained_on = [slice(middle, n), slice(0, middle)]  # the other half
        chains = run_side_by_side(
            [
                functools.partial(
                    self._trained_on, *training.slice(rows), progress, f"{other} half"
                )
                for rows, other in zip(trained_on, reversed(CALIBRATION_HALVES), strict=True)
            ]
        )
        return [
            (chain, training, first, stop)
            for chain, (first, stop) in zip(chains, halves, strict=True)
        ]

    def _trained_on(
        self,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
        progress: ProgressCallback | None,
        rows: str,
    ) -> GreyBoxChain:
        """A copy of the chain (its stages' target modes, the stages it passes through) with
        every other corrector trained on the rows given only, hyperparameters and all, on at
        most half the rows this chain's correctors hold (see :meth:`fit`).

        Parameters
        ----------
        exo, y_wb, outputs : ndarray
            Those rows.
        rows : str
            Which rows, in words (for ``progress``).
        """
        chain = self._copy()
        limit = max(1, self.config.gp.max_train_samples // 2)
        for q, stage in enumerate(self.stages):
            if self.active_[q]:  # a stage passed through has nothing to train
                label = f"{stage.name} corrector on the {rows} (to calibrate its uncertainty)"
                chain._fit_stage(q, exo, y_wb, outputs, progress, label, limit)
        return chain

    # ------------------------------------------------------------------ running
    def start(self, outputs: np.ndarray, y_wb: np.ndarray, exo: np.ndarray) -> ChainState:
        """Initial state from known data up to the row before the first predicted one.

        Parameters
        ----------
        outputs, y_wb : ndarray, shape (h, Q)
            Known stage outputs and white-box predictions of the last ``h`` rows, oldest
            first (``h <= history``; with fewer rows than the history needs, the oldest
            stands in for the ones before it).
        exo : ndarray, shape (h, n_exo)
            Exogenous inputs of the same rows (the last one is not used: the first step is
            given it).

        Returns
        -------
        ChainState
        """
        outputs, y_wb, exo = (np.atleast_2d(a) for a in (outputs, y_wb, exo))
        state = ChainState(self.layout, [stage.memory_length for stage in self.stages])
        last = outputs.shape[0] - 1
        for h in range(self.layout.depth + 1):
            state.history("wb")[h] = y_wb[max(last - h, 0)]
            state.history("out")[h] = outputs[max(last - h, 0)]
            state.history("exo")[h] = exo[max(last - 1 - h, 0)]
        for stage, memory in zip(self.stages, state.memory, strict=True):
            level = stage.level(outputs[:, stage.stage_index], y_wb[:, stage.stage_index])
            memory[:] = level[np.maximum(last - np.arange(stage.memory_length), 0)]
        return state

    def plan(self) -> ChainPlan:
        """The compiled step of the chain as it stands (correctors, ranges, active stages).

        Make a new plan after changing any of them; one plan serves any number of states.

        Returns
        -------
        ChainPlan
        """
        return ChainPlan(self)

    def _check_free_run(
        self, exo: np.ndarray, y_wb: np.ndarray, outputs: np.ndarray, tail: float
    ) -> dict[str, dict[str, float]]:
        """Free-run the last ``tail`` of the training rows; pass through stages that lose.

        The stages already passed through stay so. A corrector trained by teacher forcing can
        still drift when it is fed its own predictions. Each stage is compared with its
        white-box on the free run; a stage whose RMSE is not below the white-box's is
        deactivated (its output is the white-box's).

        Parameters
        ----------
        exo, y_wb, outputs : ndarray
            The training rows, as given to :meth:`fit`.
        tail : float
            Share of the rows free-run.

        Returns
        -------
        dict
            Stage -> ``{"wb_rmse", "gb_rmse", "active"}`` on the free-run rows.
        """
        n = exo.shape[0]
        start = max(1, int((1.0 - tail) * n) - 1)
        mean, _ = self.free_run(exo, y_wb, outputs, start)
        recorded = outputs[start + 1 :]
        wb = np.sqrt(np.mean((y_wb[start + 1 :] - recorded) ** 2, axis=0))
        gb = np.sqrt(np.mean((mean - recorded) ** 2, axis=0))
        self.active_ &= gb < wb
        return {
            name: {"wb_rmse": float(wb[q]), "gb_rmse": float(gb[q]), "active": bool(active)}
            for q, (name, active) in enumerate(zip(self.stage_names, self.active_, strict=True))
        }

    def free_run(
        self,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
        start: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Free-running prediction over precomputed white-box outputs.

        Parameters
        ----------
        exo : ndarray, shape (n, n_exo)
        y_wb : ndarray, shape (n, Q)
        outputs : ndarray, shape (n, Q)
            Recorded outputs; only rows ``start - history + 1 .. start`` are used, to
            initialise the memory.
        start : int
            Last row whose outputs are taken as known (``>= 0``).

        Returns
        -------
        mean, std : ndarray, shape (n - start - 1, Q)
            Predictions of rows ``start + 1 .. n - 1`` and their calibrated standard
            deviations.
        """
        run = self.free_run_variances(exo, y_wb, outputs, start)
        return run.mean, np.sqrt(run.var)

    def free_run_variances(
        self, exo: np.ndarray, y_wb: np.ndarray, outputs: np.ndarray, start: int
    ) -> FreeRun:
        """:meth:`free_run` with variances, calibrated and propagated (same parameters).

        Returns
        -------
        FreeRun
        """
        first = max(0, start - self.history + 1)
        known = slice(first, start + 1)
        state = self.start(outputs[known], y_wb[known], exo[known])
        rows = self.plan().run(state, exo, y_wb, start + 1)
        return FreeRun(
            mean=rows.mean, var=rows.var, latent_var=rows.latent_var, in_domain=rows.in_domain()
        )


@dataclass(frozen=True)
class RecordedRun:
    """Rows of one recording, arranged for a chain.

    Attributes
    ----------
    exo : ndarray, shape (n, n_exo)
        Exogenous inputs (columns as :attr:`GreyBoxChain.exo_names`).
    y_wb : ndarray, shape (n, Q)
        White-box predictions of the stage outputs.
    outputs : ndarray, shape (n, Q)
        Recorded stage outputs.
    """

    exo: np.ndarray
    y_wb: np.ndarray
    outputs: np.ndarray

    @property
    def rows(self) -> int:
        """``n``."""
        return int(self.exo.shape[0])

    def head(self, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(exo, y_wb, outputs)`` of the rows before ``stop``."""
        return self.slice(slice(0, stop))

    def slice(self, rows: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(exo, y_wb, outputs)`` of ``rows``."""
        return self.exo[rows], self.y_wb[rows], self.outputs[rows]


@dataclass(frozen=True)
class FreeRun:
    """A free run's stage outputs and their variances.

    Attributes
    ----------
    mean : ndarray, shape (m, Q)
    var : ndarray, shape (m, Q)
        Calibrated variances (what the exported FMU's ``_std`` squares to).
    latent_var : ndarray, shape (m, Q)
        Propagated variances before calibration.
    in_domain : ndarray of bool, shape (m,)
        The rows the exported FMU would not flag ``out_of_domain`` at its default threshold:
        no corrector feature clipped to its widened training range, and the domain score at
        least :data:`~fmu_greybox.model.chain_step.DEFAULT_OOD_THRESHOLD`.
    """

    mean: np.ndarray
    var: np.ndarray
    latent_var: np.ndarray
    in_domain: np.ndarray


def _fold_means(
    shipped: GreyBoxChain, chain: GreyBoxChain, run: RecordedRun, first: int, stop: int
) -> np.ndarray | None:
    """The free-run means of a calibration fold's rows ``first:stop`` by the chain trained
    without them; ``None`` when that is the ``shipped`` chain itself (a calibration recording:
    its means come with its variances)."""
    if chain is shipped:
        return None
    return chain.free_run_variances(*run.head(stop), first - 1).mean


def _widened_range(X: np.ndarray) -> np.ndarray:
    """Training range of each feature widened by :data:`RANGE_MARGIN`; shape (2, D)."""
    low, high = X.min(axis=0), X.max(axis=0)
    margin = RANGE_MARGIN * (high - low)
    return np.vstack([low - margin, high + margin])


def _thin(X: np.ndarray, t: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """Keep at most ``limit`` rows, evenly spread over the sequence."""
    if t.size <= limit:
        return X, t
    rows = np.linspace(0, t.size - 1, limit).round().astype(int)
    return np.ascontiguousarray(X[rows]), t[rows]


def _stage_progress(progress: ProgressCallback, name: str) -> Callable[[int, float], None]:
    def callback(iteration: int, bound: float) -> None:
        progress(name, iteration, bound)

    return callback
