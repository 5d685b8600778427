"""The autoregressive grey-box: stage correctors chained in the paper's order.

:class:`GreyBoxChain` owns the stage layouts and their sparse-GP correctors. It is trained by
teacher forcing (:meth:`GreyBoxChain.fit`) and run one communication step at a time
(:meth:`GreyBoxChain.step`), the same code serving the co-simulation master, the array-based
free run used for validation, and the exported FMU.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .config import ProjectConfig
from .errors import ConfigError
from .gp import Posterior, SparseGPR
from .stage import TARGET_MODES, StageLayout

ProgressCallback = Callable[[str, int, float], None]

#: Features are clipped to their training range widened by this share of the range.
RANGE_MARGIN = 0.05


@dataclass
class ChainState:
    """Everything the chain remembers between steps (its autoregressive memory).

    Attributes
    ----------
    memory : list of ndarray, each shape (L_q,)
        Per stage, its previous levels, most recent first.
    memory_var : list of ndarray, each shape (L_q,)
        Their variances.
    out_mean, out_var : ndarray, shape (Q,)
        Stage outputs and variances of the last step.
    wb : ndarray, shape (Q,)
        White-box predictions of the last step.
    prev_mean, prev_wb : ndarray, shape (Q,)
        Stage outputs and white-box predictions of the step before.
    outside : ndarray, shape (Q,)
        1.0 where a stage's features left their training range in the last step (they were
        clipped to it), else 0.0.
    """

    memory: list[np.ndarray]
    memory_var: list[np.ndarray]
    out_mean: np.ndarray
    out_var: np.ndarray
    wb: np.ndarray
    prev_mean: np.ndarray
    prev_wb: np.ndarray
    outside: np.ndarray

    def _blocks(self) -> list[np.ndarray]:
        return [
            *self.memory,
            *self.memory_var,
            self.out_mean,
            self.out_var,
            self.wb,
            self.prev_mean,
            self.prev_wb,
            self.outside,
        ]

    def copy(self) -> ChainState:
        """An independent copy (for saving and restoring state)."""
        return ChainState(
            memory=[m.copy() for m in self.memory],
            memory_var=[m.copy() for m in self.memory_var],
            out_mean=self.out_mean.copy(),
            out_var=self.out_var.copy(),
            wb=self.wb.copy(),
            prev_mean=self.prev_mean.copy(),
            prev_wb=self.prev_wb.copy(),
            outside=self.outside.copy(),
        )

    def to_array(self) -> np.ndarray:
        """Flatten into one float64 vector (for FMU state serialisation)."""
        return np.concatenate(self._blocks())

    def load_array(self, flat: np.ndarray) -> None:
        """Restore from :meth:`to_array` output, in place."""
        pos = 0
        for block in self._blocks():
            block[:] = flat[pos : pos + block.size]
            pos += block.size


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
        self._features = [np.empty(s.n_features) for s in self.stages]
        # kernel rows of the correctors, see _kernel_row
        self._kernel_owner: list[Posterior | None] = [None] * len(self.stages)
        self._kernel_buffer = np.zeros(0)
        self._kernel_starts = np.zeros(0, dtype=int)
        self._kernel_rows: list[np.ndarray] = []

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
            first, ``h <= history`` (fewer rows are repeated backwards from the oldest).

        Returns
        -------
        ChainState
        """
        outputs = np.atleast_2d(outputs)
        y_wb = np.atleast_2d(y_wb)
        memory, memory_var = [], []
        for stage in self.stages:
            level = stage.level(outputs[:, stage.stage_index], y_wb[:, stage.stage_index])[::-1]
            taken = np.resize(level, stage.lags) if level.size < stage.lags else level[: stage.lags]
            memory.append(np.array(taken, dtype=np.float64))
            memory_var.append(np.zeros(stage.lags))
        before = -2 if outputs.shape[0] > 1 else -1
        return ChainState(
            memory=memory,
            memory_var=memory_var,
            out_mean=np.array(outputs[-1], dtype=np.float64),
            out_var=np.zeros(len(self.stages)),
            wb=np.array(y_wb[-1], dtype=np.float64),
            prev_mean=np.array(outputs[before], dtype=np.float64),
            prev_wb=np.array(y_wb[before], dtype=np.float64),
            outside=np.zeros(len(self.stages)),
        )

    def step(
        self, state: ChainState, exo_prev: np.ndarray, y_wb: np.ndarray, enabled: bool = True
    ) -> ChainState:
        """Advance the chain by one row, in place.

        Parameters
        ----------
        state : ChainState
            Memory; updated in place.
        exo_prev : ndarray, shape (n_exo,)
            Exogenous inputs of the previous row.
        y_wb : ndarray, shape (Q,)
            White-box predictions of this row.
        enabled : bool
            ``False`` passes the white-box through (for A/B runs) while keeping the memory
            consistent with it.

        Returns
        -------
        ChainState
            ``state``, whose ``out_mean`` / ``out_var`` hold this row's outputs.
        """
        # the co-simulation hot path: small vectors as Python floats, one pass of numpy
        # conversions in and out, numpy only for the correctors' length-M work
        exo = exo_prev.tolist()
        wb = y_wb.tolist()
        prev_wb = state.wb.tolist()
        prev_mean = state.out_mean.tolist()
        out_mean = prev_mean.copy()
        out_var = state.out_var.tolist()
        active = self.active_.tolist() if enabled else [False] * len(self.stages)
        for stage, memory, memory_var in zip(
            self.stages, state.memory, state.memory_var, strict=True
        ):
            q = stage.stage_index
            y = wb[q]
            if active[q]:
                features = stage.assemble(exo, y, out_mean, prev_mean, wb, prev_wb, memory.tolist())
                low, high = self.feature_bounds_[q].tolist()
                features, state.outside[q] = _clip(features, low, high)
                x = self._features[q]
                x[:] = features
                posterior = self.correctors_[q].posterior_
                mu, var_gp, grad = posterior.predict_one_grad(x, self._kernel_row(q, posterior))
                out, var, level = stage.combine(
                    mu, var_gp, grad.tolist(), y, out_var, memory.tolist(), memory_var.tolist()
                )
            else:
                out, var = y, 0.0
                level = stage.level(out, y)
            out_mean[q] = out
            out_var[q] = var
            if memory.size > 1:
                memory[1:] = memory[:-1]  # numpy copies overlapping ranges correctly
                memory_var[1:] = memory_var[:-1]
            memory[0] = level
            memory_var[0] = var
        state.prev_wb[:] = prev_wb
        state.wb[:] = wb
        state.prev_mean[:] = prev_mean
        state.out_mean[:] = out_mean
        state.out_var[:] = out_var
        return state

    def _kernel_row(self, q: int, posterior: Posterior) -> np.ndarray:
        """Stage ``q``'s buffer for its corrector's kernel row, shape (M_q,).

        The rows of all stages are views of one buffer (for :meth:`kernel_maxima`), laid out
        again for every stage when a stage's posterior is not the one its row was made for
        (the first step, or new correctors).
        """
        if self._kernel_owner[q] is not posterior:
            self._kernel_owner = [c.posterior_ for c in self.correctors_]
            sizes = [p.n_inducing for p in self._kernel_owner]
            self._kernel_buffer = np.zeros(sum(sizes))
            self._kernel_starts = np.cumsum([0, *sizes[:-1]])
            self._kernel_rows = np.split(self._kernel_buffer, self._kernel_starts[1:])
        return self._kernel_rows[q]

    def kernel_maxima(self) -> list[float]:
        """Per stage, the largest entry of its corrector's kernel row ``K(Z, x)`` at the
        (clipped) features of the last step the corrector ran (standardised units, so that
        divided by the signal variance it is the correlation with the nearest inducing
        point); 0.0 for a stage whose corrector has not run since the correctors were set.

        Returns
        -------
        list of float, length Q
        """
        if len(self._kernel_starts) != len(self.stages):
            return [0.0] * len(self.stages)
        return np.maximum.reduceat(self._kernel_buffer, self._kernel_starts).tolist()

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
        mean = np.empty((n - start - 1, len(self.stages)))
        var = np.empty_like(mean)
        for i, j in enumerate(range(start + 1, n)):
            self.step(state, exo[j - 1], y_wb[j])
            mean[i] = state.out_mean
            var[i] = state.out_var
        return mean, np.sqrt(var)


def _clip(x: list[float], low: list[float], high: list[float]) -> tuple[list[float], float]:
    """``x`` clipped to ``[low, high]``, and 1.0 if any value was outside, else 0.0.

    ``max``/``min`` return their first argument on ties and for NaN, so an unclipped value
    (NaN included) is the same object and the list compares equal.
    """
    clipped = list(map(min, map(max, x, low), high))
    return clipped, 0.0 if clipped == x else 1.0


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
