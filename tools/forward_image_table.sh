#!/usr/bin/env bash
# The image-accuracy table of benches/RESULTS.md ("Render: the suns' single scattering exact"):
# a 48³ procedural cloud (σt 0.8, sun 3.0 plus sky 0.5) with Henyey–Greenstein g = 0.8 and 0.95
# and albedo 0.99 and 0.9, seen backlit (towards the sun), side-lit and front-lit (the sun behind
# the camera) by a 40° pinhole camera, and exactly towards the sun by an orthographic one (the
# view `toward`: every camera ray at 0° from the sun, where the forward peak is sharpest),
# 128 × 128 pixels. Each view is solved with the default
# settings and rendered by the solve, and compared with `lpm reference --image-spp` of the same
# scene and camera (kept across runs when present, one per SPP: `<view>_ref<SPP>`; at 4096 paths
# per pixel about two minutes a view on two cores); one markdown row per view: relative L2 and
# bias of the 4 × 4-pixel block means over the whole image and over the blocks the cloud covers
# (`lpm compare`'s "blocks" and "medium" rows).
#
#   tools/forward_image_table.sh [OUT_DIR]      default out/forward-image
#   LPM=target/release/lpm  BACKEND=cpu  SPP=4096 (the reference's paths per pixel)
#   GS="0.8 0.95"  ALBEDOS="0.99 0.9"  VIEWS="back side front toward"
#   NOISE=1: also a second reference per view (seed 2, same SPP; as long again) and two more
#   columns, the references' own noise: the second against the first, measured as lpm is (the
#   difference of two independent references: about √2 times either one's own noise).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/forward-image}
LPM=${LPM:-target/release/lpm}
BACKEND=${BACKEND:-cpu}
SPP=${SPP:-4096}
GS=${GS:-"0.8 0.95"}
ALBEDOS=${ALBEDOS:-"0.99 0.9"}
VIEWS=${VIEWS:-"back side front toward"}
NOISE=${NOISE:-0}
if [ ! -x "$LPM" ]; then
    [ "$LPM" = target/release/lpm ] || { echo "no lpm binary at $LPM" >&2; exit 1; }
    cargo build --release
fi
mkdir -p "$OUT"
# scene G ALBEDO VIEW FILE: the cloud with the camera 62 voxels from its centre.
scene() {
    /usr/bin/python3 - "$@" <<'PY'
import math, sys
g, a, view, out = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
d = [-0.55, -0.35, 0.75]  # towards the sun
n = math.sqrt(sum(x * x for x in d)); d = [x / n for x in d]
c, dist = [24.0, 24.0, 24.0], 62.0
projection = 'projection = "pinhole"\nfov_y = 40'
if view in ('back', 'toward'):  # the camera looks towards the sun through the cloud
    e = [c[i] - dist * d[i] for i in range(3)]
    if view == 'toward':  # every ray parallel to the sun's; 45 voxels high, as the pinhole's frame at the cloud
        projection = 'projection = "orthographic"\nview_height = 45'
elif view == 'front':  # the sun behind the camera
    e = [c[i] + dist * d[i] for i in range(3)]
elif view == 'side':   # at right angles to the sun, level
    s = [d[1], -d[0], 0.0]; m = math.hypot(s[0], s[1]); e = [c[i] + dist * s[i] / m for i in range(3)]
else:
    sys.exit(f"unknown view {view}")
open(out, 'w').write(f'''[volume]
procedural = "cloud"
dims = [48, 48, 48]
voxel_size = 1.0
seed = 2
[medium]
sigma_t = 0.8
albedo = {a}
g = {g}
[[lights]]
kind = "sky"
radiance = 0.5
[[lights]]
kind = "sun"
direction = {d}
irradiance = 3.0
[solver]
directions_per_face = 4
tolerance = 1e-3
[camera]
{projection}
position = {e}
look_at = {c}
up = [0, 0, 1]
width = 128
height = 128
''')
PY
}
if [ "$NOISE" = 1 ]; then
    echo "| g | albedo | view | blocks: rel. L2 | blocks: bias | cloud blocks: rel. L2 | cloud blocks: bias | reference noise: blocks | reference noise: cloud blocks |"
    echo "|---|---|---|---|---|---|---|---|---|"
else
    echo "| g | albedo | view | blocks: rel. L2 | blocks: bias | cloud blocks: rel. L2 | cloud blocks: bias |"
    echo "|---|---|---|---|---|---|---|"
fi
for g in $GS; do for a in $ALBEDOS; do for v in $VIEWS; do
    base="$OUT/g${g}_a${a}_$v"
    scene "$g" "$a" "$v" "$base.toml"
    ref="${base}_ref$SPP"
    [ -f "$ref/image.exr" ] ||
        nice "$LPM" reference "$base.toml" --out "$ref" --samples 16 --image-spp "$SPP" --seed 1 --log warn >/dev/null
    args=(solve "$base.toml" --out "${base}_lpm" --backend "$BACKEND" --log warn)
    nice "$LPM" "${args[@]}" >/dev/null
    "$LPM" compare "${base}_lpm" "$ref" --json "${base}_compare.json" >/dev/null
    noise=""
    if [ "$NOISE" = 1 ]; then
        ref2="${ref}_seed2"
        [ -f "$ref2/image.exr" ] ||
            nice "$LPM" reference "$base.toml" --out "$ref2" --samples 16 --image-spp "$SPP" --seed 2 --log warn >/dev/null
        "$LPM" compare "$ref2" "$ref" --json "${base}_noise.json" >/dev/null
        noise="${base}_noise.json"
    fi
    /usr/bin/python3 - "${base}_compare.json" "$g" "$a" "$v" "$noise" <<'PY'
import json, sys
c = json.load(open(sys.argv[1]))['image']
pct = lambda x: f"{100 * x:+.1f} %" if x is not None else "n/a"
l2 = lambda x: f"{100 * x:.1f} %" if x is not None else "n/a"
b, m = c['blocks'], c['medium_blocks']
row = f"| {sys.argv[2]} | {sys.argv[3]} | {sys.argv[4]} | {l2(b['relative_l2'])} | {pct(b['mean_bias'])} | {l2(m['relative_l2'])} | {pct(m['mean_bias'])} |"
if sys.argv[5]:
    n = json.load(open(sys.argv[5]))['image']
    row += f" {l2(n['blocks']['relative_l2'])} | {l2(n['medium_blocks']['relative_l2'])} |"
print(row)
PY
done; done; done
