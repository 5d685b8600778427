#!/usr/bin/env bash
# Build the wheel, install it into a fresh virtual environment away from the checkout, and run
# the first hour there with only what `--help` shows: a recording, then diagnose, train, validate
# and export on the built-in project (builtin:hydraulic_actuator), and the exported FMU on a
# bench. The installed package must carry everything it needs (C sources of the built-in FMUs,
# the project files, the SSP template). Small inputs keep it short: a 4 s recording, no grey-box
# in the diagnosis, 20 inducing points.
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
export FMU_GREYBOX_CACHE="$work/cache"  # the built-in FMUs are built from the installed sources
config="$("$bin/python" -c 'from fmu_greybox.resources import bench_config; print(bench_config("hydraulic_actuator.toml"))')"
case "$config" in "$root"/*) echo "wheel check: the installed package reads $config from the checkout" >&2; exit 1 ;; esac
project=builtin:hydraulic_actuator
"$bin/fmu-greybox" synth --effect coulomb_friction=600 --duration 4 --seed 1 --out rec.csv
"$bin/fmu-greybox" synth --effect coulomb_friction=600 --duration 3 --seed 2 --out rec2.csv
"$bin/fmu-greybox" diagnose "$project" --recording rec.csv --no-greybox --out diag/
"$bin/fmu-greybox" train "$project" --recording rec.csv --terms diag/diagnosis.json \
    --inducing 20 --max-iter 20 --out model/
"$bin/fmu-greybox" validate "$project" --model model/ --recording rec2.csv --out val/
"$bin/fmu-greybox" export model/ --out greybox.fmu --ssp bench.ssp --recording rec.csv
"$bin/fmu-greybox" cosim bench.ssp --engine fmpy --out bench.csv
grep -q '"effect": "coulomb_friction"' diag/diagnosis.json
test -s val/report.html && test -s val/metrics.json
test -s bench.csv
echo "wheel check: passed (installed from $(basename "$work"/dist/*.whl))"
