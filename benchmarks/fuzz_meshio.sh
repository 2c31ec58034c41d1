#!/usr/bin/env bash
# Fuzz the render binary's mesh readers (OBJ, OFF, PLY: crates/render-cli/src/meshio.rs) for a bounded time with
# cargo-fuzz (libFuzzer + AddressSanitizer, nightly Rust), seeded with the crash-regression corpus.
#
#   bash benchmarks/fuzz_meshio.sh [SECONDS]      # default 120
#
# Needs: `rustup toolchain install nightly` and `cargo install cargo-fuzz`. Any crash or leak stops the run and
# leaves the input in crates/render-cli/fuzz/artifacts/mesh_readers/; copy it into
# crates/render-cli/tests/crashers/ (named after what it breaks, with a .obj/.off/.ply extension) so that
# `cargo test -p meshadv-render-cli --test crashers` keeps it fixed. Prints libFuzzer's final statistics.
set -euo pipefail
seconds="${1:-120}"
cd "$(dirname "$0")/../crates/render-cli/fuzz"
corpus=corpus/mesh_readers
mkdir -p "$corpus"
cp ../tests/crashers/*.obj ../tests/crashers/*.off ../tests/crashers/*.ply "$corpus"/ 2>/dev/null || true
# -rss_limit_mb: an input that makes a reader allocate more than this is reported as a crash (unbounded reads).
cargo +nightly fuzz run -O mesh_readers "$corpus" -- \
    -max_total_time="$seconds" -rss_limit_mb=1024 -timeout=10 -max_len=4096 -print_final_stats=1
