#!/usr/bin/env bash
# Time to a converged answer, with its error against Monte Carlo beside it (issue 14, item 6).
#
# For the RGB cloud of tools/bench_cloud_scene.sh (σt = [0.9, 0.8, 0.7], albedo [0.9, 0.85, 0.8], sky + sun,
# k = 4) at each size N³ (the same cloud: voxel size 64/N), solved to tolerance 1e-3 with the plan's
# defaults, it runs
#   - the Vulkan path (lavapipe on a machine without a GPU: CPU figures; the GPU where there is one),
#   - the CPU backend at 1 thread and at every core,
# then a Monte-Carlo reference of the same scene (`lpm reference`, independent of the solver), and
# prints one Markdown row per solve: orders, the order loop's seconds (report.json's "orders" phase:
# the time to the converged answer once the volume is loaded), seconds and voxel·direction updates
# per second per order (N³ × directions over seconds per order), and the relative L2 of the fluence
# against the reference over the whole medium and over its densest 10 % (`lpm compare`, reference
# noise taken out; the reference's own noise beside it).
#
#   tools/converge_table.sh [OUT_DIR]        default out/converge
#   SIZES="64 128 256"  RUNS="vulkan cpu1 cpuN"  MC_PHOTONS_64=64000000 (photons per channel at 64³;
#   other sizes scale it by N/64, capped by MC_PHOTONS_MAX=400000000; MC_PHOTONS_<N> overrides a
#   size's)  SKIP_MC=1  NICE=-10  TABLE_ONLY=1 (no solves: the table from what OUT_DIR holds)
#
# Timed solves run first, at a raised priority (NICE, as root) so that other work on the machine
# disturbs them as little as possible; the references run after them. The machine's load average
# before each solve is printed beside its row.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/converge}
SIZES=${SIZES:-"64 128 256"}
RUNS=${RUNS:-"vulkan cpu1 cpuN"}
MC64=${MC_PHOTONS_64:-64000000}
MCMAX=${MC_PHOTONS_MAX:-400000000}
NICE=${NICE:--10}
LPM=target/release/lpm
cargo build --release --quiet
mkdir -p "$OUT"
prio=()
[ "$(id -u)" = 0 ] && prio=(nice -n "$NICE")

scene() { # N
    bash tools/bench_cloud_scene.sh "$1"
    echo "tolerance = 1e-3"
}

run_args() { # run → backend arguments
    case $1 in
        vulkan) echo "" ;;
        cpu1) echo "--backend cpu --threads 1" ;;
        cpuN) echo "--backend cpu --threads 0" ;;
        *) echo "unknown run $1 (vulkan, cpu1, cpuN)" >&2; exit 1 ;;
    esac
}

# 1. The timed solves.
[ "${TABLE_ONLY:-0}" = 1 ] || for n in $SIZES; do
    scene "$n" >"$OUT/cloud_$n.toml"
    for run in $RUNS; do
        dir="$OUT/solve_${n}_$run"
        load=$(cut -d' ' -f1 /proc/loadavg)
        echo "$load" >"$OUT/load_${n}_$run"
        # shellcheck disable=SC2046
        cmd=("$LPM" solve "$OUT/cloud_$n.toml" --out "$dir" $(run_args "$run") --no-image --log warn)
        echo "+ ${cmd[*]} (load $load)" >&2
        "${prio[@]}" "${cmd[@]}" >/dev/null
    done
done

# 2. The references, then the comparisons.
for n in $SIZES; do
    ref="$OUT/mc_$n"
    photons=$(python3 -c "print(min($MC64 * $n // 64, $MCMAX))")
    override="MC_PHOTONS_$n"
    photons=${!override:-$photons}
    if [ "${SKIP_MC:-0}" != 1 ] && [ "${TABLE_ONLY:-0}" != 1 ] && [ ! -f "$ref/report.json" ]; then
        echo "+ $LPM reference $OUT/cloud_$n.toml --out $ref --samples $photons --seed 7" >&2
        "$LPM" reference "$OUT/cloud_$n.toml" --out "$ref" --samples "$photons" --seed 7 --log warn >/dev/null
    fi
    for run in $RUNS; do
        dir="$OUT/solve_${n}_$run"
        [ -f "$ref/report.json" ] && "$LPM" compare "$dir" "$ref" --scene "$OUT/cloud_$n.toml" \
            --json "$dir/compare.json" --log warn >/dev/null
    done
done

echo "| volume | path | orders | time to converged | per order | updates/s | error vs MC: whole (core) | MC noise: whole | load |"
echo "|---|---|---|---|---|---|---|---|---|"
for n in $SIZES; do
    for run in $RUNS; do
        dir="$OUT/solve_${n}_$run"
        python3 - "$dir" "$n" "$run" "$(cat "$OUT/load_${n}_$run")" <<'PY'
import json, os, sys
d, n, run, load = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
r = json.load(open(os.path.join(d, "report.json")))
phases = {p["phase"]: p["seconds"] for p in r["seconds"]}
orders = r["orders"]
t = phases["orders"]
per = t / max(orders, 1)
updates = n ** 3 * r["plan"]["propagation_directions"] / per
path = {"vulkan": f"Vulkan ({r['device'].split(' (')[0]})", "cpu1": "CPU backend, 1 thread",
        "cpuN": f"CPU backend, {os.cpu_count()} threads"}[run]
conv = "" if r["converged"] else " (not converged)"
err = noise = "n/a"
c = os.path.join(d, "compare.json")
if os.path.exists(c):
    f = json.load(open(c))["fluence"]
    core = f["core"]["metrics"]["relative_l2"]
    err = f"{f['noise_corrected_relative_l2']:.1e} ({core:.1e})" if core is not None else f"{f['noise_corrected_relative_l2']:.1e}"
    noise = f"{f['reference_noise_relative_l2']:.1e}"
print(f"| {n}³ | {path} | {orders}{conv} | {t:.1f} s | {per:.2f} s | {updates / 1e6:.1f} M | {err} | {noise} | {load} |")
PY
    done
done
