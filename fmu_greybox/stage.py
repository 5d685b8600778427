"""One stage of the autoregressive grey-box: its features, its dataset, its one-step predictor.

Timing (see :mod:`fmu_greybox.simulate`): the prediction of the stage output at row ``j`` uses

* the exogenous inputs of row ``j - 1`` (the inputs that acted over the last step),
* the white-box prediction of the stage's output at row ``j``,
* the outputs of the earlier stages at row ``j`` (already computed this step),
* with ``feed_rates``, the changes over the last step of the earlier stages' outputs and of
  their residuals to the white-box (a velocity and a velocity error, for a position stage),
* the stage's own previous values at rows ``j - 1 ... j - L`` (its *memory*).

What the corrector learns (``target``):

``residual``
    ``r_j = y_j - y_wb_j``; memory holds previous residuals; output ``y_wb_j + r_j``.
``increment``
    ``r_j - r_{j-1}``; memory holds previous residuals; output ``y_wb_j + r_{j-1} + d_j``.
``output``
    ``y_j`` itself (the paper's formulation); memory holds previous outputs.

Training replaces the memory and the earlier stages' outputs by recorded values (teacher
forcing); a free run feeds back the predictions.

Every feature is a fixed linear combination of the stage's *sources*, one vector per row:

    exogenous inputs of row j-1 (n_exo) | white-box outputs of row j (Q) | stage outputs of
    row j (Q) | stage outputs of row j-1 (Q) | white-box outputs of row j-1 (Q) | the stage's
    memory, levels of rows j-1 ... j-L (L)

:meth:`StageLayout.feature_map` is that combination as a matrix; training applies it to
recorded sources (:meth:`StageLayout.teacher_forced`), the compiled chain step to the chain's
state (:mod:`fmu_greybox.chain_plan`), so the two cannot disagree on what a feature is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import TARGET_MODES, StageConfig

__all__ = ["SHARED_BLOCKS", "TARGET_MODES", "StageLayout"]

#: The per-stage blocks of the sources shared by all stages, in order (each Q long).
SHARED_BLOCKS = ("wb", "out", "prev_out", "prev_wb")


@dataclass
class StageLayout:
    """Where each feature of a stage comes from.

    Attributes
    ----------
    config : StageConfig
        The stage definition.
    target_mode : str
        One of :data:`TARGET_MODES`.
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
        """Length of the stage's memory."""
        return self.config.lags

    @property
    def n_rates(self) -> int:
        """Number of rate features (two per feeding stage with ``feed_rates``)."""
        return 2 * self.feed_index.size if self.config.feed_rates else 0

    @property
    def n_features(self) -> int:
        """Number of corrector inputs D."""
        return self.exo_index.size + 1 + self.feed_index.size + self.n_rates + self.lags

    @property
    def memory_slice(self) -> slice:
        """Positions of the memory features."""
        return slice(self.n_features - self.lags, self.n_features)

    def feature_names(self, exo_names: list[str], stage_names: list[str]) -> list[str]:
        """Human-readable names of the D features, in order."""
        own = "y" if self.target_mode == "output" else "r"
        return (
            [f"{exo_names[i]}[k-1]" for i in self.exo_index]
            + [f"{self.config.whitebox_output}_wb"]
            + [stage_names[i] for i in self.feed_index]
            + (
                [f"d{stage_names[i]}" for i in self.feed_index]
                + [f"d{stage_names[i]}.r" for i in self.feed_index]
                if self.config.feed_rates
                else []
            )
            + [f"{self.name}.{own}[k-{lag}]" for lag in range(1, self.lags + 1)]
        )

    # ------------------------------------------------------------------ levels
    def level(self, y: np.ndarray, y_wb: np.ndarray) -> np.ndarray:
        """Memory values from outputs: residuals, or the outputs themselves (mode ``output``)."""
        return y if self.target_mode == "output" else y - y_wb

    # ------------------------------------------------------------------ features
    def feature_map(self, n_exo: int, n_stages: int) -> np.ndarray:
        """The features as a linear map of the sources (see the module notes).

        Parameters
        ----------
        n_exo : int
            Length of the chain's exogenous vector.
        n_stages : int
            Q.

        Returns
        -------
        ndarray, shape (D, n_exo + 4 Q + L)
        """
        block = {name: n_exo + i * n_stages for i, name in enumerate(SHARED_BLOCKS)}
        memory = n_exo + len(SHARED_BLOCKS) * n_stages
        rows: list[dict[int, float]] = [{int(i): 1.0} for i in self.exo_index]
        rows.append({block["wb"] + self.stage_index: 1.0})
        feeds = [int(f) for f in self.feed_index]
        rows += [{block["out"] + f: 1.0} for f in feeds]
        if self.config.feed_rates:
            # the step change of each feeding stage's output, then of its residual
            rows += [{block["out"] + f: 1.0, block["prev_out"] + f: -1.0} for f in feeds]
            rows += [
                {
                    block["out"] + f: 1.0,
                    block["prev_out"] + f: -1.0,
                    block["wb"] + f: -1.0,
                    block["prev_wb"] + f: 1.0,
                }
                for f in feeds
            ]
        rows += [{memory + lag: 1.0} for lag in range(self.lags)]
        A = np.zeros((len(rows), memory + self.lags))
        for i, row in enumerate(rows):
            for column, weight in row.items():
                A[i, column] = weight
        return A

    # ------------------------------------------------------------------ datasets
    def teacher_forced(
        self,
        exo: np.ndarray,
        y_wb: np.ndarray,
        outputs: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Training rows with recorded values in place of every fed-back quantity.

        Parameters
        ----------
        exo : ndarray, shape (n, n_exo_chain)
            The chain's exogenous inputs per row.
        y_wb : ndarray, shape (n, n_stages)
            White-box predictions of every stage output per row.
        outputs : ndarray, shape (n, n_stages)
            Recorded stage outputs per row.

        Returns
        -------
        X : ndarray, shape (n - L, D)
            Features of rows ``L .. n-1``.
        t : ndarray, shape (n - L,)
            Corrector targets of those rows.
        """
        L = self.lags
        q = self.stage_index
        level = self.level(outputs[:, q], y_wb[:, q])
        rows = np.arange(L, outputs.shape[0])
        sources = np.hstack(
            [exo[rows - 1], y_wb[rows], outputs[rows], outputs[rows - 1], y_wb[rows - 1]]
            + [level[rows - lag][:, None] for lag in range(1, L + 1)]
        )
        X = sources @ self.feature_map(exo.shape[1], outputs.shape[1]).T
        if self.target_mode == "increment":
            t = level[rows] - level[rows - 1]
        else:
            t = level[rows]
        return np.ascontiguousarray(X), t
