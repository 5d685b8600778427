#!/usr/bin/env bash
# Build the wheel, install it into a fresh virtual environment away from the checkout, and run a
# short synth -> train -> export -> bench there: the installed package must carry everything it
# needs (C sources of the built-in FMUs, the project files, the SSP template).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
python="${PYTHON:-python3}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$python" -m pip wheel -q --no-deps -w "$work/dist" "$root"
"$python" -m venv "$work/venv"
"$work/venv/bin/python" -m pip install -q "$work"/dist/fmu_greybox-*.whl
cd "$work"  # no checkout in sight from here on
bin="$work/venv/bin"
config="$("$bin/python" -c 'from fmu_greybox.resources import bench_config; print(bench_config("hydraulic_actuator.toml"))')"
case "$config" in "$root"/*) echo "wheel check: the installed package reads $config from the checkout" >&2; exit 1 ;; esac
"$bin/fmu-greybox" fmu build --out fmus
"$bin/fmu-greybox" synth --effect gain_error=0.05 --duration 4 --seed 1 --out rec.csv
"$bin/fmu-greybox" train "$config" --recording rec.csv --inducing 20 --out model
"$bin/fmu-greybox" export model --out greybox.fmu --ssp bench.ssp --recording rec.csv
"$bin/fmu-greybox" cosim bench.ssp --engine fmpy --out bench.csv
test -s bench.csv
echo "wheel check: passed (installed from $(basename "$work"/dist/*.whl))"
