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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import TARGET_MODES, StageConfig

__all__ = ["TARGET_MODES", "StageLayout"]


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
        feeds = self.feed_index
        columns = [
            exo[rows - 1][:, self.exo_index],
            y_wb[rows, q][:, None],
            outputs[rows][:, feeds],
        ]
        if self.config.feed_rates:
            d_out = outputs[rows][:, feeds] - outputs[rows - 1][:, feeds]
            d_wb = y_wb[rows][:, feeds] - y_wb[rows - 1][:, feeds]
            columns += [d_out, d_out - d_wb]
        columns += [level[rows - lag][:, None] for lag in range(1, L + 1)]
        X = np.hstack(columns)
        if self.target_mode == "increment":
            t = level[rows] - level[rows - 1]
        else:
            t = level[rows]
        return np.ascontiguousarray(X), t

    # ------------------------------------------------------------------ one step
    def assemble(
        self,
        x: np.ndarray,
        exo_prev: np.ndarray,
        y_wb: float,
        out_mean: np.ndarray,
        memory: np.ndarray,
        prev_mean: np.ndarray,
        wb: np.ndarray,
        prev_wb: np.ndarray,
    ) -> None:
        """Fill the feature vector ``x`` (shape (D,)) in place for one step.

        ``out_mean``/``wb`` hold this step's stage outputs and white-box predictions (earlier
        stages already updated), ``prev_mean``/``prev_wb`` those of the previous step.
        """
        n_exo = self.exo_index.size
        n_feed = self.feed_index.size
        x[:n_exo] = exo_prev[self.exo_index]
        x[n_exo] = y_wb
        pos = n_exo + 1
        x[pos : pos + n_feed] = out_mean[self.feed_index]
        pos += n_feed
        if self.config.feed_rates:
            feeds = self.feed_index
            d_out = out_mean[feeds] - prev_mean[feeds]
            x[pos : pos + n_feed] = d_out
            x[pos + n_feed : pos + 2 * n_feed] = d_out - (wb[feeds] - prev_wb[feeds])
        x[self.memory_slice] = memory

    def combine(
        self,
        mu: float,
        var_gp: float,
        grad: np.ndarray,
        y_wb: float,
        out_var: np.ndarray,
        memory: np.ndarray,
        memory_var: np.ndarray,
    ) -> tuple[float, float, float]:
        """Turn the corrector's prediction into the stage output and its variance.

        Variance propagation is first order (the delta method): the corrector's own latent
        variance plus, for every uncertain input ``i`` (earlier stages' outputs and the stage's
        memory), ``(d output / d input_i)^2 * var_i``; covariances between inputs are ignored,
        and rate features are taken as exact (their uncertainty is that of the outputs they
        are differences of, already counted through those outputs).

        Parameters
        ----------
        mu, var_gp : float
            Corrector mean and latent variance at the features.
        grad : ndarray, shape (D,)
            Gradient of the corrector mean with respect to the features.
        y_wb : float
            White-box prediction of the stage output.
        out_var : ndarray, shape (n_stages,)
            Variances of the stage outputs computed so far this step.
        memory, memory_var : ndarray, shape (L,)
            The stage's previous levels (most recent first) and their variances.

        Returns
        -------
        output, variance, level : float
            The stage output, its variance, and the level to push into the memory.
        """
        n_exo = self.exo_index.size
        n_feed = self.feed_index.size
        g_feed = grad[n_exo + 1 : n_exo + 1 + n_feed]
        g_mem = grad[self.memory_slice].copy()
        if self.target_mode == "increment":
            level = memory[0] + mu
            g_mem[0] += 1.0
        else:
            level = mu
        var = var_gp + float(g_feed**2 @ out_var[self.feed_index]) + float(g_mem**2 @ memory_var)
        output = level if self.target_mode == "output" else y_wb + level
        return output, var, level
