#!/usr/bin/env bash
# Compiles every glsl/*.comp to spirv/<name>.spv (files ending in .glsl are includes, not compiled).
# The output is deterministic, so tests/it/spirv_current.rs can check the committed SPIR-V is current.
# Runs from any directory. Needs glslangValidator (Debian package glslang-tools).
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."

if ! command -v glslangValidator >/dev/null 2>&1; then
    echo "glslangValidator not found: install the Debian package glslang-tools" >&2
    exit 1
fi

mkdir -p spirv
shopt -s nullglob
count=0
for src in glsl/*.comp; do
    name="$(basename "$src" .comp)"
    # `-Iglsl` without a space: glslang 11 rejects `-I glsl`. glslang prints diagnostics on stdout,
    # so show its output only when it fails.
    if ! out="$(glslangValidator -V --target-env vulkan1.2 -Iglsl -o "spirv/$name.spv" "$src" 2>&1)"; then
        echo "$out" >&2
        echo "failed to compile $src" >&2
        exit 1
    fi
    count=$((count + 1))
done
echo "compiled $count shader(s) into spirv/"
