#!/usr/bin/env bash
# The GPU backend against its CPU twin on many random valid scenes (issue 57): the property test
# tests/it/backends_agree.rs at N cases instead of the suite's 12 (default 200), under validation.
# Every boundary kind per face, vacuum, σt = 0, sky, sun and point lights; mirrored scenes against
# the twin of the volume the GPU unfolds. A failing case prints proptest's minimal scene text.
# Usage: tools/backends_agree.sh [CASES]. Record the run (cases, time, device) in benches/RESULTS.md.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export LPM_VALIDATION=1 VK_LOADER_DEBUG=none RUST_BACKTRACE=0
LPM_BACKEND_CASES="${1:-200}" cargo nextest run --config-file tools/nextest.toml --features test-hooks \
    --test it 'backends_agree::the_gpu_and_the_twin_agree_on_random_scenes'
