"""Open-loop simulation of a co-simulation FMU over a recording's inputs.

Timing convention, shared by the synthetic recorder and the co-simulation master: row ``k`` of
a recording holds the input ``u_k`` applied over ``[t_k, t_k+1)`` and the output ``y_k``
observed at ``t_k`` *before* ``u_k`` acts. So ``y_0`` is the FMU's initial output and
``y_k+1`` is read after the step that applied ``u_k``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import FmuArchive, open_fmu
from fmu_greybox.fmi.binding import InputBinding, bind_inputs
from fmu_greybox.fmi.instance import FmuInstance


def run_open_loop(
    instance: FmuInstance,
    u: np.ndarray,
    dt: float,
    progress: bool = False,
) -> np.ndarray:
    """Step an initialised instance through an input sequence.

    Parameters
    ----------
    instance : FmuInstance
        Bound to the inputs in the column order of ``u`` and to the outputs wanted.
    u : ndarray, shape (n_samples, n_inputs)
        Input rows; row ``k`` acts over ``[t_k, t_k + dt)``.
    dt : float
        Communication step [s].
    progress : bool
        Show a progress bar.

    Returns
    -------
    ndarray, shape (n_samples, n_outputs)
        Row 0 is the initial output, row ``k + 1`` the output after applying ``u[k]``.
    """
    n = u.shape[0]
    y = np.empty((n, len(instance.output_names)))
    y[0] = instance.read_outputs()
    for k in tqdm(range(n - 1), disable=not progress, desc="simulate", unit="step", leave=False):
        y[k + 1] = instance.step(u[k], dt)
    return y


def simulate_recording(
    fmu: str | Path | FmuArchive,
    recording: Recording,
    *,
    mapping: Mapping[str, str] | None = None,
    fixed: Mapping[str, float] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    progress: bool = False,
) -> Recording:
    """Run an FMU open-loop over the inputs of a recording.

    Parameters
    ----------
    fmu : str, Path or FmuArchive
        The co-simulation FMU (opened and closed here when given as a path).
    recording : Recording
        Supplies the inputs (by name, or through ``mapping``) and the time grid; its time step
        is the communication step.
    mapping, fixed : mapping, optional
        See :func:`fmu_greybox.fmi.binding.bind_inputs`.
    parameters : mapping of str to float, optional
        FMU parameter values.
    outputs : sequence of str, optional
        Variables to record; default every Real output of the FMU.
    progress : bool
        Show a progress bar.

    Returns
    -------
    Recording
        The simulated outputs on the recording's time grid, with the FMU's units.
    """
    archive = fmu if isinstance(fmu, FmuArchive) else open_fmu(fmu)
    try:
        binding = bind_inputs(archive, recording, mapping, fixed)
        names = list(outputs) if outputs is not None else real_outputs(archive)
        y = simulate_binding(archive, binding, recording, names, parameters, progress)
    finally:
        if archive is not fmu:
            archive.close()
    return Recording(
        time=recording.time.copy(),
        signals={name: y[:, j].copy() for j, name in enumerate(names)},
        units={name: archive.variable(name).unit for name in names},
        source=f"{archive.path.name} over {recording.source}",
        metadata={"fmu": archive.path.name, "recording": recording.source},
    )


def simulate_binding(
    archive: FmuArchive,
    binding: InputBinding,
    recording: Recording,
    outputs: Sequence[str],
    parameters: Mapping[str, float] | None = None,
    progress: bool = False,
) -> np.ndarray:
    """Simulate with an already resolved input binding.

    Returns
    -------
    ndarray, shape (n_samples, len(outputs))
    """
    u = binding.matrix(recording)
    start = dict(zip(binding.inputs, u[0], strict=True))
    with FmuInstance(
        archive,
        inputs=binding.inputs,
        outputs=outputs,
        parameters=parameters,
        start_values=start,
        start_time=float(recording.time[0]),
    ) as instance:
        return run_open_loop(instance, u, recording.dt, progress)


def real_outputs(archive: FmuArchive) -> list[str]:
    """Names of the FMU's Real outputs, in declaration order."""
    return [
        v.name for v in archive.variables.values() if v.causality == "output" and v.type == "Real"
    ]
