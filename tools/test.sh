#!/usr/bin/env bash
# Runs the whole test suite on whatever Vulkan device is present (lavapipe on a machine without a
# GPU) with the Khronos validation layer and synchronization validation on: a validation error fails
# the test that caused it. First the house style: rustfmt, clippy (warnings are errors; clippy.toml
# sets msrv to the declared rust-version, so std APIs newer than that are flagged: only the
# stable toolchain is installed and rustup cannot fetch another, so this and tools/msrv_check.py,
# which checks the locked dependencies' rust-version against it, stand in for an MSRV build), and
# rustdoc (warnings are errors: broken links included).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
cargo fmt --check
cargo clippy --all-targets -- -D warnings
# After clippy: cargo has fetched the dependencies' sources the check reads.
python3 tools/msrv_check.py
RUSTDOCFLAGS=-Dwarnings cargo doc --no-deps
export LPM_VALIDATION=1
# The validation layer reads its settings from here; errors are also caught by lpm's messenger.
export VK_LOADER_DEBUG=none
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
# pipefail (above): a failing cargo test fails the script here. `test-hooks` compiles in the kill
# test's hook (LPM_TEST_ABORT_AT_SLICE, tests/it/resume.rs), which no plain or release build has.
# No backtraces: CI shows the output's tail, and a failure's own message (a proptest's minimal
# failing input, say) must not be pushed out of it by a stack trace.
RUST_BACKTRACE=0 cargo test --no-fail-fast --features test-hooks "$@" 2>&1 | tee "$log"
# A short bounded fuzzing run of every fuzz target (issue 13): 15 s each, built unoptimised (faster
# to build; debug assertions and overflow checks on), after the build.
# tools/fuzz.sh explains RUSTC_BOOTSTRAP and does long runs; it installs cargo-fuzz if missing.
LPM_FUZZ_SANITIZER=none LPM_FUZZ_DEV=1 bash tools/fuzz.sh 15 scene raw vdb nanovdb nrrd
# The Python module (tools/python, issue 37): built and installed into tools/python/.venv by its
# one install command, then its pytest suite, which holds the module's outputs against the binary
# cargo test built above (LPM_CLI; `cargo build` only finds it up to date). pytest's closing line
# ("N passed, M failed in S") joins the totals below; pipefail makes any pytest failure, exit 5
# (no test collected) included, fail the script here.
cargo build --features test-hooks --bin lpm
cargo fmt --check --manifest-path tools/python/Cargo.toml
bash tools/python/install.sh
LPM_CLI="$PWD/target/debug/lpm" tools/python/.venv/bin/python -m pytest tools/python/tests -q -p no:cacheprovider \
    2>&1 | tee -a "$log"
# The suite's totals as the closing line (the fuzz statistics above would otherwise end the output):
# cargo's "test result:" lines and pytest's closing line.
awk '/^test result:/ { p += $4; f += $6 }
     /^(=+ )?[0-9]+ (passed|failed)/ && / in [0-9.]+s/ {
         for (i = 2; i <= NF; i++) { if ($i ~ /^passed,?$/) p += $(i - 1); if ($i ~ /^failed,?$/) f += $(i - 1) }
     }
     END { printf "tests: %d passed, %d failed\n", p, f }' "$log"
