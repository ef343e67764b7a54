"""A notebook-style session: build a cloud as a NumPy array, solve it with lpm, and plot a slice
of the fluence and the rendered image with matplotlib.

    python cloud_numpy.py                       # 48³ cloud on the GPU backend, into out/cloud-numpy
    python cloud_numpy.py --size 24 --backend cpu --out /tmp/cloud

The array is indexed [x, y, z] (z is up for this scene's camera); lpm takes the dims from its
shape. Writes OUT/cloud.png (slice + image) beside lpm's own outputs (fluence.*, image.png, ...).
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # a file, no window: the same in a notebook with %matplotlib inline removed
import matplotlib.pyplot as plt
import numpy as np

import lpm


def cloud(n, seed=1):
    """A puffy cloud: a few Gaussian blobs around a flattened ellipsoid, density in [0, 1]."""
    rng = np.random.default_rng(seed)
    axis = (np.arange(n) + 0.5) / n * 2 - 1
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")  # indexed [x, y, z]
    density = np.exp(-((x / 0.55) ** 2 + (y / 0.55) ** 2 + ((z + 0.1) / 0.35) ** 2) * 2)
    for _ in range(8):
        c = rng.uniform(-0.4, 0.4, 3) * [1, 1, 0.6]
        r = rng.uniform(0.15, 0.3)
        density += 0.6 * np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / r**2)
    density[density < 0.05] = 0.0  # empty space: empty 16³ bricks are neither stored nor solved
    return np.clip(density, 0.0, 1.0).astype(np.float32)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=48)
    parser.add_argument("--backend", default="gpu", choices=["gpu", "cpu"])
    parser.add_argument("--out", type=Path, default=Path("out/cloud-numpy"))
    args = parser.parse_args()
    n = args.size

    density = cloud(n)
    scene = {
        "volume": {"raw": density, "voxel_size": 1.0},
        "medium": {"sigma_t": 0.6, "albedo": 0.95},
        "lights": [
            {"kind": "sky", "radiance": [0.30, 0.45, 0.75]},
            {"kind": "sun", "direction": [-0.55, -0.35, 0.75], "irradiance": [3.2, 3.0, 2.7]},
        ],
        "solver": {"directions_per_face": 3, "max_orders": 64, "tolerance": 1e-3},
        "camera": {
            "position": [n / 2, -0.95 * n, 0.7 * n],
            "look_at": [n / 2, n / 2, 0.45 * n],
            "up": [0, 0, 1],
            "width": 320,
            "height": 240,
        },
    }

    def progress(event):
        print(f"  {event['message']}", flush=True)

    result = lpm.solve(scene, out=args.out, backend=args.backend, progress=progress)
    report = result.report
    print(f"solved in {report['orders']} orders, residual {report['final_residual']:.2e}")

    fluence = result.fluence  # [x, y, z, channel], memory-mapped: nothing is read until plotted
    k = n // 2
    luminance = fluence[:, :, k, :] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    rgba = result.render()  # the solve's own view; render(eye=..., width=...) gives others

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    # imshow's first axis is the row: transpose [x, y] so that x runs right and y up.
    shown = left.imshow(luminance.T, origin="lower", cmap="magma")
    left.set_title(f"fluence at z = {k} (NaN: empty bricks)")
    left.set_xlabel("x")
    left.set_ylabel("y")
    fig.colorbar(shown, ax=left)
    right.imshow(np.clip(rgba[..., :3], 0, 1) ** (1 / 2.2))
    right.set_title("image (linear → gamma 2.2)")
    right.axis("off")
    fig.tight_layout()
    png = args.out / "cloud.png"
    fig.savefig(png, dpi=80)
    print(f"wrote {png}")


if __name__ == "__main__":
    main()
