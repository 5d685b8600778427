"""Findings: what the diagnosis says, one named effect (or verdict) at a time.

A finding pairs a kept hypothesis with what it means for the system engineer: the stage where
it shows first, its magnitude with units and a 95 % interval, the share of that stage's
residual it explains, where (regimes, time windows) the residual it explains concentrates, and
one sentence saying all that. Two verdicts complete the vocabulary: ``none`` (every stage
matches within noise) and ``unexplained`` (structure remains that no hypothesis explains).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fmu_greybox.data.noise import SIGNIFICANT_STRUCTURE, structure_left
from fmu_greybox.diagnosis.alternatives import Separation, separation
from fmu_greybox.diagnosis.hypotheses import Hypothesis, quantity
from fmu_greybox.diagnosis.locate import Regime, StageResidual
from fmu_greybox.diagnosis.runner import Experiment
from fmu_greybox.diagnosis.select import ForwardSelection, Round

#: A correction "changes" a stage when it moves one of its signals by this many noise levels
#: (RMS): the structure that makes a residual significant.
CHANGE_THRESHOLD = SIGNIFICANT_STRUCTURE
#: A finding's summary also names the output it helps most when that output's share explained
#: exceeds the stage's by this much (a stage's energy can be dominated by one drifting signal).
MENTION_MARGIN = 0.3


@dataclass
class Finding:
    """One entry of ``diagnosis.json``'s ``findings``.

    Attributes
    ----------
    stage : str or None
        Stage where it shows first.
    effect : str
        Vocabulary identifier.
    summary : str
        One sentence.
    magnitude : dict or None
        ``value``, ``unit``, ``ci95`` ([low, high]) of the main magnitude.
    explained_fraction : float or None
        Share of the stage's residual structure it explains (whitened power beyond noise,
        :func:`stage_structure`): of the white-box's for the first finding kept, of what the
        earlier findings left for the others.
    where : list of dict
        Regimes and time windows where the stage's residual concentrates.
    details : dict
        Hypothesis key, every magnitude, the terms that model it, further facts.
    """

    stage: str | None
    effect: str
    summary: str
    magnitude: dict | None = None
    explained_fraction: float | None = None
    where: list[dict] = field(default_factory=list)
    details: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "stage": self.stage,
            "effect": self.effect,
            "summary": self.summary,
            "magnitude": self.magnitude,
            "explained_fraction": (
                None if self.explained_fraction is None else round(self.explained_fraction, 4)
            ),
            "where": self.where,
            **self.details,
        }


def named_physics(finding: dict) -> str:
    """The physics a finding (as in ``diagnosis.json``) names: its effect, or for a
    ``parameter_mismatch`` its physics label."""
    if finding["effect"] == "parameter_mismatch":
        return finding.get("physics") or "parameter_mismatch"
    return finding["effect"]


def alternative_name(finding: dict) -> str:
    """A finding (as in ``diagnosis.json``) named in a sentence of alternatives: its physics and
    magnitude (``coulomb_friction of 573 N``); a mis-set parameter by its name and the value it
    would have (``parameter ram_stroke at 0.0618 m instead of 0.05 m``), since a relative change
    alone does not say which parameter."""
    if finding.get("parameter"):
        unit = finding.get("parameter_unit", "")
        physics = finding.get("physics")
        label = f" ({physics.replace('_', ' ')})" if physics else ""
        return (
            f"parameter {finding['parameter']}{label} at {quantity(finding['estimate'], unit)} "
            f"instead of {quantity(finding['nominal'], unit)}"
        )
    magnitude = finding.get("magnitude") or {}
    shown = quantity(magnitude.get("value", math.nan), magnitude.get("unit", ""))
    return f"{named_physics(finding)} of {shown}"


def telling_apart(apart: Separation) -> str:
    """Where two explanations differ and what to record to tell them apart, in words: ``they
    differ most where |valve_current| below 0.107 mA: record small commands to tell them
    apart``."""
    where = "in" if apart.kind == "band" else "where"
    return f"they differ most {where} {apart.label}: record {apart.advice} to tell them apart"


def where_from(stage: StageResidual | None, limit: int = 4) -> list[dict]:
    """Regimes, main frequency band and windows where a stage's residual concentrates most
    (of its signal furthest above noise)."""
    if stage is None or not stage.signals:
        return []
    signal = max(stage.signals, key=lambda s: s.noise_ratio)
    regimes = signal.regimes
    concentrated = [
        r for r in regimes if r.kind not in ("window", "band") and r.concentration >= 1.3
    ]
    concentrated.sort(key=lambda r: -r.concentration)
    bands = sorted((r for r in regimes if r.kind == "band"), key=lambda r: -r.energy_share)[:1]
    windows = [r for r in regimes if r.kind == "window"]
    picked: list[Regime] = [*concentrated[:limit], *bands, *windows]
    return [{"signal": signal.name, **r.to_dict()} for r in picked]


def stage_changed(experiment: Experiment, before: np.ndarray, after: np.ndarray) -> int | None:
    """First stage whose signals move by more than :data:`CHANGE_THRESHOLD` noise levels."""
    change = np.sqrt(np.mean(((after - before) / experiment.sigma) ** 2, axis=0))
    stages = np.array(experiment.stages)
    moved = [int(s) for s in sorted(set(stages)) if np.any(change[stages == s] > CHANGE_THRESHOLD)]
    return moved[0] if moved else None


def best_explained_signal(
    experiment: Experiment, before: np.ndarray, after: np.ndarray
) -> tuple[str, float] | None:
    """The observed output whose residual energy a step from ``before`` to ``after`` cuts most.

    Returns
    -------
    (str, float) or None
        The output's name and the share of its residual energy removed; ``None`` without
        residual.
    """
    e_before = np.sum(experiment.residual(before) ** 2, axis=0)
    e_after = np.sum(experiment.residual(after) ** 2, axis=0)
    share = np.where(e_before > 0, 1.0 - e_after / np.maximum(e_before, 1e-300), 0.0)
    if share.size == 0:
        return None
    j = int(np.argmax(share))
    return experiment.outputs[j], float(share[j])


def stage_structure(
    experiment: Experiment, before: np.ndarray, after: np.ndarray, stage: int
) -> tuple[float, float]:
    """Structure of a stage's signals before and after a change: whitened power beyond noise
    in the frequency bands where either leaves structure beyond chance
    (:func:`~fmu_greybox.data.noise.structure_left`), over the whole recording."""
    cols = [j for j, s in enumerate(experiment.stages) if s == stage]
    new, old, _ = structure_left(experiment.bands(after), experiment.bands(before))
    return float(np.sum(old[cols])), float(np.sum(new[cols]))


def named_findings(
    experiment: Experiment,
    selection: ForwardSelection,
    prefixes: list[np.ndarray],
    stages: list[StageResidual],
    regimes: dict[str, dict[str, np.ndarray]],
    units: dict[str, str],
) -> list[Finding]:
    """Findings of the kept hypotheses, best first, each with its alternatives.

    Parameters
    ----------
    experiment : Experiment
    selection : ForwardSelection
        Fitted: its kept hypotheses with joint magnitudes and covariance, and its rounds with
        the alternatives of each.
    prefixes : list of ndarray
        Simulations with the first ``i`` kept hypotheses, ``i = 0 .. m`` (0: white-box).
    stages : list of StageResidual
        The white-box residual statistics (for ``where``).
    regimes : dict
        Regime kind -> {recorded signal: values}, to tell alternatives apart
        (:func:`~.alternatives.separation`).
    units : dict[str, str]
        Recorded signal -> unit.

    Returns
    -------
    list of Finding
    """
    selected = selection.selected_
    total = [float(np.sum(experiment.residual(p) ** 2)) for p in prefixes]
    ci = selected.ci95
    offsets = np.cumsum([0] + [h.n_params for h in selected.hypotheses])
    rounds = {r.accepted: r for r in selection.rounds_ if r.accepted}
    found = []
    for i, (h, theta) in enumerate(zip(selected.hypotheses, selected.split(), strict=True)):
        before, after = prefixes[i], prefixes[i + 1]
        k = offsets[i]
        finding = _finding(
            experiment, stages, h, theta, ci[k : k + h.n_params], before, after, i > 0
        )
        round_ = rounds.get(h.key)
        if round_ is not None and round_.alternatives:
            _add_alternatives(finding, experiment, stages, round_, before, after, regimes, units)
        found.append(((total[i] - total[i + 1]) / total[0] if total[0] > 0 else 0.0, finding))
    found.sort(key=lambda pair: -pair[0])
    return [f for _, f in found]


def _finding(
    experiment: Experiment,
    stages: list[StageResidual],
    h: Hypothesis,
    theta: np.ndarray,
    ci: np.ndarray,
    before: np.ndarray,
    after: np.ndarray,
    after_others: bool = False,
) -> Finding:
    """The finding of one hypothesis at ``theta``: simulated ``before`` and ``after`` it
    (``after_others``: after the findings kept before it)."""
    stage = stage_changed(experiment, before, after)
    stage = h.entry if stage is None else stage
    left, remains = stage_structure(experiment, before, after, stage)
    explained = (left - remains) / left if left > 0 else 0.0
    best = best_explained_signal(experiment, before, after)
    if best is not None and best[1] < max(explained, 0.0) + MENTION_MARGIN:
        best = None
    return _named(h, theta, ci, stages[stage].name, explained, stages[stage], after_others, best)


def _add_alternatives(
    finding: Finding,
    experiment: Experiment,
    stages: list[StageResidual],
    round_: Round,
    before: np.ndarray,
    after: np.ndarray,
    regimes: dict[str, dict[str, np.ndarray]],
    units: dict[str, str],
) -> None:
    """Attach a round's alternatives to its accepted finding (``alternatives``, each with the
    fields of a finding, its margins and what separates it) and say so in the summary."""
    scores = {entry["key"]: entry for entry in round_.refined}
    alternatives, names = [], []
    for c in round_.alternatives:
        h, theta = c.hypotheses[-1], c.split()[-1]
        alt = _finding(experiment, stages, h, theta, c.ci95[-h.n_params :], before, c.simulated)
        margins = scores[h.key]["alternative"]
        apart = separation(experiment, regimes, units, after, c.simulated)
        alternatives.append(
            {
                **alt.to_dict(),
                **margins,
                "separation": None if apart is None else apart.to_dict(),
            }
        )
        where = "" if apart is None else f" ({telling_apart(apart)})"
        names.append(f"{alternative_name(alt.to_dict())}{where}")
    finding.details["alternatives"] = alternatives
    finding.summary = f"{finding.summary} Equally consistent with {'; '.join(names)}."


def _named(
    h: Hypothesis,
    theta: np.ndarray,
    ci: np.ndarray,
    stage: str,
    explained: float,
    residual: StageResidual,
    after_others: bool,
    best: tuple[str, float] | None = None,
) -> Finding:
    share = max(0.0, min(1.0, explained))
    left = " left by the findings before it" if after_others else ""
    also = f", and {100 * best[1]:.0f} % of {best[0]}'s" if best is not None else ""
    summary = (
        f"{h.phrase(theta)}; it explains {100 * share:.0f} % of the {stage} residual{left}{also}."
    )
    magnitudes = {
        name: {"value": float(v), "unit": unit, "ci95": _interval(c)}
        for name, v, unit, c in zip(h.names, theta, h.units, ci, strict=True)
    }
    main = next(iter(magnitudes.values()))
    return Finding(
        stage=stage,
        effect=h.effect,
        summary=summary,
        magnitude=main,
        explained_fraction=share,
        where=where_from(residual),
        details={
            "hypothesis": h.key,
            "enters_at": h.location,
            "magnitudes": magnitudes,
            "terms": [t.to_dict() for t in h.terms(theta)],
            **h.extra(theta),
            **(
                {"best_explained_signal": {"signal": best[0], "fraction": best[1]}}
                if best is not None
                else {}
            ),
        },
    )


def _interval(c: np.ndarray) -> list[float] | None:
    if not np.all(np.isfinite(c)):
        return None
    return [float(c[0]), float(c[1])]


def none_finding(stages: list[StageResidual]) -> Finding:
    """The verdict that every stage matches within noise."""
    worst = max(stages, key=lambda s: s.noise_ratio)
    return Finding(
        stage=None,
        effect="none",
        summary=(
            "Every stage matches the recording within sensor noise: the largest residual "
            f"({worst.name}) is {worst.noise_ratio:.2f} times its noise level."
        ),
    )


def unexplained_finding(
    stage: StageResidual,
    noise_ratio: float,
    remaining: float,
    unit: str,
    rms: float,
    why: str = "",
) -> Finding:
    """The verdict that structure remains in a stage that no hypothesis explains.

    Parameters
    ----------
    stage : StageResidual
        White-box statistics of the stage.
    noise_ratio : float
        Held-out RMS over noise after the named terms.
    remaining : float
        Share of the stage's white-box residual energy left after the named terms.
    unit : str
        Unit of the stage target.
    rms : float
        Held-out RMS of the stage target's residual after the named terms.
    why : str
        A sentence on why nothing explains it, when that is known (appended to the summary).
    """
    named = "the named terms" if remaining < 0.999 else "the white-box"
    return Finding(
        stage=stage.name,
        effect="unexplained",
        summary=(
            f"Structure remains in the {stage.name} residual that no hypothesis explains: after "
            f"{named} its RMS is {noise_ratio:.3g} times the sensor noise on held-out data "
            f"({100 * remaining:.0f} % of the white-box residual structure remains)."
            + (f" {why}" if why else "")
        ),
        magnitude={"value": rms, "unit": unit, "ci95": None},
        explained_fraction=None if math.isnan(remaining) else max(0.0, 1.0 - remaining),
        where=where_from(stage),
    )
