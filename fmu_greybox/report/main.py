"""The main job's report: one self-contained HTML page, and ``summary.json``.

Anatomy (``docs/report.md``): the acceptance table first (PASS or FAIL per criterion and
stage, against the project's ``[acceptance]``); the verdict in a few lines; the grey-box on an
independent recording (table, residual panels with the calibrated ±1.96σ band, zooms, the
calibration plot); frequency responses with trusted bands, bounds and a table of the band
statistics; the diagnosis (findings, held-out fit, residual per stage, in time and by regime);
the exported FMU on the SSP bench against the in-process master and the step-time target; and
a traceability table in which every hash says what it covers.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fmu_greybox.diagnosis.report import diagnosis_sections, write_json
from fmu_greybox.project.config import ProjectConfig
from fmu_greybox.report.html import (
    escape,
    figure,
    fmt,
    page,
    percent,
    table,
    verdict,
    write_page,
)
from fmu_greybox.report.plots import calibration_figure, frequency_figure, trace_figure
from fmu_greybox.workflow.acceptance import PASS, Acceptance
from fmu_greybox.workflow.demo import DemoResult
from fmu_greybox.workflow.metrics import (
    INTERVAL_NOTE,
    calibration_free_runs,
    coverage_text,
    error_ratio,
    improvement,
    spread_text,
)
from fmu_greybox.workflow.parts import summary as parts_summary
from fmu_greybox.workflow.validate import Validation, frequency_table

#: Wall time per step of the exported FMU a 1 kHz bench can afford: a tenth of the 1 ms step,
#: leaving the rest to the bench's other models and I/O (docs/bench.md, "Speed").
STEP_TARGET_US = 100.0
#: Diagnosis sections the main report leaves out: its overlay of held-out traces (the residual
#: panels show the grey-box on an independent recording) and its provenance line (the
#: traceability table labels every hash and names no local path).
REPLACED_SECTIONS = ("<h2>Before and after on held-out data</h2>", "<p><small>")


def summary(result: DemoResult) -> dict[str, Any]:
    """The machine-readable outcome (``summary.json``, ``demo --json``)."""
    validation = result.validation
    keys = (
        "wb_rmse",
        "gb_rmse",
        "improvement",
        "coverage68",
        "coverage95",
        "median_std",
        "calibration_rmse",
        "calibration_independent_rows",
        "calibration_share_low",
        "calibration_share_high",
    )
    return {
        "acceptance": validation.acceptance.to_dict() if validation.acceptance else None,
        "concealed_effects": result.effects,
        "seed": result.settings.seed,
        "origin_stage": result.payload["origin_stage"],
        "top_finding": result.payload["findings"][0] if result.payload["findings"] else None,
        "top_finding_correct": result.top_finding_correct(),
        "parts": result.parts or None,
        "validation": {
            stage: {k: row[k] for k in keys if k in row} for stage, row in validation.table.items()
        },
        "frequency": frequency_table(validation),
        "bench": {
            a.engine: {
                "steps": a.steps,
                "seconds": round(a.seconds, 2),
                "us_per_step": round(1e6 * a.seconds / a.steps, 1),
                "max_rel_diff": a.worst,
            }
            for a in result.bench
        },
        "files": {label: str(path) for label, path in result.files.items()},
        "timings": result.timings,
    }


#: What the exported model is, by the part shipped (:data:`fmu_greybox.workflow.parts.PARTS`).
SHIPPED_MODEL = {
    "terms+correctors": "White-box + named terms + correctors",
    "terms": "White-box + named terms, every corrector passed through",
    "correctors": "White-box + correctors (the named terms left out)",
}


def shipped_model(parts: Mapping[str, Any]) -> str:
    """The exported model in words, from the comparison of its parts at training
    (:func:`~fmu_greybox.workflow.parts.summary`'s input): the part shipped, or the grey-box
    without terms."""
    return SHIPPED_MODEL.get(parts.get("shipped", ""), "Grey-box")


def verdict_lines(result: DemoResult) -> list[str]:
    """The verdict, in a few sentences (the acceptance first)."""
    concealed = ", ".join(f"{k} = {v:g}" for k, v in result.effects.items())
    acceptance = result.validation.acceptance
    lines = [acceptance.summary()] if acceptance is not None else []
    lines += [
        f"Concealed in the recording: {concealed} (the truth model's setting; the diagnosis "
        "saw only the white-box FMU, the project file and the recording).",
        *result.payload["verdict"],
        "The top finding names the concealed effect."
        if result.top_finding_correct()
        else "The top finding does not name the concealed effect.",
    ]
    if result.parts:
        lines.append(f"Parts compared at training: {parts_summary(result.parts)}.")
    lines += validation_lines(
        result.validation.table,
        f"{shipped_model(result.parts)} (the exported FMU)",
        f"an independent {result.settings.validation_duration:g} s recording",
    )
    engines = ", ".join(f"{a.engine} {a.worst:.1e}" for a in result.bench)
    lines.append(
        f"Exported FMU on the SSP bench, largest difference from the in-process master "
        f"(relative): {engines}."
    )
    return lines


def validation_lines(
    table_: Mapping[str, Mapping[str, float]],
    model: str,
    recording: str,
    scored: str = "the independent recording",
) -> list[str]:
    """A validation's verdict sentences: the RMSE change against the white-box (and the named
    terms alone's), a warning where the correctors do worse, the share inside ±1.96σ.

    Parameters
    ----------
    table_ : mapping
        The validation's table, stage -> row.
    model : str
        The model validated, as the sentence's subject (``"The grey-box"``).
    recording : str
        The recording, in words (``"an independent 8 s recording"``, a file name).
    scored : str
        The same, as the share's sentence names it.
    """
    named = all("named_rmse" in row for row in table_.values())
    lines = [
        f"{model} against the white-box on {recording} (RMSE change, negative = better): "
        + ", ".join(f"{stage} {percent(row['improvement'])}" for stage, row in table_.items())
        + "."
    ]
    if named:
        lines.append(
            "The named terms alone: "
            + ", ".join(
                f"{stage} {percent(improvement(row['wb_rmse'], row['named_rmse']))}"
                for stage, row in table_.items()
            )
            + "."
        )
    base = "named_rmse" if named else "wb_rmse"
    worse = [stage for stage, row in table_.items() if row["gb_rmse"] > 1.01 * row[base]]
    if worse:
        than = "the named terms alone" if named else "the white-box"
        lines.append(
            f"The correctors do worse than {than} on {', '.join(worse)} in free run on that "
            f"recording: do not rely on them there (the exported FMU with correction_enabled = "
            f"false gives {than})."
        )
    lines.append(
        f"Share of {scored} inside the grey-box's ±1.96σ: "
        + ", ".join(f"{stage} {coverage_text(row, 'coverage95')}" for stage, row in table_.items())
        + f" ({INTERVAL_NOTE})."
    )
    return lines


def traceability_section(rows: list[tuple[str, str, str]]) -> list[str]:
    """The traceability table: rows ``(item, what it covers, value)``."""
    return [
        "<h2>Traceability</h2>",
        table(
            ("item", "what it covers", "value"),
            [
                (escape(item), escape(covers), f"<code>{escape(value)}</code>")
                for item, covers, value in rows
            ],
            raw=True,
        ),
    ]


def criteria_source(config: ProjectConfig, recordings: str) -> str:
    """Where the acceptance criteria come from and what they were checked on, in words."""
    name = config.path.name if config.path else "defaults"
    return (
        f"Criteria of the project file's [acceptance] table ({name}; docs/config.md says why "
        f"each default), checked on {recordings}."
    )


def acceptance_section(acceptance: Acceptance, source: str) -> str:
    """The PASS / FAIL table, headed by the whole verdict.

    Parameters
    ----------
    acceptance : Acceptance
    source : str
        Where the criteria come from, in words.
    """
    colours = {PASS: "pass", "FAIL": "fail"}
    rows = [
        (
            escape(c.stage),
            escape(c.criterion),
            "" if c.value != c.value else escape(f"{c.value:.3g}"),
            escape(c.limit),
            f"<span class='{colours.get(c.verdict, 'undecided')}'>{c.verdict}</span>"
            + (f" <small>{escape(c.note)}</small>" if c.note else ""),
        )
        for c in acceptance.checks
    ]
    verdict_class = colours.get(acceptance.verdict, "undecided")
    return (
        f"<h2>Acceptance: <span class='{verdict_class}'>{acceptance.verdict}</span></h2>"
        f"<p>{escape(source)}</p>"
        + table(("stage", "criterion", "measured", "limit", "verdict"), rows, raw=True)
    )


#: What the independent-recording table's last column says.
RATIO_NOTE = (
    "k: this RMSE over that of the free runs σ was calibrated on; "
    "±1.96σ then holds about erf(1.96 / k / √2) of Gaussian errors."
)


def calibration_ratios(validation: Validation) -> bool:
    """Whether every stage's row can say how its errors compare with those its σ was
    calibrated on (a model stored before ``calibration_rmse`` was kept cannot)."""
    return all(error_ratio(row) is not None for row in validation.table.values())


def validation_rows(validation: Validation, units: list[str]) -> list[tuple]:
    """Rows of the independent-recording table: errors, the uncertainty's coverage and the
    grey-box's RMSE as a multiple of the one its σ was calibrated on."""
    named = all("named_rmse" in row for row in validation.table.values())
    ratio = calibration_ratios(validation)
    return [
        (
            stage,
            unit,
            fmt(row["wb_rmse"]),
            *([fmt(row["named_rmse"])] if named else []),
            fmt(row["gb_rmse"]),
            percent(row["improvement"]),
            fmt(row["gb_nrmse"]),
            fmt(row["median_std"]),
            coverage_text(row, "coverage68"),
            coverage_text(row, "coverage95"),
            *([f"{error_ratio(row):.3g}×"] if ratio else []),
        )
        for (stage, row), unit in zip(validation.table.items(), units, strict=True)
    ]


def calibration_worth_rows(validation: Validation, units: list[str]) -> list[tuple]:
    """Per stage, what its σ was calibrated on: the calibration free runs' RMSE, what they are
    worth in independent rows, and where they put ±1.96σ on recordings like them
    (:func:`~fmu_greybox.model.calibration.calibration_spread`); [] when the model does not
    say (stored before ``independent_rows`` was kept)."""
    rows = []
    for (stage, row), unit in zip(validation.table.items(), units, strict=True):
        worth = row.get("calibration_independent_rows")
        if worth is None:
            return []
        rows.append(
            (
                stage,
                unit,
                fmt(row["calibration_rmse"]),
                f"{worth:.0f}",
                spread_text(worth),
                left_out_text(row),
            )
        )
    return rows


def left_out_text(row: dict) -> str:
    """The range of the shares the calibration's free runs held, each with σ calibrated on
    the others, e.g. ``30-100 % (20 runs)``; ``-`` when the model does not say."""
    low, high = row.get("calibration_share_low"), row.get("calibration_share_high")
    if low is None or high is None:
        return "-"
    return f"{100 * low:.3g}-{100 * high:.3g} % ({calibration_free_runs(row)} runs)"


def frequency_rows(validation: Validation) -> list[tuple]:
    """Per stage: the band statistics of white-box and grey-box (the figure's segments)."""
    rows = []
    for r in validation.responses:
        band = validation.criteria.for_stage(r.stage).band
        wb, gb = (r.band_statistics(s, band) for s in ("white-box", "grey-box"))
        rows.append(
            (
                f"{r.stage}: {r.output_name} / {r.input_name}",
                f"{band[0]:g}-{band[1]:g} Hz ({gb.bins} trusted)",
                r.gain_unit,
                f"{fmt(wb.gain_error_db)} → {fmt(gb.gain_error_db)}",
                f"{fmt(wb.phase_error_deg)} → {fmt(gb.phase_error_deg)}",
                f"{fmt(wb.median_coherence)} → {fmt(gb.median_coherence)}",
                f"±{fmt(gb.recording_bound_db, 2)}",
            )
        )
    return rows


def stage_titles(config: ProjectConfig) -> tuple[list[str], list[str]]:
    """Each stage's output unit and panel title (``"RAM: ram_position"``), in chain order."""
    units = [config.signals[stage.target].unit for stage in config.stages]
    return units, [f"{stage.name}: {stage.target}" for stage in config.stages]


def validation_sections(
    validation: Validation, units: list[str], labels: list[str], model_text: str = ""
) -> list[str]:
    """The sections on a validation (the demo's independent recording, or ``validate``'s): its
    table, the residuals with their band, the calibration plot, the frequency responses and
    their band statistics.

    Parameters
    ----------
    validation : Validation
    units : list of str
        Each stage's output unit, in chain order.
    labels : list of str
        Each stage's panel title (``"RAM: ram_position"``).
    model_text : str
        A sentence on the model validated, or ``""``.
    """
    run = validation.run
    recorded = validation.data.outputs[run.rows]
    named = all("named_rmse" in row for row in validation.table.values())
    return [
        "<h2>Grey-box on an independent recording</h2>",
        f"<p>{escape(validation.held_out)}; free run, correctors fed their own outputs."
        + model_text
        + " σ is the grey-box's calibrated standard deviation (docs/greybox.md, 'Calibrated "
        "uncertainty'), the exported FMU's _std; in brackets: the share's 95 % interval, as in "
        "the verdict." + (f" {RATIO_NOTE}" if calibration_ratios(validation) else "") + "</p>",
        table(
            (
                "stage",
                "unit",
                "white-box RMSE",
                *(["+ named terms RMSE"] if named else []),
                "grey-box RMSE",
                "change",
                "grey-box nRMSE",
                "median σ",
                "inside ±1σ",
                "inside ±1.96σ",
                *(["k: RMSE / calibration's"] if calibration_ratios(validation) else []),
            ),
            validation_rows(validation, units),
        ),
        figure(
            "Residuals with the grey-box's ±1.96σ band",
            trace_figure(
                run.time,
                recorded,
                validation.whitebox,
                run.mean,
                run.std,
                labels,
                units,
                outside=run.outside,
            ),
            "Left: recording minus grey-box inside its ±1.96σ band (the white-box's residual, "
            "often far larger, would hide it: its RMSE is in each title), grey where the "
            "correctors were outside their domain. Right: the recording, both models and the "
            "band over the 0.2 s where the grey-box's residual is largest.",
        ),
        figure(
            "Calibration of the uncertainty",
            calibration_figure(recorded, run.mean, run.std, run.latent_std, labels),
            "Share of the independent recording inside ±z σ against the share a calibrated σ "
            "puts there; dashed: the σ propagated through the chain before calibration.",
        ),
        *_calibration_worth_section(validation, units),
        figure(
            "Frequency response and coherence",
            frequency_figure(
                validation.responses,
                [validation.criteria.for_stage(r.stage).band for r in validation.responses],
            ),
            "Welch estimates from the acceptance input to each stage output, drawn where the "
            "recording's input-output coherence reaches 0.6 (the trusted frequencies); phase "
            "unwrapped across those only.",
        )
        if validation.responses
        else "",
        table(
            (
                "stage: output / input",
                "band",
                "gain unit",
                "gain error [dB RMS] white-box → grey-box",
                "phase error [deg RMS]",
                "coherence with the recording [median]",
                "recording's 95 % bound [dB]",
            ),
            frequency_rows(validation),
        ),
    ]


def _calibration_worth_section(validation: Validation, units: list[str]) -> list[str]:
    """What each stage's σ rests on (:func:`calibration_worth_rows`), or nothing."""
    rows = calibration_worth_rows(validation, units)
    if not rows:
        return []
    recordings = {int(row.get("calibration_recordings", 0)) for row in validation.table.values()}
    count = recordings.pop() if len(recordings) == 1 else 0
    runs = (
        f"{count} calibration recordings, each free-run whole by the model that ships"
        if count
        else "the training rows free-run by correctors trained on the other half"
    )
    return [
        f"<p>What σ was calibrated on: {runs}. A slow error repeats few times in a free run, "
        "and a band calibrated on few independent rows holds anywhere in a wide range on "
        "recordings of the same kind (95 % range, docs/greybox.md). The last column is what "
        "single recordings held: each free run scored with σ calibrated on the others.</p>",
        table(
            (
                "stage",
                "unit",
                "RMSE of the calibration free runs",
                "independent rows",
                "±1.96σ holds on recordings like them",
                "one free run held, σ from the others",
            ),
            rows,
        ),
    ]


def report_html(result: DemoResult) -> str:
    """The whole report page."""
    validation = result.validation
    units, labels = stage_titles(result.config)
    sections = []
    if validation.acceptance is not None:
        sections.append(
            acceptance_section(
                validation.acceptance,
                criteria_source(
                    result.config,
                    f"the independent {result.settings.validation_duration:g} s recording",
                ),
            )
        )
    diagnosis = [
        s
        for s in diagnosis_sections(result.diagnosis, result.payload)
        if not s.startswith(REPLACED_SECTIONS)
    ]
    sections += [
        verdict(verdict_lines(result)),
        *validation_sections(
            validation,
            units,
            labels,
            f" The exported model: {shipped_model(result.parts)}." if result.parts else "",
        ),
        *diagnosis,
        "<h2>The exported FMU on the SSP bench</h2>",
        f"<p>{escape(result.fmu.name)} in {escape(result.ssp.name)} (recording playback → "
        "grey-box, white-box side by side), compared output by output (corrected value, "
        "_std, _wb) with the in-process master on the same inputs. Wall time includes loading "
        f"and setting up the bench; the target is {STEP_TARGET_US:g} µs per 1 ms step "
        "(benchmarks/bench_export.py measures the step alone).</p>",
        table(
            (
                "engine",
                "steps",
                "wall time",
                "per step, setup included",
                "target for the step alone",
                "largest relative difference",
            ),
            [
                (
                    a.engine,
                    a.steps,
                    f"{a.seconds:.2f} s",
                    f"{1e6 * a.seconds / a.steps:.0f} µs",
                    f"{STEP_TARGET_US:g} µs",
                    f"{a.worst:.1e}",
                )
                for a in result.bench
            ],
        ),
        *traceability_section(result.traceability()),
        "<h3>Run time of each step of the demo</h3>",
        table(
            ("step", "seconds"),
            [(name, f"{seconds:.1f}") for name, seconds in result.timings.items()],
        ),
    ]
    return page(f"fmu-greybox report: {result.config.name}", sections)


def write_report(result: DemoResult) -> dict[str, Any]:
    """Write ``summary.json`` then ``report.html`` (each atomically) into the demo's folder.

    Returns
    -------
    dict
        The summary.
    """
    out = Path(result.settings.out_dir)
    outcome = summary(result)
    write_json(outcome, out / "summary.json")
    write_page(report_html(result), out / "report.html")
    return outcome
