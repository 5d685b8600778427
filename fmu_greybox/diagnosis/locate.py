"""Locate the mismatch: how large each residual is, where in time, in which regime, which stage.

For every observed signal (stage targets and the other recorded signals the FMU predicts) the
white-box residual is measured against the noise a right white-box would leave (the
experiment's residual: in sensor-noise levels, whitened against the drift that the recorded
inputs' noise drives, :mod:`.noise`): RMS, RMS normalised by the signal's spread, RMS in units
of the noise. Then where it concentrates: in time (windows with the most residual energy), in
operating regimes named by signal roles (direction of motion, load level, pressure level,
command amplitude), in frequency bands.

The origin stage is the first stage, in chain order, whose residual exceeds the noise: the
stages before it match, so everything it shows is its own. For every later stage the share of
its residual that its upstream stages' residuals explain (through a bank of low-pass filters
and an integrator, since errors propagate through dynamics; cross-validated over two halves of
the rows) is reported as inherited.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter, welch

from fmu_greybox.data.noise import SIGNIFICANT_RATIO, significance
from fmu_greybox.diagnosis.runner import Experiment
from fmu_greybox.diagnosis.signals import SignalMap

#: Frequency band edges of the residual spectrum [Hz] (the last band ends at Nyquist).
BAND_EDGES = (0.0, 0.1, 1.0, 10.0, 100.0)
#: Time constants of the filter bank relating a stage's residual to its upstream ones [s].
FILTER_TIMES = (0.003, 0.03, 0.3, 3.0)


@dataclass
class Regime:
    """A share of the residual energy found in a share of the time.

    Attributes
    ----------
    kind : str
        ``direction``, ``load``, ``pressure``, ``command``, ``band`` or ``window``.
    label : str
        E.g. ``"extending (ram_velocity > 0)"``, ``"1-10 Hz"``, ``"12.0-13.5 s"``.
    time_share, energy_share : float
        Fractions of the time (for a band: of the bandwidth) and of the residual energy.
    span : tuple of float or None
        Start and end time of a window [s].
    """

    kind: str
    label: str
    time_share: float
    energy_share: float
    span: tuple[float, float] | None = None

    @property
    def concentration(self) -> float:
        """Energy share over time share (1: no concentration)."""
        return self.energy_share / self.time_share if self.time_share > 0 else 0.0

    def to_dict(self) -> dict:
        if self.kind == "band":
            return {
                "kind": self.kind,
                "label": self.label,
                "bandwidth_share": round(self.time_share, 4),
                "energy_share": round(self.energy_share, 4),
            }
        found = {
            "kind": self.kind,
            "label": self.label,
            "time_share": round(self.time_share, 4),
            "energy_share": round(self.energy_share, 4),
            "concentration": round(self.concentration, 3),
        }
        if self.span is not None:
            found["start"], found["end"] = self.span
        return found


@dataclass
class SignalResidual:
    """Statistics of one observed signal's white-box residual.

    Attributes
    ----------
    name, variable, unit, role : str
        The project signal, its FMU output, unit and role.
    stage : int
        Stage it belongs to.
    rms : float
        RMS of the residual [unit].
    nrms : float
        RMS over the recorded signal's standard deviation.
    noise : float
        Estimated sensor-noise standard deviation [unit].
    noise_ratio : float
        RMS of the judged residual (whitened against input-noise drift) over the noise.
    drift : float
        RMS of the drift that input noise alone drives, in noise levels.
    significant : bool
        Whether the residual exceeds the noise (``noise_ratio > threshold``, or a frequency
        band holds significant structure, :func:`~fmu_greybox.data.noise.significance`).
    structure_bands : list of str
        Frequency bands holding significant structure of their own.
    regimes : list of Regime
        Direction, load, pressure and command regimes, frequency bands and the time windows
        with the most energy.
    """

    name: str
    variable: str
    unit: str
    role: str
    stage: int
    rms: float
    nrms: float
    noise: float
    noise_ratio: float
    drift: float
    significant: bool
    structure_bands: list[str] = field(default_factory=list)
    regimes: list[Regime] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "signal": self.name,
            "variable": self.variable,
            "unit": self.unit,
            "rms": self.rms,
            "nrms": self.nrms,
            "noise": self.noise,
            "noise_ratio": self.noise_ratio,
            "input_noise_drift": self.drift,
            "significant": self.significant,
            "structure_bands": self.structure_bands,
            "regimes": [r.to_dict() for r in self.regimes],
        }


@dataclass
class StageResidual:
    """Residual statistics of one stage.

    Attributes
    ----------
    name : str
        Stage name.
    index : int
        Position in the chain.
    signals : list of SignalResidual
        Its observed signals, target first.
    inherited_fraction : float
        Share of its residual energy explained by the upstream stages' residuals.
    """

    name: str
    index: int
    signals: list[SignalResidual]
    inherited_fraction: float = 0.0

    @property
    def significant(self) -> bool:
        """Whether any of its signals exceeds the noise."""
        return any(s.significant for s in self.signals)

    @property
    def noise_ratio(self) -> float:
        """Largest RMS-to-noise ratio of its signals."""
        return max((s.noise_ratio for s in self.signals), default=0.0)

    def to_dict(self) -> dict:
        return {
            "stage": self.name,
            "significant": self.significant,
            "noise_ratio": self.noise_ratio,
            "own_fraction": round(1.0 - self.inherited_fraction, 4),
            "inherited_fraction": round(self.inherited_fraction, 4),
            "signals": [s.to_dict() for s in self.signals],
        }


class Locator:
    """Measures the white-box residual of every observed signal and finds the origin stage.

    Parameters
    ----------
    threshold : float
        A residual is significant when its RMS exceeds ``threshold`` times the noise.
    n_windows : int
        Number of equal time windows the recording is cut into.
    top_windows : int
        Windows reported per signal (the most energetic ones).

    Attributes
    ----------
    stages_ : list of StageResidual
    origin_ : int or None
        Index of the origin stage (``None`` when every stage matches within noise).
    """

    def __init__(
        self, threshold: float = SIGNIFICANT_RATIO, n_windows: int = 20, top_windows: int = 3
    ) -> None:
        self.threshold = threshold
        self.n_windows = n_windows
        self.top_windows = top_windows

    def fit(
        self,
        experiment: Experiment,
        signals: SignalMap,
        simulated: np.ndarray,
        regressors: dict[str, dict[str, np.ndarray]],
    ) -> Locator:
        """Measure the residuals of a simulation.

        Parameters
        ----------
        experiment : Experiment
        signals : SignalMap
        simulated : ndarray, shape (n, n_observed)
            The white-box (or corrected) prediction of the observed signals.
        regressors : dict
            Regime kind -> {signal label: recorded values}, from :func:`regime_signals`.

        Returns
        -------
        Locator
            ``self``.
        """
        recorded = experiment.recorded
        residual = recorded - simulated
        judged = experiment.residual(simulated)
        bands = experiment.bands(simulated)
        ratios, significant = significance(judged, bands)
        whitening = experiment.whitening
        dt = experiment.dt
        time = experiment.start_time + dt * np.arange(recorded.shape[0])
        per_signal = []
        for j, sig in enumerate(signals.observed):
            r = residual[:, j]
            rms = float(np.sqrt(np.mean(r**2)))
            spread = float(np.std(recorded[:, j])) or 1.0
            noise = float(experiment.sigma[j])
            ratio = float(ratios[j])
            structured = bands.frequency[bands.significant[:, j]]
            labels = [f"{lo:.3g}-{hi:.3g} Hz" for lo, hi in structured]
            regimes = self._regimes(judged[:, j], time, dt, regressors)
            per_signal.append(
                SignalResidual(
                    name=sig.name,
                    variable=sig.variable,
                    unit=sig.unit,
                    role=sig.role,
                    stage=sig.stage,
                    rms=rms,
                    nrms=rms / spread,
                    noise=noise,
                    noise_ratio=ratio,
                    drift=0.0 if whitening is None else float(whitening.drift[j]),
                    significant=bool(significant[j]) or ratio > self.threshold,
                    structure_bands=labels,
                    regimes=regimes,
                )
            )
        self.stages_ = [
            StageResidual(name, q, [s for s in per_signal if s.stage == q])
            for q, name in enumerate(signals.stage_names)
        ]
        for stage in self.stages_[1:]:
            stage.inherited_fraction = _inherited(judged, signals.observed_stages, stage.index, dt)
        self.origin_ = next((s.index for s in self.stages_ if s.significant), None)
        return self

    # ------------------------------------------------------------------ regimes
    def _regimes(
        self,
        r: np.ndarray,
        time: np.ndarray,
        dt: float,
        regressors: dict[str, dict[str, np.ndarray]],
    ) -> list[Regime]:
        energy = r**2
        total = float(energy.sum()) or 1.0
        found: list[Regime] = []
        for kind, named in regressors.items():
            for label, x in named.items():
                for mask_label, mask in _bins(kind, label, x):
                    share = float(energy[mask].sum()) / total
                    found.append(Regime(kind, mask_label, float(mask.mean()), share))
        found += _bands(r, dt)
        edges = np.linspace(0, r.size, self.n_windows + 1).round().astype(int)
        windows = [
            Regime(
                "window",
                f"{time[a]:.2f}-{time[b - 1]:.2f} s",
                (b - a) / r.size,
                float(energy[a:b].sum()) / total,
                (float(time[a]), float(time[b - 1])),
            )
            for a, b in itertools.pairwise(edges)
            if b > a
        ]
        windows.sort(key=lambda w: -w.energy_share)
        return found + windows[: self.top_windows]


def regime_signals(signals: SignalMap, recorded: dict[str, np.ndarray], dt: float) -> dict:
    """The recorded signals that name operating regimes, by kind.

    ``direction``: every velocity-role signal, else the smoothed derivative of every
    position-role one; ``load``: force-role signals; ``pressure``: pressure-role signals;
    ``command``: current- and voltage-role signals.

    Parameters
    ----------
    signals : SignalMap
    recorded : dict[str, ndarray]
        Recorded column -> values, for the project's signals (inputs and outputs).
    dt : float

    Returns
    -------
    dict[str, dict[str, ndarray]]
    """
    roles: dict[str, list[str]] = {}
    for name, role in signals.input_roles.items():
        column = signals.input_columns.get(name)
        if column is not None and column in recorded:
            roles.setdefault(role, []).append(column)
    for sig in signals.observed:
        roles.setdefault(sig.role, []).append(sig.column)
    found: dict[str, dict[str, np.ndarray]] = {}
    velocity = {c: recorded[c] for c in roles.get("velocity", [])}
    if not velocity:
        velocity = {f"d/dt {c}": _smooth_rate(recorded[c], dt) for c in roles.get("position", [])}
    if velocity:
        found["direction"] = velocity
    for kind, role_names in (
        ("load", ("force",)),
        ("pressure", ("pressure",)),
        ("command", ("current", "voltage")),
    ):
        named = {c: recorded[c] for role in role_names for c in roles.get(role, [])}
        if named:
            found[kind] = named
    return found


def _smooth_rate(x: np.ndarray, dt: float, window: int = 9) -> np.ndarray:
    kernel = np.ones(window) / window
    smooth = np.convolve(x, kernel, mode="same")
    return np.gradient(smooth, dt)


def _bins(kind: str, label: str, x: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """Masks of the regimes of one signal."""
    if kind == "direction":
        threshold = 0.05 * float(np.std(x))
        return [
            (f"{label} > 0 (moving +)", x > threshold),
            (f"{label} < 0 (moving -)", x < -threshold),
            (f"{label} near 0 (at rest)", np.abs(x) <= threshold),
        ]
    magnitude = np.abs(x) if kind in ("load", "command") else x
    low, high = np.quantile(magnitude, [1 / 3, 2 / 3])
    what = f"|{label}|" if kind in ("load", "command") else label
    return [
        (f"{what} low (< {low:.3g})", magnitude < low),
        (f"{what} mid", (magnitude >= low) & (magnitude <= high)),
        (f"{what} high (> {high:.3g})", magnitude > high),
    ]


def _bands(r: np.ndarray, dt: float) -> list[Regime]:
    """Shares of the residual's energy in the frequency bands of :data:`BAND_EDGES`."""
    nyquist = 0.5 / dt
    freq, power = welch(r - r.mean(), fs=1.0 / dt, nperseg=min(r.size, 8192))
    mean_energy = float(np.mean(r) ** 2)
    total = float(np.trapezoid(power, freq)) + mean_energy or 1.0
    edges = [e for e in BAND_EDGES if e < nyquist] + [nyquist]
    found = []
    for lo, hi in itertools.pairwise(edges):
        inside = (freq >= lo) & (freq < hi) if hi < nyquist else (freq >= lo)
        share = float(np.trapezoid(power[inside], freq[inside])) if inside.sum() > 1 else 0.0
        if lo == 0.0:
            share += mean_energy
        found.append(Regime("band", f"{lo:g}-{hi:g} Hz", (hi - lo) / nyquist, share / total))
    return found


def _inherited(normalised: np.ndarray, stages: list[int], q: int, dt: float) -> float:
    """Share of stage ``q``'s residual energy that its upstream residuals explain.

    Stage ``q``'s residual is regressed on its upstream residuals, their integral and their
    low-passed versions. The share is cross-validated (coefficients fitted on one half of the
    rows, the energy explained counted on the other, both ways): the integral of upstream
    *noise* is a random walk that can fit any slow drift in-sample, which would report a
    downstream error as inherited from an upstream stage that matches within noise.
    """
    own = normalised[:, [j for j, s in enumerate(stages) if s == q]]
    upstream = normalised[:, [j for j, s in enumerate(stages) if s < q]]
    if own.size == 0 or upstream.size == 0:
        return 0.0
    features = [upstream, np.cumsum(upstream, axis=0) * dt]
    for tau in FILTER_TIMES:
        a = np.exp(-dt / tau)
        features.append(lfilter([1 - a], [1, -a], upstream, axis=0))
    x = np.column_stack([*features, np.ones(upstream.shape[0])])
    half = x.shape[0] // 2
    folds = (slice(0, half), slice(half, None))
    left = 0.0
    for fit, test in (folds, folds[::-1]):
        coef, *_ = np.linalg.lstsq(x[fit], own[fit], rcond=None)
        left += float(np.sum((own[test] - x[test] @ coef) ** 2))
    total = float(np.sum(own**2)) or 1.0
    return float(np.clip(1.0 - left / total, 0.0, 1.0))
