#!/usr/bin/env bash
# The Python package's tests: builds and installs `python/` (PyO3 + maturin, fetched from
# PyPI by pip) into the virtual environment target/python-venv with pytest and numpy, builds
# the CLI the parity tests compare with, and runs pytest. Exit code non-zero on any failure.
# Tests on real data are skipped, with the reason printed, when ../shared/data is absent
# (override with DYNAPIX_DATA=DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
venv=target/python-venv
python=${PYTHON:-python3}
if [ ! -x "$venv/bin/python" ]; then
    "$python" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check numpy pytest
cargo build --release -p dynapix-cli
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps ./python
data=${DYNAPIX_DATA:-$root/../shared/data}
if [ ! -d "$data" ]; then
    echo "test-python: $data is absent: the real-data tests (Bonn window, fr1_xyz) are skipped"
fi
# Run from target/ so that the installed package, not the source folder, is imported.
cd target
exec "$root/$venv/bin/python" -m pytest "$root/python/tests" -ra "$@"
