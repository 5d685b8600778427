#!/usr/bin/env bash
# Set up (venv + package + test tools) and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[dev]"
.venv/bin/ruff check .
.venv/bin/ruff format --check .
# system packages some tests need, from the distribution, when their command is missing:
# install_missing COMMAND WHAT-FAILS-WITHOUT PACKAGE...
install_missing() {
  local command_=$1 needed_by=$2
  shift 2
  if command -v "$command_" >/dev/null 2>&1 || ! command -v apt-get >/dev/null 2>&1; then
    return 0
  fi
  local sudo_=""
  [ "$(id -u)" -eq 0 ] || sudo_="sudo -n"
  { $sudo_ apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
      $sudo_ apt-get install -y -qq --no-install-recommends "$@" >/dev/null; } \
    || echo "could not install $*; $needed_by will fail in CI" >&2
}
# the report test renders the HTML report in headless Chromium
install_missing chromium "the report rendering test" chromium
# the fuzz targets' short runs (tests/test_fuzz.py) need clang with libFuzzer and the sanitizers
install_missing clang "the fuzz tests" clang libclang-rt-dev
# the Windows tests (tests/test_windows.py) cross-compile FMUs and a master for win64 and run them
# under Wine (Debian's wine64 puts the program in /usr/lib/wine, off the PATH)
install_missing x86_64-w64-mingw32-gcc "the Windows tests" gcc-mingw-w64-x86-64
install_missing /usr/lib/wine/wine64 "the Windows tests" wine64
# the package as a user installs it: wheel, fresh venv, a short run away from the checkout;
# beside the tests (much of it is unpacking packages), its output shown when it ends
wheel_log="$(mktemp)"
trap 'rm -f "$wheel_log"' EXIT
bash scripts/wheel_check.sh >"$wheel_log" 2>&1 &
wheel_pid=$!
status=0
# one pytest worker per CPU (pytest-xdist); the tests share no files, ports or folders; a
# module's tests stay on one worker, so that its module- and session-scoped fixtures (trained
# models, exported FMUs, the demo's run) are built once; files run heaviest first (tests/file_seconds.txt)
.venv/bin/python -m pytest -q -n auto --dist loadfile --no-loadscope-reorder "$@" || status=$?
wheel_status=0
wait "$wheel_pid" || wheel_status=$?
grep -v "^WARNING: Location" "$wheel_log" || true
if [ "$wheel_status" -ne 0 ]; then
  echo "the wheel check failed (exit $wheel_status): its output is above" >&2
  exit 1
fi
if [ "$status" -eq 5 ]; then
  echo "pytest collected no tests: that is a failure" >&2
  exit 1
fi
exit "$status"
