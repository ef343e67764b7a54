#!/usr/bin/env bash
# Long fuzzing runs of lpm's input readers (issue 13): the scene parser/validator and the raw
# density reader, the OpenVDB reader, the NanoVDB reader and the NRRD reader (header and samples), with cargo-fuzz (libFuzzer). Usage: tools/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]
# (default 600 s each, every target). Findings land in tools/fuzz/artifacts/<target>/; record
# executions and findings in benches/RESULTS.md.
#
# Why RUSTC_BOOTSTRAP=1: cargo-fuzz builds with unstable rustc flags (-Zsanitizer, sancov passes)
# that only a nightly toolchain accepts, and this machine has only the stable one (no rustup
# downloads). RUSTC_BOOTSTRAP=1 lets the stable compiler accept them; it is set for the fuzz
# builds only, never for lpm itself. LPM_FUZZ_SANITIZER picks the sanitizer (default: address;
# "none" builds faster: the code under test is safe Rust, the sanitizer mostly guards the few
# unsafe calls). LPM_FUZZ_DEV=1 builds the targets unoptimised, with debug assertions and overflow
# checks (a minute faster to build, slower to run: what a short smoke run in the test suite wants).
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_PER_TARGET="${1:-600}"
shift || true
TARGETS=("$@")
[ ${#TARGETS[@]} -gt 0 ] || TARGETS=(scene raw vdb nanovdb nrrd)
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
export RUSTC_BOOTSTRAP=1
SAN="${LPM_FUZZ_SANITIZER:-address}"
PROFILE=()
[ "${LPM_FUZZ_DEV:-0}" = 1 ] && PROFILE=(--dev)
for t in "${TARGETS[@]}"; do
  mkdir -p "tools/fuzz/corpus/$t"
  seeds=()
  [ "$t" = scene ] && seeds=(tools/scenes)
  # Small hand-written attached NRRD files (float raw, uchar with byte skip, ushort gzip).
  [ "$t" = nrrd ] && seeds=(tools/fuzz/seeds/nrrd)
  echo "== fuzzing $t for ${SECONDS_PER_TARGET}s (sanitizer $SAN)"
  log="tools/fuzz/fuzz-$t.log"
  rc=0
  cargo fuzz run "$t" "${PROFILE[@]}" --fuzz-dir tools/fuzz --sanitizer "$SAN" "tools/fuzz/corpus/$t" "${seeds[@]}" -- \
    -max_total_time="$SECONDS_PER_TARGET" -rss_limit_mb=4096 -max_len=65536 -print_final_stats=1 >"$log" 2>&1 || rc=$?
  grep -a -E "^(stat::number_of_executed_units|stat::peak_rss_mb|#[0-9]+ +DONE|SUMMARY|.*Test unit written)" "$log" || true
  if [ "$rc" -ne 0 ]; then
    tail -40 "$log"
    echo "fuzz target $t failed (exit $rc): a crash is saved under tools/fuzz/artifacts/$t"
    exit 1
  fi
done
