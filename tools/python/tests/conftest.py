"""Shared pieces of the Python module's tests: small scenes (16³–32³, so the whole file runs in
about a minute on lavapipe or the CPU backend) and the `lpm` binary the results are held against."""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def lpm_cli():
    """The `lpm` binary of this repository: $LPM_CLI (tools/test.sh sets it to the binary its
    cargo test built), else target/debug/lpm or target/release/lpm, whichever is newer. No binary
    fails the test that needs it (it is never skipped)."""
    named = os.environ.get("LPM_CLI")
    if named:
        path = Path(named)
        assert path.is_file(), f"LPM_CLI={named} is not a file"
        return path
    found = [p for p in (REPO / "target/debug/lpm", REPO / "target/release/lpm") if p.is_file()]
    assert found, "no lpm binary: build one with `cargo build --bin lpm` (tools/test.sh does) or set LPM_CLI"
    return max(found, key=lambda p: p.stat().st_mtime)


def run_cli(cli, *args, check=True):
    """Runs `lpm ARGS`; returns the CompletedProcess (text)."""
    env = dict(os.environ, LPM_LOG="warn")
    done = subprocess.run([str(cli), *map(str, args)], capture_output=True, text=True, env=env)
    if check:
        assert done.returncode == 0, f"lpm {' '.join(map(str, args))} failed:\n{done.stderr}"
    return done


def blob(shape=(24, 20, 16), seed=3, dtype=np.float32):
    """A lumpy blob of medium indexed [x, y, z], not symmetric in any axis (so a swapped axis shows)."""
    rng = np.random.default_rng(seed)
    axes = [(np.arange(n) + 0.5) / n * 2 - 1 for n in shape]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    d = np.clip(1.0 - np.sqrt((x - 0.1) ** 2 + (1.3 * y) ** 2 + (0.8 * (z + 0.15)) ** 2), 0, None)
    d *= 1.0 + 0.3 * rng.random(shape)
    return d.astype(dtype)


def scene_dict(volume, albedo=0.9, **solver):
    """A small scene over `volume` (an array, or a dict of volume keys): sky and sun, k = 2."""
    volume = volume if isinstance(volume, dict) else {"raw": volume, "voxel_size": 1.0}
    return {
        "volume": volume,
        "medium": {"sigma_t": 0.8, "albedo": albedo},
        "lights": [
            {"kind": "sky", "radiance": 0.5},
            {"kind": "sun", "direction": [0.3, -0.4, 0.8], "irradiance": 2.0},
        ],
        "solver": {"directions_per_face": 2, "max_orders": 16, "tolerance": 1e-3, **solver},
        "camera": {"width": 40, "height": 30},
    }


def same_bits(a, b):
    """Arrays equal bit for bit (NaN included)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()
