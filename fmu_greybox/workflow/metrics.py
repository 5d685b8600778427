"""Error measures of the paper's tables (RMSE, normalised RMSE, improvement) and of the
predictive uncertainty (coverage of the ±1σ and ±1.96σ bands)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fmu_greybox.model.calibration import (
    Z95,
    CoverageEstimate,
    calibration_spread,
    coverage_interval,
    independent_rows,
    pooled_coverage,
)
from fmu_greybox.model.chain import CALIBRATION_HALVES


def rmse(predicted: np.ndarray, recorded: np.ndarray) -> float:
    """Root of the mean square difference.

    Parameters
    ----------
    predicted, recorded : ndarray, shape (n,)
    """
    return float(np.sqrt(np.mean((np.asarray(predicted) - np.asarray(recorded)) ** 2)))


def improvement(before: float, after: float) -> float:
    """Relative change of an error, as a fraction: ``after / before - 1`` (negative = better)."""
    if before == 0.0:
        return 0.0 if after == 0.0 else float("inf")
    return after / before - 1.0


def stage_table(
    names: Sequence[str],
    recorded: np.ndarray,
    whitebox: np.ndarray,
    greybox: np.ndarray,
    target_std: Mapping[str, float],
    named: np.ndarray | None = None,
) -> dict[str, dict[str, float]]:
    """Per-stage white-box and grey-box errors on the same rows.

    Parameters
    ----------
    names : sequence of str
        Stage names, one per column.
    recorded, whitebox, greybox : ndarray, shape (m, Q)
        Recorded targets and the two predictions.
    target_std : mapping
        Stage -> standard deviation of its training target (normalises the RMSE).
    named : ndarray, shape (m, Q), optional
        The white-box with named terms (a grey-box trained on top of them).

    Returns
    -------
    dict
        Stage -> ``wb_rmse``, ``gb_rmse``, ``wb_nrmse``, ``gb_nrmse``, ``improvement`` (grey-box
        against white-box), and with ``named`` also ``named_rmse`` and ``named_nrmse``.
    """
    table = {}
    for q, name in enumerate(names):
        wb = rmse(whitebox[:, q], recorded[:, q])
        gb = rmse(greybox[:, q], recorded[:, q])
        scale = target_std[name] or 1.0
        table[name] = {
            "wb_rmse": wb,
            "gb_rmse": gb,
            "wb_nrmse": wb / scale,
            "gb_nrmse": gb / scale,
            "improvement": improvement(wb, gb),
        }
        if named is not None:
            terms = rmse(named[:, q], recorded[:, q])
            table[name].update(named_rmse=terms, named_nrmse=terms / scale)
    return table


def uncertainty_table(
    names: Sequence[str],
    recorded: np.ndarray,
    greybox: np.ndarray,
    std: np.ndarray,
    latent_std: np.ndarray,
) -> dict[str, dict[str, float]]:
    """Per stage, how well the grey-box's standard deviation describes its error.

    Parameters
    ----------
    names : sequence of str
        Stage names, one per column.
    recorded, greybox : ndarray, shape (m, Q)
        Recorded targets and the grey-box prediction.
    std, latent_std : ndarray, shape (m, Q)
        Its calibrated and its propagated (uncalibrated) standard deviations.

    Returns
    -------
    dict
        Stage -> ``coverage68`` and ``coverage95`` (share of rows inside ±1σ and ±1.96σ), each
        with its confidence interval (``coverage68_low``, ``coverage68_high``, ...) and
        ``independent_rows``, what the rows are worth for it
        (:func:`~fmu_greybox.model.calibration.coverage_interval`); ``median_std`` and
        ``median_latent_std``.
    """
    residual = recorded - greybox
    table = {}
    for q, name in enumerate(names):
        row = {"independent_rows": independent_rows(residual[:, q], std[:, q])}
        for key, width in (("coverage68", 1.0), ("coverage95", Z95)):
            estimate = coverage_interval(residual[:, q], std[:, q], width, row["independent_rows"])
            row |= {key: estimate.share, f"{key}_low": estimate.low, f"{key}_high": estimate.high}
        row["median_std"] = float(np.median(std[:, q]))
        row["median_latent_std"] = float(np.median(latent_std[:, q]))
        table[name] = row
    return table


def pooled_row(
    rows: Sequence[Mapping[str, float]], scored_rows: Sequence[int] | None = None
) -> dict[str, float]:
    """The shares inside a band of several recordings' rows of one stage, pooled by what their
    rows are worth (:func:`~fmu_greybox.model.calibration.pooled_coverage`).

    Parameters
    ----------
    rows : sequence of mapping
        Rows of :func:`uncertainty_table`, one per recording: ``independent_rows`` and
        ``coverage95`` with its ``_low`` and ``_high`` (and ``coverage68``, when every row
        has it with its interval).
    scored_rows : sequence of int, optional
        How many rows each recording scored. With them, rows of one model (one
        ``calibration_rmse``) that give ``gb_rmse`` pool it too, as the RMSE over all the
        scored rows, so that the pooled row has an :func:`error_ratio`, and keep the
        calibration's ``calibration_independent_rows``.

    Returns
    -------
    dict
        The same keys over all of them, and ``recordings``: how many were pooled.
    """
    pooled: dict[str, float] = {"recordings": len(rows)}
    calibrated = {r.get("calibration_rmse") for r in rows}
    if scored_rows is not None and len(calibrated) == 1 and all("gb_rmse" in r for r in rows):
        weights = np.asarray(scored_rows, dtype=float)
        errors = np.array([r["gb_rmse"] for r in rows])
        pooled["gb_rmse"] = float(np.sqrt(weights @ errors**2 / weights.sum()))
        if None not in calibrated:
            pooled["calibration_rmse"] = calibrated.pop()
            calibration = ("independent_rows", "recordings", "share_low", "share_high")
            for key in (f"calibration_{name}" for name in calibration):
                if key in rows[0]:  # one model: one calibration
                    pooled[key] = rows[0][key]
    for key in ("coverage95", "coverage68"):
        if not all(f"{key}_low" in r and f"{key}_high" in r for r in rows):
            continue
        total = pooled_coverage(
            [
                CoverageEstimate(r[key], r[f"{key}_low"], r[f"{key}_high"], r["independent_rows"])
                for r in rows
            ]
        )
        pooled |= {key: total.share, f"{key}_low": total.low, f"{key}_high": total.high}
        pooled["independent_rows"] = total.independent_rows
    return pooled


def error_ratio(row: Mapping[str, float]) -> float | None:
    """The grey-box's RMSE on a validation's scored rows (``gb_rmse``) as a multiple of its RMSE
    on the free runs its σ was calibrated on (``calibration_rmse``); ``None`` when the
    row lacks either (a model stored before it kept the latter)."""
    scored, calibrated = row.get("gb_rmse"), row.get("calibration_rmse")
    return scored / calibrated if scored is not None and calibrated else None


def format_table(
    table: Mapping[str, Mapping[str, float]],
    units: Mapping[str, str],
    contents: Mapping[str, str] | None = None,
) -> str:
    """The table as fixed-width text, one stage a line (for the terminal); a column for the
    white-box with named terms, the coverage of ±1.96σ, the model's RMSE as a multiple of the
    one its σ was calibrated on (``calibration_rmse``), and the share of ±1.96σ its
    calibration rows vouch for (:func:`spread_text` of ``calibration_independent_rows``), when
    the table has them; last, what the model computes on each stage when ``contents`` gives it
    (:meth:`~fmu_greybox.model.store.GreyBoxModel.contents`: "white-box + named terms")."""
    named = all("named_rmse" in row for row in table.values())
    covered = all("coverage95" in row for row in table.values())
    ratio = all(error_ratio(row) is not None for row in table.values())
    vouched = all("calibration_independent_rows" in row for row in table.values())
    lines = [
        f"{'stage':8s} {'unit':6s} {'WB RMSE':>11s} "
        + (f"{'+terms RMSE':>11s} " if named else "")
        + f"{'model RMSE':>11s} {'WB nRMSE':>9s} {'model nRMSE':>11s} {'improvement':>11s}"
        + (f" {'in ±1.96σ (95 % interval)':>27s}" if covered else "")
        + (f" {'model RMSE / calibration':>24s}" if ratio else "")
        + (f" {'calibration vouches (rows)':>26s}" if vouched else "")
        + ("  model" if contents else "")
    ]
    for name, row in table.items():
        lines.append(
            f"{name:8s} {units.get(name, ''):6s} {row['wb_rmse']:11.3e} "
            + (f"{row['named_rmse']:11.3e} " if named else "")
            + f"{row['gb_rmse']:11.3e} {row['wb_nrmse']:9.3g} {row['gb_nrmse']:11.3g} "
            f"{100 * row['improvement']:10.1f}%"
            + (f" {coverage_text(row, 'coverage95'):>27s}" if covered else "")
            + (f" {error_ratio(row):23.3g}×" if ratio else "")
            + (f" {_vouched_text(row['calibration_independent_rows']):>26s}" if vouched else "")
            + (f"  {contents.get(name, '')}" if contents else "")
        )
    return "\n".join(lines)


#: What the brackets of :func:`coverage_text` mean, for a reader of the report.
INTERVAL_NOTE = (
    "in brackets: the 95 % interval of the share inside a band that a longer recording would "
    "give (a free run's errors come in waves, so its rows count for fewer independent ones)"
)


def calibration_worth_text(row: Mapping[str, float]) -> str | None:
    """What a stage's σ rests on, in words: ``σ rests on about 23 independent training rows:
    ±1.96σ holds 84.6-99.9 % on recordings like them``, or ``... independent rows of 3
    calibration recordings: ...`` (``train --calibrate-on``; the row's
    ``calibration_recordings``) (:func:`~fmu_greybox.model.calibration.calibration_spread` of
    the row's ``calibration_independent_rows``); ``None`` when the row does not say, or says
    less than one row (no residual to calibrate on)."""
    rows = row.get("calibration_independent_rows")
    if rows is None or rows < 1.0:
        return None
    recordings = int(row.get("calibration_recordings", 0))
    where = f"rows of {recordings} calibration recordings" if recordings else "training rows"
    return (
        f"σ rests on about {rows:.0f} independent {where}: ±1.96σ holds "
        f"{spread_text(rows)} on recordings like them"
    )


def calibration_free_runs(row: Mapping[str, float]) -> int:
    """How many free runs a stage's σ was calibrated on: one per calibration recording
    (``calibration_recordings``), else the two halves of the training rows."""
    return int(row.get("calibration_recordings", 0)) or len(CALIBRATION_HALVES)


def _vouched_text(rows: float) -> str:
    """The table cell of a stage's calibration rows: ``47.8-99.5 % (5)``, or ``none (0)``."""
    return f"{spread_text(rows)} ({rows:.0f})"


def spread_text(rows: float) -> str:
    """:func:`~fmu_greybox.model.calibration.calibration_spread` of ``rows`` in percent, e.g.
    ``84.6-99.9 %``; ``none`` for fewer than one row."""
    low, high = calibration_spread(rows)
    return "none" if math.isnan(low) else f"{100 * low:.3g}-{100 * high:.3g} %"


def coverage_text(row: Mapping[str, float], key: str) -> str:
    """A share inside a band with its confidence interval, e.g. ``97.2 % (95.9-98.2 %)``.

    Parameters
    ----------
    row : mapping
        A row of :func:`uncertainty_table` (or one without the interval: the share alone).
    key : str
        ``"coverage95"`` or ``"coverage68"``.
    """
    share = f"{100 * row[key]:.1f} %"
    low, high = row.get(f"{key}_low"), row.get(f"{key}_high")
    if low is None or high is None or low != low:
        return share
    return f"{share} ({100 * low:.1f}-{100 * high:.1f} %)"
