"""Reads a VDB file lpm wrote with the reference implementation (OpenVDB's Python module, Debian's
python3-openvdb) and dumps what OpenVDB makes of it, for tests/it/vdb_output.rs.

Usage: /usr/bin/python3 read_vdb.py FILE.vdb OUT_PREFIX I0 J0 K0 NX NY NZ
Writes OUT_PREFIX.json (per grid: type, half flag, class, active count, active bounding box, the
world position of index (0, 0, 0) and of index (1, 1, 1)) and, per grid, OUT_PREFIX.<grid>.raw (the
values over the index box [I0, I0+NX) × … as little-endian f32, x fastest) and
OUT_PREFIX.<grid>.active (one byte per voxel of the box, 1 where the voxel is active).
"""
import json
import sys

import numpy as np
import pyopenvdb as vdb

path, prefix = sys.argv[1], sys.argv[2]
lo = [int(v) for v in sys.argv[3:6]]
n = [int(v) for v in sys.argv[6:9]]
grids, _ = vdb.readAll(path)
info = {}
for g in grids:
    acc = g.getConstAccessor()
    values = np.zeros((n[2], n[1], n[0]), dtype="<f4")
    active = np.zeros((n[2], n[1], n[0]), dtype=np.uint8)
    for k in range(n[2]):
        for j in range(n[1]):
            for i in range(n[0]):
                v, on = acc.probeValue((lo[0] + i, lo[1] + j, lo[2] + k))
                values[k, j, i] = v
                active[k, j, i] = 1 if on else 0
    values.tofile(f"{prefix}.{g.name}.raw")
    active.tofile(f"{prefix}.{g.name}.active")
    bmin, bmax = g.evalActiveVoxelBoundingBox()
    info[g.name] = {
        "type": g.valueTypeName,
        "half": bool(g.saveFloatAsHalf),
        "class": g.gridClass,
        "active": g.activeVoxelCount(),
        "bbox_min": list(bmin),
        "bbox_max": list(bmax),
        "index0_world": list(g.transform.indexToWorld((0, 0, 0))),
        "index1_world": list(g.transform.indexToWorld((1, 1, 1))),
        "leaves": g.leafCount(),
        "lpm_quantity": g["lpm_quantity"] if "lpm_quantity" in g else None,
    }
with open(f"{prefix}.json", "w") as f:
    json.dump(info, f)
