#!/usr/bin/env python3
"""Two 8-bit PNGs of the same size side by side, grey, contrast stretched together (pure Python:
no NumPy or Pillow needed). Used for benches/RESULTS.md's before/after figures, where a seam of a
few per cent must show.

    python3 tools/contrast_pair.py BEFORE.png AFTER.png OUT.png [LOW HIGH]

Pixels are composited over black (RGBA), turned to luminance, and LOW..HIGH (default: the 2nd and
99.5th percentile of the non-black pixels of both) is stretched to 0..255."""
import struct
import sys
import zlib


def read_rgb(path):
    """An 8-bit RGB or RGBA PNG as (width, height, rows of r, g, b bytes composited over black)."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    w, h, depth, colour = header[:4]
    assert depth == 8 and colour in (2, 6), "8-bit RGB or RGBA only"
    bpp = 3 if colour == 2 else 4
    raw, stride, rows, prev = zlib.decompress(idat), w * bpp, [], bytearray(w * bpp)
    for y in range(h):
        f, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            b, c = prev[i], prev[i - bpp] if i >= bpp else 0
            if f == 1:
                line[i] = (line[i] + a) & 255
            elif f == 2:
                line[i] = (line[i] + b) & 255
            elif f == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        prev = line
        out = bytearray()
        for x in range(w):
            p = line[x * bpp:(x + 1) * bpp]
            alpha = p[3] / 255 if bpp == 4 else 1.0
            out += bytes(round(v * alpha) for v in p[:3])
        rows.append(out)
    return w, h, rows


def read_png(path):
    """An 8-bit RGB or RGBA PNG's luminance (over black), as (width, height, rows of floats)."""
    w, h, rows = read_rgb(path)
    lum = [[0.2126 * r[3 * x] + 0.7152 * r[3 * x + 1] + 0.0722 * r[3 * x + 2] for x in range(w)] for r in rows]
    return w, h, lum


def write_png(path, w, h, rows, colour=0):
    """Rows of 8-bit grey (colour 0) or RGB (colour 2) values."""
    raw = b"".join(b"\x00" + bytes(r) for r in rows)
    chunk = lambda k, b: struct.pack(">I", len(b)) + k + b + struct.pack(">I", zlib.crc32(k + b) & 0xFFFFFFFF)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0))
    open(path, "wb").write(png + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def main():
    (wa, ha, a), (wb, hb, b) = read_png(sys.argv[1]), read_png(sys.argv[2])
    assert (wa, ha) == (wb, hb), "images of one size"
    if len(sys.argv) > 5:
        low, high = float(sys.argv[4]), float(sys.argv[5])
    else:
        values = sorted(v for img in (a, b) for r in img for v in r if v > 0)
        low, high = values[len(values) * 2 // 100], values[len(values) * 995 // 1000]
    gap = 4
    rows = []
    for y in range(ha):
        line = [min(255, max(0, round((v - low) / (high - low) * 255))) if v > 0 else 0 for v in a[y]]
        line += [255] * gap
        line += [min(255, max(0, round((v - low) / (high - low) * 255))) if v > 0 else 0 for v in b[y]]
        rows.append(line)
    write_png(sys.argv[3], 2 * wa + gap, ha, rows)
    print(f"stretched {low:.1f}..{high:.1f} to 0..255: {sys.argv[3]}")


if __name__ == "__main__":
    main()
