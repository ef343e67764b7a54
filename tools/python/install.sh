#!/usr/bin/env bash
# Builds the `lpm` Python module (this directory: the crate in Cargo.toml, the package in python/)
# and installs it into tools/python/.venv, created if missing. One command:
#
#     bash tools/python/install.sh            # then: tools/python/.venv/bin/python -c 'import lpm'
#
# The virtual environment is made from Debian's python3 with --system-site-packages so that
# Debian's python3-openvdb (`import pyopenvdb`, used by the VDB example and tests) is seen in it;
# NumPy stays below 2 there because that pyopenvdb is built against NumPy 1. The build is maturin's
# (`maturin develop`) in the Cargo profile LPM_PYTHON_PROFILE, by default `release`; the first one
# compiles the lpm library as a dependency (8-12 minutes on 2 cores), later ones only what changed.
# Its target folder is LPM_PYTHON_TARGET, by default ~/.cache/lpm/python-target: outside the
# checkout, so that a fresh clone on the same machine rebuilds only what differs instead of
# everything, as cargo's own registry cache spares it the downloads. tools/test.sh builds it in
# the test build's own folder and profile instead (LPM_PYTHON_TARGET=target, LPM_PYTHON_PROFILE=dev;
# this crate's dev profile is the main crate's): the dependencies both share are compiled once.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
cd "$here"
python=/usr/bin/python3
packages=(python3-venv python3-openvdb)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
    echo "lpm python: installing ${missing[*]}"
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
if [ ! -x .venv/bin/python ]; then
    "$python" -m venv --system-site-packages .venv
fi
.venv/bin/pip install -q --disable-pip-version-check "numpy>=1.21,<2" "maturin>=1.5,<2" pytest matplotlib
target="${LPM_PYTHON_TARGET:-${XDG_CACHE_HOME:-$HOME/.cache}/lpm/python-target}"
mkdir -p "$target"
VIRTUAL_ENV="$here/.venv" PATH="$here/.venv/bin:$PATH" CARGO_TARGET_DIR="$target" \
    .venv/bin/maturin develop --profile "${LPM_PYTHON_PROFILE:-release}" --quiet
.venv/bin/python -c 'import lpm; print("lpm python module installed in", __import__("sys").prefix)'
