#!/usr/bin/env bash
# Lint, type-check and run every test: ruff first (a second), mypy beside pytest (it needs
# one core for ~15 s while the tests mostly wait on robots and sockets), pytest in parallel
# workers (tests/isolation.py keeps their DDS domains apart). Extra arguments go to pytest.
# --no-loadscope-reorder: xdist hands out units of work (a test, or an xdist_group) in the
# order tests/ordering.py gives them, longest first, not by their number of tests.
set -uo pipefail
cd "$(dirname "$0")/.."
bin=${VENV:-.venv}/bin
workers=${PYTEST_WORKERS:-3}
# Byte-code caches on (tests/conftest.py says why): a shell's PYTHONDONTWRITEBYTECODE made
# every worker and every `blackbox` subprocess compile the sources again.
unset PYTHONDONTWRITEBYTECODE
# Compiled once here (under a second) rather than by each worker at once in a fresh checkout.
"$bin/python" -m compileall -q src scripts benchmarks >/dev/null 2>&1 || true  # ruff names errors
"$bin/ruff" check src tests benchmarks || exit 1
mypy_log=$(mktemp)
"$bin/mypy" >"$mypy_log" 2>&1 &
mypy_pid=$!
"$bin/python" -m pytest -q -n "$workers" --dist loadgroup --no-loadscope-reorder \
    --durations=20 "$@"
tests=$?
wait "$mypy_pid"
typed=$?
cat "$mypy_log"
rm -f "$mypy_log"
if [ "$typed" -ne 0 ]; then echo "test: mypy failed" >&2; exit "$typed"; fi
exit "$tests"
