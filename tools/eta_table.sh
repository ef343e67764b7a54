#!/usr/bin/env bash
# The ETA against the truth (issue 36, item 2): for each scene, solves it and prints one Markdown
# row: orders, the seconds the estimator said were left at the end of order 1 (the first moment it
# knows the series' decay), the seconds that really were left (to the end of the job, by the same
# clock), their ratio, the orders it predicted against those that ran, and the ratio had it known
# the machine's true pace (seconds per order and of the stages after: the load's share taken out).
# The estimates are the job's own ("progress estimate" lines at debug level, src/job.rs), the same
# that the progress bar, the log lines and the job server show.
#
#   tools/eta_table.sh [OUT_DIR] [SCENE.toml ...]    default out/eta and the small shipped scenes
#   LPM=target/debug/lpm (the binary: build it first)  BACKEND=cpu (or gpu: lavapipe without a GPU)
#   THREADS=0  EXTRA="--no-image" (more solve flags)  TABLE_ONLY=1 (the table from OUT_DIR's logs)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/eta}
shift || true
SCENES=("$@")
if [ ${#SCENES[@]} -eq 0 ]; then
    SCENES=(tools/scenes/dense_core_cloud_16.toml tools/scenes/grey_cloud.toml tools/scenes/lantern_in_fog.toml
        tools/scenes/anisotropic_cloud.toml tools/scenes/furnace_box.toml tools/scenes/demo_cloud.toml
        tools/scenes/forward_cloud_g0.8.toml tools/scenes/thick_cloud_a0.9.toml)
fi
LPM=${LPM:-target/debug/lpm}
BACKEND=${BACKEND:-cpu}
THREADS=${THREADS:-0}
EXTRA=${EXTRA:-}
mkdir -p "$OUT"
for s in "${SCENES[@]}"; do
    name=$(basename "$s" .toml)
    if [ -z "${TABLE_ONLY:-}" ]; then
        rm -rf "$OUT/$name"
        args=(solve "$s" --out "$OUT/$name" --backend "$BACKEND")
        [ "$BACKEND" = cpu ] && args+=(--threads "$THREADS")
        # shellcheck disable=SC2086
        LPM_LOG=debug "$LPM" "${args[@]}" $EXTRA 2>"$OUT/$name.log" >/dev/null ||
            { echo "$name: the solve failed (see $OUT/$name.log)" >&2; continue; }
    fi
done
echo "| scene | orders | predicted at order 1 | true | predicted / true | orders left: predicted (true) | predicted / true at the true pace |"
echo "|---|---|---|---|---|---|---|"
for s in "${SCENES[@]}"; do
    name=$(basename "$s" .toml)
    [ -f "$OUT/$name.log" ] || continue
    python3 - "$OUT/$name.log" "$name" <<'EOF'
import re, sys
log, name = sys.argv[1], sys.argv[2]
pattern = re.compile(r"stage=(.*?) elapsed=(\S+) fraction=(\S+) seconds_left=(\S+) orders_left=(\S+)")
rows = [m.groups() for m in map(pattern.search, open(log, encoding="utf-8", errors="replace")) if m]
orders = len({st for st, *_ in rows if st.startswith("order ")})
# The estimate after order 1 is done: the last one of stage "order 1" (the first is its start).
after1 = [r for r in rows if r[0] == "order 1"]
done = [r for r in rows if r[0] == "done"]
if not after1 or not done:
    print(f"| {name} | {orders} | – (fewer than 2 orders) | | | | |")
    sys.exit()
t1, left, pred = float(after1[-1][1]), float(after1[-1][3]), int(after1[-1][4])
true = float(done[-1][1]) - t1
# The orders' end: the first estimate of a stage after them. "At the true pace": the predicted
# orders left times the true seconds per order after order 1, plus the true seconds of the stages
# after the orders: what the estimate would have said had it known the machine's speed (the load's
# share of the error taken out; what is left is the orders' count).
ends = [float(r[1]) for r in rows if not r[0].startswith("order ") and float(r[1]) > t1]
t_end = ends[0] if ends else float(done[-1][1])
ran = orders - 2
pace = (t_end - t1) / ran if ran > 0 else 0.0
after = float(done[-1][1]) - t_end
at_pace = (pred * pace + after) / true if true > 0 and pred >= 0 else float("nan")
if left < 0:
    print(f"| {name} | {orders} | not known | {true:.1f} s | – | – ({ran}) | – |")
else:
    print(f"| {name} | {orders} | {left:.1f} s | {true:.1f} s | {left / true:.2f} | {pred} ({ran}) | {at_pace:.2f} |")
EOF
done
