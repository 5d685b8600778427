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

from dataclasses import dataclass, field

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
    # the same positions as tuples of ints, for the per-step path on Python floats
    _exo: tuple[int, ...] = field(init=False, repr=False, compare=False)
    _feeds: tuple[int, ...] = field(init=False, repr=False, compare=False)
    _first_memory: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._exo = tuple(int(i) for i in self.exo_index)
        self._feeds = tuple(int(i) for i in self.feed_index)
        self._first_memory = self.n_features - self.lags

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
    # Python floats and lists, not numpy: with a handful of features, each numpy call would
    # cost more than the arithmetic it does (this runs once per stage and communication step)
    def assemble(
        self,
        exo_prev: list[float],
        y_wb: float,
        out_mean: list[float],
        prev_mean: list[float],
        wb: list[float],
        prev_wb: list[float],
        memory: list[float],
    ) -> list[float]:
        """The feature vector of one step, length D.

        ``exo_prev`` holds the chain's exogenous inputs of the previous row, ``out_mean``/``wb``
        this step's stage outputs and white-box predictions (earlier stages already updated),
        ``prev_mean``/``prev_wb`` those of the previous step, ``memory`` the stage's previous
        levels (most recent first).
        """
        x = [exo_prev[i] for i in self._exo]
        x.append(y_wb)
        feeds = self._feeds
        x += [out_mean[f] for f in feeds]
        if self.config.feed_rates:
            d_out = [out_mean[f] - prev_mean[f] for f in feeds]
            x += d_out
            x += [d - (wb[f] - prev_wb[f]) for d, f in zip(d_out, feeds, strict=True)]
        x += memory
        return x

    def combine(
        self,
        mu: float,
        var_gp: float,
        grad: list[float],
        y_wb: float,
        out_var: list[float],
        memory: list[float],
        memory_var: list[float],
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
        grad : list of float, length D
            Gradient of the corrector mean with respect to the features.
        y_wb : float
            White-box prediction of the stage output.
        out_var : list of float, length n_stages
            Variances of the stage outputs computed so far this step.
        memory, memory_var : list of float, length L
            The stage's previous levels (most recent first) and their variances.

        Returns
        -------
        output, variance, level : float
            The stage output, its variance, and the level to push into the memory.
        """
        feeds = self._feeds
        first_feed = len(self._exo) + 1
        from_feeds = 0.0
        for g, f in zip(grad[first_feed : first_feed + len(feeds)], feeds, strict=True):
            from_feeds += g * g * out_var[f]
        g_mem = grad[self._first_memory :]
        if self.target_mode == "increment":
            level = memory[0] + mu
            g_mem[0] += 1.0
        else:
            level = mu
        from_memory = 0.0
        for g, v in zip(g_mem, memory_var, strict=True):
            from_memory += g * g * v
        var = var_gp + from_feeds + from_memory
        output = level if self.target_mode == "output" else y_wb + level
        return output, var, level
