"""Compare stage settings (target mode, rate features, lags) on the paper's two experiments.

Each variant is a JSON object of overrides: ``{"target": "output"}`` sets ``[gp] target``;
``{"ITFV": {"feed_rates": true}}`` updates that stage's table. Prints one line per variant and
experiment with the held-out improvement per stage (%, negative = better).

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

from fmu_greybox.config import parse_config
from fmu_greybox.training import train_model
from fmu_greybox.validation import validate_model


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variants", help="JSON list of override objects")
    parser.add_argument("--scale", type=float, default=1.0, help="shrink sample counts")
    args = parser.parse_args(argv)
    recordings = {
        name: synthesise_experiment(spec, args.scale) for name, spec in EXPERIMENTS.items()
    }
    for variant in json.loads(args.variants):
        for name, (recording, raw_overrides) in recordings.items():
            raw = tomllib.loads(CONFIG.read_text())
            raw["gp"].update(raw_overrides["gp"])
            raw["split"] = raw_overrides["split"]
            if "target" in variant:
                raw["gp"]["target"] = variant["target"]
            for stage in raw["stages"]:
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
