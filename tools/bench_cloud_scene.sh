#!/usr/bin/env bash
# Prints the benchmark scene of tools/gpu-bench.sh and tools/converge_table.sh at N³ voxels: an RGB
# procedural cloud (σt = [0.9, 0.8, 0.7] at density 1, albedo [0.9, 0.85, 0.8]) under a blue sky
# and a sun, k = 4 (96 directions). The voxel size is 64/N, so every N is the same cloud.
#
#   tools/bench_cloud_scene.sh N > scene.toml
set -euo pipefail
n=${1:?usage: tools/bench_cloud_scene.sh N}
cat <<TOML
[volume]
procedural = "cloud"
dims = [$n, $n, $n]
voxel_size = $(python3 -c "print(64 / $n)")
seed = 1
[medium]
sigma_t = [0.9, 0.8, 0.7]
albedo = [0.9, 0.85, 0.8]
[[lights]]
kind = "sky"
radiance = [0.30, 0.45, 0.75]
[[lights]]
kind = "sun"
direction = [-0.55, -0.35, 0.75]
irradiance = [3.2, 3.0, 2.7]
[solver]
directions_per_face = 4
TOML
