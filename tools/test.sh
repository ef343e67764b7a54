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
