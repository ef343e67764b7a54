#!/usr/bin/env bash
# GPU figures in one command (issue 14): the test suite under validation on the device, then the
# order benchmark and `lpm bench stream` at 128³, 256³ and 512³ (the default budget, half the
# device heap, which holds the whole working set on a data-centre GPU: the solve runs
# device-resident; and streamed with 1/8 of the bytes that plan used), then the CPU backend at 1 thread and every core; prints one table
# (Markdown, ready for benches/RESULTS.md) with the date, device, driver and exact commands.
#
#   bash tools/gpu-bench.sh prepare    # on the build machine: binaries + Vulkan loader into .gl/
#   bash tools/gpu-bench.sh run        # where the device is (or here: then they are CPU figures)
#
# A GPU machine lent by the workplace has no Rust toolchain and no Vulkan loader, so `prepare`
# builds the release binary, the integration-test binary (with the kill tests' hook) and the
# criterion bench here and copies them, stripped, with the loader's and the validation layer's
# Debian packages, into .gl/ (git-ignored; about 40 MiB, under the device tool's 64 MiB); `run` unpacks the packages when the device has no loader.
# The test binary names this checkout's absolute path (tools/scenes, spirv/, the lpm binary), so
# `run` links that path to wherever the tree lies on the device.
#
# Options of `run`: SIZES (default "128 256 512"), ORDERS (default 2), SKIP_TESTS=1,
# SKIP_ORDER_BENCH=1 (a quick check of the script itself), OUT (where the
# JSON, logs and table go; default $OUT if set, else gpu-bench-out/).
set -euo pipefail
cd "$(dirname "$0")/.."
mode="${1:-run}"
gl=.gl

prepare() {
    bash tools/setup.sh
    cargo build --release
    # The test binary: the dev profile the suite always uses, with the kill tests' hook.
    local test_bin bench_bin
    test_bin=$(cargo test --features test-hooks --test it --no-run --message-format=json 2>/dev/null |
        python3 -c 'import json,sys
for l in sys.stdin:
    m = json.loads(l)
    if m.get("reason") == "compiler-artifact" and m["target"]["name"] == "it" and m.get("executable"): print(m["executable"])' | tail -1)
    bench_bin=$(cargo bench --bench order --no-run --message-format=json 2>/dev/null |
        python3 -c 'import json,sys
for l in sys.stdin:
    m = json.loads(l)
    if m.get("reason") == "compiler-artifact" and m["target"]["name"] == "order" and m.get("executable"): print(m["executable"])' | tail -1)
    mkdir -p "$gl/bin"
    grep -qx '/.gl/' .gitignore 2>/dev/null || grep -qx '/.gl/' .git/info/exclude 2>/dev/null ||
        echo /.gl/ >>.git/info/exclude
    cp target/release/lpm "$gl/bin/lpm"
    cp "$test_bin" "$gl/bin/it"
    cp "$bench_bin" "$gl/bin/order"
    # The dev-profile lpm the tests spawn (CARGO_BIN_EXE_lpm) lies beside the test binary's target.
    cp target/debug/lpm "$gl/bin/lpm-debug"
    pwd >"$gl/bin/BUILD_ROOT"
    # Loader and validation layer for a machine without them (amd64 packages, whatever this is).
    mkdir -p /tmp/amd64/partial
    local o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
    apt-get "${o[@]}" update -qq
    (cd "$gl" && apt-get "${o[@]}" download libvulkan1 vulkan-validationlayers >/dev/null)
    # The device tool carries at most 64 MiB with the tree: debug info would be ~400 MB, stripped
    # the four binaries are ~35 MB.
    strip -s "$gl/bin/lpm" "$gl/bin/it" "$gl/bin/order" "$gl/bin/lpm-debug"
    local mib
    mib=$(du -sm "$gl" | cut -f1)
    echo "gpu-bench: .gl holds ${mib} MiB"
    if [ "$mib" -gt 60 ]; then
        echo "gpu-bench: .gl is over 60 MiB: the device tool carries at most 64 MiB with the tree" >&2
        exit 1
    fi
    echo "gpu-bench: ready; on the device run: bash tools/gpu-bench.sh run (carry .gl)"
}

run() {
    local out="${OUT:-gpu-bench-out}"
    mkdir -p "$out"
    local lpm=target/release/lpm it="" order=""
    if [ -x "$gl/bin/lpm" ]; then
        lpm="$gl/bin/lpm"
        it="$gl/bin/it"
        order="$gl/bin/order"
        if ! ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; then
            for f in "$gl"/*.deb; do dpkg -x "$f" /; done
            ldconfig
        fi
        [ -e /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] &&
            export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
        local root
        root=$(cat "$gl/bin/BUILD_ROOT")
        if [ "$root" != "$(pwd)" ] && [ ! -e "$root" ]; then
            mkdir -p "$(dirname "$root")"
            ln -s "$(pwd)" "$root"
        fi
        mkdir -p "$root/target/debug" "$root/target/release"
        [ -e "$root/target/debug/lpm" ] || cp "$gl/bin/lpm-debug" "$root/target/debug/lpm"
    else
        bash tools/setup.sh
        cargo build --release
    fi
    local sizes="${SIZES:-128 256 512}" orders="${ORDERS:-2}" date
    date=$(date -u +%Y-%m-%d)
    local device
    device=$("$lpm" bench stream tools/scenes/absorber_sphere.toml --orders 1 --json "$out/probe.json" >/dev/null 2>&1 &&
        python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["device"])' "$out/probe.json" || echo "unknown device")
    echo "gpu-bench: $date on $device"

    # 1. The suite under validation. Tests that need software a GPU machine lacks (glslang, Slurm,
    # OpenVDB's Python module, nanovdb_convert) are left to the normal suite on the build machine.
    if [ "${SKIP_TESTS:-0}" != 1 ]; then
        local skip=(--skip spirv_current --skip slurm --skip vdb_input --skip vdb_nrrd --skip vdb_sparse
            --skip vdb_output --skip nanovdb_input --skip emission::a_vdb_emission_grid
            --skip temperature::a_vdb_temperature_grid --skip scene_files::every_shipped_scene_loads)
        if [ -n "$it" ]; then
            LPM_VALIDATION=1 "$it" "${skip[@]}" 2>&1 | tee "$out/tests.log" | grep -E '^test result|FAILED|panicked' || true
        else
            LPM_VALIDATION=1 cargo test --features test-hooks --test it -- "${skip[@]}" 2>&1 | tee "$out/tests.log" |
                grep -E '^test result|FAILED|panicked' || true
        fi
    fi

    # 2. The criterion order benchmark (64³ RGB cloud, k = 5).
    if [ "${SKIP_ORDER_BENCH:-0}" = 1 ]; then
        : >"$out/order.log"
    elif [ -n "$order" ]; then
        "$order" --bench 2>&1 | tee "$out/order.log" | grep -E 'time:' || true
    else
        cargo bench --bench order 2>&1 | tee "$out/order.log" | grep -E 'time:' || true
    fi

    # 3. Stream profiles: an RGB cloud at each size, k = 4, whole working set, then 1/8 of it.
    local rows="$out/rows.md"
    : >"$rows"
    for n in $sizes; do
        local scene="$out/cloud_$n.toml"
        bash tools/bench_cloud_scene.sh "$n" >"$scene"
        # No budget: the default (half the device heap) holds the whole working set on a GPU, so
        # the solve runs device-resident; 1/8 of that plan streams every pass.
        local cmd="$lpm bench stream $scene --orders $orders --json $out/stream_${n}_full.json"
        echo "+ $cmd"
        $cmd >/dev/null 2>"$out/stream_${n}_full.log" || { echo "stream $n failed: see $out/stream_${n}_full.log"; continue; }
        local eighth
        eighth=$(python3 -c 'import json,sys; print(max(json.load(open(sys.argv[1]))["memory"]["planned_bytes"] // 8, 1))' "$out/stream_${n}_full.json")
        cmd="$lpm bench stream $scene --orders $orders --device-memory-budget $eighth --json $out/stream_${n}_eighth.json"
        echo "+ $cmd"
        $cmd >/dev/null 2>"$out/stream_${n}_eighth.log" || echo "stream $n at 1/8 failed: see $out/stream_${n}_eighth.log"
        for which in full eighth; do
            [ -f "$out/stream_${n}_${which}.json" ] || continue
            python3 - "$out/stream_${n}_${which}.json" "$n" "$which" >>"$rows" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
o = r["orders"][-1]
m = r["memory"]
label = "default (half the heap)" if sys.argv[3] == "full" else "1/8 of that plan"
label += ", " + m.get("residency", "streamed").replace("_", " ")
kind = "CPU figure (lavapipe)" if r["device_is_cpu"] else "GPU"
print(f"| {sys.argv[2]}³ | {label} ({m['planned_bytes'] / 2**20:.0f} MiB planned) | {o['wall_seconds']:.3f} s | "
      f"{o['updates_per_second'] / 1e9:.3f} G/s | {o['compute_seconds']:.3f} s | {o['upload_seconds']:.3f} / {o['download_seconds']:.3f} s | "
      f"{o['hidden_transfer_fraction']:.2f} | {o.get('host_seconds', float('nan')):.3f} s | {kind} |")
EOF
        done
    done

    # 4. The CPU backend, 1 thread and every core, on the smallest size (time per order).
    local cpu_rows="$out/cpu_rows.md"
    : >"$cpu_rows"
    local n0
    n0=$(echo "$sizes" | awk '{print $1}')
    sed -i 's/^directions_per_face = 4$/directions_per_face = 4\nmax_orders = 2/' "$out/cloud_$n0.toml"
    for threads in 1 0; do
        local dir="$out/cpu_${threads}"
        local cmd="$lpm solve $out/cloud_$n0.toml --out $dir --backend cpu --threads $threads --no-image"
        echo "+ $cmd (max_orders 2)"
        $cmd >/dev/null 2>"$out/cpu_${threads}.log" || { echo "cpu solve failed: see $out/cpu_${threads}.log"; continue; }
        python3 - "$dir/report.json" "$n0" "$threads" >>"$cpu_rows" <<'EOF'
import json, sys, os
r = json.load(open(sys.argv[1]))
phases = {p["phase"]: p["seconds"] for p in r["seconds"]}
per = phases["orders"] / max(r["orders"], 1)
t = sys.argv[3] if sys.argv[3] != "0" else f"all ({os.cpu_count()})"
print(f"| {sys.argv[2]}³ | CPU backend, {t} threads | {per:.2f} s per order | CPU figure |")
EOF
    done

    {
        echo "### $date — $device"
        echo
        echo "Command: \`bash tools/gpu-bench.sh run\` (SIZES=\"$sizes\", ORDERS=$orders; RGB cloud, k = 4, 96 directions)."
        echo
        echo "| size | budget | wall per order | updates/s | compute | upload / download | hidden transfer | host | device |"
        echo "|---|---|---|---|---|---|---|---|---|"
        cat "$rows"
        echo
        echo "| size | backend | time | device |"
        echo "|---|---|---|---|"
        cat "$cpu_rows"
        echo
        echo "Tests: $(grep -E '^test result' "$out/tests.log" 2>/dev/null | tail -1 || echo 'not run')"
        echo "Order benchmark: $(grep -E 'time:' "$out/order.log" 2>/dev/null | head -1 | sed 's/^ *//' || echo 'not run')"
    } | tee "$out/table.md"
}

case "$mode" in
    prepare) prepare ;;
    run) run ;;
    *)
        echo "usage: bash tools/gpu-bench.sh prepare|run" >&2
        exit 2
        ;;
esac
