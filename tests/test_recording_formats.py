"""The bench loggers' formats (issue 16): MDF4 through asammdf, MATLAB v7.3 through h5py; a
named pipe read once; a MAT file with several structs; units converted on load (issue 15)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest
from asammdf import MDF, Signal
from scipy.io import savemat

from fmu_greybox.data.recording import load_recording
from fmu_greybox.errors import RecordingError

N = 50
TIME = np.arange(N) * 1e-3
X = np.sin(TIME * 40.0)
Y = np.cos(TIME * 40.0) * 1e5


def load_error(path: Path, **options) -> RecordingError:
    with pytest.raises(RecordingError) as caught:
        load_recording(path, **options)
    return caught.value


# -- MDF4 --------------------------------------------------------------------------------------


def write_mdf(path: Path, groups: list[list[Signal]]) -> Path:
    mdf = MDF(version="4.10")
    for signals in groups:
        mdf.append(signals)
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def test_mdf4_channels_and_units_are_read(tmp_path: Path) -> None:
    path = write_mdf(
        tmp_path / "bench.mf4",
        [
            [
                Signal(X, TIME, name="ram_position", unit="mm"),
                Signal(Y, TIME, name="supply_pressure", unit="bar"),
                Signal(np.arange(N, dtype=np.int16), TIME, name="counter", unit=""),
            ]
        ],
    )
    recording = load_recording(path)
    np.testing.assert_array_equal(recording.time, TIME)
    np.testing.assert_array_equal(recording["ram_position"], X)
    np.testing.assert_array_equal(recording["counter"], np.arange(N))
    assert recording.units == {"ram_position": "mm", "supply_pressure": "bar", "counter": ""}
    converted = recording.converted({"ram_position": "m", "supply_pressure": "Pa"})
    np.testing.assert_allclose(converted["ram_position"], X * 1e-3, rtol=1e-15)
    np.testing.assert_allclose(converted["supply_pressure"], Y * 1e5, rtol=1e-15)
    assert converted.units["ram_position"] == "m"
    assert (
        converted.metadata["unit_conversions"]
        == "ram_position: mm -> m; supply_pressure: bar -> Pa"
    )


def test_mdf4_in_several_groups_on_one_time_base(tmp_path: Path) -> None:
    path = write_mdf(
        tmp_path / "two.mf4",
        [[Signal(X, TIME, name="a", unit="m")], [Signal(Y, TIME, name="b", unit="Pa")]],
    )
    recording = load_recording(path)
    assert recording.names == ("a", "b") and recording.units == {"a": "m", "b": "Pa"}


def test_mdf4_errors_name_the_file_and_the_channel(tmp_path: Path) -> None:
    rates = write_mdf(
        tmp_path / "rates.mf4",
        [
            [Signal(X, TIME, name="fast", unit="m")],
            [Signal(X[::10], TIME[::10], name="slow", unit="m")],
        ],
    )
    text = str(load_error(rates))
    assert "rates.mf4: channel group 1 (channel 'slow') is sampled on another time base" in text
    assert "every 0.01 s against 50 every 0.001 s" in text and "resample" in text
    twice = write_mdf(
        tmp_path / "twice.mf4",
        [[Signal(X, TIME, name="a", unit="m")], [Signal(Y, TIME, name="a", unit="Pa")]],
    )
    assert "channel 'a' appears in channel groups 0 and 1" in str(load_error(twice))
    (tmp_path / "junk.mf4").write_bytes(b"MDF     4.10    " + bytes(200))
    assert "junk.mf4: is not a readable MDF file" in str(load_error(tmp_path / "junk.mf4"))
    text = str(
        load_error(
            path := write_mdf(tmp_path / "t.mf4", [[Signal(X, TIME, name="a")]]), time_column="zeit"
        )
    )
    assert f"{path}, column 'zeit': no time channel 'zeit'" in text


# -- MATLAB v7.3 -------------------------------------------------------------------------------


def write_mat73(path: Path, variables: dict[str, object]) -> Path:
    """A v7.3 MAT file as MATLAB writes one: a 512-byte user block, then HDF5 with column-major
    datasets (an n-by-1 vector is a (1, n) dataset) and MATLAB_class attributes."""
    with h5py.File(path, "w", userblock_size=512) as handle:

        def put(group: h5py.Group, name: str, value: object) -> None:
            if isinstance(value, dict):
                sub = group.create_group(name)
                sub.attrs["MATLAB_class"] = np.bytes_("struct")
                for field, inner in value.items():
                    put(sub, field, inner)
            elif isinstance(value, str):
                data = group.create_dataset(name, data=np.frombuffer(value.encode(), np.uint8))
                data.attrs["MATLAB_class"] = np.bytes_("char")
            else:
                data = group.create_dataset(name, data=np.asarray(value).reshape(1, -1))
                data.attrs["MATLAB_class"] = np.bytes_("double")

        for name, value in variables.items():
            put(handle, name, value)
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(116, b" ")
    with open(path, "r+b") as handle:
        handle.write(header + bytes(8) + b"\x00\x02IM")
    return path


def test_mat73_variables_and_lone_struct_are_read(tmp_path: Path) -> None:
    flat = load_recording(
        write_mat73(tmp_path / "flat.mat", {"time": TIME, "x": X, "label": "run 1"})
    )
    np.testing.assert_array_equal(flat.time, TIME)
    np.testing.assert_array_equal(flat["x"], X)
    assert flat.metadata["ignored_variables"] == "label"
    nested = load_recording(write_mat73(tmp_path / "s.mat", {"run": {"time": TIME, "y": Y}}))
    np.testing.assert_array_equal(nested["y"], Y)
    assert nested.metadata["struct"] == "run"
    # the same content through scipy's v7 file gives the same recording
    savemat(tmp_path / "v7.mat", {"time": TIME, "x": X})
    assert load_recording(tmp_path / "v7.mat") == flat.select(["x"])


@pytest.mark.parametrize("writer", ["v7", "v7.3"])
def test_mat_with_two_structs_says_why_and_how(tmp_path: Path, writer: str) -> None:
    """Before: "no time variable 'time'; variables found: (none)"."""
    content = {"run1": {"time": TIME, "x": X}, "run2": {"time": TIME, "x": X}}
    path = tmp_path / "two.mat"
    if writer == "v7":
        savemat(path, content)
    else:
        write_mat73(path, content)
    text = str(load_error(path))
    assert "two.mat: holds 2 structs ('run1', 'run2') and no signal vector" in text
    assert "save(FILE, '-struct', 'run1')" in text


# -- a named pipe ------------------------------------------------------------------------------


def test_named_pipe_is_read_once(tmp_path: Path) -> None:
    """Before: the header was read by one open and the rows by another, so the header was lost."""
    pipe = tmp_path / "stream.csv"
    os.mkfifo(pipe)
    text = "time,x [mm]\n" + "".join(
        f"{t!r},{x!r}\n" for t, x in zip(TIME.tolist(), X.tolist(), strict=True)
    )

    def feed() -> None:
        with open(pipe, "w", encoding="utf-8") as handle:
            handle.write(text)

    writer = threading.Thread(target=feed)
    writer.start()
    try:
        recording = load_recording(pipe)
    finally:
        writer.join(timeout=30)
    np.testing.assert_array_equal(recording["x"], X)
    assert recording.units == {"x": "mm"}
