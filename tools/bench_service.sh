#!/usr/bin/env bash
# Jobs per hour for small scenes: N solves run one by one with `lpm solve`, against the same N
# submitted at once to `lpm serve` (one worker) and waited for. The difference is the service's
# overhead (queue, child process, polling). Usage: tools/bench_service.sh [N] [LPM binary]
# Prints one line per mode; record the figures in benches/RESULTS.md.
set -euo pipefail
n=${1:-10}
lpm=${2:-target/release/lpm}
command -v jq >/dev/null || { echo "bench_service: needs jq" >&2; exit 1; }
work=$(mktemp -d)
server_pid=""
cleanup() { [ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT
cat > "$work/scene.toml" <<'TOML'
[volume]
procedural = "cloud"
dims = [24, 24, 24]
seed = 5
[medium]
sigma_t = 0.8
albedo = 0.8
[[lights]]
kind = "sky"
radiance = 1.0
[solver]
directions_per_face = 2
max_orders = 4
tolerance = 1e-12
TOML

start=$(date +%s.%N)
for i in $(seq 1 "$n"); do
    "$lpm" --log warn solve "$work/scene.toml" --out "$work/cli-$i" --no-image >/dev/null
done
cli=$(echo "$(date +%s.%N) - $start" | bc -l)

"$lpm" --log warn serve --listen 127.0.0.1:0 --data "$work/data" > "$work/serve.out" &
server_pid=$!
for _ in $(seq 1 100); do grep -q listening "$work/serve.out" 2>/dev/null && break; sleep 0.1; done
url=$(grep -o 'http://[^ ]*' "$work/serve.out")
start=$(date +%s.%N)
for i in $(seq 1 "$n"); do
    "$lpm" --log warn submit "$work/scene.toml" --server "$url" --no-image >/dev/null
done
while [ "$("$lpm" --log warn status --server "$url" | jq '[.jobs[] | select(.state == "done")] | length')" -lt "$n" ]; do
    sleep 0.2
done
served=$(echo "$(date +%s.%N) - $start" | bc -l)
echo "cli:    $n solves in $cli s: $(echo "3600 * $n / $cli" | bc -l | cut -d. -f1) jobs/hour"
echo "server: $n solves in $served s: $(echo "3600 * $n / $served" | bc -l | cut -d. -f1) jobs/hour"
