"""The report's first box, read at a glance: whether the model passes, what was found (with
its unit), what ships on each stage, and what to do next (the plain words of the parts
comparisons, which the console prints too, are :func:`fmu_greybox.workflow.parts.parts_text`).

Every sentence is built from the validation, the acceptance and the model; terms of art link
to the glossary (:mod:`fmu_greybox.evidence.glossary`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from fmu_greybox.evidence.glossary import term
from fmu_greybox.evidence.html import Html, escape, percent, table
from fmu_greybox.workflow.acceptance import FAIL, PASS, UNDECIDED, Acceptance

if TYPE_CHECKING:
    from fmu_greybox.model.terms import Term

#: Most checks the result sentence names one by one; beyond, it counts them by verdict.
MAX_NAMED = 3


def shipped_by_stage(
    stages: Sequence[str], passed_through: Sequence[str], terms: Sequence[Term]
) -> dict[str, str]:
    """What the model computes on each stage, in words: the white-box, the named terms acting
    there (:meth:`~fmu_greybox.model.terms.Term.acts_at`), and the corrector unless it is
    switched off.

    Parameters
    ----------
    stages : sequence of str
        Stage names, in chain order.
    passed_through : sequence of str
        The stages whose corrector is switched off.
    terms : sequence of Term
        The model's named terms.

    Returns
    -------
    dict
        Stage -> e.g. ``"white-box + supply_pressure_droop (named term), corrector off"``.
    """
    shipped = {}
    for q, stage in enumerate(stages):
        acting = [t.effect for t in terms if t.acts_at(q)]
        text = "white-box"
        if acting:
            noun = "named term" if len(acting) == 1 else "named terms"
            text += f" + {', '.join(dict.fromkeys(acting))} ({noun})"
        text += ", corrector off" if stage in passed_through else " + corrector"
        shipped[stage] = text
    return shipped


def result_line(acceptance: Acceptance | None, recording: str) -> Html:
    """The verdict in one sentence: how many checks pass on ``recording``, which fail or are
    undecided (more than :data:`MAX_NAMED`: how many, on which stages), which passes rest on
    thin evidence."""
    if acceptance is None:
        return Html(f"No acceptance criteria were checked on {escape(recording)}.")
    verdict = acceptance.verdict
    colour = {PASS: "pass", FAIL: "fail"}.get(verdict, "undecided")
    passed = sum(c.verdict == PASS for c in acceptance.checks)
    text = (
        f"<span class='{colour} headline'>{verdict}</span> {passed} of "
        f"{len(acceptance.checks)} checks pass on {escape(recording)}"
    )
    others = [c for c in acceptance.checks if c.verdict != PASS]
    if 0 < len(others) <= MAX_NAMED:
        text += "; not passed: " + escape(
            ", ".join(f"{c.stage} {c.criterion} ({c.verdict})" for c in others)
        )
    elif others:
        counts = {v: sum(c.verdict == v for c in others) for v in (FAIL, UNDECIDED)}
        stages = ", ".join(dict.fromkeys(c.stage for c in others))
        text += "; not passed: " + escape(
            " and ".join(f"{n} {v}" for v, n in counts.items() if n) + f", on {stages}"
        )
    if acceptance.thin:
        text += f"; {len(acceptance.thin)} on {term('thin-evidence')}: " + escape(
            ", ".join(f"{c.stage} {c.criterion}" for c in acceptance.thin)
        )
    return Html(text + ". The notes under the acceptance table say why.")


def next_step(acceptance: Acceptance | None, use: str) -> str:
    """What to do next, by the verdict; ``use``: how to put the model to use (a sentence)."""
    if acceptance is None:
        return f"State acceptance criteria in the project file ([acceptance]). {use}"
    if acceptance.verdict == FAIL:
        return (
            "Do not use the stages that fail. The notes under the acceptance table name each "
            "failure's cause and remedy; then retrain and validate again."
        )
    if acceptance.verdict != PASS:
        return (
            "Undecided: validate on a longer recording, or on several together (validate "
            "--recording A.csv --recording B.csv), to decide."
        )
    if acceptance.thin:
        stages = ", ".join(dict.fromkeys(c.stage for c in acceptance.thin))
        return (
            f"{use} Before relying on the uncertainty band of {stages}, confirm it: validate "
            "on several recordings together, or calibrate on more (train --calibrate-on)."
        )
    return use


def summary_section(
    result: Html,
    found: Sequence[Html],
    shipped: Mapping[str, str],
    validation_table: Mapping[str, Mapping[str, float]],
    next_text: str,
) -> str:
    """The summary box: the result, what was found, a table of what ships on each stage with
    its error against the white-box, and the next step.

    Parameters
    ----------
    result : Html
        :func:`result_line`.
    found : sequence of Html
        What the diagnosis found, one sentence each (none: nothing named).
    shipped : mapping
        :func:`shipped_by_stage`; empty: the box says the result and the next step only.
    validation_table : mapping
        The validation's table (``improvement`` per stage).
    next_text : str
        :func:`next_step`.
    """
    found_text = (
        " ".join(found)
        if found
        else "No named physical effect: what the white-box misses is left to the correctors."
    )
    rows = [
        (stage, what, percent(validation_table.get(stage, {}).get("improvement")))
        for stage, what in shipped.items()
    ]
    header = (
        "stage",
        Html(f"what ships ({term('named-terms')}, {term('corrector', 'correctors')})"),
        "RMSE change against the white-box",
    )
    return (
        "<div class='summary' id='summary'><h2>Summary</h2>"
        f"<p><b>Result:</b> {result}</p>"
        + (f"<p><b>Found:</b> {found_text}</p>" + table(header, rows) if shipped else "")
        + f"<p><b>Next:</b> {escape(next_text)} Terms: see the "
        "<a href='#glossary'>glossary</a>.</p></div>"
    )


def finding_sentence(finding: Mapping[str, Any]) -> Html:
    """One finding of ``diagnosis.json`` with its magnitude, unit and 95 % interval, and the
    share of its stage's error it explains."""
    magnitude = finding.get("magnitude") or {}
    text = f"{finding['effect']} in stage {finding['stage']}"
    if magnitude.get("value") is not None:
        unit = f" {magnitude['unit']}" if magnitude.get("unit") else ""
        text += f": {magnitude['value']:.3g}{unit}"
        ci = magnitude.get("ci95")
        if ci:
            text += f" (95 % interval {ci[0]:.3g} to {ci[1]:.3g})"
    if finding.get("explained_fraction") is not None:
        text += f", explaining {100 * finding['explained_fraction']:.0f} % of that stage's error"
    return Html(escape(text + "."))
