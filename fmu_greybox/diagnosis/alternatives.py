"""Competing explanations: hypotheses whose refined fit is nearly as good as a kept one's, and
what to record to tell them apart.

A refined candidate is an **alternative** to the one a selection round accepts when it names
other physics, passes the acceptance tests itself, and fits **nearly as well**
(:func:`nearly_as_good`) by either measure: its Bayesian information criterion is less than
:data:`ALTERNATIVE_BIC` above the accepted one's (on the training rows), or its held-out
structure is within :data:`ALTERNATIVE_HELDOUT` of the accepted one's
(:func:`~.select.heldout_ratio`). Either suffices: the criterion treats what is left of the
training residual as noise, so where other effects still leave structure (or the recording is
long) a difference of a fraction of a percent in fit counts as strong evidence; the held-out
rows, which neither fit saw, then say whether one predicts better.

Where two explanations predict the recording alike, a different recording separates them. Their
simulated outputs say where: :func:`separation` finds the observed signal where they differ
most, and the operating regime (speed, load, pressure or command level, from the signals'
roles) or frequency band where that difference concentrates against the time the recording
spends there. A regime the recording rarely visits but where the two disagree is the one to
record more of.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from fmu_greybox.diagnosis.calibrate import Candidate
from fmu_greybox.diagnosis.hypotheses import Hypothesis, ParameterMismatch
from fmu_greybox.diagnosis.locate import BAND_EDGES
from fmu_greybox.diagnosis.runner import Experiment

#: An alternative's information criterion is less than this above the accepted one's.
ALTERNATIVE_BIC = 10.0
#: An alternative's held-out structure is at most this much (relative) above the accepted one's.
ALTERNATIVE_HELDOUT = 0.10
#: Least share of the time a regime must cover to be proposed.
MIN_TIME_SHARE = 0.02
#: Least concentration (share of the difference over share of the time) of a proposed regime;
#: below it the frequency band holding most of the difference is proposed.
MIN_CONCENTRATION = 1.5

#: What to record for each kind of regime, by its level (the regime's label says where).
_ADVICE = {
    ("direction", "low"): "slow motion (e.g. a slow ramp)",
    ("direction", "high"): "fast motion",
    ("load", "low"): "light loads",
    ("load", "high"): "heavy loads",
    ("pressure", "low"): "low {label}",
    ("pressure", "high"): "high {label}",
    ("command", "low"): "small commands",
    ("command", "high"): "large commands",
}


def physics_of(h: Hypothesis) -> str:
    """The physics a hypothesis names: its effect, or for a parameter mismatch its physics
    label (the parameter's name when it has none)."""
    if isinstance(h, ParameterMismatch):
        return h.physics or f"parameter_mismatch@{h.name}"
    return h.effect


def is_alternative(
    accepted: Candidate, other: Candidate, delta_bic: float, heldout_ratio: float
) -> bool:
    """Whether ``other`` names other physics than ``accepted`` and fits nearly as well (see the
    module docstring; the caller checks that it passes the acceptance tests).

    Parameters
    ----------
    accepted, other : Candidate
        Refined candidates of one round; the hypothesis each adds is its last.
    delta_bic : float
        ``other``'s information criterion minus ``accepted``'s.
    heldout_ratio : float
        ``other``'s held-out structure over ``accepted``'s.
    """
    a, b = accepted.hypotheses[-1], other.hypotheses[-1]
    return physics_of(a) != physics_of(b) and nearly_as_good(delta_bic, heldout_ratio)


def nearly_as_good(delta_bic: float, heldout_ratio: float) -> bool:
    """Whether a fit is nearly as good as another: its information criterion is less than
    :data:`ALTERNATIVE_BIC` above, or its held-out structure within :data:`ALTERNATIVE_HELDOUT`
    of, the other's.

    Parameters
    ----------
    delta_bic : float
        Its criterion minus the other's.
    heldout_ratio : float
        Its held-out structure over the other's.
    """
    return delta_bic < ALTERNATIVE_BIC or heldout_ratio <= 1.0 + ALTERNATIVE_HELDOUT


@dataclass
class Separation:
    """Where two explanations' simulated outputs differ most.

    Attributes
    ----------
    signal : str
        The observed FMU output where they differ most (in noise levels).
    kind : str
        Regime kind (``direction``, ``load``, ``pressure``, ``command``) or ``band``.
    label : str
        The regime, e.g. ``"|ram_velocity| below 0.0042"`` or ``"10-100 Hz"``.
    energy_share, time_share : float
        Share of their difference found there, and share of the time (of the bandwidth, for a
        band) the recording spends there.
    advice : str
        What to record, in words.
    """

    signal: str
    kind: str
    label: str
    energy_share: float
    time_share: float
    advice: str

    def to_dict(self) -> dict:
        return {
            "signal": self.signal,
            "kind": self.kind,
            "label": self.label,
            "energy_share": round(self.energy_share, 4),
            "time_share": round(self.time_share, 4),
            "advice": self.advice,
        }


def separation(
    experiment: Experiment,
    regimes: dict[str, dict[str, np.ndarray]],
    units: dict[str, str],
    a: np.ndarray,
    b: np.ndarray,
) -> Separation | None:
    """Where two simulations of the observed outputs differ most, and what to record there.

    Parameters
    ----------
    experiment : Experiment
    regimes : dict
        Regime kind -> {recorded signal: values} (:func:`~.locate.regime_signals`).
    units : dict[str, str]
        Recorded signal -> unit.
    a, b : ndarray, shape (n, n_observed)
        The two simulations.

    Returns
    -------
    Separation or None
        ``None`` when they do not differ.
    """
    diff = (b - a) / experiment.sigma
    energy = np.sum(diff**2, axis=0)
    if not np.any(energy > 0):
        return None
    j = int(np.argmax(energy))
    e = diff[:, j] ** 2
    total = float(e.sum())
    best: tuple[float, str, str, float, float, str] | None = None
    for kind, named in regimes.items():
        for label, x in named.items():
            for level, mask, text, value in _levels(kind, label, x):
                time_share = float(mask.mean())
                if time_share < MIN_TIME_SHARE:
                    continue
                share = float(e[mask].sum()) / total
                concentration = share / time_share
                if best is None or concentration > best[0]:
                    unit = units.get(label, "")
                    shown = f"{value:.3g} {unit}".strip()
                    advice = _ADVICE[(kind, level)].format(label=label)
                    best = (
                        concentration,
                        kind,
                        text.format(value=shown),
                        share,
                        time_share,
                        advice,
                    )
    if best is None or best[0] < MIN_CONCENTRATION:
        label, share, width = _main_band(diff[:, j], experiment.dt)
        return Separation(
            experiment.outputs[j], "band", label, share, width, f"more excitation in {label}"
        )
    _, kind, label, share, time_share, advice = best
    return Separation(experiment.outputs[j], kind, label, share, time_share, advice)


def _levels(kind: str, label: str, x: np.ndarray) -> list[tuple[str, np.ndarray, str, float]]:
    """The low and high third of a regime signal (of its magnitude, but for pressures): level,
    mask, label (with ``{value}`` for the bound) and bound."""
    magnitude = x if kind == "pressure" else np.abs(x)
    what = label if kind == "pressure" else f"|{label}|"
    low, high = np.quantile(magnitude, [1 / 3, 2 / 3])
    return [
        ("low", magnitude < low, f"{what} below {{value}}", float(low)),
        ("high", magnitude > high, f"{what} above {{value}}", float(high)),
    ]


def _main_band(d: np.ndarray, dt: float) -> tuple[str, float, float]:
    """The frequency band (:data:`~.locate.BAND_EDGES`) holding the largest share of a
    difference's energy: label, share and share of the bandwidth."""
    nyquist = 0.5 / dt
    spectrum = np.abs(np.fft.rfft(d)) ** 2
    freq = np.fft.rfftfreq(d.size, dt)
    total = float(spectrum.sum()) or 1.0
    edges = [e for e in BAND_EDGES if e < nyquist] + [nyquist]
    bands = []
    for lo, hi in itertools.pairwise(edges):
        inside = (freq >= lo) & ((freq < hi) if hi < nyquist else (freq <= hi))
        bands.append(
            (float(spectrum[inside].sum()) / total, f"{lo:g}-{hi:g} Hz", (hi - lo) / nyquist)
        )
    share, label, width = max(bands)
    return label, share, width
