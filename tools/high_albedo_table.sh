#!/usr/bin/env bash
# Regenerates benches/RESULTS.md's "The tail of the order series" table. For the thick cloud at
# albedo 0.9, 0.99 and 0.999 (tools/scenes/thick_cloud_a*.toml, tolerance 1e-3) it solves
#   - with solver.extrapolate_tail = true ("tail");
#   - without, at the same tolerance ("plain"), then at 10×, 100×, … tighter ones until the plain
#     series is as close to the converged answer as the tail, and then cut by max_orders to find
#     the fewest orders at which it is ("plain, as close");
#   - without, to tolerance 1e-8 ("converged": what the series sums to);
# and computes a Monte-Carlo reference (`lpm reference`, kept across runs when present), then prints
# one markdown row per albedo. Errors are relative L2 of the fluence over the cloud's voxels
# (density > 0, i.e. in-scattered source > 0); `lpm compare` also writes its all-voxel comparisons
# to OUT/compare-*.json. Times are the order loop's seconds from report.json.
#
#   tools/high_albedo_table.sh [OUT_DIR] [BACKEND] [MC_PHOTONS]
#   defaults: out/high-albedo, cpu (the f64 twin), 160000000 photons; ALBEDOS="0.9 0.99 0.999"
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/high-albedo}
BACKEND=${2:-cpu}
PHOTONS=${3:-160000000}
ALBEDOS=${ALBEDOS:-"0.9 0.99 0.999"}
LPM=target/release/lpm
cargo build --release --quiet
mkdir -p "$OUT"
NICE="nice -n 10"
# The plain series: the scenes' default (acceleration "auto") would accelerate it at these albedos
# (tools/acceleration_table.sh measures that).
PLAIN='s/^extrapolate_tail = false/extrapolate_tail = false\nacceleration = "off"/'

# l2 A B MASK: relative L2 of A's fluence against B's over the voxels where MASK's source is > 0;
# with B's standard error when B has one ("l2 noise": noise = the L2 B's own noise alone gives).
l2() {
  python3 - "$1" "$2" "$3" <<'PY'
import sys, os, math
from array import array
def rd(d, f):
    a = array('f'); a.frombytes(open(os.path.join(d, f + '.raw'), 'rb').read()); return a
a, b, m = rd(sys.argv[1], 'fluence'), rd(sys.argv[2], 'fluence'), rd(sys.argv[3], 'source')
has_se = os.path.exists(os.path.join(sys.argv[2], 'fluence_stderr.raw'))
se = rd(sys.argv[2], 'fluence_stderr') if has_se else None
num = den = noise = 0.0
for i, mi in enumerate(m):
    if mi > 0:
        num += (a[i] - b[i]) ** 2; den += b[i] ** 2
        if se is not None: noise += se[i] ** 2
print(f"{math.sqrt(num / den):.2e}" + (f" {math.sqrt(noise / den):.2e}" if se is not None else ""))
PY
}
# orders and loop seconds of a solve: "N, S s"
orders() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["orders"])' "$1/report.json"; }
cost() { python3 -c 'import json,sys; r=json.load(open(sys.argv[1])); print("%d, %.1f s" % (r["orders"], sum(p["seconds"] for p in r["seconds"] if p["phase"] == "orders")))' "$1/report.json"; }
solve() { $NICE $LPM solve "$1" --out "$2" --backend "$BACKEND" --no-image --log warn > /dev/null; }
less_or_equal() { python3 -c 'import sys; sys.exit(0 if float(sys.argv[1]) <= float(sys.argv[2]) else 1)' "$1" "$2"; }

echo "| albedo | plain, tol 1e-3: orders, time, error | plain, as close: orders, time, error | tail, tol 1e-3: orders, time, error | tail vs MC | converged vs MC | MC noise floor |"
echo "|---|---|---|---|---|---|---|"
for a in $ALBEDOS; do
  scene=tools/scenes/thick_cloud_a$a.toml
  sed 's/^extrapolate_tail = false/extrapolate_tail = true/' "$scene" > "$OUT/tail_a$a.toml"
  solve "$OUT/tail_a$a.toml" "$OUT/tail-$a"
  sed "s/^tolerance = 1e-3/tolerance = 1e-8/; $PLAIN" "$scene" > "$OUT/converged_a$a.toml"
  solve "$OUT/converged_a$a.toml" "$OUT/converged-$a"
  conv="$OUT/converged-$a"
  tail_err=$(l2 "$OUT/tail-$a" "$conv" "$conv")
  plain_row="" n_far=0 err_far=1
  for t in 1e-3 1e-4 1e-5 1e-6; do
    sed "s/^tolerance = 1e-3/tolerance = $t/; $PLAIN" "$scene" > "$OUT/plain_a${a}_$t.toml"
    solve "$OUT/plain_a${a}_$t.toml" "$OUT/plain-$a-$t"
    err=$(l2 "$OUT/plain-$a-$t" "$conv" "$conv")
    n=$(orders "$OUT/plain-$a-$t")
    [ -n "$plain_row" ] || plain_row="$(cost "$OUT/plain-$a-$t"), $err"
    if less_or_equal "$err" "$tail_err"; then break; fi
    n_far=$n err_far=$err
  done
  # The fewest orders at which the plain series is as close as the tail: a plain solve cut by
  # max_orders, from a log-linear guess between the bracketing solves, stepped to the boundary.
  n_close=$(python3 -c 'import math,sys; n1,e1,n2,e2,e=map(float,sys.argv[1:]); print(max(int(n1)+1, math.ceil(n1+(n2-n1)*math.log(e1/e)/math.log(e1/e2))))' \
    "$n_far" "$err_far" "$n" "$err" "$tail_err")
  step=$(( (n - n_far) / 20 + 1 ))
  capped() {
    sed "s/^max_orders = .*/max_orders = $1/; s/^tolerance = 1e-3/tolerance = 1e-12/; $PLAIN" "$scene" > "$OUT/plain_a${a}_cap.toml"
    solve "$OUT/plain_a${a}_cap.toml" "$OUT/plain-$a-cap$1"
    l2 "$OUT/plain-$a-cap$1" "$conv" "$conv"
  }
  if less_or_equal "$(capped "$n_close")" "$tail_err"; then
    while [ $((n_close - step)) -gt "$n_far" ] && less_or_equal "$(capped $((n_close - step)))" "$tail_err"; do
      n_close=$((n_close - step))
    done
  else
    while ! less_or_equal "$(capped $((n_close + step)))" "$tail_err"; do n_close=$((n_close + step)); done
    n_close=$((n_close + step))
  fi
  as_close="$(cost "$OUT/plain-$a-cap$n_close"), $(l2 "$OUT/plain-$a-cap$n_close" "$conv" "$conv")"
  [ -f "$OUT/mc-$a/report.json" ] ||
    $NICE $LPM reference "$scene" --out "$OUT/mc-$a" --samples "$PHOTONS" --seed 1 --log warn > /dev/null
  for r in tail-$a plain-$a-1e-3 converged-$a; do
    $LPM compare "$OUT/$r" "$OUT/mc-$a" --json "$OUT/compare-$r.json" > /dev/null
  done
  read -r tail_mc noise < <(l2 "$OUT/tail-$a" "$OUT/mc-$a" "$conv")
  read -r conv_mc _ < <(l2 "$conv" "$OUT/mc-$a" "$conv")
  echo "| $a | $plain_row | $as_close | $(cost "$OUT/tail-$a"), $tail_err | $tail_mc | $conv_mc | $noise |"
done
