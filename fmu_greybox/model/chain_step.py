"""The corrector chain's state and its compiled step: one call per communication step.

A :class:`ChainPlan` lays out once what ``fmu_greybox/native/chain_core.c`` needs to advance the
chain by one row — per stage its feature map
(:meth:`~fmu_greybox.model.stage.StageLayout.feature_map`),
the widened training range its features are clipped to, its packed posterior
(:attr:`~fmu_greybox.gp.predictive.Posterior.packed`), its target mode, memory length and
whether its corrector runs — and :meth:`ChainPlan.step` hands those arrays, the chain's state
and the step's inputs to the compiled function. Per stage and step that function does:

1. shift the history: this row's white-box outputs and the previous row's inputs enter it;
2. features ``x = A s`` from the sources ``s`` (the history of white-box and stage outputs,
   the stage outputs so far this row, the history of inputs, the stage's stored levels; see
   :class:`~fmu_greybox.model.stage.SourceLayout`);
3. clip ``x`` to the widened training range (the stage is flagged *outside* if it had to);
4. the corrector's mean, latent variance and mean gradient at ``x`` (one kernel row, one
   triangular solve; see :mod:`fmu_greybox.gp.predictive`);
5. the stage output and its variance: first-order propagation, the latent variance plus, for
   every uncertain source (this step's earlier stage outputs, the stage's stored levels), the
   squared sensitivity of the output to it times its variance (covariances ignored);
6. push the new level into the memory, with that propagated variance ``V``;
7. report the calibrated variance ``a V + b`` (the stage's
   :class:`~fmu_greybox.model.calibration.VarianceCalibration`; ``b`` alone for a stage
   passed through).

It returns the step's domain score: the smallest, over the stages whose correctors ran, of the
largest kernel correlation between the features and an inducing point.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, TypeVar

import numpy as np

from fmu_greybox import _chainstep
from fmu_greybox.gp import SparseGPR
from fmu_greybox.gp.linalg import aligned_zeros
from fmu_greybox.model.calibration import VarianceCalibration
from fmu_greybox.model.stage import SourceLayout, StageLayout

T = TypeVar("T", bool, np.ndarray)


class FittedChain(Protocol):
    """What a plan reads of a fitted chain (:class:`~fmu_greybox.model.chain.GreyBoxChain`
    has it; this module does not import the chain, which imports it)."""

    layout: SourceLayout
    stages: list[StageLayout]
    active_: np.ndarray
    correctors_: list[SparseGPR | None]
    feature_bounds_: list[np.ndarray | None]
    calibration_: list[VarianceCalibration]
    fade: bool


#: Default ``ood_threshold`` of the exported FMU: a step is out of its corrector's domain when
#: the features lie farther than about 2.1 length-scales from every inducing point of some stage
#: (domain score below 0.1), or when some feature had to be clipped to its widened range.
DEFAULT_OOD_THRESHOLD = 0.1
#: Domain scores between which a corrector fades out: it acts fully at and above
#: :data:`FADE_FULL` (the default ``out_of_domain`` threshold, about 2.1 length-scales from every
#: inducing point) and not at all at and below :data:`FADE_NONE` (about 3 length-scales), where
#: the stage reports its white-box with the white-box's residual variance.
FADE_FULL = DEFAULT_OOD_THRESHOLD
FADE_NONE = 0.01
#: Target mode codes of the compiled step (``MODE_*`` in chain_core.c).
MODE_CODES = {"residual": 0, "increment": 1, "output": 2}


class ChainState:
    """Everything the chain remembers between steps (its autoregressive memory), in one
    float64 vector that the compiled step updates in place.

    Layout: the shared sources of :class:`~fmu_greybox.model.stage.SourceLayout` (the history of
    white-box and stage outputs and of the exogenous inputs), the Q variances of the last
    step's outputs, Q out-of-range flags, then per stage its n stored levels (most recent
    first) and their covariance (n x n).

    Parameters
    ----------
    layout : SourceLayout
    memory_lengths : sequence of int
        Stored levels per stage.
    values : ndarray, optional
        The vector to wrap (zeros by default).

    Attributes
    ----------
    values : ndarray
    wb, out_mean : ndarray, shape (Q,)
        White-box predictions and stage outputs of the last step.
    prev_wb, prev_mean : ndarray, shape (Q,)
        The same of the step before.
    exo : ndarray, shape (n_exo,)
        The exogenous inputs the last step was given (those of the row before it).
    out_var : ndarray, shape (Q,)
        Calibrated variances of the last step's stage outputs (``a V + b``, see
        :mod:`fmu_greybox.model.calibration`).
    outside : ndarray, shape (Q,)
        1.0 where a stage's features left their training range in the last step (they were
        clipped to it), else 0.0.
    memory : list of ndarray, shapes (n_q,)
        Per stage its stored levels, most recent first.
    memory_cov : list of ndarray, shapes (n_q, n_q)
        Their covariance (first-order propagation).
    """

    def __init__(
        self, layout: SourceLayout, memory_lengths: Sequence[int], values: np.ndarray | None = None
    ) -> None:
        self.layout = layout
        self.memory_lengths = tuple(int(n) for n in memory_lengths)
        q, shared = layout.n_stages, layout.shared
        blocks = [n * (1 + n) for n in self.memory_lengths]
        size = shared + 2 * q + sum(blocks)
        self.values = np.zeros(size) if values is None else values
        if self.values.shape != (size,):
            raise ValueError(f"chain state of {self.values.size} values; {size} expected")
        v = self.values
        self.wb, self.out_mean = v[layout.wb(0, 0) :][:q], v[layout.out(0, 0) :][:q]
        self.prev_wb, self.prev_mean = v[layout.wb(1, 0) :][:q], v[layout.out(1, 0) :][:q]
        self.exo = v[layout.exo(0, 0) :][: layout.n_exo]
        self.out_var, self.outside = v[shared : shared + q], v[shared + q : shared + 2 * q]
        starts = shared + 2 * q + np.cumsum([0, *blocks[:-1]])
        self.memory_offsets = [int(o) for o in starts]
        self.memory = [v[o : o + n] for o, n in zip(starts, self.memory_lengths, strict=True)]
        self.memory_cov = [
            v[o + n : o + n + n * n].reshape(n, n)
            for o, n in zip(starts, self.memory_lengths, strict=True)
        ]
        self._newest_level_var = np.array(
            [o + n for o, n in zip(starts, self.memory_lengths, strict=True)], dtype=int
        )

    @property
    def latent_var(self) -> np.ndarray:
        """Propagated (uncalibrated) variances ``V`` of the last step's stage outputs, shape
        (Q,): the variance of each stage's newest stored level, which its memory carries on."""
        return self.values[self._newest_level_var]

    def history(self, block: str) -> np.ndarray:
        """A view of the white-box (``"wb"``) or stage-output (``"out"``) history, shape
        (H + 1, Q), row ``h`` the step ``h`` steps back, or of the inputs (``"exo"``),
        shape (H + 1, n_exo)."""
        layout, q = self.layout, self.layout.n_stages
        if block == "exo":
            return self.values[layout.exo(0, 0) : layout.shared].reshape(-1, layout.n_exo)
        rows = self.values[: layout.exo(0, 0)].reshape(layout.depth + 1, 2, q)
        return rows[:, 0 if block == "wb" else 1]

    def taps(self) -> np.ndarray:
        """Offsets in :attr:`values` of each stage's output mean, calibrated variance,
        propagated variance and out-of-range flag, shape (4 Q,), int64 (what
        :meth:`ChainPlan.run` copies out row after row)."""
        q, shared = self.layout.n_stages, self.layout.shared
        stages = np.arange(q)
        out = self.layout.out(0, 0)  # where out_mean starts
        return np.concatenate(
            [out + stages, shared + stages, self._newest_level_var, shared + q + stages]
        ).astype(np.int64)

    def copy(self) -> ChainState:
        """An independent copy (for saving and restoring state)."""
        return ChainState(self.layout, self.memory_lengths, self.values.copy())

    def to_array(self) -> np.ndarray:
        """The whole state as one float64 vector, a copy (for FMU state serialisation)."""
        return self.values.copy()

    def load_array(self, flat: np.ndarray) -> None:
        """Restore from :meth:`to_array` output, in place."""
        self.values[:] = flat


def _calibration_block(calibration: VarianceCalibration, fade: bool) -> tuple[float, ...]:
    """A stage's calibration as the compiled step reads it: ``a``, ``b``, the white-box's
    residual variance ``c`` (``b`` when not known), :data:`FADE_FULL`, :data:`FADE_NONE` (0 and
    0 without ``fade``: a corrector that never fades)."""
    c = calibration.whitebox_variance
    return (
        calibration.latent_scale,
        calibration.residual_variance,
        calibration.residual_variance if c is None else c,
        *((FADE_FULL, FADE_NONE) if fade else (0.0, 0.0)),
    )


class ChainPlan:
    """Everything the compiled chain step reads, laid out once for a fitted chain.

    Parameters
    ----------
    chain : FittedChain
        A :class:`~fmu_greybox.model.chain.GreyBoxChain`, fitted (or loaded): every stage has
        a corrector (when active), a feature range and a variance calibration.

    Layout: the plan is int64, a header then one record per stage (params offset, M, D, width
    of the feature map, memory length, target mode, active, memory offset in the state,
    calibration offset in params); params is float64, per active stage its packed posterior,
    feature map and range (each block on a cache line), then of every stage ``a, b, c`` and the
    fade scores (:func:`_calibration_block`).
    """

    def __init__(self, chain: FittedChain) -> None:
        layout = chain.layout
        n_stages = layout.n_stages
        records, blocks, offset = [], [], 0
        memory_offset = layout.shared + 2 * n_stages
        work = 0
        for q, stage in enumerate(chain.stages):
            active = bool(chain.active_[q])
            block = np.zeros(0)
            m = d = width = 0
            if active:  # a stage passed through needs nothing but its memory
                posterior = chain.correctors_[q].posterior_
                feature_map = stage.feature_map(layout)
                bounds = chain.feature_bounds_[q]
                d, m, width = posterior.input_dim, posterior.n_inducing, feature_map.shape[1]
                if feature_map.shape[0] != d or bounds.shape != (2, d):
                    raise ValueError(
                        f"stage {stage.name}: its corrector takes {d} features, its layout "
                        f"makes {feature_map.shape[0]}; the model does not belong to this project"
                    )
                block = np.concatenate(
                    [posterior.packed, feature_map.ravel(), bounds[0], bounds[1]]
                )
            records.append(
                [
                    offset,
                    m,
                    d,
                    width,
                    stage.memory_length,
                    # a stage still to be trained (target "auto") passes through as residual
                    MODE_CODES.get(stage.target_mode, MODE_CODES["residual"]),
                    int(active),
                    memory_offset,
                ]
            )
            blocks.append((offset, block))
            offset += -(-block.size // 8) * 8  # each posterior on a cache-line boundary
            memory_offset += stage.memory_length * (1 + stage.memory_length)
            work = max(work, 2 * m + 5 * d + 2 * stage.memory_length + 1)
        calibration = [_calibration_block(c, chain.fade) for c in chain.calibration_]
        for q, record in enumerate(records):
            record.append(offset + _chainstep.CALIBRATION * q)
        blocks.append((offset, np.ravel(calibration)))
        offset += _chainstep.CALIBRATION * n_stages
        self._params = aligned_zeros(offset)
        for start, block in blocks:
            self._params[start : start + block.size] = block
        self._work = np.zeros(work)
        header = [
            _chainstep.PLAN_VERSION,
            n_stages,
            layout.n_exo,
            offset,
            work,
            memory_offset,
            layout.depth,
        ]
        self._plan = np.array(header + [v for r in records for v in r], dtype=np.int64)
        self.layout = layout
        self.memory_lengths = [stage.memory_length for stage in chain.stages]

    @property
    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The plan (int64) and the parameters (float64) the compiled step reads, as they are
        (read-only views: the native grey-box FMU stores them verbatim, see
        :mod:`fmu_greybox.export.native`)."""
        plan, params = self._plan.view(), self._params.view()
        plan.flags.writeable = params.flags.writeable = False
        return plan, params

    def start(self, y_wb: np.ndarray, exo: np.ndarray) -> ChainState:
        """The chain's state when one row is all that is known (what a grey-box FMU has at
        initialisation): its white-box stage outputs stand in for the stage outputs (a zero
        residual) and its inputs for the earlier inputs; equal to
        ``GreyBoxChain.start(y_wb[None], y_wb[None], exo[None])``, computed by the compiled
        code the native FMU runs.

        Parameters
        ----------
        y_wb : ndarray, shape (Q,), float64, C-contiguous
        exo : ndarray, shape (n_exo,), float64, C-contiguous

        Returns
        -------
        ChainState
        """
        state = ChainState(self.layout, self.memory_lengths)
        _chainstep.start(self._plan, state.values, y_wb, exo)
        return state

    def step(
        self, state: ChainState, exo_prev: np.ndarray, y_wb: np.ndarray, enabled: bool = True
    ) -> float:
        """Advance the chain by one row, in place on ``state``.

        Parameters
        ----------
        state : ChainState
            From :meth:`GreyBoxChain.start`; ``out_mean``/``out_var`` then hold this row's
            stage outputs and their variances.
        exo_prev : ndarray, shape (n_exo,), float64, C-contiguous
            Exogenous inputs of the previous row.
        y_wb : ndarray, shape (Q,), float64, C-contiguous
            White-box predictions of this row.
        enabled : bool
            ``False`` passes the white-box through (for A/B runs) while keeping the memory
            consistent with it.

        Returns
        -------
        float
            The domain score (1.0 when no corrector ran).
        """
        return _chainstep.step(
            self._plan, self._params, self._work, state.values, exo_prev, y_wb, enabled
        )

    def run(self, state: ChainState, exo: np.ndarray, y_wb: np.ndarray, first: int) -> RunRows:
        """:meth:`step` over rows ``first .. n - 1``, each given the previous row's inputs and
        its own white-box outputs, every corrector enabled, in compiled code with no Python
        between the rows (the GIL is released: runs of other chains go on beside it).

        Parameters
        ----------
        state : ChainState
            The state at row ``first - 1``; left at the last row.
        exo : ndarray, shape (n, n_exo)
        y_wb : ndarray, shape (n, Q)
        first : int
            First row stepped (``>= 1``).

        Returns
        -------
        RunRows
        """
        exo = np.ascontiguousarray(exo, dtype=np.float64)
        y_wb = np.ascontiguousarray(y_wb, dtype=np.float64)
        q = self.layout.n_stages
        table = np.empty((exo.shape[0] - first, 3 * q + 2))
        work = np.zeros_like(self._work)  # its own scratch: runs may go on side by side
        _chainstep.run(
            self._plan, self._params, work, state.values, exo, y_wb, first, state.taps(), table
        )
        return RunRows(table, q)


class RunRows:
    """Per row of a :meth:`ChainPlan.run`: the stage outputs, their calibrated and propagated
    variances, the domain score and whether some stage's features left their range.

    Parameters
    ----------
    table : ndarray, shape (m, 3 Q + 2)
        What the compiled run wrote.
    n_stages : int
    """

    def __init__(self, table: np.ndarray, n_stages: int) -> None:
        q = n_stages
        self.mean, self.var = table[:, :q], table[:, q : 2 * q]
        self.latent_var = table[:, 2 * q : 3 * q]
        self.score, self.outside = table[:, 3 * q], table[:, 3 * q + 1] == 1.0

    def in_domain(self, threshold: float = DEFAULT_OOD_THRESHOLD) -> np.ndarray:
        """Rows the exported FMU would not flag ``out_of_domain`` (:func:`out_of_domain`)."""
        return ~flagged(self.score, self.outside, threshold)


def out_of_domain(
    score: float, state: ChainState, threshold: float = DEFAULT_OOD_THRESHOLD
) -> bool:
    """The exported FMU's ``out_of_domain`` flag for the step that returned ``score`` (see
    :func:`flagged`)."""
    return bool(flagged(score, 1.0 in state.outside.tolist(), threshold))


def flagged(score: T, outside: T, threshold: float) -> T:
    """``out_of_domain`` of one step or of many rows (arrays): some stage's features were
    clipped to their widened training range (``outside``), or the domain ``score`` is below
    ``threshold``."""
    return (score < threshold) | outside
