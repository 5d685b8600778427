"""Property tests of recordings as a project reads them (issue 7, section 4).

tests/test_recording.py and tests/test_recording_fuzz.py cover the loaders one defect at a time
(and random bytes). Here one property spans every defect of a CSV cell or time stamp, checking
the exact column, row and file line reported, and two more go through the project: a header unit
that differs from the FMU's and a misspelled column always name the column and the way out.
"""

from __future__ import annotations

import tempfile
import tomllib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmu_greybox.data.recording import Recording, load_recording, normalise_unit
from fmu_greybox.errors import RecordingError, UnitMismatchError
from fmu_greybox.fmi.archive import FmuArchive, open_fmu
from fmu_greybox.model.chain import GreyBoxChain
from fmu_greybox.model.stage_data import prepare
from fmu_greybox.project.config import ROLE_UNITS, ProjectConfig, parse_config
from fmu_greybox.project.data import load_project_recording
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.units import UnitSyntaxError, conversion

REFERENCE = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"
FUZZ = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
DT = 0.01

# ------------------------------------------------------------------ one defect in a CSV file

#: Defect -> (column it is reported in: "cell" = the damaged one, or "time"; message fragment).
DEFECTS = {
    "nan": ("cell", "not finite"),
    "inf": ("cell", "not finite"),
    "-inf": ("cell", "not finite"),
    "empty cell": ("cell", "missing or not finite"),
    "text": ("cell", "is not a number"),
    "decimal comma": ("cell", "decimal comma: write 1.5, not 1,5"),
    "duplicate time": ("time", "time is not strictly increasing: it repeats"),
    "decreasing time": ("time", "time is not strictly increasing: it goes back"),
    "uneven step": ("time", "time step is not uniform"),
}


#: Text written into the damaged cell, for the defects of one cell.
CELL_TEXT = {
    "nan": "nan",
    "inf": "inf",
    "-inf": "-inf",
    "empty cell": "",
    "text": "open",
    "decimal comma": "1,5",
}


def csv_text(
    time: np.ndarray, x: np.ndarray, y: np.ndarray, replace: tuple[int, int, str] | None
) -> str:
    """``time;x;y`` rows, with cell ``(row, column)`` replaced by a text if asked."""
    rows = [[repr(float(v)) for v in values] for values in zip(time, x, y, strict=True)]
    if replace is not None:
        row, column, text = replace
        rows[row][column] = text
    return "time;x;y\n" + "".join(";".join(r) + "\n" for r in rows)


@FUZZ
@given(
    data=st.data(),
    n=st.integers(4, 40),  # 3 steps at least, so the median step is a regular one
    defect=st.sampled_from(list(DEFECTS)),
    values=st.lists(st.floats(-1e6, 1e6), min_size=80, max_size=80),
)
def test_every_defect_names_its_column_row_and_file_line(
    data: st.DataObject, n: int, defect: str, values: list[float]
) -> None:
    time = 5.0 + DT * np.arange(n)
    x, y = np.array(values[:n]), np.array(values[40 : 40 + n])
    where, fragment = DEFECTS[defect]
    row = data.draw(st.integers(1 if where == "time" else 0, n - 1))
    column = data.draw(st.integers(0, 2)) if where == "cell" else 0
    if defect == "duplicate time":
        time[row] = time[row - 1]
    elif defect == "decreasing time":
        time[row] = time[row - 1] - DT / 2
    elif defect == "uneven step":
        time[row:] += 0.3 * DT
    replace = (row, column, CELL_TEXT[defect]) if defect in CELL_TEXT else None
    body = csv_text(time, x, y, replace)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "rec.csv"
        path.write_text(body, encoding="utf-8")
        with pytest.raises(RecordingError) as info:
            load_recording(path)
    error = info.value
    name = ("time", "x", "y")[column]
    assert (error.path, error.column, error.row) == (str(path), name, row), str(error)
    message = str(error)
    assert message.startswith(f"{path}, column {name!r}, row {row}: ")
    assert fragment in message and f"(file line {row + 2})" in message


# ------------------------------------------------------------------ through the project


@pytest.fixture(scope="module")
def archive(whitebox_fmu: Path) -> Iterator[FmuArchive]:
    with open_fmu(whitebox_fmu) as opened:
        yield opened


@pytest.fixture(scope="module")
def project(whitebox_fmu: Path) -> ProjectConfig:
    raw = tomllib.loads(REFERENCE.read_text(encoding="utf-8"))
    raw["whitebox"]["fmu"] = str(whitebox_fmu)
    return parse_config(raw, REFERENCE)


@pytest.fixture(scope="module")
def recording(whitebox_fmu: Path, truth_fmu: Path) -> Recording:
    """50 ms of the flight test, every column in the FMU's units."""
    request = SynthRequest(effects={}, seed=2, noise=0.0, profile=FlightTestProfile(duration=0.05))
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        return synthesise(truth, whitebox, request)


def with_header_unit(recording: Recording, column: str, unit: str, folder: Path) -> Path:
    """The recording as a CSV with ``name [unit]`` headers, ``column`` in ``unit`` (its values
    converted when the units convert, else only relabelled)."""
    frame = recording.to_frame()
    try:
        change = conversion(recording.units[column], unit)
        frame[column] = frame[column] * change.scale + change.offset
    except UnitSyntaxError:
        pass
    units = {**recording.units, column: unit}
    frame.columns = ["time [s]", *(f"{n} [{units[n]}]" for n in recording.names)]
    path = folder / "bench.csv"
    frame.to_csv(path, index=False)
    return path


def other_units() -> list[tuple[str, str]]:
    """(signal, unit) pairs: a unit of the signal's role that is not the FMU's unit."""
    raw = tomllib.loads(REFERENCE.read_text(encoding="utf-8"))
    pairs = []
    for name, entry in raw["signals"].items():
        for unit in ROLE_UNITS[entry["role"]]:
            if normalise_unit(unit) not in ("", normalise_unit(entry["unit"])):
                pairs.append((name, unit))
    return pairs


@FUZZ
@given(pair=st.sampled_from(other_units()))
def test_header_unit_differing_from_the_project_is_converted_or_named(
    project: ProjectConfig, archive: FmuArchive, recording: Recording, pair: tuple[str, str]
) -> None:
    """A unit of the same quantity (mm for m, bar for Pa, A for mA) is converted on load to
    the project's unit, the FMU's; another one (rad for m) is refused naming the column."""
    column, unit = pair
    declared = project.signals[column].unit
    with tempfile.TemporaryDirectory() as folder:
        path = with_header_unit(recording, column, unit, Path(folder))
        assert load_recording(path).units[column] == unit
        try:
            conversion(unit, declared)
        except UnitSyntaxError:
            with pytest.raises(UnitMismatchError) as info:
                load_project_recording(project, path)
            message = str(info.value)
            assert message.startswith(f"{path}: column {column!r} is recorded in {unit!r}")
            assert f"cannot be converted to {declared!r}" in message
            return
        loaded = load_project_recording(project, path)
    assert loaded.units[column] == declared
    scale = float(np.max(np.abs(recording[column]))) or 1.0
    np.testing.assert_allclose(loaded[column], recording[column], rtol=1e-12, atol=1e-12 * scale)
    prepare(project, GreyBoxChain(project), archive, loaded)  # units agree with the FMU's


def misspellings(name: str) -> st.SearchStrategy[str]:
    """One typo in ``name``: a character dropped, doubled or upper-cased."""
    return (
        st.integers(0, len(name) - 1)
        .flatmap(
            lambda i: st.sampled_from(
                [
                    name[:i] + name[i + 1 :],
                    name[:i] + name[i] * 2 + name[i + 1 :],
                    name[:i] + name[i].upper() + name[i + 1 :],
                ]
            )
        )
        .filter(lambda typo: typo != name)
    )


@FUZZ
@given(data=st.data())
def test_misspelled_column_is_named_with_the_close_match(
    project: ProjectConfig, archive: FmuArchive, recording: Recording, data: st.DataObject
) -> None:
    chain = GreyBoxChain(project)
    needed = [project.signals[n].column for n in chain.exo_names + chain.target_signals]
    column = data.draw(st.sampled_from(needed))
    typo = data.draw(misspellings(column).filter(lambda t: t not in recording.names))
    signals = {typo if n == column else n: v for n, v in recording.signals.items()}
    units = {typo if n == column else n: u for n, u in recording.units.items()}
    edited = Recording(recording.time, signals, units, source="bench.csv")
    with pytest.raises(RecordingError) as info:
        prepare(project, chain, archive, edited)
    error = info.value
    assert (error.path, error.column) == ("bench.csv", column)
    assert f"column {column!r} not found (needed by project hydraulic_actuator)" in str(error)
    assert f"did you mean {typo!r}" in str(error)
