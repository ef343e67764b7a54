#!/usr/bin/env bash
# The small-ember table of benches/RESULTS.md ("Emission traced: a small ember"): a 2 × 2 × 2-voxel
# ember glowing in a 48³ sphere of thin isotropic fog (σt 0.2 per voxel, albedo 0.9, no other
# light), solved with the default settings twice — `solver.emission_uncollided = "swept"` and
# `"auto"` (which traces it) — and compared with `lpm reference` of the same scene: fluence
# relative L2 over the voxels the reference resolves (`lpm compare`'s fluence row), the image's
# 4 × 4-pixel blocks over the medium (the reference's image is noise at a few hundred paths per
# pixel: an emitter is found by chance), and the solve's wall time; one markdown row each; the two
# images side by side in OUT/ember.png and the fluence in the ember's plane in OUT/ember-fluence.png
# (swept | auto | reference, then the error maps).
#
#   tools/ember_table.sh [OUT_DIR]      default out/ember
#   LPM=target/release/lpm  BACKEND=cpu  PHOTONS=8000000  SPP=256
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/ember}
LPM=${LPM:-target/release/lpm}
BACKEND=${BACKEND:-cpu}
PHOTONS=${PHOTONS:-8000000}
SPP=${SPP:-256}
if [ ! -x "$LPM" ]; then
    [ "$LPM" = target/release/lpm ] || { echo "no lpm binary at $LPM" >&2; exit 1; }
    cargo build --release
fi
mkdir -p "$OUT"
/usr/bin/python3 - "$OUT" <<'PY'
import struct, sys
out = sys.argv[1]
n = 48
hot = range(23, 25)  # the ember: the 2 × 2 × 2 voxels at the centre
vals = [1.0 if (x in hot and y in hot and z in hot) else 0.0 for z in range(n) for y in range(n) for x in range(n)]
open(f"{out}/ember.raw", "wb").write(struct.pack(f"<{len(vals)}f", *vals))
for mode in ("swept", "auto"):
    open(f"{out}/ember_{mode}.toml", "w").write(f'''[volume]
procedural = "sphere"
dims = [{n}, {n}, {n}]
voxel_size = 1.0
emission_raw = "ember.raw"
[medium]
sigma_t = 0.2
albedo = 0.9
emission = [400.0, 160.0, 40.0]
[solver]
emission_uncollided = "{mode}"
[camera]
projection = "pinhole"
fov_y = 45.0
position = [24.0, -30.0, 40.0]
look_at = [24.0, 24.0, 24.0]
up = [0.0, 0.0, 1.0]
width = 240
height = 180
exposure = 3.0
''')
PY
[ -f "$OUT/ref/fluence.raw" ] ||
    nice "$LPM" reference "$OUT/ember_auto.toml" --out "$OUT/ref" --samples "$PHOTONS" --image-spp "$SPP" --seed 1 --log warn >/dev/null
echo "| emission_uncollided | solve (wall) | fluence rel. L2 | fluence worst voxel | fluence bias | image blocks rel. L2 (medium) |"
echo "|---|---|---|---|---|---|"
for mode in swept auto; do
    d="$OUT/$mode"
    start=$EPOCHREALTIME
    "$LPM" solve "$OUT/ember_$mode.toml" --out "$d" --backend "$BACKEND" --log warn >/dev/null
    end=$EPOCHREALTIME
    "$LPM" compare "$d" "$OUT/ref" --json "$OUT/compare_$mode.json" >/dev/null
    /usr/bin/python3 - "$mode" "$start" "$end" "$OUT/compare_$mode.json" <<'PY'
import json, sys
mode, secs, cmp = sys.argv[1], float(sys.argv[3]) - float(sys.argv[2]), json.load(open(sys.argv[4]))
f = cmp["fluence"]["metrics"]
m = cmp["image"]["medium_blocks"]
noise = cmp["fluence"]["reference_noise_relative_l2"]
print(f"| {mode} | {secs:.1f} s | {f['relative_l2']:.2%} (reference noise {noise:.2%}) | {f['max_relative_error']:.0%} "
      f"| {f['mean_bias']:+.2%} | {m['relative_l2']:.1%} |")
PY
done
/usr/bin/python3 tools/side_by_side.py "$OUT/swept/image.png" "$OUT/auto/image.png" "$OUT/ember.png"
/usr/bin/python3 tools/fluence_slice.py 23 "$OUT/ember-fluence.png" "$OUT/swept" "$OUT/auto" "$OUT/ref" --scale 3
echo "images: $OUT/ember.png (swept | auto); the fluence through the ember: $OUT/ember-fluence.png"
echo "(swept | auto | reference on one log scale, then swept and auto against the reference, ±20 %)"
