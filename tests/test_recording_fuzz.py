"""Property tests: files round-trip exactly; damaged files always give a RecordingError."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmu_greybox.data.recording import Recording, load_recording, save_recording
from fmu_greybox.errors import RecordingError

FUZZ = settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True
)

finite = st.floats(allow_nan=False, allow_infinity=False)
names = st.text(
    alphabet=st.characters(exclude_categories=("Cc", "Cf", "Cs", "Co", "Cn")),
    min_size=1,
    max_size=12,
).filter(lambda s: s == s.strip() and s != "time" and not s.endswith("]"))
units = st.text(alphabet=st.characters(exclude_categories=("Cs",)), max_size=8)


@st.composite
def recordings(draw: st.DrawFn) -> Recording:
    """Random valid recordings: 2-40 samples, 1-4 signals with odd names, units and values."""
    n = draw(st.integers(2, 40))
    t0 = draw(st.floats(-1e3, 1e3))
    dt = draw(st.floats(1e-4, 10.0))
    signal_names = draw(st.lists(names, min_size=1, max_size=4, unique=True))
    signals = {
        name: np.array(draw(st.lists(finite, min_size=n, max_size=n))) for name in signal_names
    }
    signal_units = {name: draw(units) for name in signal_names}
    return Recording(t0 + dt * np.arange(n), signals, signal_units, "fuzz")


def _load_must_fail(path: Path) -> RecordingError:
    try:
        rec = load_recording(path)
    except RecordingError as error:
        return error
    raise AssertionError(f"damaged file loaded silently: {rec!r}")


@FUZZ
@given(rec=recordings(), suffix=st.sampled_from([".csv", ".parquet"]))
def test_saved_recordings_load_back_equal(rec, suffix):
    with tempfile.TemporaryDirectory() as folder:
        back = load_recording(save_recording(rec, Path(folder) / f"r{suffix}"))
    assert back == rec
    assert back.sha256() == rec.sha256()
    assert back.names == rec.names


def _frame(n: int) -> pd.DataFrame:
    time = np.arange(n) * 0.01
    return pd.DataFrame({"time": time, "x": np.sin(time), "y": np.cos(time)})


def _corrupt_csv(frame: pd.DataFrame, row: int, column: int, cell: str) -> str:
    lines = frame.to_csv(index=False, lineterminator="\n").splitlines()
    fields = lines[1 + row].split(",")
    fields[column] = cell
    lines[1 + row] = ",".join(fields)
    return "\n".join(lines) + "\n"


def _not_a_number(text: str) -> bool:
    try:
        return not math.isfinite(float(text))
    except ValueError:
        return True


garbage_cells = st.text(
    alphabet=st.characters(exclude_categories=("Cs",), exclude_characters="\r\n"), max_size=10
).filter(_not_a_number)


@FUZZ
@given(data=st.data(), n=st.integers(2, 30), cell=garbage_cells)
def test_corrupted_csv_cell_always_fails(data, n, cell):
    row = data.draw(st.integers(0, n - 1))
    column = data.draw(st.integers(0, 2))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "r.csv"
        path.write_text(_corrupt_csv(_frame(n), row, column, cell), encoding="utf-8")
        error = _load_must_fail(path)
    assert error.path == str(path)


@FUZZ
@given(data=st.data(), n=st.integers(2, 30), suffix=st.sampled_from([".csv", ".parquet"]))
def test_shuffled_time_always_fails(data, n, suffix):
    i = data.draw(st.integers(0, n - 2))
    j = data.draw(st.integers(i + 1, n - 1))
    frame = _frame(n)
    order = list(range(n))
    order[i], order[j] = order[j], order[i]
    frame = frame.iloc[order]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"r{suffix}"
        if suffix == ".csv":
            frame.to_csv(path, index=False)
        else:
            frame.to_parquet(path, index=False)
        error = _load_must_fail(path)
    assert error.column == "time" and error.row == i + 1
    assert "not strictly increasing" in str(error)


@FUZZ
@given(
    data=st.data(),
    n=st.integers(2, 30),
    bad=st.sampled_from([np.nan, np.inf, -np.inf]),
    suffix=st.sampled_from([".csv", ".parquet"]),
)
def test_injected_non_finite_always_fails(data, n, bad, suffix):
    row = data.draw(st.integers(0, n - 1))
    column = data.draw(st.sampled_from(["time", "x", "y"]))
    frame = _frame(n)
    frame.loc[row, column] = bad
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"r{suffix}"
        if suffix == ".csv":
            frame.to_csv(path, index=False)
        else:
            frame.to_parquet(path, index=False)
        error = _load_must_fail(path)
    assert error.column == column and error.row == row


@FUZZ
@given(content=st.binary(max_size=600), suffix=st.sampled_from([".csv", ".parquet", ".mat"]))
def test_random_bytes_never_raise_anything_but_recording_error(content, suffix):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"r{suffix}"
        path.write_bytes(content)
        try:
            rec = load_recording(path)
        except RecordingError:
            return
    assert isinstance(rec, Recording) and rec.n_samples >= 2


@FUZZ
@given(text=st.text(alphabet=st.sampled_from(list("time,xy0123456789.-e;\n \"'nan")), max_size=200))
def test_random_csv_text_never_raises_anything_but_recording_error(text):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "r.csv"
        path.write_text(text, encoding="utf-8")
        try:
            rec = load_recording(path)
        except RecordingError:
            return
    assert np.all(np.diff(rec.time) > 0) and all(np.isfinite(v).all() for v in rec.signals.values())


@FUZZ
@given(
    time=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=8),
    values=st.lists(st.one_of(finite, st.just(math.nan), st.text(max_size=3)), max_size=8),
)
def test_constructor_never_raises_anything_but_recording_error(time, values):
    try:
        rec = Recording(np.array(time, dtype=float), {"x": np.array(values, dtype=object)})
    except RecordingError:
        return
    assert rec.n_samples >= 2 and np.isfinite(rec["x"]).all()
