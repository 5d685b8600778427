"""Calibrated predictive uncertainty of a stage: the reported variance ``a V + b``.

A corrector's propagated variance ``V`` (its latent variance carried through the chain to first
order; :mod:`fmu_greybox.model.chain_step`) says how unsure the GP is of its own mean. It leaves
out the sensor noise of the recorded signal and every error the corrector does not know it makes
(the drift of a free run, a white-box error it was not trained to see), and a stage whose
corrector is switched off has ``V = 0``. What a test bench needs is the spread of the recording
about the prediction. Per stage, two numbers make one from the other:

    reported variance = a · V + b

``b`` [unit²] is the stage's residual variance: observation noise plus the model error that
``V`` does not carry (alone when the corrector is off); ``a`` scales ``V``. Both are estimated
on rows the correctors were not fitted to (:meth:`~fmu_greybox.model.chain.GreyBoxChain.fit`
free-runs each half of the training rows with correctors trained on the other half, and pairs
each residual with the ``V`` the chain that ships reports at that row), in two steps:

1. the shape, by maximum a posteriori: the residuals ``r`` as independent ``N(0, a V + b)`` and
   a log-normal prior on ``a`` centred on 1 (:data:`LATENT_SCALE_PRIOR`), so that ``a`` stays 1
   when ``V`` is too small or too even to tell it apart from ``b``;
2. the scale, by the split-conformal quantile: both are multiplied by the factor that puts
   exactly :data:`CALIBRATION_LEVEL` of those rows inside ±1.96 σ. Free-run residuals are
   neither Gaussian nor independent (a drift is a slow wave); matching the variance alone puts
   every sample of a sine-like error inside ±1.96 σ (coverage 1, not 0.95). The quantile holds
   whatever the distribution, on rows like those it was taken from.

:func:`coverage` measures the result on other rows, and :func:`coverage_interval` says how much
those rows can tell: a free run's errors come in slow waves and bursts, so a few thousand rows
may hold only a handful of independent ones, and a share of 100 % over them is no evidence that
the band is too wide.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize
from scipy.stats import beta

FloatArray = NDArray[np.float64]

#: Share of calibration rows placed inside ±:data:`Z95` σ.
CALIBRATION_LEVEL = 0.95
#: Half-width of the central 95 % interval of a standard normal.
Z95 = 1.959963984540054
#: Standard deviation of log ``a`` under its prior (``a`` within a factor e of 1 at 1 σ).
LATENT_SCALE_PRIOR = 1.0
#: Range searched for log ``a`` and for log ``b`` (relative to the mean square residual).
LOG_RANGE = (-30.0, 30.0)
#: Confidence of :func:`coverage_interval`.
INTERVAL_LEVEL = 0.95
#: Autocorrelations are summed up to the first lag where they fall below this.
CORRELATION_FLOOR = 0.05


@dataclass(frozen=True)
class VarianceCalibration:
    """The two numbers of one stage's reported variance ``latent_scale · V + residual_variance``.

    Attributes
    ----------
    latent_scale : float
        ``a`` (dimensionless, >= 0).
    residual_variance : float
        ``b`` [unit of the stage output, squared], >= 0.
    whitebox_variance : float or None
        ``c`` [unit squared]: the mean square residual of the stage's white-box on its training
        rows, the variance reported where the corrector fades out entirely (outside its domain,
        :mod:`fmu_greybox.model.chain_step`); ``None`` (a model folder written before it was
        kept): ``b``.
    """

    latent_scale: float = 1.0
    residual_variance: float = 0.0
    whitebox_variance: float | None = None

    def variance(self, latent_var: FloatArray) -> FloatArray:
        """The reported variance for propagated variances ``latent_var`` (any shape)."""
        return self.latent_scale * np.asarray(latent_var) + self.residual_variance


#: What an uncalibrated model (a folder of format 3 or older) reports: the propagated variance.
UNCALIBRATED = VarianceCalibration()


def fit_calibration(residual: FloatArray, latent_var: FloatArray) -> VarianceCalibration:
    """Estimate ``a`` and ``b`` from held-out residuals (see the module docstring).

    Parameters
    ----------
    residual : ndarray, shape (m,)
        Recorded minus predicted, on rows the corrector was not fitted to.
    latent_var : ndarray, shape (m,)
        The propagated variance ``V`` of those predictions (zeros for a stage passed through).

    Returns
    -------
    VarianceCalibration
        :data:`UNCALIBRATED` when no finite row is left or every residual is zero.
    """
    r = np.asarray(residual, dtype=np.float64)
    v = np.asarray(latent_var, dtype=np.float64)
    keep = np.isfinite(r) & np.isfinite(v)
    r, v = r[keep], np.maximum(v[keep], 0.0)
    scale = float(np.mean(r**2)) if r.size else 0.0
    if scale == 0.0:
        return UNCALIBRATED
    a, b_relative = _most_probable(r**2 / scale, v / scale)
    b = b_relative * scale
    z = np.abs(r) / np.sqrt(a * v + b)
    factor = (conformal_quantile(z, CALIBRATION_LEVEL) / Z95) ** 2
    return VarianceCalibration(latent_scale=a * factor, residual_variance=b * factor)


def left_out_shares(
    residuals: Sequence[FloatArray], latent_vars: Sequence[FloatArray]
) -> list[float]:
    """What one free run's share inside ±:data:`Z95` σ can be: each run's share with σ
    calibrated on the other runs alone (:func:`fit_calibration`).

    A band calibrated on many rows holds about 95 % of them pooled, yet one recording of a
    slowly drifting stage holds a share that depends on how far that recording drifts. The
    shares of left-out runs are that spread, measured on recordings of the calibration's kind.

    Parameters
    ----------
    residuals, latent_vars : sequence of ndarray, each shape (m_i,)
        Per free run, as for :func:`fit_calibration`.

    Returns
    -------
    list of float
        One share per run (NaN for a run with no rows); ``[]`` for fewer than two runs.
    """
    if len(residuals) < 2:
        return []
    shares = []
    for i, (r, v) in enumerate(zip(residuals, latent_vars, strict=True)):
        others = [j for j in range(len(residuals)) if j != i]
        left_out = fit_calibration(
            np.concatenate([residuals[j] for j in others]),
            np.concatenate([latent_vars[j] for j in others]),
        )
        shares.append(coverage(r, np.sqrt(left_out.variance(np.maximum(v, 0.0))), Z95))
    return shares


def _most_probable(r2: FloatArray, v: FloatArray) -> tuple[float, float]:
    """``(a, b)`` maximising the Gaussian likelihood of ``r2 = r²`` with variance ``a v + b``
    times the prior on ``a`` (normalised units: mean of ``r2`` is 1)."""

    def objective(theta: FloatArray) -> tuple[float, FloatArray]:
        a, b = np.exp(theta)
        s = a * v + b
        misfit = (1.0 - r2 / s) / s  # d/ds of log s + r²/s (no s² to overflow)
        value = 0.5 * np.sum(np.log(s) + r2 / s) + 0.5 * (theta[0] / LATENT_SCALE_PRIOR) ** 2
        grad = np.array(
            [
                0.5 * np.sum(misfit * a * v) + theta[0] / LATENT_SCALE_PRIOR**2,
                0.5 * np.sum(misfit) * b,
            ]
        )
        return float(value), grad

    result = minimize(
        objective, np.zeros(2), jac=True, method="L-BFGS-B", bounds=[LOG_RANGE, LOG_RANGE]
    )
    a, b = np.exp(result.x)
    return float(a), float(b)


def conformal_quantile(scores: FloatArray, level: float) -> float:
    """The split-conformal ``level`` quantile of ``scores``: the ``ceil((m + 1) level)``-th
    smallest of ``m`` (the largest when that exceeds ``m``).

    Parameters
    ----------
    scores : ndarray, shape (m,)
    level : float
        In (0, 1).
    """
    ordered = np.sort(np.asarray(scores, dtype=np.float64))
    rank = min(ordered.size, math.ceil((ordered.size + 1) * level))
    return float(ordered[rank - 1])


def coverage(residual: FloatArray, std: FloatArray, width: float) -> float:
    """Share of samples with ``|residual| <= width · std`` (NaN when there are none).

    Parameters
    ----------
    residual, std : ndarray, shape (m,)
        Recorded minus predicted, and the predictive standard deviation.
    width : float
        Half-width of the band in standard deviations (1 for ±1σ, :data:`Z95` for 95 %).
    """
    r = np.abs(np.asarray(residual, dtype=np.float64))
    s = np.asarray(std, dtype=np.float64)
    return float(np.mean(r <= width * s)) if r.size else float("nan")


@dataclass(frozen=True)
class CoverageEstimate:
    """The share of rows inside a band, and how well those rows determine it.

    Attributes
    ----------
    share : float
        Share of rows inside (NaN when there are none).
    low, high : float
        The :data:`INTERVAL_LEVEL` confidence interval of the share a longer recording of the
        same kind would give.
    independent_rows : float
        The rows' count divided by the autocorrelation time of the normalised residual: how
        many independent rows they are worth.
    """

    share: float
    low: float
    high: float
    independent_rows: float


def autocorrelation_time(residual: np.ndarray, max_lag: int | None = None) -> float:
    """Integrated autocorrelation time of a residual, averaged over its columns by energy.

    ``tau = 1 + 2 sum_k rho_k``, summed while the autocorrelation stays above
    :data:`CORRELATION_FLOOR` (a white residual gives 1; a slowly drifting one gives hundreds).
    The rows of a residual count as ``n / tau`` independent ones: for the diagnosis' tests of
    its hypotheses and for :func:`coverage_interval`.

    Parameters
    ----------
    residual : ndarray, shape (n,) or (n, m)
    max_lag : int, optional
        Largest lag considered (default ``n // 4``).

    Returns
    -------
    float
        ``tau >= 1``.
    """
    r = np.atleast_2d(np.asarray(residual, dtype=np.float64).T).T
    n = r.shape[0]
    if n < 8:
        return 1.0
    max_lag = max_lag or n // 4
    size = 1 << math.ceil(math.log2(2 * n))
    taus, weights = [], []
    for x in r.T:
        x = x - x.mean()
        energy = float(np.dot(x, x))
        if energy <= 0:
            continue
        spectrum = np.fft.rfft(x, size)
        acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[: max_lag + 1] / energy
        below = np.flatnonzero(acf[1:] < CORRELATION_FLOOR)
        stop = int(below[0]) if below.size else max_lag
        taus.append(1.0 + 2.0 * float(np.sum(acf[1 : stop + 1])))
        weights.append(energy)
    if not taus:
        return 1.0
    return max(1.0, float(np.average(taus, weights=weights)))


def independent_rows(residual: FloatArray, std: FloatArray) -> float:
    """How many independent rows a free run's residual is worth for a share inside its band.

    ``m / tau``, ``tau`` the :func:`autocorrelation_time` of the normalised residual's size
    ``|residual| / std``, of which inside-or-outside is a function (the indicator's own
    correlation cannot be estimated when every row is inside; the size, unlike the sign, stays
    correlated when an error rings). A row with ``std`` 0 is far outside: a large size stands in.

    Parameters
    ----------
    residual, std : ndarray, shape (m,)
        Recorded minus predicted, and the predictive standard deviation.

    Returns
    -------
    float
        In ``(0, m]``; 0 for no rows.
    """
    r = np.abs(np.asarray(residual, dtype=np.float64))
    if not r.size:
        return 0.0
    s = np.asarray(std, dtype=np.float64)
    with np.errstate(over="ignore"):
        size = np.minimum(r / np.maximum(s, np.finfo(np.float64).tiny), 1e3)
    return r.size / autocorrelation_time(size)


def error_independent_rows(residual: FloatArray) -> float:
    """How many independent rows a free run's errors are worth for learning their size.

    ``m / tau``, ``tau`` the :func:`autocorrelation_time` of the residual itself. A free run's
    error is sensor noise (a new draw each row) plus a slow part, a drift that lasts seconds;
    only the slow part's memory says how many times the calibration saw it afresh, and the
    size's (:func:`independent_rows`) can hide it under the noise. On AR(1) errors the
    :func:`calibration_spread` of this count holds the band's share on an endless recording
    of the same kind in at least 92 % of calibrations (``tests/test_calibration.py``, up to
    ``phi`` = 0.999).

    Parameters
    ----------
    residual : ndarray, shape (m,)

    Returns
    -------
    float
        In ``(0, m]``; 0 for no rows.
    """
    r = np.asarray(residual, dtype=np.float64)
    r = r[np.isfinite(r)]
    return r.size / autocorrelation_time(r) if r.size else 0.0


def calibration_rows(residual: FloatArray, std: FloatArray) -> float:
    """How many independent rows a calibration's free-run residuals are worth for the band
    fitted to them: the fewer of two counts, each blind to what the other sees.

    :func:`error_independent_rows` follows the error's own memory: a drift that lasts seconds,
    which the size's count hides under sensor noise. :func:`independent_rows` follows the
    memory of the error's size against the band: errors whose sign changes every row but whose
    size grows and shrinks with the manoeuvre (a valve's error during fast motion, none at
    rest), which look white to the first count. A band's share depends on both, so its rows
    are worth no more than the longer memory allows. On white errors whose size switches
    between two levels every 1-3 s, the :func:`calibration_spread` of this count holds the
    band's share on an endless recording of the same kind in at least 92 % of calibrations;
    that of the error's count alone, which sees 19 000 independent rows in 19 000, in a
    fraction of them (``tests/test_calibration.py``).

    Parameters
    ----------
    residual : ndarray, shape (m,)
        The calibration's free-run residuals (recorded minus predicted).
    std : ndarray, shape (m,)
        The calibrated standard deviation of those rows.

    Returns
    -------
    float
        In ``(0, m]``; 0 for no rows.
    """
    r = np.asarray(residual, dtype=np.float64)
    s = np.asarray(std, dtype=np.float64)
    keep = np.isfinite(r) & np.isfinite(s)
    return min(error_independent_rows(r[keep]), independent_rows(r[keep], s[keep]))


def calibration_spread(rows: float, level: float = CALIBRATION_LEVEL) -> tuple[float, float]:
    """Where a band calibrated on ``rows`` independent rows holds, on recordings of their kind.

    The split-conformal quantile puts ``level`` of its own rows inside; the share it holds on an
    endless recording of the same kind is itself random, and for ``n`` independent rows follows
    ``Beta(l, n + 1 - l)``, ``l = ceil((n + 1) level)`` (at most ``n``), whatever the rows'
    distribution. This gives its :data:`INTERVAL_LEVEL` range. Few rows cannot vouch for a
    band: 5 give 0.48-0.995, 80 give 0.89-0.99, 1 000 give 0.94-0.96.

    Parameters
    ----------
    rows : float
        The calibration's independent rows (:func:`calibration_rows`; rounded down).
    level : float
        The share the calibration put inside.

    Returns
    -------
    (low, high) : tuple of float
        NaN for fewer than one row.
    """
    n = math.floor(rows)
    if n < 1:
        return float("nan"), float("nan")
    tail = (1.0 - INTERVAL_LEVEL) / 2.0
    low, high = _coverage_law(n, level).ppf([tail, 1.0 - tail])
    return float(low), float(high)


def _coverage_law(n: int | np.ndarray, level: float) -> Any:
    """The Beta law of the share a split-conformal band calibrated on ``n`` (>= 1, or an
    array of such) exchangeable rows holds on an endless recording of their kind (frozen
    ``scipy.stats.beta``)."""
    rank = np.minimum(n, np.ceil((np.asarray(n) + 1) * level))
    return beta(rank, np.asarray(n) + 1 - rank)


def chance_within(
    rows: float, bounds: tuple[float, float], level: float = CALIBRATION_LEVEL
) -> float:
    """The chance that a band calibrated on ``rows`` independent rows holds a share within
    ``bounds`` of an endless recording of the same kind (the Beta law of
    :func:`calibration_spread`): 0.36 for 5 rows and 0.90-0.99, 0.70 for 20, 1.00 for 2 000.
    NaN for fewer than one row."""
    n = math.floor(rows)
    if n < 1:
        return float("nan")
    law = _coverage_law(n, level)
    return float(law.cdf(bounds[1]) - law.cdf(bounds[0]))


@functools.lru_cache(maxsize=64)
def rows_to_vouch(
    bounds: tuple[float, float], level: float = CALIBRATION_LEVEL, most: int = 20_000
) -> int | None:
    """The fewest independent calibration rows from which on every :func:`calibration_spread`
    lies within ``bounds``: 100 for 0.90-0.99 (85 already do, but not 99).

    Parameters
    ----------
    bounds : (float, float)
        The limits of the share inside the band.
    level : float
        The share the calibration put inside.
    most : int
        Largest count considered.

    Returns
    -------
    int or None
        ``None`` when even ``most`` rows do not (limits narrower than any calibration vouches
        for, or not around ``level``).
    """
    law = _coverage_law(np.arange(1, most + 1), level)
    tail = (1.0 - INTERVAL_LEVEL) / 2.0
    low, high = law.ppf(tail), law.ppf(1.0 - tail)
    short = np.flatnonzero((low < bounds[0]) | (high > bounds[1]))
    if short.size and short[-1] == most - 1:
        return None
    return int(short[-1]) + 2 if short.size else 1


def coverage_interval(
    residual: FloatArray, std: FloatArray, width: float, trials: float | None = None
) -> CoverageEstimate:
    """:func:`coverage` with its confidence interval: Clopper-Pearson's for ``trials``
    Bernoulli trials (default :func:`independent_rows`).

    Parameters
    ----------
    residual, std : ndarray, shape (m,)
        Recorded minus predicted, and the predictive standard deviation.
    width : float
        Half-width of the band in standard deviations.
    trials : float, optional
        The rows' worth, when already known (it does not depend on ``width``).

    Returns
    -------
    CoverageEstimate
    """
    share = coverage(residual, std, width)
    trials = independent_rows(residual, std) if trials is None else trials
    return _share_interval(share, float(trials))


def pooled_coverage(estimates: Sequence[CoverageEstimate]) -> CoverageEstimate:
    """One share over several recordings' bands: each share weighted by its independent rows,
    with the interval of their sum.

    A drifting stage's recording is worth a handful of independent rows, too few for its share
    alone to tell a calibrated band from a wide or narrow one; over many recordings of the same
    kind of stage (different seeds, so independent of each other) the rows add up.

    Parameters
    ----------
    estimates : sequence of CoverageEstimate
        One per recording and stage; those without independent rows are left out.

    Returns
    -------
    CoverageEstimate
        NaN share and interval when no estimate has rows.
    """
    kept = [e for e in estimates if e.independent_rows > 0 and e.share == e.share]
    trials = sum(e.independent_rows for e in kept)
    if not trials:
        return CoverageEstimate(float("nan"), float("nan"), float("nan"), 0.0)
    share = sum(e.share * e.independent_rows for e in kept) / trials
    return _share_interval(share, trials)


def _share_interval(share: float, trials: float) -> CoverageEstimate:
    """``share`` with the Clopper-Pearson :data:`INTERVAL_LEVEL` interval of ``trials``
    Bernoulli trials (a fractional count of hits and trials, as the beta quantiles allow)."""
    if not trials:
        return CoverageEstimate(share, float("nan"), float("nan"), 0.0)
    hits = share * trials
    tail = (1.0 - INTERVAL_LEVEL) / 2.0
    low = float(beta.ppf(tail, hits, trials - hits + 1.0)) if hits > 0 else 0.0
    high = float(beta.ppf(1.0 - tail, hits + 1.0, trials - hits)) if hits < trials else 1.0
    return CoverageEstimate(share, low, high, trials)
