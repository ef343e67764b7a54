#!/usr/bin/env bash
# Builds lpm and solves the demo cloud (sun + sky, multiple scattering) on the Vulkan device,
# writing fluence, source, report and image.{exr,png} to out/demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
cargo build --release
out=${1:-out/demo}
./target/release/lpm solve tools/scenes/demo_cloud.toml --out "$out"
echo "demo: image at $out/image.png (linear HDR in $out/image.exr), report at $out/report.json"
