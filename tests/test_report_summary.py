"""The report's summary box, its parts wording and its glossary, on hand-made inputs."""

from __future__ import annotations

import dataclasses
import re

from fmu_greybox.evidence.glossary import GLOSSARY, glossary_section, term
from fmu_greybox.model.terms import FlowDroop
from fmu_greybox.report.main import worse_text
from fmu_greybox.report.summary import (
    finding_sentence,
    next_step,
    result_line,
    shipped_by_stage,
    summary_section,
)
from fmu_greybox.workflow.acceptance import FAIL, PASS, UNDECIDED, Acceptance, Check
from fmu_greybox.workflow.parts import DIAGNOSIS_PARTS, TRAINING_PARTS, parts_text

PARTS = {
    "score": {"correctors": 0.0686, "terms": 0.016, "terms+correctors": 0.0162},
    "best": "terms",
    "equally_good": ["terms+correctors"],
    "equal_margin": 0.05,
    "shipped": "terms",
}


def test_each_comparison_of_the_parts_says_whose_it_is_in_plain_words() -> None:
    """The console printed 'Parts on held-out rows: ... best terms+correctors' then 'Parts
    compared at training: ... best terms; shipped terms': the labels now say which check
    decides, and the parts read as words."""
    assert "training decides" in DIAGNOSIS_PARTS and "decides what ships" in TRAINING_PARTS
    text = parts_text(PARTS)
    assert text == (
        "error score (nRMSE, lower is better): named terms alone 0.016, named terms + "
        "correctors 0.0162, correctors alone 0.0686; best: named terms alone, as good within 5 %: "
        "named terms + correctors; shipped: named terms alone"
    )
    per_stage = parts_text({**PARTS, "shipped": {"EHV": "white-box", "RAM": "terms"}})
    assert per_stage.endswith("; shipped: EHV white-box alone, RAM named terms alone")
    unshipped = {k: v for k, v in PARTS.items() if k != "shipped"} | {"best": None}
    assert parts_text(unshipped).endswith(
        "; too few rows to tell, as good within 5 %: named terms + correctors"
    )


def test_what_ships_on_each_stage() -> None:
    """A term acts from its entry stage on; a stage whose corrector is off says so."""
    droop = FlowDroop(input="supply_pressure", source="supply_flow", resistance=1e10, entry=1)
    shipped = shipped_by_stage(["EHV", "RAM", "ITFV"], ["ITFV"], [droop])
    assert shipped == {
        "EHV": "white-box + corrector",
        "RAM": "white-box + supply_pressure_droop (named term) + corrector",
        "ITFV": "white-box + supply_pressure_droop (named term), corrector off",
    }
    # a stage that ships without the terms (chosen at training) takes the plain white-box
    off = dataclasses.replace(droop, stages_off=(2,))
    assert shipped_by_stage(["EHV", "RAM", "ITFV"], ["ITFV"], [off])["ITFV"] == (
        "white-box, corrector off"
    )


def check(stage: str, verdict: str, thin: bool = False) -> Check:
    return Check(stage, "share of rows inside ±1.96σ", 0.969, "0.9 .. 0.99", verdict, "", thin)


def test_the_result_and_the_next_step_follow_the_verdict() -> None:
    thin = Acceptance((check("EHV", PASS), check("RAM", PASS, thin=True)))
    line = result_line(thin, "an independent 8 s recording")
    assert line.startswith("<span class='pass headline'>PASS</span> 2 of 2 checks pass on an ")
    assert "1 on <a class='term' href='#glossary-thin-evidence'>thin evidence</a>: RAM " in line
    use = "Load greybox.fmu in your bench."
    assert next_step(thin, use).startswith(use + " Before relying on the uncertainty band of RAM")
    assert next_step(Acceptance((check("EHV", PASS),)), use) == use
    failed = Acceptance((check("EHV", FAIL), check("RAM", UNDECIDED)))
    assert "not passed: EHV share of rows inside ±1.96σ (FAIL), RAM" in result_line(failed, "x")
    assert next_step(failed, use).startswith("Do not use the stages that fail")
    many = Acceptance((*failed.checks, check("ITFV", UNDECIDED), check("ITFV", FAIL)))
    assert "; not passed: 2 FAIL and 2 UNDECIDED, on EHV, RAM, ITFV." in result_line(many, "x")
    assert next_step(Acceptance((check("RAM", UNDECIDED),)), use).startswith("Undecided")
    assert "No acceptance criteria" in result_line(None, "x")


def test_a_finding_carries_its_unit_and_the_box_holds_it() -> None:
    finding = {
        "stage": "RAM",
        "effect": "supply_pressure_droop",
        "magnitude": {"value": 1.5013e10, "unit": "Pa/(m3/s)", "ci95": [1.4987e10, 1.504e10]},
        "explained_fraction": 0.9998,
    }
    sentence = finding_sentence(finding)
    assert sentence == (
        "supply_pressure_droop in stage RAM: 1.5e+10 Pa/(m3/s) (95 % interval 1.5e+10 to "
        "1.5e+10), explaining 100 % of that stage&#x27;s error."
    )
    box = summary_section(
        result_line(Acceptance((check("RAM", PASS),)), "the recording"),
        [sentence],
        {"RAM": "white-box + corrector"},
        {"RAM": {"improvement": -0.983}},
        "Load it.",
    )
    assert box.startswith("<div class='summary' id='summary'><h2>Summary</h2>")
    assert "Pa/(m3/s)" in box and "<td>-98.3 %</td>" in box and "Load it." in box
    assert "<a href='#glossary'>glossary</a>" in box


def test_every_glossary_link_lands_on_its_definition() -> None:
    section = glossary_section()
    for key, (shown, definition) in GLOSSARY.items():
        assert f"<dt id='glossary-{key}'>{shown}</dt>" in section, key
        assert len(definition.split()) >= 8, key
        assert re.search(rf"href='#glossary-{key}'>", term(key))
    assert term("sigma", "σ") == "<a class='term' href='#glossary-sigma'>σ</a>"


def test_the_next_step_warns_where_the_correctors_do_worse() -> None:
    """The verdict's warning (correctors worse than the named terms alone on a stage) reaches
    the summary's next step; without such a stage the step says nothing of it."""
    table = {
        "EHV": {"wb_rmse": 1.0, "named_rmse": 1.0, "gb_rmse": 1.0},
        "RAM": {"wb_rmse": 5.8e-5, "named_rmse": 2.3e-5, "gb_rmse": 3.6e-5},
    }
    assert worse_text(table) == (
        " On RAM the correctors do worse than the named terms alone on this recording: set "
        'ship = "terms" under those stages in the project file and train again (their '
        "correctors are then off, the other stages keep theirs), or add a recording like this "
        "one to the training."
    )
    assert worse_text({"EHV": table["EHV"]}) == ""
