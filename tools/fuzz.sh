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
# Seeds written by OpenVDB's Python module and nanovdb_convert (tools/setup.sh installs both),
# once: OpenVDB files for the vdb target (which had none: 483 edges in 30 s from nothing) and the
# same converted to NanoVDB for the nanovdb target: a few voxels in one leaf; the same and a
# second grid with a tile and a transform; a grid of root tiles only.
generated_seeds() {
  vdb_seeds="tools/fuzz/seeds-generated/vdb"
  nvdb_seeds="tools/fuzz/seeds-generated/nanovdb"
  mkdir -p "$vdb_seeds" "$nvdb_seeds"
  if [ ! -s "$vdb_seeds/root-tiles.vdb" ]; then
    /usr/bin/python3 - "$vdb_seeds" <<'PY'
import sys, pyopenvdb as vdb
d = sys.argv[1]
g = vdb.FloatGrid(); g.name = 'density'
a = g.getAccessor()
for i in range(5):
    a.setValueOn((i, 2 * i, i), 0.5 + i)
vdb.write(d + '/one-leaf.vdb', [g])
h = vdb.FloatGrid(); h.name = 'temperature'
h.fill((8, 0, 0), (15, 7, 7), 2.0)
h.transform = vdb.createLinearTransform(voxelSize=0.25)
vdb.write(d + '/two-grids.vdb', [g, h])
t = vdb.FloatGrid(); t.name = 'density'
t.fill((0, 0, 0), (4095, 4095, 4095), 0.5, True)
t.fill((-4096, 0, 0), (-1, 4095, 4095), 0.25, False)
t.transform = vdb.createLinearTransform(voxelSize=0.5)
vdb.write(d + '/root-tiles.vdb', [t])
PY
  fi
  for v in one-leaf two-grids root-tiles; do
    [ -s "$nvdb_seeds/$v.nvdb" ] || nanovdb_convert -f "$vdb_seeds/$v.vdb" "$nvdb_seeds/$v.nvdb" >/dev/null
  done
}
for t in "${TARGETS[@]}"; do
  mkdir -p "tools/fuzz/corpus/$t"
  seeds=()
  [ "$t" = scene ] && seeds=(tools/scenes)
  # Small hand-written attached NRRD files (float raw, uchar with byte skip, ushort gzip).
  [ "$t" = nrrd ] && seeds=(tools/fuzz/seeds/nrrd)
  max_len=65536
  if [ "$t" = vdb ]; then
    # The three OpenVDB seeds are 1 to 12 KB: within the default limit.
    generated_seeds
    seeds=("$vdb_seeds")
  fi
  if [ "$t" = nanovdb ]; then
    # A NanoVDB grid holding even one voxel is about 300 KB (a 32³ node's table alone is 270 KB):
    # within 64 KiB only the root-tiles seed (1 KB: the headers, the map, the root and the checks
    # of its claimed sizes) fits, and the fuzzer never got past the headers (issue 35: 127 edges).
    # The leaf seeds (310 and 615 KB) need 1 MiB.
    max_len=1048576
    generated_seeds
    seeds=("$nvdb_seeds")
  fi
  echo "== fuzzing $t for ${SECONDS_PER_TARGET}s (sanitizer $SAN)"
  log="tools/fuzz/fuzz-$t.log"
  rc=0
  cargo fuzz run "$t" "${PROFILE[@]}" --fuzz-dir tools/fuzz --sanitizer "$SAN" "tools/fuzz/corpus/$t" "${seeds[@]}" -- \
    -max_total_time="$SECONDS_PER_TARGET" -rss_limit_mb=4096 -max_len="$max_len" -print_final_stats=1 >"$log" 2>&1 || rc=$?
  grep -a -E "^(stat::number_of_executed_units|stat::peak_rss_mb|#[0-9]+[[:space:]]+DONE|SUMMARY|.*Test unit written)" "$log" || true
  if [ "$rc" -ne 0 ]; then
    tail -40 "$log"
    echo "fuzz target $t failed (exit $rc): a crash is saved under tools/fuzz/artifacts/$t"
    exit 1
  fi
done
