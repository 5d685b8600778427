"""Writing a recording to CSV: the package's writer (``fmu_greybox/data/csv.py``, Arrow's CSV
writer for the numbers) against pandas's ``DataFrame.to_csv``, the writer it replaced.

The recording: N rows of a time column and S signals of standard-normal values scaled to
magnitudes from 1e-8 to 1e7, with negative zeros among them. Both files are read back with
``load_recording`` and checked bit for bit against the values written.

Usage::

    .venv/bin/python benchmarks/bench_csv.py [--rows 600000] [--signals 14] [--repeat 3]

Prints the median write time of each with its range, the ratio, and whether both read back
bit for bit.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np
from spread import alternated, print_against, yes

from fmu_greybox.data.recording import Recording, load_recording, save_recording


def recording(rows: int, signals: int) -> Recording:
    """The benchmark's recording (see the module docstring)."""
    rng = np.random.default_rng(0)
    columns = {}
    for k in range(signals):
        values = rng.standard_normal(rows) * 10.0 ** (k % 16 - 8)
        values[k::97] = -0.0
        columns[f"s{k}"] = values
    return Recording(np.arange(rows) * 1e-3, columns, {})


def write_pandas(rec: Recording, path: Path) -> None:
    """The peer: pandas's writer, as ``save_recording`` called it before."""
    rec.to_frame().to_csv(path, index=False, lineterminator="\n")


def exact(rec: Recording, path: Path) -> bool:
    """Whether ``path`` reads back to ``rec``'s values, bit for bit."""
    return load_recording(path).sha256() == rec.sha256()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=600_000)
    parser.add_argument("--signals", type=int, default=14)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    rec = recording(args.rows, args.signals)
    with tempfile.TemporaryDirectory() as tmp:
        paths = {"fmu-greybox": Path(tmp) / "ours.csv", "pandas": Path(tmp) / "peer.csv"}
        figures, _ = alternated(
            {
                "fmu-greybox": lambda: save_recording(rec, paths["fmu-greybox"]),
                "pandas": lambda: write_pandas(rec, paths["pandas"]),
            },
            args.repeat,
        )
        same = {name: exact(rec, path) for name, path in paths.items()}
    print_against(
        f"a recording of {args.rows} rows x {1 + args.signals} columns to CSV",
        figures,
        "fmu-greybox",
        "pandas",
        "read back bit for bit: " + ", ".join(f"{name} {yes(ok)}" for name, ok in same.items()),
        load_before,
        args.repeat,
    )


if __name__ == "__main__":
    main()
