#!/usr/bin/env bash
# The tests and gates, exactly what CI runs (`.ci/run` calls this script):
# formatting, clippy with warnings as errors, rustdoc with warnings as errors, the
# unused-dependency check, then the whole test suite.
# the import-cycle and file-size checks, then the whole Rust test suite, then the Python
# package's tests (scripts/test-python.sh: builds the package into a virtual environment).
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n== %s\n' "$*"; }

step "cargo fmt --all -- --check"
cargo fmt --all -- --check
step "cargo clippy --workspace --all-targets --release -- -D warnings"
cargo clippy --workspace --all-targets --release -- -D warnings
# The CLI's viewer flags (`--features viz`, issue 35) are not part of the default build. They
# are checked with the whole workspace selected: `-p dynapix-cli --features viz` alone would
# unify the dependencies' features differently and rebuild Rerun's 300 crates a second time.
step "cargo clippy --workspace --features dynapix-cli/viz --all-targets --release -- -D warnings"
cargo clippy --workspace --features dynapix-cli/viz --all-targets --release -- -D warnings
step "cargo doc --workspace --no-deps (warnings are errors)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --release
step "python3 scripts/check-api.py (the public items of dynapix, as listed)"
python3 scripts/check-api.py
step "python3 scripts/check-unused-deps.py"
python3 scripts/check-unused-deps.py
step "python3 scripts/check-cycles.py"
python3 scripts/check-cycles.py
step "python3 scripts/check-file-size.py"
python3 scripts/check-file-size.py
step "cargo test --workspace --release"
cargo test --workspace --release
step "cargo test --workspace --release --features dynapix-cli/viz --test rerun_cli"
cargo test --workspace --release --features dynapix-cli/viz --test rerun_cli
step "scripts/test-python.sh"
bash scripts/test-python.sh
