#!/usr/bin/env bash
# Runs the whole test suite on whatever Vulkan device is present (lavapipe on a machine without a
# GPU) with the Khronos validation layer and synchronization validation on: a validation error fails
# the test that caused it. First the house style: rustfmt, clippy (warnings are errors; clippy.toml
# sets msrv to the declared rust-version, so std APIs newer than that are flagged: only the
# stable toolchain is installed and rustup cannot fetch another, so this and tools/msrv_check.py,
# which checks the locked dependencies' rust-version against it, stand in for an MSRV build), and
# rustdoc (warnings are errors: broken links included).
#
# The budget (issue 56): on the 2-core machine, a clean clone in at most 25 minutes, the test
# phases (unit, integration, fuzz, pytest) in at most 15. Each phase's time and the 20 slowest
# tests are printed at the end (tools/test_times.py), so a new test can be judged against it.
# The Rust tests run under cargo-nextest (each test a process of its own, one per core; settings
# and the tests kept one at a time in tools/nextest.toml), which records every test's time.
# Arguments are passed to both nextest runs (a filter, say: `tools/test.sh budget::`).
set -euo pipefail
cd "$(dirname "$0")/.."
export LPM_VALIDATION=1
# The validation layer reads its settings from here; errors are also caught by lpm's messenger.
export VK_LOADER_DEBUG=none
# No backtraces: CI shows the output's tail, and a failure's own message (a proptest's minimal
# failing input, say) must not be pushed out of it by a stack trace.
export RUST_BACKTRACE=0
times="$(mktemp)"
trap 'rm -f "$times"' EXIT
failed=0
# Records of an earlier run in this checkout would be counted as this run's.
rm -rf target/nextest/unit target/nextest/integration target/pytest-junit.xml
# phase NAME COMMAND...: runs COMMAND, records its wall time; a failing phase is recorded and the
# later phases still run (their times and failures are the report), the script fails at its end.
phase() {
    local name="$1" start rc=0
    shift
    echo "== $name"
    start=$(date +%s)
    "$@" || rc=$?
    local status=ok
    [ "$rc" -eq 0 ] || { status="failed($rc)"; failed=1; }
    echo "$name $(($(date +%s) - start)) $status" >>"$times"
}
nextest_ok() {
    command -v cargo-nextest >/dev/null || cargo install cargo-nextest --locked
}
lint() {
    cargo fmt --check &&
        cargo fmt --check --manifest-path tools/python/Cargo.toml &&
        cargo clippy --all-targets -- -D warnings &&
        python3 tools/msrv_check.py && # after clippy: cargo has fetched the sources it reads
        RUSTDOCFLAGS=-Dwarnings cargo doc --no-deps
}
# `test-hooks` compiles in the kill test's hook (LPM_TEST_ABORT_AT_SLICE, tests/it/resume.rs),
# which no plain or release build has. The binary the tests run (CARGO_BIN_EXE_lpm) and pytest's
# LPM_CLI are this build's target/debug/lpm (a separate `cargo build --bin lpm` would compile the
# library again: the tests' dev-dependencies unify other features of shared dependencies).
build() {
    cargo test --features test-hooks --no-run
}
unit() {
    cargo nextest run --config-file tools/nextest.toml --profile unit --features test-hooks --lib "$@" &&
        cargo test --features test-hooks --doc -q
}
integration() {
    cargo nextest run --config-file tools/nextest.toml --profile integration --features test-hooks --test it "$@"
}
# A short bounded fuzzing run of every fuzz target (issue 13): 15 s each, built unoptimised
# (faster to build; debug assertions and overflow checks on). tools/fuzz.sh explains
# RUSTC_BOOTSTRAP and does long runs; it installs cargo-fuzz if missing.
fuzz() {
    LPM_FUZZ_SANITIZER=none LPM_FUZZ_DEV=1 bash tools/fuzz.sh 15 scene raw vdb nanovdb nrrd
}
# The Python module (tools/python, issue 37), built and installed into tools/python/.venv by its
# one install command in the test build's own target folder and profile (LPM_PYTHON_PROFILE=dev):
# the dependencies it shares with the library are compiled once for both. Its pytest suite holds
# the module's outputs against the binary built above (LPM_CLI).
python_build() {
    LPM_PYTHON_PROFILE=dev LPM_PYTHON_TARGET="$PWD/target" bash tools/python/install.sh
}
pytest() {
    LPM_CLI="$PWD/target/debug/lpm" tools/python/.venv/bin/python -m pytest tools/python/tests -q \
        -p no:cacheprovider --durations=5 --junitxml=target/pytest-junit.xml
}
phase setup bash tools/setup.sh
phase tools nextest_ok
phase lint lint
phase build build
if [ "$(grep -c '^build .* ok$' "$times")" -eq 1 ]; then
    phase unit unit "$@"
    phase integration integration "$@"
    phase fuzz fuzz
    phase python-build python_build
    grep -q '^python-build .* ok$' "$times" && phase pytest pytest
fi
# The phase times, the slowest tests and the closing line ("tests: N passed, M failed") from the
# runners' own records.
python3 tools/test_times.py "$times" target/nextest/unit/junit.xml target/nextest/integration/junit.xml \
    target/pytest-junit.xml
exit "$failed"
