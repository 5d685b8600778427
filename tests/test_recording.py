"""Recording: construction checks, operations, loaders, writers, units, and every error message."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.io import savemat

from fmu_greybox.data.recording import (
    UNITS_KEY,
    Recording,
    load_recording,
    normalise_unit,
    save_recording,
    units_compatible,
)
from fmu_greybox.errors import FmuGreyboxError, RecordingError

DT = 0.001


def make(n: int = 10, **extra: np.ndarray) -> Recording:
    """A small valid recording: valve_current [A] and ram_position [m] at 1 kHz."""
    time = np.arange(n) * DT
    signals = {"valve_current": np.sin(time * 50), "ram_position": 0.01 * time, **extra}
    return Recording(time, signals, {"valve_current": "A", "ram_position": "m"}, "bench.csv")


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def load_error(path: Path, **options) -> RecordingError:
    with pytest.raises(RecordingError) as caught:
        load_recording(path, **options)
    return caught.value


def build_error(time, signals, units=None) -> RecordingError:
    with pytest.raises(RecordingError) as caught:
        Recording(np.asarray(time), signals, units or {}, "mem")
    return caught.value


# -- construction -----------------------------------------------------------------------------


def test_recording_basics():
    rec = make()
    assert rec.n_samples == 10
    assert rec.dt == pytest.approx(DT)
    assert rec.duration == pytest.approx(9 * DT)
    assert rec.names == ("valve_current", "ram_position")
    assert rec.units == {"valve_current": "A", "ram_position": "m"}
    assert rec["time"] is rec.time
    assert "ram_position" in rec and "time" in rec and "nope" not in rec
    assert rec.time.dtype == np.float64 and not rec.time.flags.writeable
    assert not rec["ram_position"].flags.writeable
    assert "valve_current [A]" in repr(rec)


def test_recording_copies_inputs_and_fills_units():
    values = np.arange(4.0)
    rec = Recording(np.arange(4), {"x": values, "flag": np.array([True, False, True, True])})
    values[0] = 99.0
    assert rec["x"][0] == 0.0
    assert rec.units == {"x": "", "flag": ""}
    assert rec["flag"].tolist() == [1.0, 0.0, 1.0, 1.0]
    assert isinstance(RecordingError("x"), FmuGreyboxError)


def test_length_mismatch_names_column_and_both_lengths():
    error = build_error(np.arange(5) * DT, {"x": np.zeros(5), "y": np.zeros(4)})
    assert error.column == "y"
    assert "has 4 values but the time axis has 5" in str(error)
    assert str(error).startswith("mem, column 'y'")


def test_too_few_samples():
    error = build_error([0.0], {"x": [1.0]})
    assert "holds 1 sample; a recording needs at least 2" in str(error)


def test_time_not_increasing_names_row_and_values():
    error = build_error([0.0, 0.001, 0.0005, 0.0015], {"x": np.zeros(4)})
    assert (error.column, error.row) == ("time", 2)
    assert "goes back from 0.001 s at row 1 to 0.0005 s at row 2" in str(error)
    assert "Sort the rows by time" in str(error)
    error = build_error([0.0, 0.001, 0.001, 0.002, 0.002], {"x": np.zeros(5)})
    assert "repeats" in str(error) and "2 steps like this in all" in str(error)


def test_non_uniform_time_names_row_deviation_and_resample_hint():
    time = np.arange(6) * DT
    time[4:] += 0.0005
    error = build_error(time, {"x": np.zeros(6)})
    assert (error.column, error.row) == ("time", 4)
    text = str(error)
    assert "step into row 4 is 0.0015 s, 50 % away from the typical step 0.001 s" in text
    assert "resample=DT (CLI: --resample DT;" in text and "resample=0.001" in text


def test_tiny_jitter_is_accepted():
    time = np.arange(100) * DT + np.linspace(0, 1e-12, 100)
    assert Recording(time, {"x": np.zeros(100)}).n_samples == 100


def test_non_finite_names_column_first_row_and_count():
    values = np.zeros(8)
    values[[3, 5]] = np.nan
    values[6] = np.inf
    error = build_error(np.arange(8) * DT, {"x": np.zeros(8), "p": values})
    assert (error.column, error.row) == ("p", 3)
    assert "3 of 8 values are missing or not finite" in str(error)
    assert "the first is nan at row 3" in str(error)
    error = build_error([0.0, np.nan, 2.0], {"x": np.zeros(3)})
    assert error.column == "time"


def test_non_numeric_names_column_row_and_value():
    error = build_error(np.arange(3), {"x": ["1.0", "2.5", "open"]})
    assert (error.column, error.row) == ("x", 2)
    assert "value 'open' is not a number" in str(error)
    error = build_error(np.arange(3), {"z": np.array([1j, 2, 3])})
    assert "complex" in str(error)
    error = build_error(np.arange(3), {"m": np.zeros((3, 2))})
    assert "shape (3, 2)" in str(error)


@pytest.mark.parametrize(
    ("signals", "fragment"),
    [
        ({}, "at least one signal"),
        ({"time": np.zeros(3)}, "reserved for the time axis"),
        ({" x": np.zeros(3)}, "leading or trailing spaces"),
        ({"a\tb": np.zeros(3)}, "control or invisible characters"),
        ({"": np.zeros(3)}, "empty name"),
        ({3: np.zeros(3)}, "must be strings"),
    ],
)
def test_bad_signal_names(signals, fragment):
    assert fragment in str(build_error(np.arange(3), signals))


def test_unit_for_unknown_signal_is_an_error():
    error = build_error(np.arange(3), {"pressure": np.zeros(3)}, {"presure": "Pa"})
    assert "gives a unit for 'presure', which is not a signal; did you mean 'pressure'?" in str(
        error
    )
    error = build_error(np.arange(3), {"pressure": np.zeros(3)}, {"pressure": 5})
    assert "pair of strings" in str(error)


# -- lookups ----------------------------------------------------------------------------------


def test_getitem_misspelled_suggests_closest():
    with pytest.raises(RecordingError) as caught:
        make()["valve_curent"]
    text = str(caught.value)
    assert caught.value.column == "valve_curent"
    assert "column 'valve_curent' not found; did you mean 'valve_current'? (available:" in text
    assert text.startswith("bench.csv, column 'valve_curent'")


def test_require_lists_every_missing_name_with_context():
    rec = make()
    rec.require(["valve_current", "time"])
    rec.require("ram_position")
    with pytest.raises(RecordingError) as caught:
        rec.require(["valve_curent", "RAM_POSITION", "load_force"], context="stage 'RAM'")
    text = str(caught.value)
    assert "3 columns not found (needed by stage 'RAM')" in text
    assert "'valve_curent' (did you mean 'valve_current'?)" in text
    assert "'RAM_POSITION' (did you mean 'ram_position'?)" in text
    assert "'load_force' (available: 'valve_current', 'ram_position')" in text


# -- operations -------------------------------------------------------------------------------


def test_slice_time_includes_both_ends():
    part = make(20).slice_time(0.003, 0.007)
    np.testing.assert_allclose(part.time, np.arange(3, 8) * DT)
    assert part.units == make().units and part.source == "bench.csv"
    with pytest.raises(RecordingError, match="keeps 1 sample"):
        make().slice_time(0.004, 0.0041)
    with pytest.raises(RecordingError, match="t0 <= t1"):
        make().slice_time(0.005, 0.001)


def test_split_by_time():
    train, validation = make(10).split(0.7)
    assert (train.n_samples, validation.n_samples) == (7, 3)
    assert train.time[-1] < validation.time[0]
    np.testing.assert_array_equal(np.concatenate([train.time, validation.time]), make(10).time)
    with pytest.raises(RecordingError, match="between 0 and 1"):
        make().split(1.0)
    with pytest.raises(RecordingError, match="validation part, keeps 1 sample"):
        make(10).split(0.9)


def test_select_and_with_signals():
    rec = make()
    only = rec.select(["ram_position", "time"])
    assert only.names == ("ram_position",) and only.units == {"ram_position": "m"}
    with pytest.raises(RecordingError, match="needed by select"):
        rec.select(["ram_pos"])
    more = rec.with_signals({"ram_position": rec["ram_position"] * 1e3, "flow": np.ones(10)})
    assert more.names == ("valve_current", "ram_position", "flow")
    assert more.units["ram_position"] == "m" and more.units["flow"] == ""
    renamed = rec.with_signals({"ram_position": rec["ram_position"] * 1e3}, {"ram_position": "mm"})
    assert renamed.units["ram_position"] == "mm"
    with pytest.raises(RecordingError, match="has 3 values"):
        rec.with_signals({"flow": np.ones(3)})


def test_frame_round_trip():
    rec = make()
    frame = rec.to_frame()
    assert list(frame.columns) == ["time", "valve_current", "ram_position"]
    assert frame.attrs["units"]["time"] == "s"
    assert Recording.from_frame(frame) == rec
    frame = frame.rename(columns={"time": "t"})
    assert Recording.from_frame(frame, time_column="t", units={"t": "s"}) == rec


def test_sha256_is_stable_and_tracks_data_and_units():
    rec = make()
    reordered = Recording(rec.time, dict(reversed(rec.signals.items())), rec.units, "other")
    assert rec.sha256() == reordered.sha256() and rec == reordered
    assert rec.sha256() != rec.with_signals({}, {"ram_position": "mm"}).sha256()
    assert rec.sha256() != rec.with_signals({"ram_position": rec["ram_position"] + 1e-15}).sha256()
    assert len(rec.sha256()) == 64
    assert rec != "not a recording"


# -- CSV --------------------------------------------------------------------------------------


def test_csv_round_trip_is_exact(tmp_path):
    time = np.arange(50) * 0.1
    values = np.random.default_rng(0).standard_normal(50) * 1e-7
    values[:3] = [0.1 + 0.2, 5e-324, 1.7976931348623157e308]
    rec = Recording(time, {"p": values, "x": time**2}, {"p": "Pa"}, "mem", {"note": "kept"})
    path = save_recording(rec, tmp_path / "out.csv")
    back = load_recording(path)
    assert back == rec and back.sha256() == rec.sha256()
    assert back.source == str(path)
    assert json.loads((tmp_path / "out.csv.units.json").read_text()) == {
        "time": "s",
        "p": "Pa",
        "x": "",
    }
    assert sorted(os.listdir(tmp_path)) == ["out.csv", "out.csv.units.json"]


def test_csv_round_trip_keeps_every_bit_of_every_magnitude_and_negative_zeros(tmp_path):
    """Every magnitude from 1e-300 to 1e300, whole numbers, and negative zeros (which Arrow's
    writer puts as ``-0``, read back as 0: the writer puts ``-0.0``) come back bit for bit."""
    rng = np.random.default_rng(7)
    time = np.arange(2000) * 1e-3
    signals = {f"m{e}": rng.standard_normal(2000) * 10.0**e for e in range(-300, 301, 50)}
    whole = np.round(rng.standard_normal(2000) * 100)
    whole[::7] = -0.0
    signals["whole"] = whole
    mixed = rng.standard_normal(2000)
    mixed[::5] = -0.0
    signals["mixed"] = mixed
    rec = Recording(time, signals, {})
    back = load_recording(save_recording(rec, tmp_path / "out.csv"))
    assert back.sha256() == rec.sha256()
    assert np.signbit(back["whole"][::7]).all() and np.signbit(back["mixed"][::5]).all()


def test_csv_units_from_header_sidecar_and_argument(tmp_path):
    path = write(tmp_path, "r.csv", "time [s],p [bar],q [l/min],x\n0,1,2,3\n0.5,1,2,3\n")
    assert load_recording(path).units == {"p": "bar", "q": "l/min", "x": ""}
    (tmp_path / "r.csv.units.json").write_text('{"p": "Pa", "x": "m"}')
    assert load_recording(path).units == {"p": "Pa", "q": "l/min", "x": "m"}
    assert load_recording(path, units={"p": "MPa"}).units["p"] == "MPa"


def test_csv_time_unit_converts_to_seconds(tmp_path):
    path = write(tmp_path, "r.csv", "time [ms],x\n0,1\n1,2\n2,3\n")
    np.testing.assert_allclose(load_recording(path).time, [0.0, 0.001, 0.002])
    error = load_error(path, units={"time": "fortnights"})
    assert "time unit 'fortnights' is not a unit of time" in str(error)
    assert "use e.g. s, ms" in str(error)
    error = load_error(path, units={"time": "m"})
    assert "time unit 'm' is not a unit of time ('m' and 's' measure different" in str(error)


def test_csv_tolerates_bom_semicolons_spaces_trailing_comma_and_blank_end(tmp_path):
    path = tmp_path / "r.csv"
    path.write_bytes(b"\xef\xbb\xbftime; x\r\n0; 1.5 \r\n0.1;2\r\n")
    np.testing.assert_allclose(load_recording(path)["x"], [1.5, 2.0])
    path = write(tmp_path, "s.csv", "time,x,\n0,1,\n0.1,2,\n\n\n")
    assert load_recording(path).names == ("x",)


def test_csv_time_column_option(tmp_path):
    path = write(tmp_path, "r.csv", "t,x\n0,1\n1,2\n")
    assert load_recording(path, time_column="t").n_samples == 2


def test_csv_missing_time_column_names_columns_and_option(tmp_path):
    error = load_error(write(tmp_path, "r.csv", "Time,x\n0,1\n1,2\n"))
    text = str(error)
    assert text.startswith(f"{tmp_path / 'r.csv'}, column 'time':")
    assert "no time column 'time'; did you mean 'Time'? (columns found: 'Time', 'x')" in text
    assert "time_column='NAME'" in text


def test_csv_non_numeric_cell_names_column_row_line_and_text(tmp_path):
    error = load_error(write(tmp_path, "r.csv", "time,x,y\n0,1,2\n1,2,3\n2,3,open\n3,4,5\n"))
    assert (error.path, error.column, error.row) == (str(tmp_path / "r.csv"), "y", 2)
    assert "value 'open' is not a number (file line 4)" in str(error)
    error = load_error(write(tmp_path, "s.csv", "time;x\n0;1,5\n1;2\n"))
    assert "decimal comma" in str(error)
    error = load_error(write(tmp_path, "t.csv", "time,x\n0,1\nabc,2\n"))
    assert (error.column, error.row) == ("time", 1)


def test_csv_empty_cells_and_nan_are_reported(tmp_path):
    error = load_error(write(tmp_path, "r.csv", "time,x\n0,1\n1,\n2,NaN\n3,4\n"))
    assert (error.column, error.row) == ("x", 1)
    assert "2 of 4 values are missing or not finite" in str(error)
    assert "(file line 3)" in str(error)
    error = load_error(write(tmp_path, "s.csv", "time,x\n0,1\n\n2,3\n"))
    assert (error.column, error.row) == ("time", 1)


def test_csv_row_checks_give_file_lines(tmp_path):
    error = load_error(write(tmp_path, "r.csv", "time,x\n0,1\n2,2\n1,3\n"))
    assert error.row == 2 and "(file line 4)" in str(error)
    error = load_error(write(tmp_path, "s.csv", "time,x\n0,1\n1,2\n3,3\n4,4\n"))
    assert error.row == 2 and "(file line 4)" in str(error) and "resample=" in str(error)


def test_csv_structure_errors(tmp_path):
    cases = {
        "": "the file is empty",
        "\ntime,x\n": "the first line is empty",
        "0,1\n1,2\n": "has no header line: the first line '0,1' holds numbers",
        "time,x\n": "holds 0 samples; a recording needs at least 2",
        "time,x\n0,1\n": "holds 1 sample",
        "time\n0\n1\n": "holds no signal columns besides the time column 'time'",
        "time,x,x [m]\n0,1,2\n1,2,3\n": "appears twice in the header (columns 2 and 3)",
        "time,,x\n0,1,2\n1,2,3\n": "column 2 of the header has no name",
        "time,x\n0,1\n1,2,3\n2,3\n": "line 3 has 3 fields but the header has 2",
        "time,x\n0,1,9\n1,2,9\n": "line 2 has 3 fields but the header has 2",
        "time,x,\n0,1,\n1,2,7\n": "column 3 holds values but has no name",
        'time,x\n0,"1\n': "cannot be parsed as CSV",
    }
    for i, (text, fragment) in enumerate(cases.items()):
        error = load_error(write(tmp_path, f"c{i}.csv", text))
        assert fragment in str(error), (text, str(error))
        assert error.path == str(tmp_path / f"c{i}.csv")


def test_csv_not_utf8(tmp_path):
    path = tmp_path / "r.csv"
    path.write_bytes("time,x [µm]\n0,1\n1,2\n".encode("latin-1"))
    assert "is not UTF-8 text" in str(load_error(path))


def test_sidecar_errors_name_the_sidecar(tmp_path):
    path = write(tmp_path, "r.csv", "time,x\n0,1\n1,2\n")
    sidecar = tmp_path / "r.csv.units.json"
    sidecar.write_text('{"x": "m",}')
    error = load_error(path)
    assert error.path == str(sidecar) and "is not valid JSON" in str(error)
    assert "line 1 column" in str(error)
    sidecar.write_text('["m"]')
    assert "must map signal names to unit strings" in str(load_error(path))
    sidecar.write_text('{"xx": "m"}')
    error = load_error(path)
    assert error.path == str(sidecar) and "the units file gives a unit for 'xx'" in str(error)


def test_units_argument_unknown_name(tmp_path):
    path = write(tmp_path, "r.csv", "time,valve_current\n0,1\n1,2\n")
    error = load_error(path, units={"valve_curent": "A"})
    assert "did you mean 'valve_current'?" in str(error)


# -- file-level errors ------------------------------------------------------------------------


def test_missing_file_names_path_and_reason(tmp_path):
    error = load_error(tmp_path / "nope.csv")
    assert error.path == str(tmp_path / "nope.csv")
    assert "cannot read the file: No such file or directory" in str(error)


def test_directory_is_not_a_recording(tmp_path):
    (tmp_path / "dir.csv").mkdir()
    assert "cannot read the file: Is a directory" in str(load_error(tmp_path / "dir.csv"))


def test_unsupported_extension_lists_supported(tmp_path):
    error = load_error(write(tmp_path, "r.xlsx", "x"))
    supported = ".csv, .mat, .mdf, .mf4, .parquet"
    assert f"unsupported recording format '.xlsx'; supported: {supported}" in str(error)
    assert "'(no extension)'" in str(load_error(write(tmp_path, "r", "x")))


# -- resampling -------------------------------------------------------------------------------


def test_resample_matches_np_interp_on_non_uniform_grid(tmp_path):
    rng = np.random.default_rng(1)
    time = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 200))
    values = np.sin(40 * time)
    pd.DataFrame({"time": time, "x": values}).to_csv(tmp_path / "r.csv", index=False)
    with pytest.raises(RecordingError, match="not uniform"):
        load_recording(tmp_path / "r.csv")
    rec = load_recording(tmp_path / "r.csv", resample=0.002)
    grid = time[0] + 0.002 * np.arange(rec.n_samples)
    assert grid[-1] <= time[-1] < grid[-1] + 0.002
    np.testing.assert_allclose(rec.time, grid)
    np.testing.assert_allclose(rec["x"], np.interp(grid, time, values))
    assert rec.metadata["resampled_dt"] == "0.002"


def test_resample_errors(tmp_path):
    path = write(tmp_path, "r.csv", "time,x\n0,1\n0.3,2\n1,3\n")
    assert "positive number of seconds" in str(load_error(path, resample=-1))
    assert "positive number of seconds" in str(load_error(path, resample="fast"))
    assert "longer than the recorded span" in str(load_error(path, resample=2.0))
    assert "is in seconds" in str(load_error(path, resample=1e-6))
    path = write(tmp_path, "s.csv", "time,x\n0,1\n1,2\n0.5,3\n")
    assert "not strictly increasing" in str(load_error(path, resample=0.1))


# -- Parquet ----------------------------------------------------------------------------------


def test_parquet_round_trip_keeps_units_and_metadata(tmp_path):
    rec = Recording(make().time, make().signals, make().units, "mem", {"rig": "B2"})
    path = save_recording(rec, tmp_path / "r.parquet")
    back = load_recording(path)
    assert back == rec and back.metadata == {"rig": "B2"}
    schema = pq.read_schema(path)
    assert json.loads(schema.metadata[UNITS_KEY])["ram_position"] == "m"
    assert schema.field("valve_current").metadata[b"unit"] == b"A"
    assert sorted(os.listdir(tmp_path)) == ["r.parquet"]


def test_parquet_from_pandas_with_timestamps_index_and_header_units(tmp_path):
    frame = pd.DataFrame(
        {
            "time": pd.date_range("2024-05-01 10:00", periods=4, freq="10ms"),
            "p [bar]": [1.0, 2.0, 3.0, 4.0],
            "n": pd.array([1, 2, 3, 4], dtype="Int64"),
        },
        index=[7, 8, 9, 10],
    )
    frame.to_parquet(tmp_path / "r.parquet")
    rec = load_recording(tmp_path / "r.parquet")
    np.testing.assert_allclose(rec.time, [0.0, 0.01, 0.02, 0.03])
    assert rec.names == ("p", "n") and rec.units["p"] == "bar"
    assert rec.metadata["time_origin"].startswith("2024-05-01T10:00")


def test_parquet_field_unit_metadata(tmp_path):
    schema = pa.schema(
        [pa.field("time", pa.float64()), pa.field("f", pa.int32(), metadata={b"unit": b"N"})]
    )
    table = pa.table({"time": [0.0, 0.5], "f": pa.array([1, 2], pa.int32())}, schema=schema)
    pq.write_table(table, tmp_path / "r.parquet")
    assert load_recording(tmp_path / "r.parquet").units == {"f": "N"}


def test_parquet_errors(tmp_path):
    (tmp_path / "bad.parquet").write_bytes(b"PAR1 not really")
    assert "is not a readable Parquet file" in str(load_error(tmp_path / "bad.parquet"))
    table = pa.table({"time": [0.0, 1.0], "v": [[1.0, 2.0], [3.0]]})
    pq.write_table(table, tmp_path / "nested.parquet")
    error = load_error(tmp_path / "nested.parquet")
    assert error.column == "v" and "must hold plain numbers" in str(error)
    pq.write_table(
        pa.table({"time": [0.0, 1.0, 2.0], "s": ["1", "x", "3"]}), tmp_path / "s.parquet"
    )
    error = load_error(tmp_path / "s.parquet")
    assert (error.column, error.row) == ("s", 1) and "value 'x' is not a number" in str(error)
    table = pa.table({"time": [0.0, 1.0], "v": [1.0, None]})
    pq.write_table(table, tmp_path / "null.parquet")
    error = load_error(tmp_path / "null.parquet")
    assert (error.column, error.row) == ("v", 1) and "missing or not finite" in str(error)
    schema = pa.schema([pa.field("time", pa.float64())], metadata={UNITS_KEY: b"{oops"})
    pq.write_table(pa.table({"time": [0.0, 1.0]}, schema=schema), tmp_path / "m.parquet")
    assert "schema metadata 'fmu_greybox.units' is not valid JSON" in str(
        load_error(tmp_path / "m.parquet")
    )


# -- MATLAB -----------------------------------------------------------------------------------


@pytest.mark.parametrize("options", [{"format": "4"}, {"format": "5"}, {"do_compression": True}])
def test_mat_versions(tmp_path, options):
    time = np.arange(6) * 0.01
    content = {"time": time[:, None], "x": np.sin(time)[None, :], "n": np.arange(6, dtype=np.int16)}
    savemat(tmp_path / "r.mat", content, **options)
    rec = load_recording(tmp_path / "r.mat", units={"x": "rad"})
    np.testing.assert_array_equal(rec["x"], np.sin(time))
    assert rec.names == ("x", "n") and rec.units["x"] == "rad"


def test_mat_struct_and_ignored_variables(tmp_path):
    time = np.arange(4) * 0.5
    savemat(tmp_path / "s.mat", {"run": {"time": time, "p": time + 1}})
    rec = load_recording(tmp_path / "s.mat")
    assert rec.names == ("p",) and rec.metadata["struct"] == "run"
    savemat(
        tmp_path / "v.mat", {"time": time, "p": time, "gain": 2.0, "label": "x", "M": np.eye(3)}
    )
    rec = load_recording(tmp_path / "v.mat")
    assert rec.names == ("p",) and rec.metadata["ignored_variables"] == "gain, label, M"


def test_mat_errors(tmp_path):
    time = np.arange(6) * 0.01
    savemat(tmp_path / "len.mat", {"time": time, "x": time[:5]})
    error = load_error(tmp_path / "len.mat")
    assert error.column == "x" and "has 5 values but the time axis has 6" in str(error)
    savemat(tmp_path / "tout.mat", {"tout": time, "x": time})
    error = load_error(tmp_path / "tout.mat")
    assert "no time variable 'time'; did you mean 'tout'? (variables found: 'tout', 'x')" in str(
        error
    )
    assert load_recording(tmp_path / "tout.mat", time_column="tout").n_samples == 6
    x = time.copy()
    x[2] = np.nan
    savemat(tmp_path / "nan.mat", {"time": time, "x": x})
    assert "(MATLAB index 3)" in str(load_error(tmp_path / "nan.mat"))
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all" * 10)
    assert "is not a readable MATLAB file" in str(load_error(tmp_path / "junk.mat"))


def test_damaged_mat_v73_is_named(tmp_path):
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(128, b" ")
    (tmp_path / "r.mat").write_bytes(header.ljust(512, b"\0") + b"\x89HDF\r\n\x1a\n" + bytes(64))
    text = str(load_error(tmp_path / "r.mat"))
    assert "r.mat: is not a readable MATLAB v7.3 (HDF5) file" in text


# -- saving -----------------------------------------------------------------------------------


def test_save_errors(tmp_path):
    with pytest.raises(
        RecordingError, match=r"cannot save as '\.mat'; supported: \.csv, \.parquet"
    ):
        save_recording(make(), tmp_path / "r.mat")
    with pytest.raises(RecordingError, match="cannot write the file"):
        save_recording(make(), tmp_path / "missing" / "r.csv")
    odd = Recording(np.arange(3), {"p [bar]": np.zeros(3)})
    with pytest.raises(RecordingError, match="would be read back as a unit"):
        save_recording(odd, tmp_path / "r.parquet")
    assert os.listdir(tmp_path) == []


def test_save_replaces_previous_file(tmp_path):
    save_recording(make(5), tmp_path / "r.csv")
    save_recording(make(8), tmp_path / "r.csv")
    assert load_recording(tmp_path / "r.csv").n_samples == 8


# -- units ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spellings", "canonical"),
    [
        (["m^3/s", "m3/s", "m³·s⁻¹", "m3.s-1", " m^3 / s "], "m3/s"),
        (["N·s/m", "N.s/m", "N*s/m", "N s/m", "s.N/m"], "N.s/m"),
        (["", "1", "-", "none", "dimensionless"], ""),
        (["kg/(m.s)", "kg/m/s", "kg.m-1.s-1"], "kg/m/s"),
        (["1/s", "s-1", "s^-1", "/s"], "1/s"),
        (["µm", "μm", "um"], "um"),
        (["°C", "degC"], "degC"),
        (["sec", "s"], "s"),
        (["m/s^2", "m/s²", "m.s-2"], "m/s2"),
        (["Pa", " Pa "], "Pa"),
    ],
)
def test_normalise_unit(spellings, canonical):
    assert [normalise_unit(u) for u in spellings] == [canonical] * len(spellings)


def test_units_compatible():
    assert units_compatible("m^3/s", "m3/s")
    assert units_compatible("N·s/m", "N.s/m")
    assert units_compatible("-", "")
    assert not units_compatible("mm", "m")
    assert not units_compatible("Pa", "pa")
    assert normalise_unit("m^") == "m^" and normalise_unit("(m") == "(m"


def _element(kind: int, payload: bytes) -> bytes:
    """A v5 MAT data element: tag, payload, padding to 8 bytes."""
    return struct.pack("<II", kind, len(payload)) + payload + bytes(-len(payload) % 8)


def _array(array_class: int, name: bytes, parts: list[bytes], dims=(1, 2)) -> bytes:
    """A miMATRIX element: flags, dimensions, name, then the given parts."""
    flags = _element(6, struct.pack("<II", array_class, 0))
    shape = _element(5, struct.pack(f"<{len(dims)}i", *dims))
    return _element(14, flags + shape + _element(1, name) + b"".join(parts))


def _mat5(*arrays: bytes) -> bytes:
    header = b"MATLAB 5.0 MAT-file, written by hand".ljust(116) + bytes(8)
    return header + struct.pack("<H", 0x0100) + b"IM" + b"".join(arrays)


def test_mat_written_by_hand_loads(tmp_path):
    time = _array(6, b"time", [_element(9, struct.pack("<2d", 0.0, 0.5))])
    x = _array(6, b"x", [_element(9, struct.pack("<2d", 1.0, 2.0))])
    (tmp_path / "r.mat").write_bytes(_mat5(time, x))
    assert load_recording(tmp_path / "r.mat")["x"].tolist() == [1.0, 2.0]


@pytest.mark.parametrize(
    "damage",
    [
        "unknown data type",  # scipy indexes a type table with 10 and crashes
        "missing data part",  # scipy reads the next array's tag as the data and crashes
        "short dimensions",  # a 2-byte small dimensions element crashes scipy's char reader
    ],
)
def test_damaged_mat_that_crashes_scipy_gives_recording_error(tmp_path, damage):
    time = _array(6, b"time", [_element(9, struct.pack("<2d", 0.0, 0.5))])
    if damage == "unknown data type":
        x = _array(6, b"x", [_element(10, struct.pack("<2d", 1.0, 2.0))])
    elif damage == "missing data part":
        x = _array(1, b"x", [_array(6, b"", [])], dims=(1, 1))
    else:
        flags = _element(6, struct.pack("<II", 4, 0))
        short_dims = struct.pack("<I", (2 << 16) | 5) + bytes(4)
        x = _element(14, flags + short_dims + _element(1, b"x") + _element(16, b"ab"))
    (tmp_path / "r.mat").write_bytes(_mat5(time, x, time))
    assert "is not a readable MATLAB file" in str(load_error(tmp_path / "r.mat"))
