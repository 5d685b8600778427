"""The noise a residual carries when the white-box is right: sensor noise, and the drift that the
noise on the recorded inputs drives through the white-box (errors in variables).

Three estimates, each from the recording and the FMU, none from a model of the test:

* **sensor noise** of an observed signal (:func:`sensor_noise_level`): the robust white-noise
  level of its second differences (:func:`noise_level`), taken of the recording and of its
  residual against the white-box, whichever is smaller. Both are the sensor noise plus
  something that is not negative: the signal's own fast dynamics (an armature current with a
  1.7 ms time constant moves a lot between samples) or the white-box's error; where the
  white-box follows the fast dynamics, the residual is the tighter bound.
* **input noise** of a recorded input (:func:`input_noise_levels`): the part of its fast
  content that no other recorded signal explains, read as white noise. A logged command's
  genuine fast content (a controller's reaction to its own sensors' noise, which the plant then
  follows) is explained by the recorded outputs; the noise of the sensor that logged it is
  explained by nothing, since the plant never felt it.
* **smoothed inputs** (:class:`InputSmoother`): each noisy input is Wiener-smoothed against its
  noise before it drives any simulation, so that fits answer the inputs and not their sensors'
  noise (whose answer through the FMU depends on the magnitudes fitted: errors in variables).
* **input-noise drift** (:class:`DriftWhitening`): the white-box is run again with a fresh draw
  of each smoothed input's remaining error; the spread of the outputs is what input noise
  alone drives (an integrating output such as an angle or a position wanders like a random
  walk). Its spectrum, against the sensor noise's, sets a zero-phase whitening filter per
  observed signal: frequencies where input-noise drift dominates count less, in proportion.
  Every residual the diagnosis judges or fits is whitened so (``Experiment.residual``), which
  makes a correct white-box's residual white at the sensor-noise level even when an output
  integrates noisy inputs, and keeps the fit of an integrating output well conditioned.
"""

from __future__ import annotations

import copy
import functools
import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from fmu_greybox.side_by_side import run_side_by_side

#: A residual is significant when its RMS exceeds this many noise levels: structure of about
#: 0.83 noise levels (RMS) on top of the noise.
SIGNIFICANT_RATIO = 1.3
#: The RMS of structure that makes a residual significant, in noise levels.
SIGNIFICANT_STRUCTURE = (SIGNIFICANT_RATIO**2 - 1.0) ** 0.5
#: Chance, under noise alone, that some frequency band of a residual looks structured.
BAND_FALSE_ALARM = 1e-3
#: Lags (either side) of the other recorded signals that explain an input's fast content.
INPUT_LAGS = 2
#: Relative width of the frequency smoothing of the drift spectrum (a fraction of the frequency).
SMOOTHING_WIDTH = 0.1


def noise_level(x: np.ndarray) -> float:
    """Standard deviation of a signal's white sensor noise, from its high-frequency content.

    Robust and model-free: the median absolute deviation of the second differences divided by
    ``sqrt(6)`` (a second difference of white noise of variance s^2 has variance 6 s^2), scaled
    to a standard deviation. Smooth signal content barely contributes at usual sample rates.

    Parameters
    ----------
    x : ndarray, shape (n,)

    Returns
    -------
    float
        Estimated noise standard deviation (0 for fewer than 4 samples or a constant signal).
    """
    if x.size < 4:
        return 0.0
    d2 = np.diff(np.asarray(x, dtype=np.float64), 2)
    mad = np.median(np.abs(d2 - np.median(d2)))
    return float(1.4826 * mad / np.sqrt(6.0))


def sensor_noise_level(recorded: np.ndarray, simulated: np.ndarray) -> float:
    """Sensor noise of one observed signal: the smaller of the noise levels of the recording
    and of its residual against the white-box.

    Parameters
    ----------
    recorded, simulated : ndarray, shape (n,)

    Returns
    -------
    float
    """
    return min(noise_level(recorded), noise_level(recorded - simulated))


def input_noise_levels(u: np.ndarray, others: np.ndarray, lags: int = INPUT_LAGS) -> np.ndarray:
    """Sensor noise of each recorded input: the white-noise level of the part of its second
    differences that no other recorded signal explains.

    The second differences of an input are regressed on those of every other recorded signal
    (inputs and outputs) at lags ``-lags .. lags`` by least squares, trimmed of the rows beyond
    four robust standard deviations (reference steps, saturation), three times; the robust
    level of what is left, over ``sqrt(6)``, is the noise. A closed-loop command's fast content
    is its controller's reaction to the recorded sensors' noise and is explained; the noise of
    the sensor that logged it is explained by nothing (the plant never felt it). Fast content
    that no recorded signal explains counts as noise, so the level is an upper bound.

    Parameters
    ----------
    u : ndarray, shape (n, n_inputs)
        Recorded inputs.
    others : ndarray, shape (n, n_observed)
        Recorded outputs.
    lags : int
        Lags either side.

    Returns
    -------
    ndarray, shape (n_inputs,)
        Standard deviations (0 for a constant input).
    """
    d2 = np.diff(np.column_stack([u, others]), 2, axis=0)
    spread = d2.std(axis=0)
    rows = slice(lags, d2.shape[0] - lags)
    levels = np.zeros(u.shape[1])
    for i in range(u.shape[1]):
        target = d2[rows, i]
        if spread[i] == 0 or target.size < 8:
            continue
        regressors = [
            np.roll(d2[:, j] / spread[j], lag)[rows]
            for j in range(d2.shape[1])
            if j != i and spread[j] > 0
            for lag in range(-lags, lags + 1)
        ]
        x = np.column_stack(regressors) if regressors else np.zeros((target.size, 0))
        keep = np.ones(target.size, dtype=bool)
        for _ in range(3):
            coef = np.linalg.lstsq(x[keep], target[keep], rcond=None)[0]
            left = target - x @ coef
            scale = 1.4826 * float(np.median(np.abs(left - np.median(left))))
            keep = np.abs(left) <= 4.0 * scale
        levels[i] = scale / np.sqrt(6.0)
    return levels


class InputSmoother:
    """Zero-phase Wiener smoothing of the recorded inputs against their sensor noise.

    A recorded input is its true value plus the white noise of the sensor that logged it
    (:func:`input_noise_levels`). Simulated over it, the white-box also answers the noise: in a
    least-squares fit that answer's power depends on the hypotheses' magnitudes (a softer
    actuator passes less of it), which biases them (errors in variables). Per input and
    frequency, the gain ``H = max(0, 1 - N / S)`` (``S`` the input's smoothed power spectrum,
    ``N`` its noise's) keeps what stands above the noise and drops what does not; what is left
    of the error has the spectrum ``H N`` (the Wiener error), which :meth:`noise` draws for the
    drift estimate. The filter runs over the input followed by its mirror image (no jump at the
    wrap), so it adds no lag and no end transients.

    Parameters
    ----------
    u : ndarray, shape (n, n_inputs)
        Recorded inputs.
    sigma : ndarray, shape (n_inputs,)
        Their noise levels (0: leave that input as it is).

    Attributes
    ----------
    gain : ndarray, shape (n + 1, n_inputs)
        ``H`` on the rfft grid of the mirrored inputs (``2 n`` samples).
    """

    def __init__(self, u: np.ndarray, sigma: np.ndarray) -> None:
        n = u.shape[0]
        power = np.abs(np.fft.rfft(_mirrored(u, 0), axis=0)) ** 2
        noise = 2 * n * np.asarray(sigma, dtype=np.float64) ** 2
        smoothed = np.maximum(_smooth(power), 1e-300)
        self.gain = np.clip(1.0 - noise / smoothed, 0.0, 1.0)
        self.gain[0] = 1.0

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """The inputs smoothed, shape (n, n_inputs) (a new array)."""
        return self._filtered(u, self.gain)

    def noise(self, rng: np.random.Generator, sigma: np.ndarray) -> np.ndarray:
        """A draw of the error left in the smoothed inputs: white noise at ``sigma`` shaped by
        ``sqrt(H)``, shape (n, n_inputs)."""
        n = self.gain.shape[0] - 1
        white = rng.standard_normal((n, self.gain.shape[1])) * sigma
        return self._filtered(white, np.sqrt(self.gain))

    @staticmethod
    def _filtered(x: np.ndarray, gain: np.ndarray) -> np.ndarray:
        n = x.shape[0]
        spectrum = np.fft.rfft(_mirrored(x, 0), axis=0) * gain
        return np.fft.irfft(spectrum, n=2 * n, axis=0)[:n]


class DriftWhitening:
    """Zero-phase whitening of residuals against the drift that input noise drives.

    Parameters
    ----------
    deviations : ndarray, shape (runs, n, n_observed)
        Simulated outputs with re-noised inputs minus the simulation with the recorded inputs.
    sigma : ndarray, shape (n_observed,)
        Sensor-noise levels.
    dt : float
        Sample time [s].

    Attributes
    ----------
    frequency : ndarray, shape (n_freq,)
        Frequencies [Hz] of :attr:`ratio`.
    ratio : ndarray, shape (n_freq, n_observed)
        Power of the input-noise drift over the sensor noise's, per frequency (smoothed).
    drift : ndarray, shape (n_observed,)
        RMS of the input-noise drift in sensor-noise levels.
    """

    def __init__(self, deviations: np.ndarray, sigma: np.ndarray, dt: float) -> None:
        n = deviations.shape[1]
        self.dt = dt
        self.frequency = np.fft.rfftfreq(2 * n, dt)
        power = np.mean(np.abs(np.fft.rfft(_mirrored(deviations, 1), axis=1)) ** 2, axis=0)
        self.ratio = _smooth(power / (2 * n * sigma**2))
        self.drift = np.sqrt(np.mean(deviations**2, axis=(0, 1))) / sigma
        self._weights: dict[int, np.ndarray] = {}

    def columns(self, which: Sequence[int]) -> DriftWhitening:
        """The whitening of some of the signals only, in the order of ``which``."""
        chosen = copy.copy(self)
        chosen.ratio = self.ratio[:, list(which)]
        chosen.drift = self.drift[list(which)]
        chosen._weights = {}
        return chosen

    def weights(self, n: int) -> np.ndarray:
        """Gain of the whitening filter on the rfft grid of ``n`` samples, shape
        (n // 2 + 1, n_observed) (read-only: kept for the next residual of that length)."""
        if n not in self._weights:
            freq = np.fft.rfftfreq(n, self.dt)
            ratio = np.column_stack(
                [np.interp(freq, self.frequency, column) for column in self.ratio.T]
            )
            gain = 1.0 / np.sqrt(1.0 + ratio)
            gain.setflags(write=False)
            self._weights[n] = gain
        return self._weights[n]

    def __call__(self, residual: np.ndarray) -> np.ndarray:
        """The residual, whitened column by column (a new array, same shape (n, n_observed)).

        The filter runs over the residual followed by its mirror image, so that it sees no jump
        where the discrete transform wraps the end onto the start: a drift that ends far from
        where it started would otherwise leave transients at both ends.
        """
        n = residual.shape[0]
        if n < 2:
            return residual.copy()
        spectrum = np.fft.rfft(_mirrored(residual, 0), axis=0) * self.weights(2 * n)
        return np.fft.irfft(spectrum, n=2 * n, axis=0)[:n]


def floored_levels(levels: Sequence[float], recorded: np.ndarray) -> np.ndarray:
    """Noise levels floored at 1e-6 of each signal's RMS (for noise-free recordings).

    Parameters
    ----------
    levels : sequence of float, length k
    recorded : ndarray, shape (n, k)

    Returns
    -------
    ndarray, shape (k,)
    """
    floor = 1e-6 * np.sqrt(np.mean(recorded**2, axis=0)) + 1e-300
    return np.maximum(np.asarray(levels, dtype=np.float64), floor)


@dataclass
class NoiseModel:
    """What noise a recording's residual against a right white-box carries
    (:func:`estimate_noise_model`).

    Attributes
    ----------
    input_sigma : ndarray, shape (n_inputs,)
        Each recorded input's noise level (0: none found).
    smoother : InputSmoother or None
        Smooths the noisy inputs (None when no input is noisy).
    u : ndarray, shape (n, n_inputs)
        The inputs the white-box was run over (smoothed where noisy).
    simulated : ndarray, shape (n, n_outputs)
        The white-box over ``u``.
    sigma : ndarray, shape (n_outputs,)
        Each output's sensor-noise level (:func:`floored_levels`).
    whitening : DriftWhitening or None
        Against the drift input noise drives (None when no input is noisy).
    """

    input_sigma: np.ndarray
    smoother: InputSmoother | None
    u: np.ndarray
    simulated: np.ndarray
    sigma: np.ndarray
    whitening: DriftWhitening | None

    def judge(self) -> ResidualJudge:
        """The judge of residuals of these outputs (:class:`ResidualJudge`)."""
        return ResidualJudge(self.sigma, self.whitening)


def estimate_noise_model(
    u: np.ndarray,
    recorded: np.ndarray,
    simulate: Callable[[np.ndarray], np.ndarray | None],
    dt: float,
    runs: int = 4,
    seed: int = 0,
    side_by_side: bool = False,
) -> NoiseModel | None:
    """Estimate the noise of a recording against its white-box (see the module docstring).

    Each recorded input's noise is estimated and noisy inputs are smoothed against it; then,
    against the white-box over those inputs, each output's sensor noise, and the whitening
    against the drift that ``runs`` simulations with the inputs' remaining error re-drawn show.

    Parameters
    ----------
    u : ndarray, shape (n, n_inputs)
        Recorded inputs.
    recorded : ndarray, shape (n, n_outputs)
        Recorded outputs.
    simulate : callable
        The white-box over inputs of shape (n, n_inputs): outputs of shape (n, n_outputs), or
        None if it fails.
    dt : float
        Sample time [s].
    runs : int
        Simulations with re-drawn input error.
    seed : int
        Seed of the re-drawing.
    side_by_side : bool
        Run the re-drawn simulations in threads side by side
        (:func:`~fmu_greybox.side_by_side.run_side_by_side`): ``simulate`` may be called from
        several threads at once. The same numbers either way (the draws are made first, in
        turn).

    Returns
    -------
    NoiseModel or None
        None if the white-box fails on the (smoothed) inputs.
    """
    input_sigma = input_noise_levels(u, recorded)
    smoother = InputSmoother(u, input_sigma) if np.any(input_sigma > 0) else None
    if smoother is not None:
        u = smoother(u)
    simulated = simulate(u)
    if simulated is None:
        return None
    levels = [sensor_noise_level(r, s) for r, s in zip(recorded.T, simulated.T, strict=True)]
    sigma = floored_levels(levels, recorded)
    whitening = None
    if smoother is not None and runs >= 1:
        rng = np.random.default_rng(seed)
        drawn = [u + smoother.noise(rng, input_sigma) for _ in range(runs)]
        tasks = [functools.partial(simulate, inputs) for inputs in drawn]
        runs_ = run_side_by_side(tasks) if side_by_side else [task() for task in tasks]
        deviations = [run - simulated for run in runs_ if run is not None]
        if deviations:
            whitening = DriftWhitening(np.array(deviations), sigma, dt)
    return NoiseModel(input_sigma, smoother, u, simulated, sigma, whitening)


@dataclass(frozen=True)
class ResidualJudge:
    """Residuals as a part is judged on them: in units of each signal's sensor noise, and
    whitened against the drift that input noise drives (:class:`DriftWhitening`).

    A drift is one realisation of noise: the next recording has another, and no model predicts
    it. Judged raw, a corrector that learns where the drift of its own recording happens to
    wander wins on that recording's later rows and loses on the next one; whitened, the
    frequencies where drift dominates count in proportion to what noise alone explains.

    Attributes
    ----------
    sigma : ndarray, shape (k,)
        Each signal's sensor-noise level.
    whitening : DriftWhitening or None
        Over the same ``k`` signals (None: no input noise, nothing to whiten).
    """

    sigma: np.ndarray
    whitening: DriftWhitening | None = None

    def __call__(self, residual: np.ndarray) -> np.ndarray:
        """The judged residual, shape (m, k), of a residual of shape (m, k) (a new array)."""
        normalised = np.asarray(residual, dtype=np.float64) / self.sigma
        return normalised if self.whitening is None else self.whitening(normalised)


def _mirrored(x: np.ndarray, axis: int) -> np.ndarray:
    """``x`` followed by its mirror image along ``axis`` (twice as long, no jump at the wrap)."""
    return np.concatenate([x, np.flip(x, axis=axis)], axis=axis)


def _smooth(power: np.ndarray) -> np.ndarray:
    """Each column averaged over a window of bins growing with frequency (about
    :data:`SMOOTHING_WIDTH` of the frequency either side; the lowest bins over three)."""
    n = power.shape[0]
    index = np.arange(n)
    half = np.maximum(1, (SMOOTHING_WIDTH * index).astype(int))
    lo = np.clip(index - half, 0, n - 1)
    hi = np.clip(index + half, 0, n - 1)
    total = np.vstack([np.zeros((1, power.shape[1])), np.cumsum(power, axis=0)])
    return (total[hi + 1] - total[lo]) / (hi - lo + 1)[:, None]


def band_edges(n_freq: int) -> list[tuple[int, int]]:
    """Bands of an rfft grid of ``n_freq`` bins: the mean alone, then third octaves (at least one
    bin each), as ``(first, stop)`` bin indices."""
    edges = [0, 1]
    while edges[-1] < n_freq:
        edges.append(min(n_freq, max(edges[-1] + 1, round(edges[-1] * 2 ** (1 / 3)))))
    return list(itertools.pairwise(edges))


@dataclass
class Bands:
    """A residual's power band by band, against the noise a right white-box leaves.

    Attributes
    ----------
    edges : list of (int, int)
        Bins of each band (:func:`band_edges`).
    frequency : ndarray, shape (n_bands, 2)
        Lowest and highest frequency of each band [Hz].
    whitened : ndarray, shape (n_bands, n_observed)
        Mean power of the whitened residual per bin (1 under noise alone).
    threshold : ndarray, shape (n_bands,)
        The level ``whitened`` exceeds by chance with probability :data:`BAND_FALSE_ALARM`
        shared by the bands.
    excess : ndarray, shape (n_bands, n_observed)
        The band's share of the residual's mean square beyond what sensor noise and input-noise
        drift explain, in squared noise levels.
    """

    edges: list[tuple[int, int]]
    frequency: np.ndarray
    whitened: np.ndarray
    threshold: np.ndarray
    excess: np.ndarray

    @property
    def structured(self) -> np.ndarray:
        """Bands beyond chance, shape (n_bands, n_observed)."""
        return self.whitened > self.threshold[:, None]

    @property
    def significant(self) -> np.ndarray:
        """Bands beyond chance whose excess is significant structure on its own (RMS of
        :data:`SIGNIFICANT_STRUCTURE` noise levels), shape (n_bands, n_observed)."""
        return self.structured & (self.excess >= SIGNIFICANT_STRUCTURE**2)

    def structure(self, where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whitened power beyond noise in the bands ``where``, summed over their bins, and the
        same at the chance threshold of those bands.

        Parameters
        ----------
        where : ndarray of bool, shape (n_bands, n_observed)

        Returns
        -------
        excess, floor : ndarray, shape (n_observed,)
        """
        bins = np.array([b - a for a, b in self.edges], dtype=np.float64)[:, None]
        excess = np.sum(np.where(where, bins * np.maximum(self.whitened - 1.0, 0.0), 0.0), axis=0)
        floor = np.sum(np.where(where, bins * (self.threshold[:, None] - 1.0), 0.0), axis=0)
        return excess, floor


def structure_left(new: Bands, old: Bands) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Structure of two fits of the same rows, over the bands where either leaves structure
    beyond chance.

    Returns
    -------
    new, old, floor : ndarray, shape (n_observed,)
        Whitened power beyond noise of each fit in those bands, and that at their chance
        threshold (0 where no band is structured).
    """
    where = new.structured | old.structured
    excess_new, floor = new.structure(where)
    excess_old, _ = old.structure(where)
    return excess_new, excess_old, floor


def residual_bands(normalised: np.ndarray, whitening: DriftWhitening | None, dt: float) -> Bands:
    """Band powers of a noise-normalised residual (not yet whitened).

    Parameters
    ----------
    normalised : ndarray, shape (n, n_observed)
        ``(recorded - simulated) / sigma``.
    whitening : DriftWhitening or None
        The input-noise drift (``None``: none).
    dt : float
        Sample time [s].

    Returns
    -------
    Bands
    """
    n = normalised.shape[0]
    spectrum = np.fft.rfft(normalised, axis=0)
    power = np.abs(spectrum) ** 2 / n
    expected = 1.0 if whitening is None else 1.0 / whitening.weights(n) ** 2
    counts = np.full(power.shape[0], 2.0)
    counts[0] = 1.0
    if n % 2 == 0:
        counts[-1] = 1.0
    edges = band_edges(power.shape[0])
    freq = np.fft.rfftfreq(n, dt)
    whitened = power / expected
    excess = counts[:, None] * (power - expected) / n
    dof = np.array([1.0 if a == 0 else 2.0 * (b - a) for a, b in edges])
    return Bands(
        edges=edges,
        frequency=np.array([[freq[a], freq[b - 1]] for a, b in edges]),
        whitened=np.array([whitened[a:b].mean(axis=0) for a, b in edges]),
        threshold=chi2.isf(BAND_FALSE_ALARM / len(edges), dof) / dof,
        excess=np.array([excess[a:b].sum(axis=0) for a, b in edges]),
    )


def significance(whitened: np.ndarray, bands: Bands) -> tuple[np.ndarray, np.ndarray]:
    """Which residuals carry significant structure: RMS of the whitened residual above
    :data:`SIGNIFICANT_RATIO`, or a band with significant structure of its own (an offset is
    one band; spread over the whole band of a drifting signal it would not lift the RMS).

    Parameters
    ----------
    whitened : ndarray, shape (n, n_observed)
        The whitened, noise-normalised residual.
    bands : Bands
        Its band powers.

    Returns
    -------
    ratio : ndarray, shape (n_observed,)
        RMS of ``whitened``.
    significant : ndarray of bool, shape (n_observed,)
    """
    ratio = np.sqrt(np.mean(whitened**2, axis=0))
    return ratio, (ratio > SIGNIFICANT_RATIO) | bands.significant.any(axis=0)
