#!/usr/bin/env bash
# Set up (venv + package + test tools) and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[dev]"
.venv/bin/ruff check .
.venv/bin/ruff format --check .
# the report test renders the HTML report in headless Chromium, from the distribution's packages
if ! command -v chromium >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  sudo_=""
  [ "$(id -u)" -eq 0 ] || sudo_="sudo -n"
  { $sudo_ apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
      $sudo_ apt-get install -y -qq --no-install-recommends chromium >/dev/null; } \
    || echo "could not install chromium; the report rendering test will fail in CI" >&2
fi
# the fuzz targets' short runs (tests/test_fuzz.py) need clang with libFuzzer and the sanitizers
if ! command -v clang >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  sudo_=""
  [ "$(id -u)" -eq 0 ] || sudo_="sudo -n"
  { $sudo_ apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
      $sudo_ apt-get install -y -qq --no-install-recommends clang libclang-rt-dev >/dev/null; } \
    || echo "could not install clang; the fuzz tests will fail in CI" >&2
fi
# the package as a user installs it: wheel, fresh venv, a short run away from the checkout
bash scripts/wheel_check.sh
status=0
# one pytest worker per CPU (pytest-xdist); the tests share no files, ports or folders; a
# module's tests stay on one worker, so that its module- and session-scoped fixtures (trained
# models, exported FMUs, the demo's run) are built once
.venv/bin/python -m pytest -q -n auto --dist loadfile "$@" || status=$?
if [ "$status" -eq 5 ]; then
  echo "pytest collected no tests: that is a failure" >&2
  exit 1
fi
exit "$status"
