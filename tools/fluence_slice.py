#!/usr/bin/env python3
"""One z slice of the fluence of several output directories, side by side, on one log scale, then
each but the last against the last (the reference) as an error map: red where above, blue where
below, full at ±RANGE. Pure Python (no NumPy or Pillow). Used for benches/RESULTS.md's figures
where an image would be too noisy (a Monte-Carlo reference's fluence is far less noisy than its
image).

    python3 tools/fluence_slice.py Z OUT.png DIR [DIR ...] REFERENCE_DIR [--range 0.2] [--scale 4]

Each DIR holds fluence.json and fluence.raw (f32, components fastest, then x, y, z); the slice
shows the mean over the components. Voxels with no value (NaN: lpm's empty bricks, which it does
not solve) and voxels where the reference is 0 are black."""
import json
import math
import os
import struct
import sys

from contrast_pair import write_png  # tools/ is the script's own folder


def read_slice(directory, z):
    meta = json.load(open(os.path.join(directory, "fluence.json")))
    nx, ny, nz = meta["dims"]
    c = meta["components"]
    if not 0 <= z < nz:
        sys.exit(f"{directory}: slice {z} outside 0..{nz - 1}")
    if meta["dtype"] != "f32" or meta["endianness"] != "little":
        sys.exit(f"{directory}: fluence.raw must be little-endian f32")
    count = nx * ny * c
    with open(os.path.join(directory, meta.get("file", "fluence.raw")), "rb") as f:
        f.seek(z * count * 4)
        data = f.read(count * 4)
    if len(data) != count * 4:
        sys.exit(f"{directory}: fluence.raw is truncated")
    values = struct.unpack(f"<{count}f", data)
    rows = [[sum(values[(y * nx + x) * c:(y * nx + x + 1) * c]) / c for x in range(nx)] for y in range(ny)]
    return nx, ny, rows


def main():
    args = sys.argv[1:]
    options = {"--range": 0.2, "--scale": 4}
    for key in list(options):
        if key in args:
            i = args.index(key)
            options[key] = float(args[i + 1]) if key == "--range" else int(args[i + 1])
            del args[i:i + 2]
    if len(args) < 4:
        sys.exit(__doc__)
    z, out, dirs = int(args[0]), args[1], args[2:]
    slices = [read_slice(d, z) for d in dirs]
    nx, ny = slices[0][0], slices[0][1]
    if any((w, h) != (nx, ny) for w, h, _ in slices):
        sys.exit("the directories' volumes differ in size")
    positive = [v for _, _, rows in slices for r in rows for v in r if v > 0 and math.isfinite(v)]
    if not positive:
        sys.exit("no positive fluence in the slice")
    positive.sort()
    low, high = math.log(positive[len(positive) // 100]), math.log(positive[-1])
    reference = slices[-1][2]
    scale, gap, span = options["--scale"], 4, options["--range"]

    def grey(v):
        g = 0 if not v > 0 else round(255 * min(1.0, max(0.0, (math.log(v) - low) / (high - low))))
        return (g, g, g)

    def error(v, r):
        if not (r > 0 and math.isfinite(v)):
            return (0, 0, 0)
        t = min(1.0, abs(v / r - 1.0) / span)
        return (round(255 * t), 0, 0) if v > r else (0, 0, round(255 * t))

    panels = [[[grey(v) for v in row] for row in rows] for _, _, rows in slices]
    panels += [[[error(v, r) for v, r in zip(row, ref_row)] for row, ref_row in zip(rows, reference)]
               for _, _, rows in slices[:-1]]
    width = len(panels) * nx * scale + gap * (len(panels) - 1)
    lines = []
    for y in reversed(range(ny)):  # y up
        line = bytearray()
        for i, panel in enumerate(panels):
            if i:
                line += bytes([255, 255, 255] * gap)
            for px in panel[y]:
                line += bytes(px) * scale
        lines += [line] * scale
    write_png(out, width, ny * scale, lines, colour=2)
    print(f"{out}: {len(dirs)} slices at z = {z} (log scale), then {len(dirs) - 1} error maps (±{span:.0%})")


if __name__ == "__main__":
    main()
