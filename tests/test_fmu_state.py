"""FMU state, serialisation, several instances, reset, the FMI state machine, fmpy agreement."""

from __future__ import annotations

import struct
import threading
from hashlib import sha256
from pathlib import Path

import numpy as np
import pytest
import state_flips
from conftest import INPUTS, OUTPUTS
from fmpy import simulate_fmu
from fmpy.fmi1 import FMICallException

from fmu_greybox.errors import FmuError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.instance import FmuInstance

H = 1e-3  # communication step [s]
EFFECTS = {"coulomb_friction": 500.0, "compliance": 0.1, "time_delay": 0.004}


def current(t: np.ndarray) -> np.ndarray:
    """Valve current [mA]: step plus multi-sine."""
    return 2.0 + 3.0 * np.sin(2 * np.pi * 2.0 * t) + 1.0 * np.sin(2 * np.pi * 19.0 * t)


def _step(slave, refs: dict[str, int], t0: float, n: int) -> np.ndarray:
    """n communication steps from t0 with the test current; the outputs after each."""
    out = np.empty((n, len(OUTPUTS)))
    output_refs = [refs[name] for name in OUTPUTS]
    for k in range(n):
        t = t0 + k * H
        slave.setReal([refs["valve_current"]], [float(current(np.array(t)))])
        slave.doStep(t, H)
        out[k] = slave.getReal(output_refs)
    return out


@pytest.mark.parametrize(("model", "parameters"), [("whitebox", {}), ("truth", EFFECTS)])
def test_get_set_state_reproduces_bitwise(
    instantiate, whitebox_fmu: Path, truth_fmu: Path, model: str, parameters: dict
) -> None:
    slave, refs = instantiate(
        whitebox_fmu if model == "whitebox" else truth_fmu, parameters=parameters
    )
    _step(slave, refs, 0.0, 200)
    state = slave.getFMUstate()
    first = _step(slave, refs, 0.2, 300)
    slave.setFMUstate(state)
    again = _step(slave, refs, 0.2, 300)
    assert np.array_equal(first, again)

    serialized = slave.serializeFMUstate(state)
    slave.freeFMUstate(state)
    restored = slave.deSerializeFMUstate(serialized)
    slave.setFMUstate(restored)
    assert np.array_equal(_step(slave, refs, 0.2, 300), first)
    slave.freeFMUstate(restored)
    slave.terminate()
    slave.freeInstance()


@pytest.mark.parametrize("model", ["whitebox", "truth"])
def test_single_bit_flips_of_a_saved_state_are_refused_never_crash(
    whitebox_fmu: Path, truth_fmu: Path, actuator_inputs: np.ndarray, tmp_path: Path, model: str
) -> None:
    """Every bit of the header, phase, flags and time (96 bytes) and 400 bits drawn from the
    rest, flipped one at a time, in a process of its own: none crashes it, none is accepted."""
    fmu = whitebox_fmu if model == "whitebox" else truth_fmu
    counts = state_flips.sweep(fmu, list(INPUTS), actuator_inputs[:40], tmp_path, 96, 400)
    assert counts["tried"] == 96 * 8 + 400
    assert counts["refused"] == counts["tried"], counts


@pytest.mark.parametrize(
    ("offset", "packed", "named"),
    [(72, struct.pack("<i", 7), "phase 7"), (88, struct.pack("<d", np.nan), "time = nan")],
)
def test_forged_state_with_a_valid_checksum_is_refused(
    whitebox_fmu: Path, offset: int, packed: bytes, named: str
) -> None:
    """A state edited at its phase or time with its SHA-256 recomputed, as a forger would
    (layout: the shell's 72-byte header, fmi2_shell.h, then SimData), is refused naming the
    field."""
    with open_fmu(whitebox_fmu) as archive, FmuInstance(archive, ["valve_current"]) as instance:
        instance.step([1.0], H)
        saved = instance.serialize_state()
        body = bytearray(saved[:-64])
        body[offset : offset + len(packed)] = packed
        with pytest.raises(FmuError, match="fmi2DeSerializeFMUstate") as caught:
            instance.deserialize_state(bytes(body) + sha256(body).hexdigest().encode(), H)
        assert named in str(caught.value)
        instance.deserialize_state(saved, H)  # the undamaged state still restores


def test_serialized_state_moves_to_another_instance_of_the_same_fmu_only(
    instantiate, whitebox_fmu: Path, truth_fmu: Path
) -> None:
    source, refs = instantiate(whitebox_fmu, name="source")
    _step(source, refs, 0.0, 100)
    state = source.getFMUstate()
    serialized = source.serializeFMUstate(state)
    expected = _step(source, refs, 0.1, 100)

    target, _ = instantiate(whitebox_fmu, name="target")
    moved = target.deSerializeFMUstate(serialized)
    target.setFMUstate(moved)
    assert np.array_equal(_step(target, refs, 0.1, 100), expected)

    other, _ = instantiate(truth_fmu, name="other")
    with pytest.raises(FMICallException):
        other.deSerializeFMUstate(serialized)
    for slave in (source, target, other):
        slave.freeInstance()


def test_instances_are_independent(
    instantiate, simulate, whitebox_fmu: Path, truth_fmu: Path
) -> None:
    currents = {"a": 1.0, "b": -3.0, "c": 6.0}
    slaves = {
        name: instantiate(whitebox_fmu, name=name, inputs={"valve_current": i})
        for name, i in currents.items()
    }
    truth, truth_refs = instantiate(
        truth_fmu, name="truth", parameters=EFFECTS, inputs={"valve_current": 2.0}
    )
    interleaved = {name: [] for name in currents}
    for k in range(300):  # step all in lockstep, the truth model in between
        for name, (slave, refs) in slaves.items():
            slave.doStep(k * H, (k + 1) * H - k * H)
            interleaved[name].append(slave.getReal([refs["ram_position"]])[0])
        truth.doStep(k * H, (k + 1) * H - k * H)
    finals = {name: values[-1] for name, values in interleaved.items()}
    assert len(set(finals.values())) == 3
    for name, i in currents.items():
        solo = simulate(whitebox_fmu, 0.3, inputs={"valve_current": i})
        assert np.array_equal(np.array(interleaved[name]), solo["ram_position"][1:])
    solo_truth = simulate(truth_fmu, 0.3, inputs={"valve_current": 2.0}, parameters=EFFECTS)
    assert truth.getReal([truth_refs["ram_position"]])[0] == solo_truth["ram_position"][-1]
    for slave, _ in [*slaves.values(), (truth, truth_refs)]:
        slave.terminate()
        slave.freeInstance()


def test_reset_gives_a_fresh_instance(instantiate, truth_fmu: Path) -> None:
    fresh, refs = instantiate(truth_fmu, name="fresh", parameters=EFFECTS)
    expected = _step(fresh, refs, 0.0, 200)
    slave, _ = instantiate(truth_fmu, name="reused", parameters={"time_delay": 0.01})
    _step(slave, refs, 0.0, 150)
    slave.reset()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([refs[k] for k in EFFECTS], list(EFFECTS.values()))
    slave.exitInitializationMode()
    assert np.array_equal(_step(slave, refs, 0.0, 200), expected)
    for s in (fresh, slave):
        s.terminate()
        s.freeInstance()


def test_state_machine_refuses_misuse(instantiate, whitebox_fmu: Path) -> None:
    slave, refs = instantiate(whitebox_fmu)
    with pytest.raises(FMICallException):
        slave.setReal([refs["ram_position"]], [0.01])  # an output
    with pytest.raises(FMICallException):
        slave.setReal([refs["valve_current"]], [float("nan")])
    with pytest.raises(FMICallException):
        slave.doStep(0.5, H)  # the FMU is at t = 0
    with pytest.raises(FMICallException):
        slave.getReal([9999])
    with pytest.raises(FMICallException):
        slave.setDebugLogging(True, ["logEverything"])
    slave.setDebugLogging(True, ["logStatusError"])
    slave.doStep(0.0, H)  # refusals leave the instance usable
    assert slave.getRealStatus(2) == H  # fmi2LastSuccessfulTime
    slave.terminate()
    with pytest.raises(FMICallException):
        slave.doStep(H, H)
    slave.freeInstance()


def test_simulate_fmu_agrees_with_step_loop(simulate, whitebox_fmu: Path) -> None:
    time = np.array([k * H for k in range(1001)])
    signals = np.zeros(
        time.size, dtype=[("time", float), ("valve_current", float), ("load_force", float)]
    )
    signals["time"] = time
    signals["valve_current"] = current(time)
    signals["load_force"] = 3000.0 * np.sin(2 * np.pi * 1.5 * time)
    fmpy_run = simulate_fmu(
        str(whitebox_fmu), stop_time=1.0, output_interval=H, input=signals, output=list(OUTPUTS)
    )
    loop = simulate(
        whitebox_fmu,
        1.0,
        inputs={
            "valve_current": current,
            "load_force": lambda t: 3000.0 * np.sin(2 * np.pi * 1.5 * t),
        },
    )
    assert np.array_equal(fmpy_run["time"], loop["time"])
    for name in OUTPUTS:
        spread = np.ptp(loop[name])
        assert np.max(np.abs(fmpy_run[name] - loop[name])) <= 1e-12 * spread, name


def test_instances_loaded_from_many_threads_leave_the_working_folder_alone(
    whitebox_fmu: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """fmpy enters a binary's folder to load it. Loads from threads side by side (training's
    fits) must not leave the process in another FMU's extraction folder, which is then removed
    (a later load failed with 'No such file or directory' from os.getcwd)."""
    monkeypatch.chdir(tmp_path)

    def load() -> None:
        for _ in range(10):
            with open_fmu(whitebox_fmu) as archive, FmuInstance(archive, [], ["ram_position"]):
                pass

    threads = [threading.Thread(target=load) for _ in range(6)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert Path.cwd() == tmp_path
