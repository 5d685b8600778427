"""Opening untrusted FMU archives, and the FmuInstance stepping wrapper."""

from __future__ import annotations

import re
import stat
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from fmpy import platform as fmpy_platform
from fmpy import platform_tuple as fmpy_platform_tuple

from fmu_greybox.errors import FmuArchiveError, FmuError
from fmu_greybox.fmi.archive import MAX_COMPRESSION_RATIO, open_fmu
from fmu_greybox.fmi.instance import FmuInstance

INPUTS = ("valve_current", "supply_pressure", "load_force", "engage")
OUTPUTS = ("spool_position", "ram_position", "itfv_pressure", "pressure_a")
FMI3_DESCRIPTION = b"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="HydraulicActuator"
    instantiationToken="{d94aba40-47e3-5974-8ed0-f3c9c88099ae}">
  <CoSimulation modelIdentifier="HydraulicActuator"/>
  <ModelVariables>
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
  </ModelVariables>
  <ModelStructure/>
</fmiModelDescription>
"""


@pytest.fixture()
def temp_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A private system temporary folder: where open_fmu extracts to, checked afterwards."""
    root = tmp_path / "tmp"
    root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(root))
    return root


def rewrite(
    source: Path,
    target: Path,
    replace: dict[str, bytes] | None = None,
    drop: Callable[[str], bool] = lambda name: False,
    add: list[tuple[zipfile.ZipInfo, bytes]] = (),
) -> Path:
    """Copy the FMU ``source`` to ``target`` with members replaced, dropped or added."""
    replace = replace or {}
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if not drop(info.filename):
                dst.writestr(info.filename, replace.get(info.filename, src.read(info)))
        for info, data in add:
            dst.writestr(info, data)
    return target


def description(fmu: Path) -> bytes:
    with zipfile.ZipFile(fmu) as zf:
        return zf.read("modelDescription.xml")


def symlink_member(name: str, target: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name)
    info.external_attr = (stat.S_IFLNK | 0o777) << 16
    info.create_system = 3  # unix
    return info


def hostile(kind: str, fmu: Path, target: Path, outside: Path) -> Path:
    """A copy of the reference FMU made hostile or broken in one way."""
    if kind == "parent path":
        return rewrite(fmu, target, add=[(zipfile.ZipInfo("../evil.txt"), b"owned")])
    if kind == "nested parent path":
        return rewrite(fmu, target, add=[(zipfile.ZipInfo("resources/../../evil.txt"), b"x")])
    if kind == "absolute path":
        return rewrite(fmu, target, add=[(zipfile.ZipInfo(str(outside)), b"owned")])
    if kind == "symbolic link":
        return rewrite(
            fmu,
            target,
            add=[
                (
                    symlink_member("resources/link", str(outside.parent)),
                    str(outside.parent).encode(),
                )
            ],
        )
    if kind == "zip bomb":
        bomb = zipfile.ZipInfo("resources/zeros.bin")
        bomb.compress_type = zipfile.ZIP_DEFLATED
        return rewrite(fmu, target, add=[(bomb, bytes(16 * 1024**2))])
    if kind == "not a zip":
        target.write_bytes(b"modelDescription.xml is not here, this is text\n" * 20)
        return target
    if kind == "no model description":
        return rewrite(fmu, target, drop=lambda name: name == "modelDescription.xml")
    if kind == "neither interface":
        xml = re.sub(rb"<CoSimulation [^>]*/>", b"", description(fmu))
        return rewrite(fmu, target, replace={"modelDescription.xml": xml})
    if kind == "FMI 3.0":
        return rewrite(fmu, target, replace={"modelDescription.xml": FMI3_DESCRIPTION})
    if kind == "no binary for this platform":
        return rewrite(fmu, target, drop=lambda name: name.startswith(f"binaries/{fmpy_platform}/"))
    if kind == "corrupt XML":
        xml = description(fmu)
        return rewrite(fmu, target, replace={"modelDescription.xml": xml[: len(xml) // 2]})
    raise AssertionError(kind)


PROBLEMS = {
    "parent path": r"member '\.\./evil\.txt' would be written outside the extraction folder",
    "nested parent path": r"'resources/\.\./\.\./evil\.txt' would be written outside",
    "absolute path": r"would be written outside the extraction folder",
    "symbolic link": r"member 'resources/link' is a symbolic link; refused",
    "zip bomb": r"member 'resources/zeros\.bin' expands \d+ times; refused as a likely zip bomb",
    "not a zip": r"not a zip archive, so not an FMU",
    "no model description": r"no modelDescription\.xml at the archive root",
    "neither interface": r"an FMI 2\.0 FMU with neither a co-simulation nor a model-exchange "
    r"interface; fmu-greybox runs FMI 2\.0 co-simulation, FMI 3\.0 co-simulation, FMI 2\.0 "
    r"model exchange or FMI 3\.0 model exchange FMUs",
    "FMI 3.0": rf"no binary for this platform \({fmpy_platform_tuple}, FMI 3\.0 co-simulation\)",
    "no binary for this platform": rf"no binary for this platform \({fmpy_platform}, FMI 2\.0 ",
    "corrupt XML": r"unreadable modelDescription\.xml",
}


@pytest.mark.parametrize("kind", list(PROBLEMS))
def test_hostile_or_broken_archive_is_refused(
    kind: str, whitebox_fmu: Path, tmp_path: Path, temp_root: Path
) -> None:
    outside = tmp_path / "outside" / "evil.txt"
    outside.parent.mkdir()
    fmu = hostile(kind, whitebox_fmu, tmp_path / "broken.fmu", outside)
    before = sorted(tmp_path.rglob("*"))
    with pytest.raises(FmuArchiveError, match=PROBLEMS[kind]) as info:
        open_fmu(fmu)
    assert str(fmu) in str(info.value)
    assert sorted(tmp_path.rglob("*")) == before  # nothing written, extraction folder removed
    assert not outside.exists() and not list(temp_root.iterdir())


def test_zip_bomb_fixture_exceeds_the_ratio(whitebox_fmu: Path, tmp_path: Path) -> None:
    fmu = hostile("zip bomb", whitebox_fmu, tmp_path / "bomb.fmu", tmp_path / "x")
    with zipfile.ZipFile(fmu) as zf:
        info = zf.getinfo("resources/zeros.bin")
    assert info.file_size / info.compress_size > MAX_COMPRESSION_RATIO


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FmuArchiveError, match="no such FMU file"):
        open_fmu(tmp_path / "absent.fmu")


def test_reference_fmu_opens_and_cleans_up(whitebox_fmu: Path, temp_root: Path) -> None:
    with open_fmu(whitebox_fmu) as archive:
        assert archive.unzip_dir.parent == temp_root and archive.unzip_dir.is_dir()
        assert archive.model_identifier == "HydraulicActuator"
        assert archive.inputs == list(INPUTS)
        assert archive.variable("supply_pressure").unit == "Pa"
        with pytest.raises(FmuArchiveError, match="did you mean 'ram_position'"):
            archive.variable("ram_positon")
    assert not list(temp_root.iterdir())


# ------------------------------------------------------------------------------ FmuInstance


@pytest.fixture(scope="module")
def archive(whitebox_fmu: Path) -> Iterator:
    with open_fmu(whitebox_fmu) as opened:
        yield opened


def inputs(n: int, amplitude: float = 3.0) -> np.ndarray:
    """Input rows: a valve current sine, nominal supply, a load step, engaged."""
    t = np.arange(n) * 1e-3
    return np.column_stack(
        [
            amplitude * np.sin(2 * np.pi * 4.0 * t),
            np.full(n, 20.7e6),
            np.where(t > 0.05, 5e3, 0.0),
            np.ones(n),
        ]
    )


def run(instance: FmuInstance, u: np.ndarray) -> np.ndarray:
    return np.array([instance.step(row, 1e-3).copy() for row in u])


def make(archive, name: str = "a", **kwargs) -> FmuInstance:
    return FmuInstance(archive, INPUTS, OUTPUTS, instance_name=name, **kwargs)


def test_two_instances_in_one_process_are_independent(archive) -> None:
    u_a, u_b = inputs(200), inputs(200, amplitude=-5.0)
    with make(archive, "alone") as alone:
        expected = run(alone, u_a)
    with make(archive, "a") as a, make(archive, "b", parameters={"viscous_damping": 5e3}) as b:
        rows_a, rows_b = [], []
        for k in range(200):  # interleaved steps
            rows_a.append(a.step(u_a[k], 1e-3).copy())
            rows_b.append(b.step(u_b[k], 1e-3).copy())
    assert np.array_equal(np.array(rows_a), expected)
    assert not np.allclose(np.array(rows_b), expected)


def test_serialized_state_round_trip(archive) -> None:
    u = inputs(300)
    with make(archive) as first:
        run(first, u[:100])
        data, time = first.serialize_state(), first.time
        assert isinstance(data, bytes) and time == pytest.approx(0.1)
        expected = run(first, u[100:])
        first.deserialize_state(data, time)  # back in time, same instance
        assert first.time == time
        again = run(first, u[100:])
    with make(archive, "fresh") as fresh:  # and into another instance
        fresh.deserialize_state(data, time)
        moved = run(fresh, u[100:])
    assert np.array_equal(again, expected) and np.array_equal(moved, expected)


def test_state_snapshot_restore(archive) -> None:
    u = inputs(200)
    with make(archive) as instance:
        run(instance, u[:50])
        snapshot = instance.get_state()
        expected = run(instance, u[50:])
        instance.set_state(snapshot)
        again = run(instance, u[50:])
        instance.free_state(snapshot)
    assert np.array_equal(again, expected)


def test_reset_starts_again(archive) -> None:
    u = inputs(150)
    with make(archive) as instance:
        initial = instance.read_outputs().copy()
        first = run(instance, u)
        instance.reset()
        assert instance.time == 0.0
        assert np.array_equal(instance.read_outputs(), initial)
        second = run(instance, u)
        instance.reset(parameters={"viscous_damping": 5e3})
        damped = run(instance, u)
    assert np.array_equal(second, first)
    assert not np.allclose(damped, first)


def test_instance_errors_carry_call_status_and_time(archive) -> None:
    with make(archive) as instance:
        run(instance, inputs(20))
        with pytest.raises(FmuError) as info:
            instance.step([np.nan, 20.7e6, 0.0, 1.0], 1e-3)
        assert (info.value.call, info.value.status) == ("fmi2SetReal", "fmi2Error")
        assert info.value.time == pytest.approx(0.02)
        assert "valve_current = nan is not a finite number" in str(info.value)
        with pytest.raises(
            FmuError,
            match=r"fmi2DoStep returned fmi2Error at t = 0.02 s.*"
            "communicationStepSize = -0.001 s must be positive",
        ):
            instance.step([0.0, 20.7e6, 0.0, 1.0], -1e-3)
    with pytest.raises(FmuError, match=r"fmi2ExitInitializationMode.*piston_area"):
        make(archive, parameters={"piston_area": -1.0})


def test_log_messages_reach_their_own_instance(archive) -> None:
    with make(archive, "a") as a, make(archive, "b") as b:
        with pytest.raises(FmuError, match="valve_current = nan is not a finite number"):
            a.step([np.nan, 20.7e6, 0.0, 1.0], 1e-3)
        with pytest.raises(FmuError) as info:
            b.step([0.0, 20.7e6, 0.0, 1.0], -1e-3)
        assert "nan" not in str(info.value) and "must be positive" in str(info.value)


def test_fmu_logging_after_an_instance_is_gone_is_safe(whitebox_fmu: Path) -> None:
    """fmpy's C logger proxy keeps one process-wide pointer to the last Python logger."""
    code = f"""
import gc
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.instance import FmuInstance
path = {str(whitebox_fmu)!r}
with open_fmu(path) as archive, FmuInstance(archive, [], ["ram_position"]) as instance:
    instance.step([], 1e-3)
del instance
gc.collect()
description = read_model_description(path)
slave = FMU2Slave(guid=description.guid, unzipDirectory=extract(path),
                  modelIdentifier="HydraulicActuator", instanceName="plain")
slave.instantiate()
slave.setupExperiment(startTime=0.0)
try:
    slave.doStep(1.0, 1e-3)  # wrong phase: the FMU logs an error
except Exception:
    print("refused")
"""
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 0, result.stderr
    assert "fmi2DoStep failed: not allowed" in result.stdout and "refused" in result.stdout
