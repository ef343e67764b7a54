#!/usr/bin/env python3
"""PNGs side by side, each as it is (8-bit RGB or RGBA over black), on one row with a 4-pixel black
gap; images of different heights are padded at the bottom. Pure Python (no NumPy or Pillow). Used
for benches/RESULTS.md's figures where the panels were tone-mapped alike by lpm itself.

    python3 tools/side_by_side.py A.png B.png [C.png ...] OUT.png"""
import sys

from contrast_pair import read_rgb, write_png  # tools/ is the script's own folder


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    panels = [read_rgb(p) for p in sys.argv[1:-1]]
    gap = 4
    width = sum(p[0] for p in panels) + gap * (len(panels) - 1)
    height = max(p[1] for p in panels)
    rows = []
    for y in range(height):
        row = bytearray()
        for i, (w, h, pixels) in enumerate(panels):
            if i:
                row += bytes(3 * gap)
            row += bytes(pixels[y]) if y < h else bytes(3 * w)
        rows.append(row)
    write_png(sys.argv[-1], width, height, rows, colour=2)


if __name__ == "__main__":
    main()
