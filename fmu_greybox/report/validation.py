"""``validate``'s report: one self-contained HTML page per recording, and one over several.

A page per recording: the acceptance table first (the project's ``[acceptance]`` checked on
that recording), the verdict in a few lines, the grey-box on the recording (the demo report's
sections: :func:`~fmu_greybox.report.main.validation_sections`) and a traceability table in
which every hash says what it covers. Over several recordings: the acceptance over all of
them (coverage on the pooled shares), the pooled shares, each recording's verdict with a link
to its own page, and the same traceability.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from fmu_greybox.data.recording import Recording
from fmu_greybox.evidence.glossary import glossary_section, term
from fmu_greybox.evidence.html import Html, escape, page, table, verdict
from fmu_greybox.model.store import GreyBoxModel, file_sha256
from fmu_greybox.model.terms import Term
from fmu_greybox.project.config import ProjectConfig
from fmu_greybox.project.data import whitebox_path
from fmu_greybox.report.main import (
    acceptance_section,
    criteria_source,
    shipped_model,
    stage_titles,
    traceability_section,
    validation_lines,
    validation_sections,
    worse_text,
)
from fmu_greybox.report.provenance import environment_rows, project_row, tool_rows
from fmu_greybox.report.summary import (
    next_step,
    result_line,
    shipped_by_stage,
    summary_section,
)
from fmu_greybox.workflow.metrics import INTERVAL_NOTE, coverage_text, error_ratio
from fmu_greybox.workflow.parts import passed_through_text
from fmu_greybox.workflow.validate import PooledValidation, Validation

#: Name of the page in each folder ``validate`` writes.
REPORT = "report.html"
#: How to put a validated model to use, the summary's next step when it passes.
USE = (
    "Export it (fmu-greybox export MODEL_DIR) and load the FMU in your bench (docs/bench.md); "
    "its _std outputs are the uncertainty."
)


def validation_report_html(
    validation: Validation,
    model: GreyBoxModel,
    config: ProjectConfig,
    model_dir: Path,
    command: str,
) -> str:
    """The page of one recording's validation.

    Parameters
    ----------
    validation : Validation
        :func:`~fmu_greybox.workflow.validate.validate_model`'s result.
    model : GreyBoxModel
        The model validated (what it ships, which stages it passes through).
    config : ProjectConfig
        The project file the model was validated with (its acceptance criteria, units).
    model_dir : Path
        The model folder (its files are hashed).
    command : str
        The command line, for the traceability table.
    """
    units, labels = stage_titles(config)
    recording = _recording_name(validation.data.recording)
    terms = model.terms
    stages = model.chain.stage_names
    found = (
        [
            Html(
                escape(
                    "The model carries the diagnosis' named terms: "
                    + ", ".join(f"{t.effect} ({_term_stages(t, stages)})" for t in terms)
                    + "."
                )
            )
        ]
        if terms
        else []
    )
    sections = [
        summary_section(
            result_line(validation.acceptance, recording),
            found,
            shipped_by_stage(model.chain.stage_names, model.chain.passed_through, model.terms),
            validation.table,
            next_step(validation.acceptance, USE) + worse_text(validation.table),
        )
    ]
    if validation.acceptance is not None:
        sections.append(
            acceptance_section(validation.acceptance, criteria_source(config, recording))
        )
    shipped = shipped_model(model.training.parts or {}, model)
    lines = [validation.acceptance.summary()] if validation.acceptance is not None else []
    lines += validation_lines(validation.table, f"The model ({shipped})", recording, recording)
    passed = model.chain.passed_through
    if passed:
        lines.append(
            "Correctors switched off (σ is the stage's residual alone): "
            f"{passed_through_text(model.training.parts or {}, passed)}."
        )
    sections += [
        verdict(lines),
        *validation_sections(validation, units, labels, f" The model: {shipped}.", model.kind),
        glossary_section(),
        *_traceability(config, model_dir, [validation.data.recording], command),
    ]
    return page(f"fmu-greybox validation: {config.name}, {recording}", sections)


def pooled_report_html(
    result: PooledValidation, config: ProjectConfig, model_dir: Path, command: str
) -> str:
    """The page over several recordings: the acceptance over all, the pooled shares, and each
    recording's verdict with a link to its own page (``<folder>/report.html``).

    Parameters
    ----------
    result : PooledValidation
        :func:`~fmu_greybox.workflow.validate.validate_recordings`'s result (folder name ->
        validation).
    config, model_dir, command
        As for :func:`validation_report_html`.
    """
    names = ", ".join(_recording_name(v.data.recording) for v in result.validations.values())
    sections = [
        summary_section(
            result_line(result.acceptance, names), [], {}, {}, next_step(result.acceptance, USE)
        ),
        acceptance_section(
            result.acceptance,
            criteria_source(
                config,
                f"{names}: the coverage criteria on the shares pooled over them, every other "
                "criterion on each (its worst)",
            ),
        ),
        "<h2>Recordings</h2>",
        table(
            ("recording", "rows scored", "its own verdict", "its page"),
            [
                (
                    escape(_recording_name(v.data.recording)),
                    str(v.scored.size),
                    escape(v.acceptance.verdict if v.acceptance else "no criteria"),
                    f"<a href='{escape(folder)}/{REPORT}'>{escape(folder)}/{REPORT}</a>",
                )
                for folder, v in result.validations.items()
            ],
            raw=True,
        ),
        "<h2>Shares inside the band, pooled</h2>",
        table(
            ("stage", "inside ±1σ", "inside ±1.96σ", term("independent-rows"), term("error-ratio")),
            [
                (
                    stage,
                    coverage_text(row, "coverage68"),
                    coverage_text(row, "coverage95"),
                    f"{row['independent_rows']:.0f}",
                    "" if (k := error_ratio(row)) is None else f"{k:.3g}×",
                )
                for stage, row in result.pooled.items()
            ],
        ),
        f"<p>Each recording's share weighted by its independent rows; {escape(INTERVAL_NOTE)}. "
        "Error ratio k: the grey-box's RMSE over all the scored rows over its RMSE on the free "
        "runs σ was calibrated on.</p>",
        glossary_section(),
        *_traceability(
            config, model_dir, [v.data.recording for v in result.validations.values()], command
        ),
    ]
    return page(
        f"fmu-greybox validation: {config.name}, {len(result.validations)} recordings", sections
    )


def _recording_name(recording: Recording) -> str:
    """A recording by its file name (no local folder), or ``the recording`` when it has none."""
    return Path(recording.source).name if recording.source else "the recording"


def _traceability(
    config: ProjectConfig, model_dir: Path, recordings: list[Recording], command: str
) -> list[str]:
    """The traceability section: the tool, the project file, the white-box FMU, the model
    folder's files and the recordings' data, each hash labelled with what it covers."""
    rows = tool_rows()
    if config.path is not None:
        rows.append(project_row(config.path))
    fmu = whitebox_path(config)
    rows.append(("white-box FMU", f"SHA-256 of the file {fmu.name}", file_sha256(fmu)))
    rows += [
        (f"model: {path.name}", "SHA-256 of the model folder's file", file_sha256(path))
        for path in sorted(model_dir.iterdir())
        if path.is_file()
    ]
    rows += [
        (
            _recording_name(r),
            "SHA-256 of the recording's time, signals and units as read (independent of the "
            "file format)",
            r.sha256(),
        )
        for r in recordings
    ]
    return traceability_section(rows + environment_rows(command))


def _term_stages(named: Term, stages: Sequence[str]) -> str:
    """The stages a named term acts on, in words."""
    acting = [stage for q, stage in enumerate(stages) if named.acts_at(q)]
    return f"on {', '.join(acting)}" if acting else "on no stage"
