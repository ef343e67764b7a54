#!/usr/bin/env bash
# GPU figures without wasting a GPU window (issue 33, item 5): build here, then two calls on the
# device machine, each meant to end well inside 5 minutes on a 16-core machine with an H100/H200.
#
#   bash tools/gpu-bench.sh prepare   # here: binaries + Vulkan loader, glvnd, validation layer into .gl/
#   bash tools/gpu-bench.sh tests     # there: the integration suite under validation (172 s on an H200)
#   bash tools/gpu-bench.sh bench     # there: order benchmark, `lpm bench stream`, CPU backend, emission trace (79 s on an H200 before the trace step)
#
# On the device tool: carry .gl, and begin the command with
#   for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig;
# (the modes do it themselves when the loader or glvnd is missing). Measured 2026-11-27 on a
# 16-core machine with an NVIDIA H200 (driver 580.159.04): tests 172 s, bench 79 s with
# STEP_TIMEOUT=60 SIZES="128 256 512"; each needs a timeout_s well under 600.
#
# Both device modes also run here, on lavapipe, with the same .gl/ folder (their rows then say
# "CPU figure"). Everything they measure goes into $OUT (default gpu-bench-out/) as it is measured:
# `table.md` gains its header first and a row after each figure, so a run killed at its limit still
# returns every row it had; logs come back as tails of at most 1 MiB. Scenes, JSON and solved fields
# go to a scratch folder (SCRATCH, default a fresh temporary one), never to $OUT: the device tool
# returns at most 8 files of 16 MiB. The first thing either mode does is a probe solve on the
# device; if it fails the mode stops at once, printing why.
#
# A GPU machine lent by the workplace has no Rust toolchain and no Vulkan loader, so `prepare` builds
# the release binary, the integration-test binary (with the kill tests' hook) and the criterion
# bench here and copies them, stripped, with the loader's and the validation layer's Debian
# packages, into .gl/ (git-ignored; about 40 MiB, under the device tool's 64 MiB). The test binary
# names this checkout's absolute path (tools/scenes, spirv/, the lpm binary), so the device modes
# link that path to wherever the tree lies there.
#
# Options: SIZES (bench, default "128 256 512"), ORDERS (default 2), SKIP_ORDER_BENCH=1,
# STEP_TIMEOUT (seconds one measured command may take, default 240), TEST_TIMEOUT (default 270),
# TESTS (extra arguments for the test binary, e.g. a filter), OUT, SCRATCH.
set -euo pipefail
cd "$(dirname "$0")/.."
mode="${1:-}"
gl=.gl
out="${OUT:-gpu-bench-out}"

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
    rm -rf "$gl/bin"
    mkdir -p "$gl/bin"
    grep -qx '/.gl/' .gitignore 2>/dev/null || grep -qx '/.gl/' .git/info/exclude 2>/dev/null ||
        echo /.gl/ >>.git/info/exclude
    cp target/release/lpm "$gl/bin/lpm"
    cp "$test_bin" "$gl/bin/it"
    cp "$bench_bin" "$gl/bin/order"
    # The dev-profile lpm the tests spawn (CARGO_BIN_EXE_lpm), built with the test binary.
    cp target/debug/lpm "$gl/bin/lpm-debug"
    pwd >"$gl/bin/BUILD_ROOT"
    git rev-parse --short HEAD >"$gl/bin/COMMIT" 2>/dev/null || echo unknown >"$gl/bin/COMMIT"
    # Loader and validation layer for a machine without them (amd64 packages, whatever this is).
    if ! ls "$gl"/libvulkan1_*.deb "$gl"/vulkan-validationlayers_*.deb "$gl"/libglvnd0_*.deb >/dev/null 2>&1; then
        mkdir -p /tmp/amd64/partial
        local o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
        apt-get "${o[@]}" update -qq
        (cd "$gl" && apt-get "${o[@]}" download libvulkan1 vulkan-validationlayers libglvnd0 libglx0 libgl1 libegl1 libopengl0 libgles2 >/dev/null)
    fi
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
    echo "gpu-bench: ready; on the device: bash tools/gpu-bench.sh tests, then bench (carry .gl)"
}

# The binaries of .gl/ when prepared (the device machine), else this checkout's own builds.
lpm=target/release/lpm
it=""
order=""
scratch=""
device="unknown device"

# Appends one line to $OUT/table.md at once (and prints it).
row() { echo "$*" | tee -a "$out/table.md"; }

# Copies the last MiB of a log into $OUT.
keep_tail() { [ -f "$1" ] && tail -c 1048576 "$1" >"$out/$(basename "$1")" || true; }

device_setup() {
    mkdir -p "$out"
    scratch="${SCRATCH:-$(mktemp -d)}"
    mkdir -p "$scratch"
    if [ -x "$gl/bin/lpm" ]; then
        lpm="$gl/bin/lpm"
        it="$gl/bin/it"
        order="$gl/bin/order"
        # The loader, the validation layer, and glvnd (NVIDIA's Vulkan driver is libGLX_nvidia,
        # which needs libGLdispatch).
        if ! ldconfig -p 2>/dev/null | grep -q libvulkan.so.1 || ! ldconfig -p 2>/dev/null | grep -q libGLdispatch.so.0; then
            for f in "$gl"/*.deb; do dpkg -x "$f" /; done
            ldconfig
        fi
        # The driver's libraries may lie outside the loader's library path on the lent machines.
        for d in /usr/local/nvidia/lib64 /usr/local/nvidia/lib; do
            [ -d "$d" ] && export LD_LIBRARY_PATH="$d${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
        done
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
    # The probe: one order of a small scene, with the loader's own search first, then with each
    # driver file found (VK_DRIVER_FILES). Nothing else runs if every try fails.
    local probe="$scratch/probe.json" icd ok=0
    : >"$scratch/probe.log"
    for icd in "${VK_DRIVER_FILES:-}" $(find /usr/share/vulkan /etc/vulkan /usr/local/nvidia -name '*.json' -path '*icd.d*' 2>/dev/null); do
        echo "== driver file: ${icd:-the default search}" >>"$scratch/probe.log"
        if VK_DRIVER_FILES="$icd" timeout 120 "$lpm" bench stream tools/scenes/absorber_sphere.toml --orders 1 \
            --json "$probe" >>"$scratch/probe.log" 2>&1; then
            ok=1
            if [ -n "$icd" ]; then export VK_DRIVER_FILES="$icd"; else unset VK_DRIVER_FILES; fi
            break
        fi
    done
    if [ "$ok" != 1 ]; then
        cp "$scratch/probe.log" "$out/probe.log"
        echo "gpu-bench: the device probe failed; nothing else was run. Its log:" >&2
        tail -n 40 "$scratch/probe.log" >&2
        exit 1
    fi
    echo "gpu-bench: Vulkan driver file: ${VK_DRIVER_FILES:-the default search}"
    device=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["device"])' "$probe")
    echo "gpu-bench: $(date -u +%Y-%m-%dT%H:%M:%SZ) on $device (build $(cat "$gl/bin/COMMIT" 2>/dev/null || git rev-parse --short HEAD))"
}

tests() {
    device_setup
    # Tests that need software a GPU machine lacks (glslang, Slurm, OpenVDB's Python module,
    # nanovdb_convert, /usr/bin/python3 for the benchmark generators) are left to the normal suite.
    local skip=(--skip spirv_current --skip slurm --skip vdb_input --skip vdb_nrrd --skip vdb_sparse
        --skip vdb_output --skip nanovdb_input --skip emission::a_vdb_emission_grid
        --skip temperature::a_vdb_temperature_grid --skip scene_files::every_shipped_scene_loads
        --skip albedo_grid::a_vdb_albedo_grid --skip albedo_grid::bad_albedo_input --skip bench_refine::a_refined_vdb_volume)
    [ -x /usr/bin/python3 ] || skip+=(--skip i3rc --skip kobayashi)
    # Each test in a process of its own, JOBS at a time: a crash (a driver's segfault) costs that
    # test only, and says which it was.
    local started=$SECONDS names status="$scratch/status" logs="$scratch/logs"
    mkdir -p "$logs"
    : >"$status"
    if [ -n "$it" ]; then
        names=$("$it" --list --format terse "${skip[@]}" ${TESTS:-} | sed -n 's/: test$//p')
    else
        cargo test --features test-hooks --test it --no-run
        it=$(ls -t target/debug/deps/it-* | grep -v '\.d$' | head -1)
        names=$("$it" --list --format terse "${skip[@]}" ${TESTS:-} | sed -n 's/: test$//p')
    fi
    export it logs status
    echo "$names" | timeout "${TEST_TIMEOUT:-270}" xargs -P "${JOBS:-$(nproc)}" -I{} sh -c \
        'LPM_VALIDATION=1 timeout 200 "$it" --exact "$1" --test-threads 1 >"$logs/$1.log" 2>&1; echo "$? $1" >>"$status"' _ {} || true
    local total passed failed
    total=$(echo "$names" | grep -c . || true)
    passed=$(grep -c '^0 ' "$status" || true)
    failed=$(grep -vc '^0 ' "$status" || true)
    {
        echo "### Tests under validation, $(date -u +%Y-%m-%d) — $device"
        echo
        echo "\`bash tools/gpu-bench.sh tests\` (each test in a process of its own): $passed passed, $failed failed, $((total - passed - failed)) not run, of $total; $((SECONDS - started)) s"
        { grep -v '^0 ' "$status" || true; } | sort | awk '{ r = $1 == 139 ? "segmentation fault" : $1 == 124 ? "timed out" : $1 == 134 ? "aborted" : "exit " $1; print "- failed: " $2 " (" r ")" }'
        echo
    } | tee -a "$out/table.md"
    # The failures' logs, their last 4 KiB each, at most 1 MiB in all.
    { grep -v '^0 ' "$status" || true; } | sort | while read -r _ name; do
        echo "===== $name"
        tail -c 4096 "$logs/$name.log"
    done | head -c 1048576 >"$out/failures.log"
    [ "$failed" = 0 ]
}

bench() {
    device_setup
    local sizes="${SIZES:-128 256 512}" orders="${ORDERS:-2}" step="${STEP_TIMEOUT:-240}"
    {
        echo "### Benchmarks, $(date -u +%Y-%m-%d) — $device"
        echo
        echo "Command: \`bash tools/gpu-bench.sh bench\` (SIZES=\"$sizes\", ORDERS=$orders; RGB cloud of tools/bench_cloud_scene.sh, k = 4, 96 directions)."
        echo
    } | tee -a "$out/table.md"

    # 1. The criterion order benchmark (64³ RGB cloud, k = 5).
    if [ "${SKIP_ORDER_BENCH:-0}" != 1 ]; then
        local olog="$scratch/order.log"
        if [ -n "$order" ]; then
            timeout "$step" "$order" --bench >"$olog" 2>&1 || echo "order benchmark failed or timed out" >>"$olog"
        else
            timeout "$step" cargo bench --bench order >"$olog" 2>&1 || echo "order benchmark failed or timed out" >>"$olog"
        fi
        keep_tail "$olog"
        row "Order benchmark (\`order --bench\`, 64³ RGB, k = 5): $(grep -E 'time:' "$olog" | head -2 | sed 's/^ *//' | tr '\n' ' ' || echo 'no figure')"
        row ""
    fi

    # 2. Stream profiles: an RGB cloud at each size, default budget, then 1/8 of that plan.
    row "| size | budget | wall per order | updates/s | compute | upload / download | hidden transfer | host | device |"
    row "|---|---|---|---|---|---|---|---|---|"
    for n in $sizes; do
        local scene="$scratch/cloud_$n.toml"
        bash tools/bench_cloud_scene.sh "$n" >"$scene"
        for which in full eighth; do
            local json="$scratch/stream_${n}_${which}.json" log="$scratch/stream_${n}_${which}.log"
            local cmd=("$lpm" bench stream "$scene" --orders "$orders" --json "$json")
            if [ "$which" = eighth ]; then
                [ -f "$scratch/stream_${n}_full.json" ] || continue
                local eighth
                eighth=$(python3 -c 'import json,sys; print(max(json.load(open(sys.argv[1]))["memory"]["planned_bytes"] // 8, 1))' "$scratch/stream_${n}_full.json")
                cmd+=(--device-memory-budget "$eighth")
            fi
            echo "+ ${cmd[*]}"
            if ! timeout "$step" "${cmd[@]}" >/dev/null 2>"$log"; then
                keep_tail "$log"
                row "| ${n}³ | $which | failed or timed out: see stream_${n}_${which}.log | | | | | | |"
                continue
            fi
            python3 - "$json" "$n" "$which" >>"$out/table.md" <<'EOF'
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
            tail -n 1 "$out/table.md"
        done
    done
    row ""

    # 3. The CPU backend, 1 thread and every core, on the smallest size (time per order).
    local n0
    n0=$(echo "$sizes" | awk '{print $1}')
    row "| size | backend | time | device |"
    row "|---|---|---|---|"
    sed 's/^directions_per_face = 4$/directions_per_face = 4\nmax_orders = 2/' "$scratch/cloud_$n0.toml" >"$scratch/cpu_$n0.toml"
    for threads in 1 0; do
        local dir="$scratch/cpu_${threads}" log="$scratch/cpu_${threads}.log"
        echo "+ $lpm solve $scratch/cpu_$n0.toml --out $dir --backend cpu --threads $threads --no-image (max_orders 2)"
        if ! timeout "$step" "$lpm" solve "$scratch/cpu_$n0.toml" --out "$dir" --backend cpu --threads "$threads" --no-image \
            >/dev/null 2>"$log"; then
            keep_tail "$log"
            row "| ${n0}³ | CPU backend, $threads threads | failed or timed out | |"
            continue
        fi
        python3 - "$dir/report.json" "$n0" "$threads" >>"$out/table.md" <<'EOF'
import json, sys, os
r = json.load(open(sys.argv[1]))
phases = {p["phase"]: p["seconds"] for p in r["seconds"]}
per = phases["orders"] / max(r["orders"], 1)
t = sys.argv[3] if sys.argv[3] != "0" else f"all ({os.cpu_count()})"
print(f"| {sys.argv[2]}³ | CPU backend, {t} threads | {per:.2f} s per order | CPU figure |")
EOF
        tail -n 1 "$out/table.md"
    done
    row ""

    # 4. The emission's uncollided light traced on the device (solver::uncollided::gpu): the cloud
    #    at TRACE_SIZE³ thinned to σt·h ≈ 0.1, every voxel of it emitting, the trace forced (about as
    #    many emitter-voxel pairs at 64³ as the fire scene's, which the host walks for about an hour
    #    on two cores), one order; the trace's phase from report.json, and where the plan says it ran.
    local tn="${TRACE_SIZE:-64}" tdir="$scratch/trace" tlog="$scratch/trace.log"
    bash tools/bench_cloud_scene.sh "$tn" |
        sed -e "s/^sigma_t = .*/sigma_t = $(python3 -c "print(0.1 * $tn / 64)")\nemission = 1.0/" \
            -e 's/^directions_per_face = 4$/directions_per_face = 4\nmax_orders = 1\nemission_uncollided = "traced"/' \
            >"$scratch/trace_$tn.toml"
    echo "+ $lpm solve $scratch/trace_$tn.toml --out $tdir --no-image (emission traced, one order)"
    row "| emission trace | size | emitters | clusters taken whole / exact near / far pairs | trace | where |"
    row "|---|---|---|---|---|---|"
    if ! timeout "$step" "$lpm" solve "$scratch/trace_$tn.toml" --out "$tdir" --no-image >/dev/null 2>"$tlog"; then
        keep_tail "$tlog"
        row "| emission trace | ${tn}³ | failed or timed out: see trace.log | | | |"
    else
        python3 - "$tdir/report.json" "$tn" >>"$out/table.md" <<'EOF'
import json, re, sys
r = json.load(open(sys.argv[1]))
phases = {p["phase"]: p["seconds"] for p in r["seconds"]}
note = next((x for x in r["plan"]["reasons"] if x.startswith("emission trace:")), "")
m = re.search(r"(\d+) emitters.*?(\d+) clusters taken whole, (\d+) exact near pairs, (\d+) far pairs", note)
where = re.search(r"(on the (GPU|host).*)$", note)
e, c, n, f = m.groups() if m else ("?", "?", "?", "?")
print(f"| emission trace | {sys.argv[2]}³ | {e} | {c} / {n} / {f} | {phases.get('emission trace', float('nan')):.2f} s | "
      f"{where.group(1) if where else '?'} |")
EOF
        tail -n 1 "$out/table.md"
    fi
    row ""
}

case "$mode" in
    prepare) prepare ;;
    tests) tests ;;
    bench) bench ;;
    *)
        echo "usage: bash tools/gpu-bench.sh prepare|tests|bench" >&2
        exit 2
        ;;
esac
