"""Writes the VDB test files with the reference implementation (OpenVDB's Python module, Debian's
python3-openvdb) and, for each grid, what OpenVDB itself reads back: the active-voxel bounding box,
the transform, and the values over the box as little-endian f32, x fastest (a raw lpm volume).

Usage: /usr/bin/python3 write_vdb.py OUT_DIR
Writes OUT_DIR/<case>.vdb and OUT_DIR/<case>.json (+ <case>.<grid>.raw for boxes small enough).
"""
import json
import os
import sys

import numpy as np
import pyopenvdb as vdb

out = sys.argv[1]
os.makedirs(out, exist_ok=True)
rng = np.random.default_rng(12345)
DENSE_LIMIT = 40_000_000  # voxels: boxes larger than this are checked at sample points only


def cloud(name, origin, size, scale=1.0):
    """A grid with a smooth blob (compressible leaves) plus noise (incompressible leaves)."""
    g = vdb.FloatGrid()
    g.name = name
    n = size
    x, y, z = np.meshgrid(*(np.arange(n, dtype=np.float32) for _ in range(3)), indexing="ij")
    c = (n - 1) / 2
    r2 = ((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2) / (c * c)
    blob = np.clip(1.0 - r2, 0.0, None).astype(np.float32) * scale
    noise = rng.random((n, n, n), dtype=np.float32) * (r2 < 1.2)
    arr = np.where((x + y) % 16 < 8, blob, noise * scale).astype(np.float32)
    g.copyFromArray(arr, ijk=origin, tolerance=0.0)
    return g


def add_tiles(g, base):
    """Active tiles at the leaf level (an 8³ node tile) and at the 128³ level."""
    b = base
    g.fill((b[0], b[1], b[2]), (b[0] + 7, b[1] + 7, b[2] + 7), 0.75, True)
    g.fill((b[0] + 128, b[1], b[2]), (b[0] + 255, b[1] + 127, b[2] + 127), 0.25, True)


def set_inactive(g, base):
    """Inactive voxels holding two distinct non-background values inside a leaf (mask compression
    with two inactive values and a selection mask)."""
    acc = g.getAccessor()
    for i in range(8):
        acc.setValueOff((base[0] + i, base[1], base[2]), 0.5 if i % 2 else 0.125)
        acc.setValueOn((base[0] + i, base[1] + 1, base[2]), 0.3 + i)


def describe(path, want_dense=True):
    """What OpenVDB reads back from `path`, grid by grid."""
    grids, _ = vdb.readAll(path)
    info = {}
    for g in grids:
        lo, hi = g.evalActiveVoxelBoundingBox()
        dims = [hi[i] - lo[i] + 1 for i in range(3)]
        t = g.transform
        entry = {
            "bbox_min": list(lo),
            "bbox_max": list(hi),
            "voxel_size": list(t.voxelSize()),
            "index0_world": list(t.indexToWorld((0, 0, 0))),
            "half": bool(g.saveFloatAsHalf),
            "background": g.background,
            "leaves": g.leafCount(),
            # Sample points (including outside the box, and inside tiles).
            "samples": [],
        }
        acc = g.getConstAccessor()
        pts = [tuple(lo), tuple(hi), (lo[0] - 1, lo[1], lo[2])]
        for _ in range(200):
            pts.append(tuple(int(rng.integers(lo[i], hi[i] + 1)) for i in range(3)))
        for p in pts:
            entry["samples"].append([list(p), float(acc.getValue(p))])
        n = dims[0] * dims[1] * dims[2]
        if want_dense and n <= DENSE_LIMIT:
            arr = np.zeros(dims, dtype=np.float32)
            g.copyToArray(arr, ijk=lo)
            raw = f"{os.path.splitext(path)[0]}.{g.name}.raw"
            np.ascontiguousarray(arr.transpose(2, 1, 0)).astype("<f4").tofile(raw)
            entry["raw"] = os.path.basename(raw)
        info[g.name] = entry
    with open(os.path.splitext(path)[0] + ".json", "w") as f:
        json.dump(info, f, indent=1)


def write(case, grids, half=False):
    for g in grids:
        g.saveFloatAsHalf = half
    path = os.path.join(out, case + ".vdb")
    vdb.write(path, grids=grids)
    describe(path)


# 1. float: a cloud at negative coordinates, tiles at the two internal levels, inactive values.
g = cloud("density", (-37, -5, -70), 40)
add_tiles(g, (-256, 128, -128))
set_inactive(g, (-32, 0, -64))
write("float", [g])

# 2. the same saved as half.
g = cloud("density", (-37, -5, -70), 40)
add_tiles(g, (-256, 128, -128))
set_inactive(g, (-32, 0, -64))
write("half", [g], half=True)

# 3. several grids, a voxel size and a translation.
d = cloud("density", (3, 9, -2), 24)
t = cloud("temperature", (0, 0, 0), 16, scale=1500.0)
f = cloud("flame", (100, 100, 100), 8)
for g in (d, t, f):
    tr = vdb.createLinearTransform(voxelSize=0.25)
    tr.translate((1.5, -2.0, 0.75))
    g.transform = tr
write("multi", [d, t, f])

# 4. a root-level tile (4096³ active): checked at sample points only.
g = vdb.FloatGrid()
g.name = "density"
g.fill((-4096, 0, 0), (-1, 4095, 4095), 0.5, True)
acc = g.getAccessor()
acc.setValueOn((5, 6, 7), 2.0)
path = os.path.join(out, "root_tile.vdb")
vdb.write(path, grids=[g])
describe(path)

# 5. a rotated transform (refused).
g = cloud("density", (0, 0, 0), 8)
tr = vdb.createLinearTransform(voxelSize=1.0)
tr.rotate(0.3, vdb.Axis.Z)
g.transform = tr
vdb.write(os.path.join(out, "rotated.vdb"), grids=[g])

# 6. a fog volume with every voxel active in a 40³ block (a solve compares it with the raw file).
g = cloud("density", (-8, 16, 4), 24)
g.gridClass = vdb.GridClass.FOG_VOLUME
write("solve", [g])

# 7. sparse: a few leaves at the corners and inside of an EDGE³ box (dense: EDGE³ × 4 bytes), for
# the out-of-core import (tests/vdb_sparse.rs).
for edge in (1024, 4096):
    g = vdb.FloatGrid()
    g.name = "density"
    acc = g.getAccessor()
    pts = [(0, 0, 0), (edge - 1, edge - 1, edge - 1), (edge // 3, 17, edge // 2), (5, edge - 9, 100)]
    for n, p in enumerate(pts):
        for d in range(8):
            acc.setValueOn((p[0], p[1], p[2] + (d if p[2] + d < edge else -d)), 0.5 + n + d / 8)
    path = os.path.join(out, f"sparse{edge}.vdb")
    vdb.write(path, grids=[g])
    describe(path)
