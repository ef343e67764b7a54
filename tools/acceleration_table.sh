#!/usr/bin/env bash
# Regenerates benches/RESULTS.md's "Diffusion synthetic acceleration" table. For
# the thick cloud (tools/scenes/thick_cloud_a0.999.toml with the albedo set to 0.9, 0.99, 0.999,
# 0.9999; tolerance 1e-3) it solves
#   - with solver.acceleration = "off" ("plain"),
#   - with solver.acceleration = "diffusion" ("accelerated"),
#   - accelerated to tolerance 1e-9 ("converged": the plain series converges to the same answer,
#     to 5e-9 at albedo 0.999, but would need ~10⁴ orders at 0.9999),
# and prints one markdown row per albedo: orders, the order loop's seconds (report.json) and the
# relative L2 of the fluence over the cloud's voxels (density > 0) against the converged answer,
# plus the largest relative error of a cloud voxel.
#
#   tools/acceleration_table.sh [OUT_DIR] [BACKEND]
#   defaults: out/acceleration, cpu (the f64 twin, one thread: CPU figures); ALBEDOS="0.9 0.99 0.999 0.9999"
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/acceleration}
BACKEND=${2:-cpu}
ALBEDOS=${ALBEDOS:-"0.9 0.99 0.999 0.9999"}
LPM=target/release/lpm
cargo build --release --quiet
mkdir -p "$OUT"
THREADS=()
[ "$BACKEND" = cpu ] && THREADS=(--threads 1)

# err A B: relative L2 and largest relative error of A's fluence against B's over the voxels where
# B's source is > 0 (the cloud).
err() {
  python3 - "$1" "$2" <<'PY'
import sys, os, math
from array import array
def rd(d, f):
    a = array('f'); a.frombytes(open(os.path.join(d, f + '.raw'), 'rb').read()); return a
a, b, m = rd(sys.argv[1], 'fluence'), rd(sys.argv[2], 'fluence'), rd(sys.argv[2], 'source')
num = den = worst = 0.0
for i, mi in enumerate(m):
    if mi > 0:
        num += (a[i] - b[i]) ** 2; den += b[i] ** 2; worst = max(worst, abs(a[i] / b[i] - 1))
print(f"{math.sqrt(num / den):.1e} (max {worst:.1e})")
PY
}
cost() { python3 -c 'import json,sys; r=json.load(open(sys.argv[1])); print("%d, %.1f s" % (r["orders"], sum(p["seconds"] for p in r["seconds"] if p["phase"] == "orders")))' "$1/report.json"; }
solve() { $LPM solve "$1" --out "$2" --backend "$BACKEND" "${THREADS[@]}" --no-image --log warn > /dev/null; }
scene_for() { # albedo acceleration tolerance
  sed "s/^albedo = .*/albedo = $1/; s/^extrapolate_tail = false/acceleration = \"$2\"/; s/^tolerance = .*/tolerance = $3/" \
    tools/scenes/thick_cloud_a0.999.toml
}

echo "| albedo | plain: orders, time | plain: error (max) | accelerated: orders, time | accelerated: error (max) | converged (orders) |"
echo "|---|---|---|---|---|---|"
for a in $ALBEDOS; do
  scene_for "$a" diffusion 1e-9 > "$OUT/converged_a$a.toml"
  solve "$OUT/converged_a$a.toml" "$OUT/converged-$a"
  scene_for "$a" diffusion 1e-3 > "$OUT/accelerated_a$a.toml"
  solve "$OUT/accelerated_a$a.toml" "$OUT/accelerated-$a"
  scene_for "$a" off 1e-3 > "$OUT/plain_a$a.toml"
  solve "$OUT/plain_a$a.toml" "$OUT/plain-$a"
  conv="$OUT/converged-$a"
  echo "| $a | $(cost "$OUT/plain-$a") | $(err "$OUT/plain-$a" "$conv") | $(cost "$OUT/accelerated-$a") | $(err "$OUT/accelerated-$a" "$conv") | $(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["orders"])' "$conv/report.json") |"
done
