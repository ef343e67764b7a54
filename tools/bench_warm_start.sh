#!/usr/bin/env bash
# Orders saved by `frames.warm_start = "previous"`: an animated sequence of a soft cloud moving one
# voxel per frame along x, solved by `lpm sweep` tasks cold and warm-started, frame by frame in
# order (as on a cluster with slurm.max_running = 1). Prints per frame the orders and seconds of
# each, and the largest per-voxel relative difference of the warm fluence from the cold one.
# Usage: tools/bench_warm_start.sh [FRAMES] [EDGE] [LPM binary]. Needs python3 and jq.
set -euo pipefail
frames=${1:-6}
n=${2:-32}
lpm=${3:-target/release/lpm}
command -v jq >/dev/null || { echo "bench_warm_start: needs jq" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 - "$work" "$frames" "$n" <<'PY'
import math, struct, sys
work, frames, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
c = (n - 1) / 2
for f in range(1, frames + 1):
    cx = c - frames / 2 + f
    values = []
    for z in range(n):
        for y in range(n):
            for x in range(n):
                r2 = ((x - cx) ** 2 + (y - c) ** 2 + ((z - c) * 1.3) ** 2) / (0.3 * n) ** 2
                bumps = 1.0 + 0.3 * math.sin(x * 0.9) * math.cos(y * 0.7)
                values.append(2.0 * math.exp(-r2) * bumps)
    with open(f"{work}/cloud_{f}.raw", "wb") as out:
        out.write(struct.pack(f"<{len(values)}f", *values))
PY
cat > "$work/cloud.toml" <<TOML
[volume]
raw = "cloud_{frame}.raw"
dims = [$n, $n, $n]
[medium]
sigma_t = 1.2
albedo = 0.95
[[lights]]
kind = "sky"
radiance = 0.5
[[lights]]
kind = "sun"
direction = [0.3, -0.5, 1.0]
irradiance = 3.0
[solver]
directions_per_face = 3
max_orders = 400
tolerance = 1e-3
TOML
for mode in cold warm; do
    warm=$([ $mode = warm ] && echo 'warm_start = "previous"' || true)
    printf 'scene = "cloud.toml"\ndir = "%s"\n[frames]\nfirst = 1\nlast = %d\n%s\n[solve]\nno_image = true\n' \
        "$mode" "$frames" "$warm" > "$work/$mode.toml"
    for t in $(seq 0 $((frames - 1))); do
        "$lpm" --log warn solve "$work/$mode.toml" --task "$t" > /dev/null
    done
done
printf 'frame  cold orders  cold s  warm orders  warm s  max |warm-cold|/cold\n'
for t in $(seq 0 $((frames - 1))); do
    c="$work/cold/task-$(printf %04d "$t")/out"
    w="$work/warm/task-$(printf %04d "$t")/out"
    diff=$(python3 - "$c/fluence.raw" "$w/fluence.raw" <<'PY'
import struct, sys
a, b = (open(p, "rb").read() for p in sys.argv[1:3])
a, b = (struct.unpack(f"<{len(x) // 4}f", x) for x in (a, b))
print(f"{max(abs(y - x) / x for x, y in zip(a, b) if x == x and x > 0):.2e}")
PY
)
    secs() { jq '[.seconds[] | select(.phase == "orders") | .seconds] | add' "$1/report.json"; }
    printf '%5d  %11s  %6.1f  %11s  %6.1f  %s\n' $((t + 1)) "$(jq .orders "$c/report.json")" "$(secs "$c")" \
        "$(jq .orders "$w/report.json")" "$(secs "$w")" "$diff"
done
