#!/usr/bin/env bash
# Runs the whole test suite on whatever Vulkan device is present (lavapipe on a machine without a
# GPU) with the Khronos validation layer and synchronization validation on: a validation error fails
# the test that caused it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export LPM_VALIDATION=1
# The validation layer reads its settings from here; errors are also caught by lpm's messenger.
export VK_LOADER_DEBUG=none
cargo test --no-fail-fast "$@" 2>&1
# A short bounded fuzzing run of every fuzz target (issue 13): 20 s each, after the build.
# tools/fuzz.sh explains RUSTC_BOOTSTRAP and does long runs; it installs cargo-fuzz if missing.
LPM_FUZZ_SANITIZER=none bash tools/fuzz.sh 20 scene raw vdb
