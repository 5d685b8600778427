"""Acceptance: the project's criteria (``[acceptance]``) checked against a validation.

Each criterion of each stage gives one :class:`Check` with its measured value, its limit and a
verdict: ``PASS``, ``FAIL``, or ``UNDECIDED`` when the data cannot decide (a frequency band
where the recording's own estimate cannot be trusted, no rows to count, a share inside the
uncertainty band outside its limits over too few independent rows to say so). The whole verdict is
``FAIL`` if any check fails, else ``UNDECIDED`` if any is undecided, else ``PASS``: an
engineer signs a ``PASS`` only. A coverage check that passes on evidence too thin to vouch for
its limits is marked so (:attr:`Check.thin`), its note saying why.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

from fmu_greybox.evidence.spectra import FrequencyResponse
from fmu_greybox.model.calibration import Z95, calibration_spread, rows_to_vouch
from fmu_greybox.project.config import AcceptanceConfig, Criteria
from fmu_greybox.workflow.metrics import (
    calibration_free_runs,
    calibration_worth_text,
    error_ratio,
)

PASS, FAIL, UNDECIDED = "PASS", "FAIL", "UNDECIDED"


@dataclass(frozen=True)
class Check:
    """One criterion of one stage.

    Attributes
    ----------
    stage : str
    criterion : str
        What is measured, in words with its unit.
    value : float
        The measured value (NaN when it could not be measured).
    limit : str
        The limit, e.g. ``<= 0.1`` or ``0.9 .. 0.99``.
    verdict : str
        ``PASS``, ``FAIL`` or ``UNDECIDED``.
    note : str
        Why a check is undecided or failed, or why a pass rests on thin evidence; over several
        recordings, also which recording a check is the worst of (empty otherwise).
    thin : bool
        A ``PASS`` whose evidence cannot vouch for its limits: the share's 95 % interval, or
        the range a band calibrated on so few independent rows holds on recordings like
        them, reaches beyond the limits.
    """

    stage: str
    criterion: str
    value: float
    limit: str
    verdict: str
    note: str = ""
    thin: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN as ``None``)."""
        row = asdict(self)
        row["value"] = None if math.isnan(self.value) else self.value
        return row


@dataclass(frozen=True)
class Acceptance:
    """Every check of a validation, in stage order.

    Attributes
    ----------
    checks : tuple of Check
    """

    checks: tuple[Check, ...]

    @property
    def verdict(self) -> str:
        """``FAIL`` if any check fails, else ``UNDECIDED`` if any is undecided or there is no
        check at all (every criterion switched off: nothing was shown), else ``PASS``."""
        verdicts = {c.verdict for c in self.checks}
        if not verdicts:
            return UNDECIDED
        return FAIL if FAIL in verdicts else UNDECIDED if UNDECIDED in verdicts else PASS

    def to_dict(self) -> dict[str, Any]:
        """``{"verdict", "checks": [...]}`` for ``metrics.json`` and ``summary.json``."""
        return {"verdict": self.verdict, "checks": [c.to_dict() for c in self.checks]}

    @property
    def thin(self) -> list[Check]:
        """The passes that rest on thin evidence (:attr:`Check.thin`)."""
        return [c for c in self.checks if c.thin]

    def summary(self) -> str:
        """One line: the verdict, the checks that did not pass and the passes on thin
        evidence."""
        if not self.checks:
            return (
                f"Acceptance: {self.verdict} (no criterion to check: every one is switched off "
                "in the project's [acceptance]; set max_nrmse, a coverage or a band to decide)."
            )
        others = [c for c in self.checks if c.verdict != PASS]
        named = "; ".join(
            f"{c.stage} {c.criterion}: {c.verdict} ({_number(c.value)}, limit {c.limit})"
            for c in others
        )
        counted = f"{len(self.checks) - len(others)} of {len(self.checks)} checks pass"
        if self.thin:
            counted += (
                f", {len(self.thin)} on thin evidence ("
                + "; ".join(f"{c.stage} {c.criterion}" for c in self.thin)
                + ")"
            )
        return f"Acceptance: {self.verdict} ({counted}{'; ' + named if named else ''})."


def evaluate(
    criteria: AcceptanceConfig,
    table: Mapping[str, Mapping[str, float]],
    responses: Sequence[FrequencyResponse],
    outside_share: float = 0.0,
    beyond: str = "",
) -> Acceptance:
    """Check every stage of a validation table against its criteria.

    Parameters
    ----------
    criteria : AcceptanceConfig
    table : mapping
        Stage -> its row of :attr:`~fmu_greybox.workflow.validate.Validation.table`
        (``gb_nrmse``, ``coverage95``, ``coverage68``).
    responses : sequence of FrequencyResponse
        Per stage (matched by :attr:`~FrequencyResponse.stage`); a stage without one has its
        frequency-domain checks undecided.
    outside_share : float
        Share of the scored rows on which the correctors were outside their domain; a coverage
        check that does not pass says so in its note.
    beyond : str
        The inputs that went beyond their training range, in words
        (:func:`~fmu_greybox.model.domain.beyond_training`): the note says a training
        recording should cover them.

    Returns
    -------
    Acceptance
    """
    by_stage = {r.stage: r for r in responses}
    checks: list[Check] = []
    for stage, row in table.items():
        limits = criteria.for_stage(stage)
        if limits.max_nrmse is not None:
            checks.append(_at_most(stage, "nRMSE", row["gb_nrmse"], limits.max_nrmse))
        checks += _frequency_checks(stage, limits, by_stage.get(stage))
        checks += _coverage_checks(stage, limits, row, outside_share, beyond)
    return Acceptance(tuple(checks))


def across_recordings(
    criteria: AcceptanceConfig,
    acceptances: Mapping[str, Acceptance],
    pooled: Mapping[str, Mapping[str, float]],
    outside_share: float = 0.0,
) -> Acceptance:
    """Several recordings' acceptance as one.

    A coverage criterion is checked once, against the shares pooled over the recordings
    (:func:`~fmu_greybox.workflow.metrics.pooled_row`): a drifting stage's recording is worth a
    handful of independent rows, and several recordings can decide what one cannot. Every other
    criterion must hold on each recording: its check is the worst of the recordings' (``FAIL``,
    then ``UNDECIDED``, then ``PASS``; among equal verdicts the value farthest on the wrong side
    of its limit), its note naming that recording.

    Parameters
    ----------
    criteria : AcceptanceConfig
    acceptances : mapping
        Recording name -> its :func:`evaluate` (in the recordings' order).
    pooled : mapping
        Stage -> its shares pooled over the recordings (``coverage95``, ``coverage68`` with
        their ``_low``, ``_high``, and ``independent_rows``).
    outside_share : float
        Share of all the scored rows on which the correctors were outside their domain.

    Returns
    -------
    Acceptance
    """
    worst: dict[tuple[str, str], tuple[str, Check]] = {}
    for name, acceptance in acceptances.items():
        for check in acceptance.checks:
            key = (check.stage, check.criterion)
            if key not in worst or _badness(check) > _badness(worst[key][1]):
                worst[key] = (name, check)
    checks: list[Check] = []
    for stage in dict.fromkeys(stage for stage, _ in worst):
        for (of, criterion), (name, check) in worst.items():
            if of == stage and not criterion.startswith(SHARE_INSIDE):
                note = f"worst on {name}" + (f"; {check.note}" if check.note else "")
                checks.append(replace(check, note=note))
        if stage in pooled:
            limits = criteria.for_stage(stage)
            checks += _coverage_checks(stage, limits, pooled[stage], outside_share)
    return Acceptance(tuple(checks))


def _badness(check: Check) -> tuple[int, float]:
    """Orders checks from best to worst: by verdict, then by how far the value lies toward the
    wrong side of an ``<=`` or ``>=`` limit."""
    rank = {PASS: 0, UNDECIDED: 1, FAIL: 2}[check.verdict]
    if math.isnan(check.value):
        return rank, -math.inf
    sign = 1.0 if check.limit.startswith("<=") else -1.0 if check.limit.startswith(">=") else 0.0
    return rank, sign * check.value


#: How a coverage check's criterion begins (the band follows).
SHARE_INSIDE = "share of rows inside"


def _coverage_checks(
    stage: str, limits: Criteria, row: Mapping[str, float], outside_share: float, beyond: str = ""
) -> list[Check]:
    """The stage's coverage criteria checked against the shares of ``row``."""
    checks = []
    for key, z, width in (("coverage95", Z95, "±1.96σ"), ("coverage68", 1.0, "±1σ")):
        bounds = getattr(limits, key)
        if bounds is not None:
            check = _share_inside(stage, (z, width), row, key, bounds, (outside_share, beyond))
            checks.append(check)
    return checks


def _share_inside(
    stage: str,
    band: tuple[float, str],
    row: Mapping[str, float],
    key: str,
    bounds: tuple[float, float],
    domain: tuple[float, str],
) -> Check:
    """A coverage check: ``FAIL`` only when the share's confidence interval (``key_low`` ..
    ``key_high`` in ``row``, when it has them) lies wholly outside the limits; a share outside
    them whose interval still reaches them is ``UNDECIDED`` (too few independent rows). A check
    that does not pass names ``domain``'s share, the rows outside the correctors' domain, which
    no calibration vouches for, if any, with the inputs a training recording should cover, and
    a recording whose errors are not the size of those the band was calibrated on, when that
    alone accounts for the miss (:func:`share_at_error_ratio`). ``band``: ``z`` and the band in
    words (``±1.96σ``)."""
    z, width = band
    check = _within(stage, f"{SHARE_INSIDE} {width}", row[key], bounds)
    if check.verdict == PASS:
        thin = _thin_evidence(row, key, bounds)
        return replace(check, note="; ".join(thin), thin=bool(thin))
    if check.verdict != FAIL:
        return check
    notes = []
    low, high = row.get(f"{key}_low"), row.get(f"{key}_high")
    undecided = low is not None and high is not None and low <= bounds[1] and high >= bounds[0]
    if undecided:
        notes.append(
            f"the rows are worth about {row.get('independent_rows', float('nan')):.0f} "
            f"independent ones, and the share's 95 % interval {low:.3g}-{high:.3g} reaches the "
            "limits: a longer recording, or more of them validated together, decides"
        )
    outside_share, beyond = domain
    if outside_share > 0.0:
        notes.append(
            f"on {100 * outside_share:.3g} % of the rows the correctors were outside their "
            "domain (out_of_domain), where no calibration vouches for the band"
            + (
                f"; a training recording that also covers {beyond} would bring them in"
                if beyond
                else ""
            )
        )
    notes += _error_size(row, z, bounds, narrow=check.value < bounds[0])
    if key == "coverage95":
        notes += _calibration_worth(row, bounds)
        notes += _free_run_spread(row, check.value)
    return replace(check, verdict=UNDECIDED if undecided else FAIL, note="; ".join(notes))


def _thin_evidence(row: Mapping[str, float], key: str, bounds: tuple[float, float]) -> list[str]:
    """Why a share inside its limits does not vouch for them: its 95 % interval (``key_low``
    .. ``key_high``) reaches beyond them, and for ±1.96σ, the band was calibrated on too few
    independent rows to hold within them on recordings like them (:func:`_calibration_worth`);
    [] when neither."""
    notes = []
    low, high = row.get(f"{key}_low"), row.get(f"{key}_high")
    if low is not None and high is not None and (low < bounds[0] or high > bounds[1]):
        notes.append(
            f"the rows are worth about {row.get('independent_rows', float('nan')):.0f} "
            f"independent ones, and the share's 95 % interval {low:.3g}-{high:.3g} reaches "
            "beyond the limits: a longer recording, or more of them validated together, would "
            "confirm the pass"
        )
    if key == "coverage95":
        notes += _calibration_worth(row, bounds)
    return notes


#: Why a band calibrated on the training rows' halves is often too wide (their free runs are
#: by correctors trained on half the rows), and the remedy.
HALVES_ERR_MORE = (
    "; σ was calibrated on free runs of the training rows' halves, each by correctors trained "
    "on the other half, which often err more than the chain trained on all of them: "
    "calibration recordings (train --calibrate-on) calibrate the chain that ships"
)


def share_at_error_ratio(ratio: float, z: float) -> float:
    """Share of Gaussian errors inside ±``z`` σ, σ calibrated on errors ``ratio`` times smaller
    than them: ``erf(z / ratio / √2)`` (0.95 at ``z`` = 1.96 and ``ratio`` = 1; 0.82 at
    ``ratio`` = 1.46; 0.68 at ``ratio`` = 1.96)."""
    return math.erf(z / ratio / math.sqrt(2.0))


def _error_size(
    row: Mapping[str, float], z: float, bounds: tuple[float, float], narrow: bool
) -> list[str]:
    """Why a band that was calibrated may miss on a recording: its grey-box errors
    (``gb_rmse``) are not the size of those the band was calibrated on (``calibration_rmse``,
    the held-out free runs of its calibration). Said when that alone puts the expected share
    outside ``bounds`` on the side of the miss (``narrow``: below them), with the remedy: a
    training recording that excites the stage as much (too narrow), or calibration recordings
    when σ came from the training rows' halves (too wide, :data:`HALVES_ERR_MORE`); [] otherwise,
    or when the row does not say."""
    ratio = error_ratio(row)
    if not ratio:
        return []
    expected = share_at_error_ratio(ratio, z)
    if not (expected < bounds[0] if narrow else expected > bounds[1]):
        return []
    size = "larger" if narrow else "smaller"
    if narrow:
        remedy = "; train on a recording that excites the stage as much"
    elif row.get("calibration_recordings") == 0:
        remedy = HALVES_ERR_MORE
    else:
        remedy = ""
    return [
        f"errors {ratio:.3g} times those the band was calibrated on (RMSE "
        f"{row['calibration_rmse']:.3g} on the calibration free runs), where it holds about "
        f"{100 * expected:.3g} %: this recording's errors are {size} than the training one's"
        + remedy
    ]


def _calibration_worth(row: Mapping[str, float], bounds: tuple[float, float]) -> list[str]:
    """Why no recording may find a band within ``bounds``: the free runs its σ was
    calibrated on are worth too few independent rows (``calibration_independent_rows``) to
    vouch for them, even on recordings of their kind
    (:func:`~fmu_greybox.model.calibration.calibration_spread`). Said when that range reaches
    beyond ``bounds``; [] otherwise, or when the row does not say.

    The rows that would vouch come with the recording length that gives them, and its
    condition: the errors keep the memory they had. A drift that grows with the run (an
    integrating stage with no restoring force, a ram held by Coulomb friction) keeps a
    handful of independent rows however long the recording (docs/diagnosis.md)."""
    text = calibration_worth_text(row)
    if text is None:
        return []
    rows = row["calibration_independent_rows"]
    low, high = calibration_spread(rows)
    if bounds[0] <= low and high <= bounds[1]:
        return []
    needed = rows_to_vouch((float(bounds[0]), float(bounds[1])))
    if needed is not None and needed > rows:
        # a recording is worth what its free runs were: both halves, or one calibration run
        halves = not row.get("calibration_recordings")
        per_recording = rows if halves else rows / calibration_free_runs(row)
        more = math.ceil((needed - rows) / per_recording)
        text += (
            f"; about {needed} would vouch for {bounds[0]:g}-{bounds[1]:g}. A recording "
            f"given to train --calibrate-on adds about {per_recording:.2g} (a recording's "
            f"errors drift as one): about {more} more recordings like "
            + ("the training one" if halves else "those")
            + " would vouch"
        )
    return [text]


def _free_run_spread(row: Mapping[str, float], share: float) -> list[str]:
    """What one recording's share can be for this band: the range of the calibration's own
    free runs, each scored with σ calibrated on the others (``calibration_share_low`` ..
    ``_high``, :func:`~fmu_greybox.model.calibration.left_out_shares`), and whether ``share``
    lies in it; [] when the row does not say."""
    low, high = row.get("calibration_share_low"), row.get("calibration_share_high")
    if low is None or high is None:
        return []
    runs = calibration_free_runs(row)
    inside = low <= share <= high
    return [
        f"each of the {runs} free runs σ was calibrated on, scored with σ calibrated on the "
        f"others, held {100 * low:.3g}-{100 * high:.3g} %: "
        + (
            "this share is one such recordings show"
            if inside
            else "this recording's share lies outside what they show"
        )
    ]


def _frequency_checks(
    stage: str, limits: Criteria, response: FrequencyResponse | None
) -> list[Check]:
    """Gain, phase and coherence of the grey-box in the stage's band."""
    low, high = limits.band
    band = f"{low:g}-{high:g} Hz"
    wanted = [
        (f"gain error in {band} [dB RMS]", "gain_error_db", limits.max_gain_error_db, _at_most),
        (
            f"phase error in {band} [deg RMS]",
            "phase_error_deg",
            limits.max_phase_error_deg,
            _at_most,
        ),
        (
            f"coherence with the recording in {band} [median]",
            "median_coherence",
            limits.min_coherence,
            _at_least,
        ),
    ]
    wanted = [w for w in wanted if w[2] is not None]
    if response is None:
        note = "no frequency response (no input to take it from)"
        return [
            _undecided(stage, name, _limit(check, value), note) for name, _, value, check in wanted
        ]
    stats = response.band_statistics("grey-box", limits.band)
    if stats.bins == 0:
        note = (
            "no frequency in the band where the recording's estimate can be trusted (input "
            "power or the recording's coherence too low)"
        )
        return [
            _undecided(stage, name, _limit(check, value), note) for name, _, value, check in wanted
        ]
    return [check(stage, name, getattr(stats, key), value) for name, key, value, check in wanted]


def _at_most(stage: str, criterion: str, value: float, limit: float) -> Check:
    return _judged(stage, criterion, value, f"<= {limit:g}", value <= limit)


def _at_least(stage: str, criterion: str, value: float, limit: float) -> Check:
    return _judged(stage, criterion, value, f">= {limit:g}", value >= limit)


def _within(stage: str, criterion: str, value: float, bounds: tuple[float, float]) -> Check:
    low, high = bounds
    return _judged(stage, criterion, value, f"{low:g} .. {high:g}", low <= value <= high)


def _limit(check: Any, value: float) -> str:
    return f"<= {value:g}" if check is _at_most else f">= {value:g}"


def _judged(stage: str, criterion: str, value: float, limit: str, passed: bool) -> Check:
    value = float(value)
    if math.isnan(value):
        return _undecided(stage, criterion, limit, "not measured (no rows)")
    return Check(stage, criterion, value, limit, PASS if passed else FAIL)


def _undecided(stage: str, criterion: str, limit: str, note: str) -> Check:
    return Check(stage, criterion, float("nan"), limit, UNDECIDED, note)


def _number(value: float) -> str:
    return "not measured" if math.isnan(value) else f"{value:.3g}"
