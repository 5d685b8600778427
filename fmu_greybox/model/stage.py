"""One stage of the autoregressive grey-box: its features and its training dataset.

Timing (see :mod:`fmu_greybox.model.simulate`): the prediction of the stage output at row ``j`` uses

* the exogenous inputs of row ``j - 1`` (the inputs that acted over the last step),
* the white-box prediction of the stage's output at row ``j``,
* the outputs of the earlier stages at row ``j`` (already computed this step),
* with ``feed_rates``, the changes over the last step of the earlier stages' outputs and of
  their residuals to the white-box (a velocity and a velocity error, for a position stage),
* with ``differences = K``, the last K step changes of each input (``u[j-1] - u[j-2]``, ...),
  of the stage's white-box output and of each feeding stage's output (``s[j] - s[j-1]``, ...),
* the stage's own memory: its previous levels at rows ``j - 1 ... j - L``, or in ``increment``
  mode their last L step changes.

What the corrector learns (``target``):

``residual``
    ``r_j = y_j - y_wb_j``; memory: ``r_{j-1} ... r_{j-L}``; output ``y_wb_j + r_j``.
``increment``
    ``d_j = r_j - r_{j-1}``; memory: ``d_{j-1} ... d_{j-L}`` (from L + 1 stored residuals);
    output ``y_wb_j + r_{j-1} + d_j``.
``output``
    ``y_j`` itself (the paper's formulation); memory: ``y_{j-1} ... y_{j-L}``.

Every feature is a fixed linear combination of the stage's *sources*, one vector per row, laid
out by :class:`SourceLayout`: the white-box and stage outputs of rows ``j ... j - H``, the
exogenous inputs of rows ``j - 1 ... j - 1 - H`` (H, the chain's history depth, covers the
deepest difference), then the stage's stored levels. :meth:`StageLayout.feature_map` is that
combination as a matrix; training applies it to recorded sources (:meth:`StageLayout.
teacher_forced`), the compiled chain step (:mod:`fmu_greybox.model.chain_step`) to the chain's
state, so the two cannot disagree on what a feature is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmu_greybox.project.config import TARGET_MODES, StageConfig

__all__ = ["TARGET_MODES", "SourceLayout", "StageLayout"]


@dataclass(frozen=True)
class SourceLayout:
    """Positions of the sources shared by every stage of a chain.

    ``H + 1`` rows of history, each the Q white-box outputs then the Q stage outputs (row
    ``j - h`` at ``h``), then ``H + 1`` rows of exogenous inputs (row ``j - 1 - h`` at ``h``).
    A stage's stored levels follow them in its own sources.

    Attributes
    ----------
    n_exo : int
        Length of the chain's exogenous vector.
    n_stages : int
        Q.
    depth : int
        H >= 1.
    """

    n_exo: int
    n_stages: int
    depth: int

    def wb(self, h: int, q: int) -> int:
        """White-box output of stage ``q`` at row ``j - h``."""
        return 2 * self.n_stages * h + q

    def out(self, h: int, q: int) -> int:
        """Output of stage ``q`` at row ``j - h``."""
        return 2 * self.n_stages * h + self.n_stages + q

    def exo(self, h: int, i: int) -> int:
        """Exogenous input ``i`` at row ``j - 1 - h``."""
        return 2 * self.n_stages * (self.depth + 1) + self.n_exo * h + i

    @property
    def shared(self) -> int:
        """Number of shared sources: ``(H + 1)(2Q + n_exo)``."""
        return (self.depth + 1) * (2 * self.n_stages + self.n_exo)

    def memory(self, lag: int) -> int:
        """The stage's stored level of row ``j - 1 - lag``."""
        return self.shared + lag

    def sources(
        self, exo: np.ndarray, y_wb: np.ndarray, outputs: np.ndarray, rows: np.ndarray
    ) -> np.ndarray:
        """The shared sources of the given rows from arrays of the whole sequence.

        Parameters
        ----------
        exo : ndarray, shape (n, n_exo)
        y_wb, outputs : ndarray, shape (n, Q)
        rows : ndarray of int, shape (m,)
            Each ``>= depth + 1``.

        Returns
        -------
        ndarray, shape (m, shared)
        """
        history = [block[rows - h] for h in range(self.depth + 1) for block in (y_wb, outputs)]
        inputs = [exo[rows - 1 - h] for h in range(self.depth + 1)]
        return np.hstack(history + inputs)


@dataclass
class StageLayout:
    """Where each feature of a stage comes from.

    Attributes
    ----------
    config : StageConfig
        The stage definition.
    target_mode : str
        One of :data:`TARGET_MODES` (or ``"auto"`` until training chose).
    exo_index : ndarray of int, shape (n_exo,)
        Positions of this stage's exogenous inputs in the chain's exogenous vector.
    stage_index : int
        Position of this stage in the chain.
    feed_index : ndarray of int, shape (n_feeds,)
        Positions of the feeding stages in the chain.
    """

    config: StageConfig
    target_mode: str
    exo_index: np.ndarray
    stage_index: int
    feed_index: np.ndarray

    @property
    def name(self) -> str:
        """Stage name."""
        return self.config.name

    @property
    def lags(self) -> int:
        """Number of memory features L."""
        return self.config.lags

    @property
    def memory_length(self) -> int:
        """Stored levels: L, or L + 1 in ``increment`` mode (whose memory is differences)."""
        return self.lags + (self.target_mode == "increment")

    @property
    def depth(self) -> int:
        """Rows of history beyond the current one that the features reach back."""
        return max(self.config.differences, 1 if self.config.feed_rates else 0)

    def feature_names(self, exo_names: list[str], stage_names: list[str]) -> list[str]:
        """Human-readable names of the D features, in order (as :meth:`feature_map`)."""
        own = "y" if self.target_mode == "output" else "r"
        wb = f"{self.config.whitebox_output}_wb"
        feeds = [stage_names[i] for i in self.feed_index]
        names = [f"{exo_names[i]}[k-1]" for i in self.exo_index] + [wb] + feeds
        if self.config.feed_rates:
            names += [f"d{f}" for f in feeds] + [f"d{f}.r" for f in feeds]
        for k in range(self.config.differences):
            names += [f"d({exo_names[i]})[k-{k + 1}]" for i in self.exo_index]
            names += [f"d({s})[k{f'-{k}' if k else ''}]" for s in [wb, *feeds]]
        if self.target_mode == "increment":
            return names + [f"d({self.name}.r)[k-{lag}]" for lag in range(1, self.lags + 1)]
        return names + [f"{self.name}.{own}[k-{lag}]" for lag in range(1, self.lags + 1)]

    # ------------------------------------------------------------------ levels
    def level(self, y: np.ndarray, y_wb: np.ndarray) -> np.ndarray:
        """Memory values from outputs: residuals, or the outputs themselves (mode ``output``)."""
        return y if self.target_mode == "output" else y - y_wb

    # ------------------------------------------------------------------ features
    def feature_map(self, layout: SourceLayout) -> np.ndarray:
        """The features as a linear map of the stage's sources (see the module notes).

        Parameters
        ----------
        layout : SourceLayout
            The chain's shared sources (``depth`` at least :attr:`depth`).

        Returns
        -------
        ndarray, shape (D, layout.shared + memory_length)
        """
        q = self.stage_index
        feeds = [int(f) for f in self.feed_index]
        exo = [int(i) for i in self.exo_index]
        rows: list[dict[int, float]] = [{layout.exo(0, i): 1.0} for i in exo]
        rows.append({layout.wb(0, q): 1.0})
        rows += [{layout.out(0, f): 1.0} for f in feeds]
        if self.config.feed_rates:
            # the step change of each feeding stage's output, then of its residual
            rows += [{layout.out(0, f): 1.0, layout.out(1, f): -1.0} for f in feeds]
            rows += [
                {
                    layout.out(0, f): 1.0,
                    layout.out(1, f): -1.0,
                    layout.wb(0, f): -1.0,
                    layout.wb(1, f): 1.0,
                }
                for f in feeds
            ]
        for k in range(self.config.differences):
            rows += [{layout.exo(k, i): 1.0, layout.exo(k + 1, i): -1.0} for i in exo]
            rows.append({layout.wb(k, q): 1.0, layout.wb(k + 1, q): -1.0})
            rows += [{layout.out(k, f): 1.0, layout.out(k + 1, f): -1.0} for f in feeds]
        for lag in range(self.lags):
            if self.target_mode == "increment":
                rows.append({layout.memory(lag): 1.0, layout.memory(lag + 1): -1.0})
            else:
                rows.append({layout.memory(lag): 1.0})
        A = np.zeros((len(rows), layout.shared + self.memory_length))
        for i, row in enumerate(rows):
            for column, weight in row.items():
                A[i, column] = weight
        return A

    def first_row(self, layout: SourceLayout) -> int:
        """First row whose features the recorded sequence holds."""
        return max(layout.depth + 1, self.memory_length)

    # ------------------------------------------------------------------ datasets
    def teacher_forced(
        self,
        layout: SourceLayout,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
        fed: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Training rows with recorded values in place of the stage's own fed-back values.

        Parameters
        ----------
        layout : SourceLayout
        exo : ndarray, shape (n, n_exo_chain)
            The chain's exogenous inputs per row.
        y_wb : ndarray, shape (n, Q)
            White-box predictions of every stage output per row.
        outputs : ndarray, shape (n, Q)
            Recorded stage outputs per row (the stage's memory and target come from them).
        fed : ndarray, shape (n, Q), optional
            The earlier stages' outputs as the features see them (default ``outputs``:
            teacher forcing; a free run of the earlier stages for ``feeds = "free_run"``).

        Returns
        -------
        X : ndarray, shape (n - first_row, D)
            Features of rows ``first_row .. n-1``.
        t : ndarray, shape (n - first_row,)
            Corrector targets of those rows.
        """
        q = self.stage_index
        level = self.level(outputs[:, q], y_wb[:, q])
        rows = np.arange(self.first_row(layout), outputs.shape[0])
        shared = layout.sources(exo, y_wb, outputs if fed is None else fed, rows)
        memory = [level[rows - 1 - lag][:, None] for lag in range(self.memory_length)]
        X = np.hstack([shared, *memory]) @ self.feature_map(layout).T
        if self.target_mode == "increment":
            t = level[rows] - level[rows - 1]
        else:
            t = level[rows]
        return np.ascontiguousarray(X), t
