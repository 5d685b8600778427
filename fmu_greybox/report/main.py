"""The main job's report: one self-contained HTML page, and ``summary.json``.

Anatomy (``docs/report.md``): a summary read at a glance (:mod:`fmu_greybox.report.summary`);
the acceptance table (PASS or FAIL per criterion and stage, against the project's
``[acceptance]``, its notes under it); the verdict in a few lines; the grey-box on an
independent recording (table, residual panels with the calibrated ±1.96σ band, zooms, the
calibration plot); frequency responses with trusted bands, bounds and a table of the band
statistics; the diagnosis (findings, held-out fit, residual per stage, in time and by regime);
the exported FMU on the SSP bench against the in-process master and the step-time target; a
glossary of the terms the tables link to; and a traceability table in which every hash says
what it covers. No table cell holds an explanation: those stand under the tables.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fmu_greybox.diagnosis.report import diagnosis_sections, write_json
from fmu_greybox.evidence.glossary import glossary_section, term
from fmu_greybox.evidence.html import (
    Html,
    escape,
    figure,
    fmt,
    note_link,
    notes_list,
    page,
    percent,
    table,
    verdict,
    write_page,
)
from fmu_greybox.evidence.plots import calibration_figure, frequency_figure, trace_figure
from fmu_greybox.evidence.render import rendering_aside
from fmu_greybox.model.store import GreyBoxModel
from fmu_greybox.project.config import ProjectConfig
from fmu_greybox.report.demo import DemoResult
from fmu_greybox.report.summary import (
    finding_sentence,
    next_step,
    result_line,
    shipped_by_stage,
    summary_section,
)
from fmu_greybox.workflow.acceptance import PASS, Acceptance
from fmu_greybox.workflow.metrics import (
    INTERVAL_NOTE,
    calibration_free_runs,
    coverage_text,
    error_ratio,
    improvement,
    spread_text,
)
from fmu_greybox.workflow.parts import PART_WORDS, TRAINING_PARTS, parts_text, shipped_parts
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


#: What the exported model is, by the part shipped on every stage
#: (:data:`fmu_greybox.project.config.STAGE_PARTS`).
SHIPPED_MODEL = {
    "terms+correctors": "white-box + named terms + correctors",
    "terms": "white-box + named terms, every corrector passed through",
    "correctors": "white-box + correctors (the named terms left out)",
    "white-box": "white-box alone (the named terms and the correctors left out)",
}


def shipped_model(parts: Mapping[str, Any], model: GreyBoxModel | None = None) -> str:
    """The exported model in words (lower case): what ``model`` computes on each stage
    (:meth:`~fmu_greybox.model.store.GreyBoxModel.contents`) when given, else the part shipped
    from the comparison of its parts at training (:func:`~fmu_greybox.workflow.parts.
    shipped_parts`), or the grey-box without terms."""
    if model is not None:
        contents = model.contents()
        if len(set(contents.values())) == 1:
            return f"{next(iter(contents.values()))} on every stage"
        return "; ".join(f"{stage}: {what}" for stage, what in contents.items())
    shipped = shipped_parts(parts)
    chosen = set(shipped.values())
    if len(chosen) > 1:
        return "; ".join(f"{stage}: {PART_WORDS.get(p, p)}" for stage, p in shipped.items())
    return SHIPPED_MODEL.get(chosen.pop(), "grey-box") if chosen else "grey-box"


def verdict_lines(result: DemoResult) -> list[str]:
    """The verdict, in a few sentences (the acceptance first)."""
    concealed = concealed_text(result)
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
        lines.append(f"{TRAINING_PARTS}: {parts_text(result.parts)}.")
    lines += validation_lines(
        result.validation.table,
        f"The exported FMU ({shipped_model(result.parts, result.model)})",
        f"an independent {result.settings.validation_duration:g} s recording",
    )
    engines = ", ".join(f"{a.engine} {a.worst:.1e}" for a in result.bench)
    lines.append(
        f"Exported FMU on the SSP bench, largest difference from the in-process master "
        f"(relative): {engines}."
    )
    return lines


def concealed_text(result: DemoResult) -> str:
    """The concealed effects with their units, e.g.
    ``supply_pressure_droop = 1.5e+10 Pa/(m3/s)``."""
    return ", ".join(
        f"{name} = {value:g} {result.effect_units.get(name, '')}".rstrip()
        for name, value in result.effects.items()
    )


def demo_summary(result: DemoResult) -> str:
    """The summary box of the demo's report (:func:`~fmu_greybox.report.summary.
    summary_section`): the acceptance on the independent recording, the findings with their
    units and the concealed effect, what ships on each stage, the next step."""
    found = [finding_sentence(f) for f in result.payload["findings"] if f["effect"] != "none"]
    found.append(
        Html(
            escape(f"The demo concealed {concealed_text(result)}: the top finding ")
            + ("names it." if result.top_finding_correct() else "<b>does not name it</b>.")
        )
    )
    model = result.model
    stages = list(result.validation.table)
    shipped = (
        shipped_by_stage(model.chain.stage_names, model.chain.passed_through, model.terms)
        if model is not None
        else dict.fromkeys(stages, shipped_model(result.parts))
    )
    recording = f"an independent {result.settings.validation_duration:g} s recording"
    use = (
        f"Load {result.fmu.name} in your bench (docs/bench.md); its _std outputs are the "
        "uncertainty."
    )
    return summary_section(
        result_line(result.validation.acceptance, recording),
        found,
        shipped,
        result.validation.table,
        next_step(result.validation.acceptance, use) + worse_text(result.validation.table),
    )


def worse_stages(table_: Mapping[str, Mapping[str, float]]) -> tuple[list[str], str]:
    """The stages where the correctors do worse (by over 1 %) than what they correct: the named
    terms alone when the table has them, else the white-box; and that in words."""
    named = all("named_rmse" in row for row in table_.values())
    base = "named_rmse" if named else "wb_rmse"
    worse = [stage for stage, row in table_.items() if row["gb_rmse"] > 1.01 * row[base]]
    return worse, "the named terms alone" if named else "the white-box"


def worse_text(table_: Mapping[str, Mapping[str, float]]) -> str:
    """The summary's warning where the correctors do worse (:func:`worse_stages`), or ``""``."""
    worse, than = worse_stages(table_)
    if not worse:
        return ""
    part = "terms" if than == "the named terms alone" else "white-box"
    return (
        f" On {', '.join(worse)} the correctors do worse than {than} on this recording: set "
        f'ship = "{part}" under those stages in the project file and train again (their '
        "correctors are then off, the other stages keep theirs), or add a recording like this "
        "one to the training."
    )


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
        The model validated, as the sentence's subject (``"The exported FMU (...)"``).
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
    if worse_stages(table_)[0]:
        lines.append(worse_text(table_).strip())
    lines.append(
        f"Share of {scored} inside the model's ±1.96σ: "
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


#: Words of the acceptance criteria linked to the glossary: word -> glossary key.
CRITERION_TERMS = {"nRMSE": "nrmse", "σ": "sigma", "coherence": "coherence"}


def criterion_html(criterion: str) -> str:
    """A criterion as HTML, its first word of :data:`CRITERION_TERMS` linked to the glossary."""
    text = escape(criterion)
    for word, key in CRITERION_TERMS.items():
        if word in text:
            return text.replace(word, term(key, word), 1)
    return text


def acceptance_section(acceptance: Acceptance, source: str) -> str:
    """The PASS / FAIL table, headed by the whole verdict.

    Parameters
    ----------
    acceptance : Acceptance
    source : str
        Where the criteria come from, in words.
    """
    colours = {PASS: "pass", "FAIL": "fail"}
    rows, notes = [], []
    for c in acceptance.checks:
        cell = f"<span class='{colours.get(c.verdict, 'undecided')}'>{c.verdict}</span>"
        if c.thin:
            cell += f" <span class='thin'>{term('thin-evidence')}</span>"
        if c.note:
            notes.append(f"{escape(c.stage)}, {escape(c.criterion)}: {escape(c.note)}.")
            cell += f" {note_link(len(notes))}"
        rows.append(
            (
                escape(c.stage),
                criterion_html(c.criterion),
                "" if c.value != c.value else escape(f"{c.value:.3g}"),
                escape(c.limit),
                cell,
            )
        )
    verdict_class = colours.get(acceptance.verdict, "undecided")
    return (
        f"<h2>Acceptance: <span class='{verdict_class}'>{acceptance.verdict}</span></h2>"
        + table(("stage", "criterion", "measured", "limit", "verdict"), rows, raw=True)
        + f"<p>{escape(source)}</p>"
        + notes_list(notes)
    )


#: What the independent-recording table's last column says (the glossary gives the law).
RATIO_NOTE = (
    "Error ratio k: this RMSE over that of the free runs σ was calibrated on; near 1, "
    "±1.96σ holds about 95 %, less the larger k."
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
    validation: Validation,
    units: list[str],
    labels: list[str],
    model_text: str = "",
    kind: str = "grey-box",
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
    kind : str
        What the model is, in words (:attr:`~fmu_greybox.model.store.GreyBoxModel.kind`):
        ``"grey-box"`` only when some corrector is used.
    """
    run = validation.run
    recorded = validation.data.outputs[run.rows]
    named = all("named_rmse" in row for row in validation.table.values())
    return [
        f"<h2>The {escape(kind)} on an independent recording</h2>",
        table(
            (
                "stage",
                "unit",
                "white-box RMSE",
                *([Html(f"+ {term('named-terms')} RMSE")] if named else []),
                f"{kind} RMSE",
                "change",
                Html(f"{escape(kind)} {term('nrmse', 'nRMSE')}"),
                Html(f"median {term('sigma', 'σ')}"),
                "inside ±1σ",
                "inside ±1.96σ",
                *([term("error-ratio")] if calibration_ratios(validation) else []),
            ),
            validation_rows(validation, units),
        ),
        f"<p>{escape(validation.held_out)}; a {term('free-run')}."
        + escape(model_text)
        + f" {term('sigma', 'σ')}: the {escape(kind)}'s calibrated standard deviation, the "
        "exported FMU's _std. In brackets: the share's 95 % interval."
        + (f" {escape(RATIO_NOTE)}" if calibration_ratios(validation) else "")
        + "</p>",
        figure(
            f"Residuals with the {kind}'s ±1.96σ band",
            trace_figure(
                run.time,
                recorded,
                validation.whitebox,
                run.mean,
                run.std,
                labels,
                units,
                outside=run.outside,
                model_label=kind,
            ),
            f"Left: recording minus the {kind} inside its ±1.96σ band (the white-box's "
            "residual, often far larger, would hide it: its RMSE is in each title), grey where "
            "the correctors were outside their domain. Right: the recording, both models and "
            f"the band over the 0.2 s where the {kind}'s residual is largest.",
        ),
        figure(
            "Calibration of the uncertainty",
            calibration_figure(recorded, run.mean, run.std, run.latent_std, labels),
            "Share of the independent recording inside ±z σ against the share a calibrated σ "
            "puts there; dashed: the σ propagated through the chain before calibration, where "
            "it holds a visible share (a stage where it held almost nothing is named beside "
            "the plot instead).",
        ),
        *_calibration_worth_section(validation, units),
        figure(
            "Frequency response and coherence",
            frequency_figure(
                validation.responses,
                [validation.criteria.for_stage(r.stage).band for r in validation.responses],
                model_label=kind,
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
        f"<p>What σ was calibrated on: {runs}.</p>",
        table(
            (
                "stage",
                "unit",
                "RMSE of the calibration free runs",
                term("independent-rows"),
                "±1.96σ holds on recordings like them",
                "one free run held, σ from the others",
            ),
            rows,
        ),
        "<p>A slow error repeats few times in a free run, and a band calibrated on few "
        f"{term('independent-rows')} holds anywhere in a wide range on recordings of the same "
        "kind (95 % range, docs/greybox.md). The last column is what single recordings held: "
        "each free run scored with σ calibrated on the others.</p>",
    ]


def report_html(result: DemoResult) -> str:
    """The whole report page."""
    validation = result.validation
    units, labels = stage_titles(result.config)
    sections = [demo_summary(result)]
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
            f" The exported model: {shipped_model(result.parts, result.model)}."
            if result.parts
            else "",
            result.model.kind if result.model is not None else "grey-box",
        ),
        *diagnosis,
        "<h2>The exported FMU on the SSP bench</h2>",
        f"<p>{escape(result.fmu.name)} in {escape(result.ssp.name)} (recording playback → "
        "grey-box, white-box side by side), compared output by output (corrected value, "
        "_std, _wb) with the in-process master on the same inputs, the engines side by side. "
        "Wall time includes loading "
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
        glossary_section(),
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
    with rendering_aside():
        text = report_html(result)
    write_page(text, out / "report.html")
    return outcome
