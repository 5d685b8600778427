"""The white-box's sections of the native data file: its identity, its binaries' hashes, its
input references, and its parts with their terms.

``native/whitebox.c`` reads them; the native FMU (:mod:`fmu_greybox.export.native`) and the
native simulation runner (:mod:`fmu_greybox.model.native_run`) both write them from here.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.model.native_terms import encode_term
from fmu_greybox.model.store import file_sha256
from fmu_greybox.model.whitebox import PartLayout


def whitebox_sections(
    archive: FmuArchive,
    inputs: Sequence[str],
    layouts: Sequence[PartLayout],
    dt: float,
    n_outputs: int,
    stages: Sequence[int] = (0, 0),
    unpacked: Path | None = None,
) -> dict[str, Any]:
    """The sections ``native/whitebox.c`` reads: ``sizes`` (inputs, outputs, ``stages``: the
    chain's stages and exogenous inputs, parts, terms), the white-box's identity, its binaries'
    hashes and input references, and its parts with their terms (shared by the native FMU and
    the native simulation runner, :mod:`fmu_greybox.model.native_run`); ``unpacked`` is the
    folder whose binaries are hashed, the archive's when ``None`` (the native FMU: the
    white-box's copy in its resources, which may have gained a win64 binary)."""
    n_terms = sum(len(layout.terms) for layout in layouts)
    return {
        "sizes": np.array([len(inputs), n_outputs, *stages, len(layouts), n_terms], dtype=np.int64),
        "wb_input_vr": _references(archive, list(inputs)),
        "wb_guid": archive.guid,
        "wb_identifier": archive.model_identifier,
        "wb_binaries": _binary_hashes(
            unpacked or archive.unzip_dir, archive.model_identifier, archive.kind.remote
        ),
        **_part_sections(list(layouts), archive, list(inputs), dt),
    }


def _references(archive: FmuArchive, names: list[str]) -> np.ndarray:
    return np.array([archive.variable(n).value_reference for n in names], dtype=np.int64)


def _part_sections(layouts: list, archive: FmuArchive, inputs: list[str], dt: float) -> dict:
    """The white-box instances and their terms, concatenated part after part."""
    records, columns, bound, param_vr, param_value = [], [], [], [], []
    term_int, term_real, channels = [], [], []
    for layout in layouts:
        records.append(
            [
                len(layout.columns),
                len(layout.bound),
                len(layout.parameters),
                len(layout.terms),
                layout.substeps,
                layout.level,
            ]
        )
        columns += layout.columns
        bound += list(_references(archive, layout.bound))
        param_vr += list(_references(archive, list(layout.parameters)))
        param_value += [float(v) for v in layout.parameters.values()]
        for term in layout.terms:
            ints, reals, delayed = encode_term(term, inputs, layout.bound, layout.every(term, dt))
            term_int += ints
            term_real += reals
            channels += delayed
    return {
        "part": np.array(records, dtype=np.int64),
        "part_columns": np.array(columns, dtype=np.int64),
        "part_bound_vr": np.array(bound, dtype=np.int64),
        "part_param_vr": np.array(param_vr, dtype=np.int64),
        "part_param_value": np.array(param_value, dtype=float),
        "term_int": np.array(term_int, dtype=np.int64),
        "term_real": np.array(term_real, dtype=float),
        "term_channels": np.array(channels, dtype=np.int64),
    }


def _binary_hashes(unpacked: Path, identifier: str, remote: str = "") -> str:
    """``platform sha256`` lines of the white-box's binaries (checked before dlopen); of one
    run through Wine (``remote``, its kind's :attr:`~fmu_greybox.fmi.kinds.FmuKind.remote`),
    that platform's only: its host folder holds fmpy's remoting client (2.6 MB, hashed at
    every simulation for nothing), not the white-box."""
    lines = []
    folders = [unpacked / "binaries" / remote] if remote else (unpacked / "binaries").iterdir()
    for folder in sorted(folders):
        for library in sorted(folder.glob(f"{identifier}.*")):
            lines.append(f"{folder.name} {file_sha256(library)}")
    return "\n".join(lines)
