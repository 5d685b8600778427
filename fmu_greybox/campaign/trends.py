"""Trends of the named effects across the recordings of a campaign, and the drift test.

Every magnitude a diagnosis names (a finding's ``magnitudes``: for a ``parameter_mismatch`` the
relative change of its FMU parameter, for a Stribeck friction both the force and the velocity)
becomes one trend: its value per recording, with the 95 % interval the diagnosis gave, null
where that recording did not name it (or failed). Findings of different recordings belong to
the same trend when they name the same hypothesis (``coulomb_friction@load_force(ram_velocity)``)
and the same magnitude.

The drift test (``docs/campaign.md``) takes each interval as a Gaussian measurement error,
``sigma_i = (high_i - low_i) / (2 * 1.96)``, and asks whether one constant magnitude explains
all of them: the chi-square statistic of the weighted mean, ``sum w_i (y_i - mean_w)^2`` with
``w_i = 1 / sigma_i^2``, against ``m - 1`` degrees of freedom. ``drift`` is true when its
p-value is below :data:`DRIFT_ALPHA`, false otherwise, and null when fewer than two recordings
named the magnitude with an interval (the data cannot decide). The slope is the weighted
least-squares line through ``(recording index, magnitude)``, with its 95 % interval.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

#: Significance level of the drift test.
DRIFT_ALPHA = 0.05
#: Standard-normal quantile of a two-sided 95 % interval.
Z95 = float(stats.norm.ppf(0.975))


@dataclass(frozen=True)
class DriftTest:
    """The drift test of one trend.

    Attributes
    ----------
    slope : float or None
        Weighted least-squares slope [unit per recording].
    intercept : float or None
        The line's value at the first recording (index 0).
    slope_ci95 : list of float or None
        Its 95 % interval ``[low, high]``.
    chi2 : float or None
        Chi-square statistic of constancy.
    dof : int
        Its degrees of freedom (recordings tested minus one).
    p_value : float or None
        Probability of a chi-square at least this large if the magnitude were constant.
    drift : bool or None
        ``p_value < DRIFT_ALPHA``; ``None`` when fewer than two recordings can be tested.
    """

    slope: float | None
    intercept: float | None
    slope_ci95: list[float] | None
    chi2: float | None
    dof: int
    p_value: float | None
    drift: bool | None

    def to_dict(self) -> dict:
        return {
            "slope": self.slope,
            "intercept": self.intercept,
            "slope_ci95": self.slope_ci95,
            "chi2": self.chi2,
            "dof": self.dof,
            "p_value": self.p_value,
            "drift": self.drift,
        }


def magnitude_problem(magnitude: object) -> str | None:
    """What makes a magnitude of ``diagnosis.json`` one no diagnosis writes, or ``None``.

    A diagnosis writes ``{"value": v, "unit": u, "ci95": [low, high] or null}`` with ``v`` a
    finite number and, where there is an interval, ``low <= v <= high``, both finite.

    Parameters
    ----------
    magnitude : object
        The entry as read from the file.

    Returns
    -------
    str or None
        The problem, in words (the value and the interval as found).
    """
    if not isinstance(magnitude, dict):
        return f"{magnitude!r} is not an object with a 'value'"
    value, interval = magnitude.get("value"), magnitude.get("ci95")
    if not _is_number(value) or not math.isfinite(value):
        return f"its value {value!r} is not a finite number"
    if interval is None:
        return None
    if not (isinstance(interval, list) and len(interval) == 2 and all(map(_is_number, interval))):
        return f"its 95 % interval {interval!r} is not a pair of numbers [low, high]"
    low, high = interval
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        return f"its 95 % interval [{low!r}, {high!r}] is not finite and ordered (low <= high)"
    if not low <= value <= high:
        return f"its value {value!r} lies outside its own 95 % interval [{low!r}, {high!r}]"
    return None


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def drift_test(values: Sequence[float | None], ci95: Sequence[Sequence[float] | None]) -> DriftTest:
    """Test whether magnitudes change across recordings by more than their intervals allow.

    Parameters
    ----------
    values : sequence of float or None, length n
        Magnitude per recording, in campaign order (``None``: not named).
    ci95 : sequence of [low, high] or None, length n
        Its 95 % interval per recording (``None``: none given).

    Returns
    -------
    DriftTest
        Recordings without a value or without a finite, non-empty interval are left out.
    """
    kept = [
        (x, float(v), (float(c[1]) - float(c[0])) / (2 * Z95))
        for x, (v, c) in enumerate(zip(values, ci95, strict=True))
        if v is not None and c is not None and np.isfinite(c).all() and c[1] > c[0]
    ]
    if len(kept) < 2:
        return DriftTest(None, None, None, None, max(len(kept) - 1, 0), None, None)
    x, y, sigma = (np.array(column, dtype=float) for column in zip(*kept, strict=True))
    w = 1.0 / sigma**2
    mean = np.sum(w * y) / np.sum(w)
    chi2 = float(np.sum(w * (y - mean) ** 2))
    dof = len(y) - 1
    p_value = float(stats.chi2.sf(chi2, dof))
    x_mean = np.sum(w * x) / np.sum(w)
    sxx = float(np.sum(w * (x - x_mean) ** 2))
    slope = float(np.sum(w * (x - x_mean) * (y - mean)) / sxx)
    half = Z95 / np.sqrt(sxx)
    return DriftTest(
        slope,
        float(mean - slope * x_mean),
        [slope - half, slope + half],
        chi2,
        dof,
        p_value,
        bool(p_value < DRIFT_ALPHA),
    )


@dataclass
class Trend:
    """One named magnitude across the recordings of a campaign (an entry of ``trends``).

    Attributes
    ----------
    effect : str
        Vocabulary identifier.
    stage : str or None
        Stage where it showed first, in most of the recordings that named it.
    parameter : str
        The FMU parameter for a ``parameter_mismatch``, else the magnitude's name.
    unit : str
    hypothesis : str
        The diagnosis' hypothesis key.
    magnitude : str
        Name of the magnitude within the finding's ``magnitudes``.
    values : list of float or None, length n_recordings
    ci95 : list of [low, high] or None, length n_recordings
    test : DriftTest
    """

    effect: str
    stage: str | None
    parameter: str
    unit: str
    hypothesis: str
    magnitude: str
    values: list[float | None]
    ci95: list[list[float] | None]
    test: DriftTest

    @property
    def named_in(self) -> int:
        """Recordings that named this magnitude."""
        return sum(v is not None for v in self.values)

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "stage": self.stage,
            "parameter": self.parameter,
            "unit": self.unit,
            "hypothesis": self.hypothesis,
            "magnitude": self.magnitude,
            "values": self.values,
            "ci95": self.ci95,
            "named_in": self.named_in,
            **self.test.to_dict(),
        }


def campaign_trends(findings: Sequence[Sequence[dict] | None]) -> list[Trend]:
    """The trend of every magnitude named in at least one recording.

    Parameters
    ----------
    findings : sequence of (list of dict or None), length n_recordings
        Each recording's ``findings`` as in ``diagnosis.json``, in campaign order (``None``
        for a recording that failed).

    Returns
    -------
    list of Trend
        In order of first appearance.
    """
    n = len(findings)
    seen: dict[tuple[str, str], dict] = {}
    for i, found in enumerate(findings):
        for finding in found or []:
            for name, magnitude in (finding.get("magnitudes") or {}).items():
                key = (finding["hypothesis"], name)
                entry = seen.setdefault(
                    key,
                    {
                        "finding": finding,
                        "unit": magnitude.get("unit", ""),
                        "stages": Counter(),
                        "values": [None] * n,
                        "ci95": [None] * n,
                    },
                )
                entry["stages"][finding["stage"]] += 1
                entry["values"][i] = magnitude["value"]
                entry["ci95"][i] = magnitude.get("ci95")
    trends = []
    for (hypothesis, name), entry in seen.items():
        finding = entry["finding"]
        mismatch = finding["effect"] == "parameter_mismatch"
        parameter = finding.get("parameter", name) if mismatch else name
        trends.append(
            Trend(
                effect=finding["effect"],
                stage=entry["stages"].most_common(1)[0][0],
                parameter=parameter,
                unit=entry["unit"],
                hypothesis=hypothesis,
                magnitude=name,
                values=entry["values"],
                ci95=entry["ci95"],
                test=drift_test(entry["values"], entry["ci95"]),
            )
        )
    return trends
