#!/usr/bin/env bash
# Create the project's virtual environment and install the package with its test tools.
set -euo pipefail
python=${1:-python3}
venv=${2:-.venv}
cd "$(dirname "$0")/.."
if [ ! -x "$venv/bin/python" ]; then
    echo "setup: creating $venv with $($python --version)"
    "$python" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet -e '.[test]'
touch "$venv/bin/blackbox"
echo "setup: ready ($venv/bin/blackbox)"
