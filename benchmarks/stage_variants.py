"""Compare stage settings (target mode, rate features, lags) on the paper's two experiments.

Each variant is a JSON object of overrides of the reference project: ``{"gp": {"feeds":
"recorded"}}`` updates ``[gp]``; ``{"ITFV": {"lags": 1}}`` updates that stage's table; ``{"*":
{...}}`` every stage's. Prints one line per variant and experiment with the held-out improvement
per stage (%, negative = better) and, with ``--json``, ends with one JSON line of them all.

Usage::

    python benchmarks/stage_variants.py --scale 0.2 '[{}, {"ITFV": {"target_mode": "output"}}]'
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib

from reproduce_paper import CONFIG, EXPERIMENTS, synthesise_experiment

from fmu_greybox.project.config import parse_config
from fmu_greybox.workflow.train import train_model
from fmu_greybox.workflow.validate import validate_model


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variants", help="JSON list of override objects")
    parser.add_argument("--scale", type=float, default=1.0, help="shrink sample counts")
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    args = parser.parse_args(argv)
    results = []
    recordings = {
        name: synthesise_experiment(spec, args.scale) for name, spec in EXPERIMENTS.items()
    }
    for variant in json.loads(args.variants):
        for name, (recording, raw_overrides) in recordings.items():
            raw = tomllib.loads(CONFIG.read_text())
            raw["gp"].update(raw_overrides["gp"])
            raw["split"] = raw_overrides["split"]
            raw["gp"].update(variant.get("gp", {}))
            for stage in raw["stages"]:
                stage.update(variant.get("*", {}))
                stage.update(variant.get(stage["name"], {}))
            started = time.perf_counter()
            model = train_model(parse_config(raw, CONFIG), recording)
            table = validate_model(model, recording).table
            change = {k: round(100 * v["improvement"], 1) for k, v in table.items()}
            print(
                json.dumps(variant),
                name,
                change,
                f"{time.perf_counter() - started:.0f} s",
                flush=True,
            )
            results.append({"variant": variant, "experiment": name, "improvement_pct": change})
    if args.json:
        print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
