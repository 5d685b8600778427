"""The corrector chain's state and its compiled step: one call per communication step.

A :class:`ChainPlan` lays out once what ``fmu_greybox/native/chainstep.c`` needs to advance the
chain by one row — per stage its feature map (:meth:`~fmu_greybox.stage.StageLayout.feature_map`),
the widened training range its features are clipped to, its packed posterior
(:attr:`~fmu_greybox.gp.predictive.Posterior.packed`), its target mode, memory length and
whether its corrector runs — and :meth:`ChainPlan.step` hands those arrays, the chain's state
and the step's inputs to the compiled function. Per stage and step that function does:

1. features ``x = A s`` from the sources ``s`` (exogenous inputs of the previous row, this
   row's white-box outputs, the stage outputs so far, the previous row's, the stage's memory);
2. clip ``x`` to the widened training range (the stage is flagged *outside* if it had to);
3. the corrector's mean, latent variance and mean gradient at ``x`` (one kernel row, one
   triangular solve; see :mod:`fmu_greybox.gp.predictive`);
4. the stage output and its variance: first-order propagation, the latent variance plus, for
   every uncertain source (this step's earlier stage outputs, the stage's memory), the squared
   sensitivity of the output to it times its variance (covariances ignored);
5. push the new level into the memory.

It returns the step's domain score: the smallest, over the stages whose correctors ran, of the
largest kernel correlation between the features and an inducing point.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from . import _chainstep
from .gp.linalg import aligned_zeros
from .stage import SHARED_BLOCKS

if TYPE_CHECKING:
    from .greybox import GreyBoxChain

#: Target mode codes of the compiled step (``MODE_*`` in chainstep.c).
MODE_CODES = {"residual": 0, "increment": 1, "output": 2}

#: The state's per-stage blocks (each Q long), in the order the compiled step keeps them.
STATE_BLOCKS = (*SHARED_BLOCKS, "out_var", "outside")


class ChainState:
    """Everything the chain remembers between steps (its autoregressive memory), in one
    float64 vector that the compiled step updates in place.

    Layout: the blocks of :data:`STATE_BLOCKS`, Q values each, then per stage its memory
    (L_q previous levels, most recent first) and their variances.

    Parameters
    ----------
    lags : sequence of int
        L_q per stage.
    values : ndarray, optional
        The vector to wrap (zeros by default).

    Attributes
    ----------
    values : ndarray, shape (6 Q + 2 Σ L_q,)
    wb, out_mean, prev_mean, prev_wb : ndarray, shape (Q,)
        White-box predictions and stage outputs of the last step, and of the step before.
    out_var : ndarray, shape (Q,)
        Variances of the last step's stage outputs.
    outside : ndarray, shape (Q,)
        1.0 where a stage's features left their training range in the last step (they were
        clipped to it), else 0.0.
    """

    def __init__(self, lags: Sequence[int], values: np.ndarray | None = None) -> None:
        self.lags = tuple(int(lag) for lag in lags)
        q = len(self.lags)
        size = len(STATE_BLOCKS) * q + 2 * sum(self.lags)
        self.values = np.zeros(size) if values is None else values
        if self.values.shape != (size,):
            raise ValueError(f"chain state of {self.values.size} values; {size} expected")
        (self.wb, self.out_mean, self.prev_mean, self.prev_wb, self.out_var, self.outside) = (
            self.values[i * q : (i + 1) * q] for i in range(len(STATE_BLOCKS))
        )
        starts = len(STATE_BLOCKS) * q + 2 * np.cumsum([0, *self.lags[:-1]])
        self.memory = [self.values[o : o + n] for o, n in zip(starts, self.lags, strict=True)]
        self.memory_var = [
            self.values[o + n : o + 2 * n] for o, n in zip(starts, self.lags, strict=True)
        ]

    def copy(self) -> ChainState:
        """An independent copy (for saving and restoring state)."""
        return ChainState(self.lags, self.values.copy())

    def to_array(self) -> np.ndarray:
        """The whole state as one float64 vector, a copy (for FMU state serialisation)."""
        return self.values.copy()

    def load_array(self, flat: np.ndarray) -> None:
        """Restore from :meth:`to_array` output, in place."""
        self.values[:] = flat




class ChainPlan:
    """Everything the compiled chain step reads, laid out once for a fitted chain.

    Parameters
    ----------
    chain : GreyBoxChain
        Fitted (or loaded): every stage has a corrector and a feature range.
    """

    def __init__(self, chain: GreyBoxChain) -> None:
        if len(chain.correctors_) != len(chain.stages):
            raise ValueError("the chain has no fitted correctors; fit or load it first")
        n_stages, n_exo = len(chain.stages), len(chain.exo_names)
        records, blocks, offset = [], [], 0
        memory_offset = len(STATE_BLOCKS) * n_stages
        work = 0
        for stage, corrector, bounds, active in zip(
            chain.stages, chain.correctors_, chain.feature_bounds_, chain.active_, strict=True
        ):
            posterior = corrector.posterior_
            feature_map = stage.feature_map(n_exo, n_stages)
            d, m = posterior.input_dim, posterior.n_inducing
            if feature_map.shape[0] != d or bounds.shape != (2, d):
                raise ValueError(
                    f"stage {stage.name}: its corrector takes {d} features, its layout makes "
                    f"{feature_map.shape[0]}; the model does not belong to this project"
                )
            block = np.concatenate([posterior.packed, feature_map.ravel(), bounds[0], bounds[1]])
            records.append(
                [
                    offset,
                    m,
                    d,
                    feature_map.shape[1],
                    stage.lags,
                    MODE_CODES[stage.target_mode],
                    int(bool(active)),
                    memory_offset,
                ]
            )
            blocks.append((offset, block))
            offset += -(-block.size // 8) * 8  # each posterior on a cache-line boundary
            memory_offset += 2 * stage.lags
            work = max(work, m + 4 * d + 1)
        self._params = aligned_zeros(offset)
        for start, block in blocks:
            self._params[start : start + block.size] = block
        self._work = np.zeros(work)
        header = [_chainstep.PLAN_VERSION, n_stages, n_exo, offset, work, memory_offset]
        self._plan = np.array(header + [v for r in records for v in r], dtype=np.int64)
        self.lags = tuple(stage.lags for stage in chain.stages)

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
