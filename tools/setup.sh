#!/usr/bin/env bash
# Installs the system packages lpm needs, only those missing: the Vulkan loader, Mesa's lavapipe
# (a CPU Vulkan driver, so everything runs without a GPU), the Khronos validation layer, and
# glslang/spirv-tools to compile the shaders, OpenVDB's Python module (python3-openvdb: the tests
# write and read their .vdb files with the reference implementation) and NanoVDB's converter
# (libnanovdb-tools: nanovdb_convert writes the tests' .nvdb files). Sourced by demo.sh and test.sh.
set -euo pipefail

# `lpm serve` links the system SQLite (libsqlite3-dev, pkg-config); the Slurm array test starts a
# single-node slurmctld + slurmd (slurm-wlm), and tools/slurm-local.sh one authenticated by munge.
packages=(libvulkan1 mesa-vulkan-drivers vulkan-validationlayers glslang-tools spirv-tools
    libsqlite3-dev pkg-config slurm-wlm munge python3-openvdb libnanovdb-tools)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
    echo "lpm setup: installing ${missing[*]}"
    sudo=""
    if [ "$(id -u)" -ne 0 ]; then
        command -v sudo >/dev/null || { echo "lpm setup: need root or sudo to install ${missing[*]}" >&2; exit 1; }
        sudo="sudo"
    fi
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
command -v cargo >/dev/null || { echo "lpm setup: cargo not found; install Rust (https://rustup.rs)" >&2; exit 1; }
