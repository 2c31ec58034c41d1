#!/usr/bin/env bash
# The test command: installs (idempotent), then runs the Rust core's cargo tests and the Python test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
cargo test --workspace
python3 -m pytest -q
