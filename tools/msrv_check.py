#!/usr/bin/env python3
"""Checks the declared MSRV against the locked dependencies (run by tools/test.sh).

Only the stable toolchain exists here and rustup cannot fetch another, so lpm cannot be *built* with
its declared rust-version. Two checks stand in: clippy's `msrv` (clippy.toml) flags std APIs newer
than it in lpm's own code, and this script fails when a locked dependency declares a newer
rust-version than Cargo.toml (read from the registry sources cargo has already fetched).
"""
import glob, json, os, re, subprocess, sys

root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
declared = re.search(r'^rust-version\s*=\s*"([0-9.]+)"', open(os.path.join(root, "Cargo.toml")).read(), re.M)
if not declared:
    sys.exit("Cargo.toml declares no rust-version")
clippy = re.search(r'^msrv\s*=\s*"([0-9.]+)"', open(os.path.join(root, "clippy.toml")).read(), re.M)
if not clippy or clippy.group(1) != declared.group(1):
    sys.exit(f"clippy.toml's msrv must equal Cargo.toml's rust-version {declared.group(1)}")


def key(v):
    return tuple(int(x) for x in (v.split(".") + ["0", "0"])[:3])


lock = open(os.path.join(root, "Cargo.lock")).read()
newer, checked = [], 0
home = os.environ.get("CARGO_HOME", os.path.expanduser("~/.cargo"))
# Only the packages built for this machine's target: the lock file also names ones for other
# targets (wasip2 for wasm), never compiled here, whose sources another build may have fetched.
host = re.search(r"^host: (\S+)$", subprocess.run(["rustc", "-vV"], capture_output=True, text=True, check=True).stdout, re.M)
meta = json.loads(subprocess.run(
    ["cargo", "metadata", "--format-version", "1", "--filter-platform", host.group(1)],
    cwd=root, capture_output=True, text=True, check=True).stdout)
built = {(p["name"], p["version"]) for p in meta["packages"]}
for name, version in re.findall(r'\[\[package\]\]\nname = "([^"]+)"\nversion = "([^"]+)"\nsource = "registry', lock):
    if (name, version) not in built:
        continue
    found = glob.glob(os.path.join(home, "registry", "src", "*", f"{name}-{version}", "Cargo.toml"))
    if not found:
        continue
    checked += 1
    m = re.search(r'^rust-version\s*=\s*"([0-9.]+)"', open(found[0]).read(), re.M)
    if m and key(m.group(1)) > key(declared.group(1)):
        newer.append(f"{name} {version} needs Rust {m.group(1)}")
if newer:
    sys.exit(f"declared rust-version {declared.group(1)} is below what the lockfile needs: " + "; ".join(newer))
print(f"msrv check: rust-version {declared.group(1)} covers the {checked} locked registry packages found")
