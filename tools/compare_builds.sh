#!/usr/bin/env bash
# Are two builds' answers byte-identical? Solves each scene with both lpm binaries and compares
# fluence.raw and source.raw with cmp (how a refactor shows it changed no result: RESULTS, "The GPU
# driver's restructuring: the same bytes").
#
#   tools/compare_builds.sh BEFORE_LPM AFTER_LPM OUT SCENE.toml...
#
# Options (environment): CAP=N caps every scene's solver.max_orders at N (each order runs the same
# code, so a few show a change as well as hundreds); BUDGET=8M solves with that
# --device-memory-budget (streamed, sub-slices); BACKEND=cpu for the CPU twin. The [camera]
# exposure/view keys are dropped from both sides' copies (they change only the image, and older
# builds do not know them). Each scene's copy, outputs and logs go to OUT; the last line per scene
# says identical or DIFFERENT; exits 1 when any differs.
set -uo pipefail
[ $# -ge 4 ] || { sed -n '2,13p' "$0"; exit 2; }
before=$(realpath "$1") after=$(realpath "$2") out=$3
shift 3
mkdir -p "$out"
status=0
for scene in "$@"; do
    name=$(basename "$scene" .toml)
    # The copy sits in OUT: files the scene names relative to itself are linked beside it.
    python3 - "$scene" "$out/$name.toml" "${CAP:-}" <<'PY'
import os, re, sys
src, dst, cap = sys.argv[1], sys.argv[2], sys.argv[3]
lines = [l for l in open(src).read().splitlines() if not re.match(r'^(exposure|view)\s*=', l)]
for l in lines:
    m = re.match(r'^\w+\s*=\s*"([^"]+\.(raw|vdb|nvdb|nhdr|nrrd|exr))"', l)
    if m and not os.path.isabs(m.group(1)):
        target = os.path.join(os.path.dirname(os.path.abspath(src)), m.group(1))
        link = os.path.join(os.path.dirname(dst), m.group(1))
        if os.path.exists(target) and not os.path.exists(link):
            os.symlink(target, link)
if cap:
    cap, found = int(cap), False
    for i, l in enumerate(lines):
        m = re.match(r'^max_orders\s*=\s*(\d+)', l)
        if m:
            lines[i], found = f"max_orders = {min(int(m.group(1)), cap)}", True
    if not found:
        if '[solver]' in lines:
            lines.insert(lines.index('[solver]') + 1, f"max_orders = {cap}")
        else:
            lines += ['[solver]', f"max_orders = {cap}"]
open(dst, 'w').write('\n'.join(lines) + '\n')
PY
    verdict=identical
    for side in before after; do
        bin=$before
        [ "$side" = after ] && bin=$after
        rm -rf "${out:?}/$side-$name"
        "$bin" solve "$out/$name.toml" --out "$out/$side-$name" --no-image \
            ${BUDGET:+--device-memory-budget "$BUDGET"} ${BACKEND:+--backend "$BACKEND"} \
            >"$out/$side-$name.log" 2>&1 || { echo "$name: the $side build failed (see $out/$side-$name.log)"; verdict=failed; }
    done
    if [ "$verdict" = identical ]; then
        for f in fluence.raw source.raw; do
            cmp -s "$out/before-$name/$f" "$out/after-$name/$f" || verdict=DIFFERENT
        done
    fi
    [ "$verdict" = identical ] || status=1
    echo "$name: fluence.raw and source.raw $verdict"
done
exit $status
