#!/usr/bin/python3
"""Writes the example fire of tools/scenes/fire.toml: an OpenVDB file with a `density` and a
`temperature` grid (kelvin), as a fire simulation from Houdini, Blender or EmberGen would.

    /usr/bin/python3 tools/fire_vdb.py tools/scenes/fire.vdb [N]

N (default 80) is the volume's width in voxels; the volume is N × 1.5N × N, y up, voxel size 3/N
world units (metres): 3 m wide, 4.5 m tall whatever N. Needs OpenVDB's Python module and numpy
(Debian: python3-openvdb, python3-numpy; tools/setup.sh installs them).

The shape is procedural, not simulated: a flame (hot, thin: a teardrop of 900–2000 K over the
burner, flickering with noise) rising into a plume of cooler smoke that widens as it climbs. The
noise is seeded, so the file is the same on every run.
"""
import sys

import numpy as np
import pyopenvdb as vdb


def value_noise(shape, cells, rng):
    """Trilinear value noise in [-1, 1] over `shape`, with `cells` lattice cells along each axis."""
    lattice = rng.uniform(-1.0, 1.0, size=tuple(c + 2 for c in cells))
    axes = [np.linspace(0.0, c, n, endpoint=False) for n, c in zip(shape, cells)]
    idx = [np.floor(a).astype(int) for a in axes]
    frac = [a - i for a, i in zip(axes, idx)]
    frac = [f * f * (3.0 - 2.0 * f) for f in frac]  # smoothstep: no creases at cell faces
    out = np.zeros(shape)
    for dx in (0, 1):
        wx = frac[0] if dx else 1.0 - frac[0]
        for dy in (0, 1):
            wy = frac[1] if dy else 1.0 - frac[1]
            for dz in (0, 1):
                wz = frac[2] if dz else 1.0 - frac[2]
                corner = lattice[np.ix_(idx[0] + dx, idx[1] + dy, idx[2] + dz)]
                out += corner * wx[:, None, None] * wy[None, :, None] * wz[None, None, :]
    return out


def fbm(shape, base, octaves, rng):
    """Fractal sum of value noise: octaves of doubling frequency and halving amplitude."""
    total = np.zeros(shape)
    amplitude, norm = 1.0, 0.0
    for o in range(octaves):
        cells = [max(1, int(round(b * 2**o))) for b in base]
        total += amplitude * value_noise(shape, cells, rng)
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def smoothstep(a, b, x):
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    path = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) == 3 else 80
    nx, ny, nz = n, (3 * n) // 2, n
    rng = np.random.default_rng(7)
    # Voxel-centre coordinates: x, z in [-0.5, 0.5] across, y in [0, 1.5] up (units of the width).
    x = (np.arange(nx) + 0.5) / n - 0.5
    y = (np.arange(ny) + 0.5) / n
    z = (np.arange(nz) + 0.5) / n - 0.5
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    # Turbulence: the plume's axis wanders with height and every point is pushed around a little.
    wobble = fbm((nx, ny, nz), (3, 4, 3), 4, rng)
    sway_x = 0.06 * np.sin(5.0 * Y + 0.7) * smoothstep(0.1, 1.0, Y)
    sway_z = 0.05 * np.sin(4.0 * Y + 2.1) * smoothstep(0.1, 1.0, Y)
    r = np.sqrt((X - sway_x) ** 2 + (Z - sway_z) ** 2) * (1.0 + 0.35 * wobble)

    # Flame: a teardrop over the burner (y ≈ 0.05), up to ~0.8 high, hottest low in its core.
    height = 0.8 * (1.0 + 0.3 * fbm((nx, ny, nz), (3, 4, 3), 3, rng))
    h = np.clip((Y - 0.04) / height, 0.0, 1.0)
    flame_radius = 0.4 * np.sqrt(h) * (1.0 - h) ** 0.6 + 1e-6
    inside = np.clip(1.0 - (r / flame_radius) ** 2, 0.0, 1.0) * (Y > 0.04)
    flicker = fbm((nx, ny, nz), (6, 8, 6), 3, rng)
    heat = np.clip(inside * (1.0 - 0.55 * h) * (1.0 + 0.5 * flicker), 0.0, 1.0)
    temperature = np.where(heat > 0.0, 900.0 + 1100.0 * heat, 300.0)

    # Smoke: a plume widening as it climbs, thin around the flame, thickest above it.
    plume_radius = 0.14 + 0.20 * smoothstep(0.1, 1.4, Y)
    detail = fbm((nx, ny, nz), (5, 7, 5), 4, rng)
    plume = np.clip(1.0 - (r / plume_radius) ** 2, 0.0, 1.0) ** 0.8
    rise = 0.35 + 0.65 * smoothstep(0.2, 0.8, Y)
    fade = 1.0 - smoothstep(1.2, 1.5, Y)
    density = plume * rise * fade * np.clip(0.6 + 1.2 * detail, 0.0, None) ** 1.5
    # Fire glows where there is medium to emit: give the flame a little soot of its own.
    density = np.maximum(density, 0.35 * inside)

    grids = []
    for name, values, background in (("density", density, 0.0), ("temperature", temperature, 300.0)):
        g = vdb.FloatGrid(background)
        g.name = name
        # Voxels at the background are left inactive (sparse), the rest copied.
        g.copyFromArray(values.astype(np.float32), tolerance=1e-6)
        g.transform = vdb.createLinearTransform(voxelSize=3.0 / n)
        grids.append(g)
    vdb.write(path, grids=grids)
    hot = int((temperature >= 500.0).sum())
    print(f"{path}: density and temperature over {nx}x{ny}x{nz} voxels, {hot} above 500 K, "
          f"peak {temperature.max():.0f} K")


if __name__ == "__main__":
    main()
