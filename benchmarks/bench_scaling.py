"""Time and peak memory of ``train``, ``diagnose`` and ``validate`` against recording length.

Synthetic flight tests of the reference actuator (``synth --duration``, 1 kHz, a concealed
Coulomb friction) of each length given are trained on, diagnosed and validated by the
command line, exactly as a user runs it, each command in its own process: its wall time and
the peak resident memory of its largest process (the command or one of its simulation
workers) are printed per length, with the slope of log time against log rows (1 is linear).
The peer, measured in the same run, is ``synth`` making the same recording: a closed-loop
simulation of the truth model over every row.

Usage: ``.venv/bin/python benchmarks/bench_scaling.py [--rows 25000 100000 600000]
[--inducing M ...] [--steps train diagnose validate] [--json]``. With several ``--inducing``,
``train`` is run at each (the table of time against inducing points).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from spread import conditions

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "bench_configs" / "hydraulic_actuator.toml"
CLI = [sys.executable, "-c", "from fmu_greybox.cli import main; main()"]
MEASURE = (
    "import resource, subprocess, sys, time\n"
    "t = time.perf_counter()\n"
    "code = subprocess.run(sys.argv[1:]).returncode\n"
    "seconds = time.perf_counter() - t\n"
    "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
    "print(f'{seconds} {peak} {code}')\n"
)


def measured(arguments: list[str], log: Path) -> dict[str, float]:
    """Run one command in a fresh process; its wall time [s] and peak memory [MB].

    Raises
    ------
    RuntimeError
        The command failed (its log is named).
    """
    with log.open("w") as out:
        done = subprocess.run(
            [sys.executable, "-c", MEASURE, *CLI, *arguments],
            stdout=subprocess.PIPE,
            stderr=out,
            text=True,
            check=True,
        )
    seconds, peak_kb, code = done.stdout.split()[-3:]
    if int(code) not in (0, 3):  # 3: validate --strict's "not every criterion passes"
        raise RuntimeError(f"{' '.join(arguments[:1])} exited {code}; see {log}")
    return {"seconds": float(seconds), "peak_mb": int(peak_kb) / 1024.0}


def slope(rows: list[int], seconds: list[float]) -> float:
    """Least-squares slope of log(seconds) against log(rows)."""
    x = [math.log(r) for r in rows]
    y = [math.log(s) for s in seconds]
    mx, my = sum(x) / len(x), sum(y) / len(y)
    den = sum((a - mx) ** 2 for a in x)
    return sum((a - mx) * (b - my) for a, b in zip(x, y, strict=True)) / den if den else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, nargs="+", default=[25_000, 100_000, 600_000])
    parser.add_argument("--inducing", type=int, nargs="+", default=[None])
    parser.add_argument(
        "--steps", nargs="+", default=["train", "diagnose", "validate"], help="Commands to time."
    )
    parser.add_argument("--json", action="store_true", help="Print one JSON line.")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    table = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for rows in args.rows:
            rec = folder / f"rec{rows}.csv"
            val = folder / f"val{rows}.csv"
            duration = f"{(rows - 1) * 1e-3:.3f}"
            synth = ["synth", "--effect", "coulomb_friction=600", "--duration", duration]
            row = {"rows": rows, "synth": measured([*synth, "--out", str(rec)], folder / "s.log")}
            measured([*synth, "--seed", "1", "--out", str(val)], folder / "s.log")
            if "diagnose" in args.steps:
                out = ["--recording", str(rec), "--out", str(folder / f"diag{rows}")]
                row["diagnose"] = measured(["diagnose", str(CONFIG), *out], folder / "d.log")
            for inducing in args.inducing:
                key = "train" if inducing is None else f"train M={inducing}"
                model = folder / f"model{rows}_{inducing}"
                extra = [] if inducing is None else ["--inducing", str(inducing)]
                if "train" in args.steps or "validate" in args.steps:
                    out = ["--recording", str(rec), "--out", str(model), *extra]
                    row[key] = measured(["-q", "train", str(CONFIG), *out], folder / "t.log")
            if "validate" in args.steps:
                model = folder / f"model{rows}_{args.inducing[0]}"
                out = ["--model", str(model), "--recording", str(val)]
                out += ["--out", str(folder / f"val{rows}")]
                row["validate"] = measured(["-q", "validate", str(CONFIG), *out], folder / "v.log")
            table.append(row)
            print(
                f"{rows} rows: "
                + ", ".join(
                    f"{k} {v['seconds']:.1f} s, {v['peak_mb']:.0f} MB"
                    for k, v in row.items()
                    if k != "rows"
                ),
                flush=True,
            )
    steps = [k for k in table[0] if k != "rows"]
    slopes = {k: slope([r["rows"] for r in table], [r[k]["seconds"] for r in table]) for k in steps}
    facts = conditions(load_before)
    if args.json:
        print(json.dumps({"table": table, "slopes": slopes, **facts}))
        return
    shown = ", ".join(f"{k} {v:.2f}" for k, v in slopes.items())
    print(f"slope of log time against log rows: {shown}")
    if len(args.inducing) > 1 and None not in args.inducing:
        for row in table:
            times = [row[f"train M={m}"]["seconds"] for m in args.inducing]
            print(
                f"slope of log train time against log inducing points, {row['rows']} rows: "
                f"{slope(args.inducing, times):.2f}"
            )
    print(
        f"one run each; {facts['date']}, {facts['cpus']} CPUs, load average "
        f"{facts['load_before']:.2f} before, {facts['load_after']:.2f} after"
    )


if __name__ == "__main__":
    start = time.perf_counter()
    main()
    print(f"({time.perf_counter() - start:.0f} s in all)")
