#!/usr/bin/env bash
# The tests and gates, exactly what CI runs (`.ci/run` calls this script):
# formatting, clippy with warnings as errors, rustdoc with warnings as errors, the
# unused-dependency check, then the whole test suite.
#
# Not yet gates (other branches are fixing the files they list; the integrator enables them):
#   python3 scripts/check-cycles.py      # import cycles between the files of a crate
#   python3 scripts/check-file-size.py   # files with over 800 lines of non-test code
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n== %s\n' "$*"; }

step "cargo fmt --all -- --check"
cargo fmt --all -- --check
step "cargo clippy --workspace --all-targets --release -- -D warnings"
cargo clippy --workspace --all-targets --release -- -D warnings
step "cargo doc --workspace --no-deps (warnings are errors)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --release
step "python3 scripts/check-unused-deps.py"
python3 scripts/check-unused-deps.py
step "cargo test --workspace --release"
cargo test --workspace --release
