"""What a diagnosis writes: ``diagnosis.json`` (versioned schema) and a self-contained HTML report.

The schema is documented in ``docs/diagnosis.md``; :data:`SCHEMA_VERSION` changes whenever a
field changes meaning or disappears (adding fields keeps the version). The HTML report embeds
its figures as base64 PNGs, so it can be mailed or filed as one file: verdict first, then the
findings, the before/after table and the evidence plots.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fmu_greybox import __version__
from fmu_greybox.atomic import atomic_write
from fmu_greybox.diagnosis.figures import regime_figure, residual_figure, trace_figure
from fmu_greybox.evidence.glossary import glossary_section, term
from fmu_greybox.evidence.html import (
    Html,
    escape,
    figure,
    fmt,
    page,
    percent,
    table,
    verdict,
    write_page,
)
from fmu_greybox.evidence.render import rendering_aside
from fmu_greybox.workflow.parts import DIAGNOSIS_PARTS, parts_text

SCHEMA_VERSION = 1


def diagnosis_payload(diagnosis, recording) -> dict:
    """The content of ``diagnosis.json``.

    Parameters
    ----------
    diagnosis : Diagnosis
        A fitted diagnosis.
    recording : Recording
        The recording it was fitted on.
    """
    exp = diagnosis.experiment_
    findings = [f.to_dict() for f in diagnosis.findings_]
    origin = diagnosis.origin_stage_
    named = [f for f in diagnosis.findings_ if f.effect not in ("none", "unexplained")]
    selection = diagnosis.selection_
    return {
        "schema_version": SCHEMA_VERSION,
        "tool": f"fmu-greybox {__version__}",
        "project": diagnosis.config.name,
        "config": str(diagnosis.config.path) if diagnosis.config.path else None,
        "fmu": str(diagnosis.fmu_path_),
        "recording": {
            "source": str(recording.source),
            "sha256": recording.sha256(),
            "n_samples": recording.n_samples,
            "dt": recording.dt,
            "train_rows": exp.train_rows,
            "heldout_rows": exp.n_samples - exp.train_rows,
            # a long recording is diagnosed on one stretch; the rows above count from its first
            "window": None if diagnosis.window_ is None else diagnosis.window_.to_dict(),
        },
        "verdict": verdict_lines(diagnosis),
        "origin_stage": origin,
        "origin_consistent": (not named) or named[0].stage == origin,
        "stages": [s.to_dict() for s in diagnosis.locator_.stages_],
        "findings": findings,
        "fit": diagnosis.fit_,
        "parts": None if diagnosis.parts_ is None else parts_payload(diagnosis.parts_),
        "inferred_roles": [r.to_dict() for r in diagnosis.signals_.inferred_roles],
        "input_noise": dict(zip(exp.inputs, exp.input_sigma, strict=True)),
        "hypotheses_tested": [h.key for h in diagnosis.hypotheses_],
        "selection": selection_rounds(selection),
        "simulations": diagnosis.simulations_,
        "timings": diagnosis.timings_,
    }


def selection_rounds(selection) -> list[dict]:
    """``diagnosis.json``'s ``selection``: per round what was screened, refined (with the reason
    a candidate was rejected for harm, or the margins of an alternative) and accepted; the
    hypotheses dropped after the rounds for worsening a held-out signal are listed under the
    last round's ``dropped``."""
    if selection is None:
        return []
    rounds = [
        {
            "screen_rows": r.screen_rows,
            "refine_rows": r.refine_rows,
            "screened": r.screened,
            "refined": r.refined,
            "accepted": r.accepted,
            "dropped": [],
        }
        for r in selection.rounds_
    ]
    if rounds:
        rounds[-1]["dropped"] = selection.dropped_
    return rounds


def verdict_lines(diagnosis) -> list[str]:
    """The verdict in a few lines of text (what the terminal prints)."""
    lines = []
    read = [r for r in diagnosis.signals_.inferred_roles if r.source != "unit"]
    if read:
        roles = ", ".join(f"{r.variable} {r.role} ('{r.evidence}')" for r in read)
        lines.append(
            f"Roles read from the FMU's names and descriptions: {roles} (declare them under "
            "[signals] to override)."
        )
    stages = diagnosis.locator_.stages_
    drift = diagnosis.experiment_.whitening is not None
    noise = "sensor noise and the drift its inputs' noise explains" if drift else "sensor noise"
    if diagnosis.origin_stage_ is None:
        lines.append(f"No significant mismatch: every stage matches within {noise}.")
    else:
        before = [s.name for s in stages if stages.index(s) < diagnosis.locator_.origin_]
        matched = f" ({', '.join(before)} match{'es' if len(before) == 1 else ''} within noise)"
        lines.append(
            f"Mismatch starts in stage {diagnosis.origin_stage_}{matched if before else ''}."
        )
    for i, finding in enumerate(diagnosis.findings_, 1):
        if finding.effect == "none":
            continue
        lines.append(f"{i}. [{finding.stage}] {finding.effect}: {finding.summary}")
    for name, row in diagnosis.fit_.items():
        unit = row["unit"]
        alone = f"; correctors alone {row['correctors_rmse']:.3g}" if "best" in row else ""
        greybox = f" -> grey-box {row['gb_rmse']:.3g}" if "gb_rmse" in row else ""
        lines.append(
            f"   {name}: held-out RMSE white-box {row['wb_rmse']:.3g} -> named "
            f"{row['named_rmse']:.3g}{greybox}{alone} {unit}"
        )
    if diagnosis.parts_ is not None:
        parts = parts_text(parts_payload(diagnosis.parts_))
        lines.append(f"   {DIAGNOSIS_PARTS}: {parts}.")
    return lines


def parts_payload(parts) -> dict:
    """``diagnosis.json``'s ``parts``: the comparison without ``shipped`` (a diagnosis ships no
    model; ``train --terms`` compares again with the project's own corrector settings), on the
    whole and on each stage."""
    payload = {k: v for k, v in parts.to_dict().items() if k != "shipped"}
    payload["stages"] = {
        stage: {k: v for k, v in row.items() if k != "shipped"}
        for stage, row in payload["stages"].items()
    }
    return payload


def write_outputs(diagnosis, recording, out_dir: str | Path) -> dict:
    """Write ``diagnosis.json`` and ``report.html`` into ``out_dir`` (created if needed).

    Each file is written atomically. Returns the JSON payload.
    """
    payload = diagnosis_payload(diagnosis, recording)
    with rendering_aside():
        text = report_html(diagnosis, payload)
    write_report_files(payload, text, out_dir)
    return payload


def write_report_files(payload: dict, html: str, out_dir: str | Path) -> None:
    """Write a diagnosis' ``diagnosis.json`` and ``report.html`` (made elsewhere, e.g. on a
    cluster worker) into ``out_dir`` (created if needed), each atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(payload, out / "diagnosis.json")
    write_page(html, out / "report.html")


def write_json(payload: dict, path: str | Path) -> None:
    """Write a payload as JSON atomically (numpy scalars as numbers, non-finite as null)."""
    with atomic_write(Path(path)) as f:
        json.dump(_plain(payload), f, indent=2, allow_nan=False)
        f.write("\n")


def report_html(diagnosis, payload: dict) -> str:
    """The self-contained HTML report of a diagnosis."""
    title = f"Diagnosis of {payload['project']}"
    return page(
        title,
        [verdict(payload["verdict"]), *diagnosis_sections(diagnosis, payload), glossary_section()],
    )


def diagnosis_sections(diagnosis, payload: dict) -> list[str]:
    """HTML sections of a diagnosis: findings, held-out fit, stage residuals, evidence plots.

    Parameters
    ----------
    diagnosis : Diagnosis
        A fitted diagnosis.
    payload : dict
        Its :func:`diagnosis_payload`.
    """
    findings, summaries = [], []
    for i, f in enumerate(payload["findings"], 1):
        summaries.append(escape(f"{i}. {f['summary']}"))
        mag = f.get("magnitude") or {}
        ci = mag.get("ci95")
        findings.append(
            (
                i,
                f["stage"],
                f["effect"],
                fmt(mag.get("value"), 4, mag.get("unit", "")),
                f"[{ci[0]:.4g}, {ci[1]:.4g}]" if ci else "",
                ""
                if f.get("explained_fraction") is None
                else f"{100 * f['explained_fraction']:.0f} %",
            )
        )
    greybox = all("gb_rmse" in row for row in payload["fit"].values())
    fit = [
        (
            name,
            row["unit"],
            fmt(row["noise"]),
            fmt(row["wb_rmse"]),
            f"{fmt(row['named_rmse'])} ({percent(row['named_improvement'])})",
            *([f"{fmt(row['gb_rmse'])} ({percent(row['gb_improvement'])})"] if greybox else []),
        )
        for name, row in payload["fit"].items()
    ]
    residuals = [
        (
            stage["stage"],
            sig["signal"],
            fmt(sig["rms"], 3, sig["unit"]),
            fmt(sig["noise_ratio"]),
            fmt(sig["nrms"]),
            f"{100 * stage['inherited_fraction']:.0f} %",
        )
        for stage in payload["stages"]
        for sig in stage["signals"]
    ]
    window = payload["recording"].get("window")
    stretch = (
        []
        if window is None
        else [
            f"<p>Diagnosed on rows {window['first_row']}-{window['last_row']} of "
            f"{window['of_rows']}: {escape(window['how'])}.</p>"
        ]
    )
    return [
        *stretch,
        "<h2>Findings</h2>",
        table(("#", "stage", "effect", "magnitude", "95 % interval", "explained"), findings),
        "".join(f"<p>{line}</p>" for line in summaries),
        "<h2>Diagnosis: fit on the rows it held out</h2>",
        table(
            (
                "stage",
                "unit",
                "noise",
                "white-box RMSE",
                Html(f"+ {term('named-terms')}"),
                *([Html(f"grey-box ({term('corrector', 'correctors')})")] if greybox else []),
            ),
            fit,
        ),
        f"<p>RMSE on the diagnosis' {term('held-out')}, and its change against the white-box.</p>",
        "<h2>Residual per stage (white-box)</h2>",
        table(
            (
                "stage",
                "signal",
                "RMS",
                term("noise-ratio"),
                Html(f"RMS / recorded spread ({term('nrmse', 'nRMS')})"),
                Html(f"{term('inherited')} from the stages before"),
            ),
            residuals,
        ),
        figure("Residual versus time", residual_figure(diagnosis)),
        figure("Residual by regime and frequency band", regime_figure(diagnosis)),
        figure("Before and after on held-out data", trace_figure(diagnosis)),
        f"<p><small>{escape(payload['tool'])}; recording {escape(payload['recording']['source'])}"
        f" (sha256 {payload['recording']['sha256'][:12]}); FMU {escape(payload['fmu'])}; "
        f"{payload['simulations']} simulations in {payload['timings'].get('total', 0)} s."
        "</small></p>",
    ]


def _plain(value):
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
