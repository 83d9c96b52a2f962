#!/usr/bin/env bash
# The test suite: installs what is missing, then runs every test of the workspace.
# The first run builds Burn (about 15 minutes on 2 cores) and fetches VGG-16 (65 MB) once.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/ins-rs-target}"
cargo test --release --workspace "$@"
