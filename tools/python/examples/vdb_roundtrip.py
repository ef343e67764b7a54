"""From a simulation's VDB to lpm and back: read a Houdini/EmberGen-style OpenVDB file with
pyopenvdb, solve its density grid with lpm, and write the fluence back as a grid beside the
density, on the same index grid and transform (what a Houdini or Blender user imports and plugs
into a volume shader, e.g. as emission for a pre-lit look).

    python vdb_roundtrip.py smoke.vdb smoke_lit.vdb [--grid density] [--sigma-t 20]
    python vdb_roundtrip.py --demo smoke.vdb smoke_lit.vdb    # writes a small smoke VDB first

The output holds the input's density grid unchanged and a `fluence` fog-volume grid (one per
channel, `fluence_r`, `_g`, `_b`, for a coloured scene).
"""

import argparse
from pathlib import Path

import numpy as np
import pyopenvdb as vdb

import lpm


def write_demo_smoke(path, n=24, voxel_size=0.05):
    """A small smoke puff as a simulation would write it: a `density` grid in a sparse tree, its
    voxels not starting at index 0, metres as world units."""
    axis = np.arange(n) - n / 2 + 0.5
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    density = np.clip(1.2 - np.sqrt(x**2 + y**2 + (1.5 * z) ** 2) / (n / 2.5), 0.0, 1.0)
    density += 0.2 * np.sin(x / 2.0) * np.cos(y / 3.0) * (density > 0)
    grid = vdb.FloatGrid()
    grid.copyFromArray(np.clip(density, 0.0, None).astype(np.float32), ijk=(-12, 5, 40))
    grid.name = "density"
    grid.gridClass = vdb.GridClass.FOG_VOLUME
    grid.transform = vdb.createLinearTransform(voxelSize=voxel_size)
    vdb.write(str(path), grids=[grid])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", type=Path)
    parser.add_argument("output", type=Path)
    parser.add_argument("--grid", default="density")
    parser.add_argument("--sigma-t", type=float, default=40.0, help="extinction per world unit at density 1")
    parser.add_argument("--backend", default="gpu", choices=["gpu", "cpu"])
    parser.add_argument("--out", type=Path, help="lpm's output directory (default: beside OUTPUT)")
    parser.add_argument("--demo", action="store_true", help="write a small smoke VDB to INPUT first")
    args = parser.parse_args()
    if args.demo:
        write_demo_smoke(args.input)

    density = vdb.read(str(args.input), args.grid)
    scene = {
        "volume": {"vdb": density},  # a pyopenvdb grid: placement and voxel size from its transform
        "medium": {"sigma_t": args.sigma_t, "albedo": 0.9},
        "lights": [
            {"kind": "sky", "radiance": 0.4},
            {"kind": "sun", "direction": [0.3, 0.5, 0.8], "irradiance": 3.0},
        ],
        "solver": {"directions_per_face": 3, "max_orders": 48, "tolerance": 1e-3},
    }
    out = args.out or args.output.with_suffix(".lpm")
    result = lpm.solve(scene, out=out, backend=args.backend, no_image=True)
    print(f"solved {args.input} in {result.report['orders']} orders; lpm's outputs in {out}")

    # lpm voxel (0, 0, 0) is the low corner of the grid's active bounding box, in index space.
    (lo, _hi) = density.evalActiveVoxelBoundingBox()
    fluence = result.fluence  # [x, y, z, channel], NaN where lpm solved nothing (empty bricks)
    names = result.field_info("fluence")["component_names"]
    grids = [density]
    for c, channel in enumerate(names):
        grid = vdb.FloatGrid()
        # pyopenvdb reads an array's memory as C order, ignoring strides: hand it a C-ordered copy
        # of the channel (the memory map is the file's layout, x fastest), NaN (not solved) as 0.
        channel_values = np.ascontiguousarray(np.nan_to_num(fluence[..., c], nan=0.0))
        grid.copyFromArray(channel_values, ijk=lo)
        grid.name = "fluence" if channel == "grey" else f"fluence_{channel}"
        grid.gridClass = vdb.GridClass.FOG_VOLUME
        grid.transform = density.transform
        grids.append(grid)
    vdb.write(str(args.output), grids=grids)
    print(f"wrote {args.output}: grids {', '.join(g.name for g in grids)}")


if __name__ == "__main__":
    main()
