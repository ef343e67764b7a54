#!/usr/bin/env bash
# The pictures in README.md, made again from the shipped scenes: the demo cloud, the fire and the
# smoke plume (an OpenVDB volume), each solved and rendered with its scene's own camera, exposure
# and view, the PNG copied into benches/ under the name README shows.
#
#   tools/readme_images.sh [OUT_DIR]          default out/readme; the solves' outputs stay there
#   LPM=target/release/lpm (the binary; built with `cargo build --release` when missing)
#   BACKEND=cpu (or gpu)  THREADS=0 (all cores)  SCENES="demo fire plume" (a subset)
#
# fire.toml and smoke_plume.toml read tools/scenes/fire.vdb, which tools/fire_vdb.py writes (it is
# not committed; it needs OpenVDB's Python module, which tools/setup.sh installs).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/readme}
LPM=${LPM:-target/release/lpm}
BACKEND=${BACKEND:-cpu}
THREADS=${THREADS:-0}
SCENES=${SCENES:-demo fire plume}
if [ ! -x "$LPM" ]; then
    [ "$LPM" = target/release/lpm ] || { echo "no lpm binary at $LPM" >&2; exit 1; }
    cargo build --release
fi
if [[ " $SCENES " == *" fire "* || " $SCENES " == *" plume "* ]] && [ ! -f tools/scenes/fire.vdb ]; then
    /usr/bin/python3 tools/fire_vdb.py tools/scenes/fire.vdb
fi
mkdir -p "$OUT"
for name in $SCENES; do
    case $name in
    demo) scene=tools/scenes/demo_cloud.toml png=benches/demo-cloud.png ;;
    fire) scene=tools/scenes/fire.toml png=benches/fire.png ;;
    plume) scene=tools/scenes/smoke_plume.toml png=benches/smoke-plume.png ;;
    *) echo "unknown picture '$name' (demo, fire, plume)" >&2; exit 1 ;;
    esac
    args=(solve "$scene" --out "$OUT/$name" --backend "$BACKEND")
    [ "$BACKEND" = cpu ] && args+=(--threads "$THREADS")
    start=$(date +%s)
    "$LPM" "${args[@]}"
    cp "$OUT/$name/image.png" "$png.tmp"
    mv "$png.tmp" "$png"
    echo "$png: $scene, $(($(date +%s) - start)) s ($BACKEND backend)"
done
