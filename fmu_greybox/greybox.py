"""The autoregressive grey-box: stage correctors chained in the paper's order.

:class:`GreyBoxChain` owns the stage layouts and their sparse-GP correctors. It is trained by
teacher forcing (:meth:`GreyBoxChain.fit`) and run one communication step at a time
(:meth:`GreyBoxChain.step`), the same code serving the co-simulation master, the array-based
free run used for validation, and the exported FMU.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .chain_step import ChainPlan, ChainState
from .config import ProjectConfig
from .errors import ConfigError
from .gp import SparseGPR
from .stage import TARGET_MODES, StageLayout

ProgressCallback = Callable[[str, int, float], None]

#: Features are clipped to their training range widened by this share of the range.
RANGE_MARGIN = 0.05


class GreyBoxChain:
    """The chain of stage correctors of a project.

    Parameters
    ----------
    config : ProjectConfig
        Stages, signals and GP settings.
    target_mode : str, optional
        Overrides ``config.gp.target``.

    Attributes
    ----------
    stages : list of StageLayout
        In autoregressive order.
    exo_names : list of str
        Signals forming the chain's exogenous vector (union of the stages' inputs).
    correctors_ : list of SparseGPR
        Fitted correctors, one per stage (after :meth:`fit` or loading).
    active_ : ndarray of bool, shape (Q,)
        Stages whose corrector is used; a stage found to free-run worse than its white-box on
        the tail of its training data is passed through (see :meth:`check_free_run`).
    feature_bounds_ : list of ndarray, each shape (2, D_q)
        Per stage, the training range of each feature (widened by :data:`RANGE_MARGIN`);
        features are clipped to it when the chain steps, so a free run never extrapolates.
    """

    def __init__(self, config: ProjectConfig, target_mode: str | None = None) -> None:
        mode = target_mode or config.gp.target
        if mode not in TARGET_MODES:
            raise ConfigError(
                f"{mode!r} is not one of {', '.join(TARGET_MODES)}", field="gp.target"
            )
        self.config = config
        self.target_mode = mode
        self.exo_names: list[str] = []
        for stage in config.stages:
            self.exo_names += [s for s in stage.inputs if s not in self.exo_names]
        names = [s.name for s in config.stages]
        self.stages = [
            StageLayout(
                config=s,
                target_mode=s.target_mode or mode,
                exo_index=np.array([self.exo_names.index(i) for i in s.inputs], dtype=int),
                stage_index=q,
                feed_index=np.array([names.index(f) for f in s.feeds_from], dtype=int),
            )
            for q, s in enumerate(config.stages)
        ]
        self.correctors_: list[SparseGPR] = []
        self.feature_bounds_: list[np.ndarray] = []
        self.active_ = np.ones(len(self.stages), dtype=bool)

    # ------------------------------------------------------------------ names
    @property
    def stage_names(self) -> list[str]:
        """Stage names in order."""
        return [s.name for s in self.stages]

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
        """Rows of known outputs :meth:`start` needs: the longest memory, and at least two
        (for the rate features)."""
        return max(2, *(s.lags for s in self.stages))

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
    ) -> GreyBoxChain:
        """Train every stage by teacher forcing.

        Parameters
        ----------
        exo : ndarray, shape (n, n_exo)
            Exogenous inputs per row (columns as :attr:`exo_names`).
        y_wb : ndarray, shape (n, Q)
            White-box predictions of the stage outputs.
        outputs : ndarray, shape (n, Q)
            Recorded stage outputs.
        progress : callable, optional
            Called as ``progress(stage_name, iteration, bound)`` during optimisation.

        Returns
        -------
        GreyBoxChain
            ``self``, with :attr:`correctors_` set.
        """
        gp = self.config.gp
        self.correctors_ = []
        self.feature_bounds_ = []
        for stage in self.stages:
            X, t = stage.teacher_forced(exo, y_wb, outputs)
            X, t = _thin(X, t, gp.max_train_samples)
            self.feature_bounds_.append(_widened_range(X))
            corrector = SparseGPR(
                n_inducing=min(gp.inducing, t.size),
                inducing=gp.inducing_method,
                max_iter=gp.max_iter,
                seed=gp.seed,
            )
            callback = None
            if progress is not None:
                callback = _stage_progress(progress, stage.name)
            self.correctors_.append(corrector.fit(X, t, progress=callback))
        return self

    # ------------------------------------------------------------------ running
    def start(self, outputs: np.ndarray, y_wb: np.ndarray) -> ChainState:
        """Initial memory from known outputs before the first predicted row.

        Parameters
        ----------
        outputs, y_wb : ndarray, shape (h, Q)
            Known stage outputs and white-box predictions of the last ``h`` rows, oldest
            first, ``h <= history`` (a stage whose memory is longer cycles through them).

        Returns
        -------
        ChainState
        """
        outputs = np.atleast_2d(outputs)
        y_wb = np.atleast_2d(y_wb)
        state = ChainState([stage.lags for stage in self.stages])
        for stage, memory in zip(self.stages, state.memory, strict=True):
            level = stage.level(outputs[:, stage.stage_index], y_wb[:, stage.stage_index])[::-1]
            memory[:] = np.resize(level, stage.lags)  # the most recent first, cycled if short
        before = -2 if outputs.shape[0] > 1 else -1
        state.out_mean[:] = outputs[-1]
        state.wb[:] = y_wb[-1]
        state.prev_mean[:] = outputs[before]
        state.prev_wb[:] = y_wb[before]
        return state

    def plan(self) -> ChainPlan:
        """The compiled step of the chain as it stands (correctors, ranges, active stages).

        Make a new plan after changing any of them; one plan serves any number of states.

        Returns
        -------
        ChainPlan
        """
        return ChainPlan(self)

    def check_free_run(
        self, exo: np.ndarray, y_wb: np.ndarray, outputs: np.ndarray, tail: float = 0.2
    ) -> dict[str, dict[str, float]]:
        """Free-run the last ``tail`` of the training rows; pass through stages that lose.

        A corrector trained by teacher forcing can still drift when it is fed its own
        predictions. Each stage is compared with its white-box on the free run; a stage whose
        RMSE is not below the white-box's is deactivated (its output is the white-box's), so
        the grey-box is never knowingly worse than the model it corrects.

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
        self.active_[:] = True
        mean, _ = self.free_run(exo, y_wb, outputs, start)
        recorded = outputs[start + 1 :]
        wb = np.sqrt(np.mean((y_wb[start + 1 :] - recorded) ** 2, axis=0))
        gb = np.sqrt(np.mean((mean - recorded) ** 2, axis=0))
        self.active_[:] = gb < wb
        return {
            name: {"wb_rmse": float(wb[q]), "gb_rmse": float(gb[q]), "active": bool(gb[q] < wb[q])}
            for q, name in enumerate(self.stage_names)
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
            Predictions of rows ``start + 1 .. n - 1``.
        """
        first = max(0, start - self.history + 1)
        state = self.start(outputs[first : start + 1], y_wb[first : start + 1])
        n = exo.shape[0]
        exo = np.ascontiguousarray(exo, dtype=np.float64)
        y_wb = np.ascontiguousarray(y_wb, dtype=np.float64)
        mean = np.empty((n - start - 1, len(self.stages)))
        var = np.empty_like(mean)
        plan = self.plan()
        for i, j in enumerate(range(start + 1, n)):
            plan.step(state, exo[j - 1], y_wb[j])
            mean[i] = state.out_mean
            var[i] = state.out_var
        return mean, np.sqrt(var)


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
