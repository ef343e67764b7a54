#!/usr/bin/env bash
# Compiles every glsl/*.comp to spirv/<name>.spv (glsl/*.glsl are includes). The SPIR-V is
# committed; tests/spirv_current.rs fails when it is out of date with the GLSL.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v glslangValidator >/dev/null || { echo "glslangValidator not found: apt-get install glslang-tools" >&2; exit 1; }
mkdir -p spirv
for src in glsl/*.comp; do
    name=$(basename "$src" .comp)
    glslangValidator -V --target-env vulkan1.2 -Iglsl -o "spirv/$name.spv" "$src" >/dev/null
    echo "spirv/$name.spv"
done
