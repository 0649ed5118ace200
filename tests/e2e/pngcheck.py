"""Reads 8-bit RGB PNGs (the window's screenshots) without third-party modules, and counts pixels.

Used by the window tests:  python3 pngcheck.py FILE NAME=x0,y0,x1,y1,EXPR ...
prints "NAME COUNT" for each region: the pixels (x0 <= x < x1, y0 <= y < y1) where EXPR, a Python
expression of r, g, b, holds. Coordinates may be negative (from the right / bottom edge).
"""
import struct
import sys
import zlib


def read_rgb(path):
    """(width, height, rows): rows[y] is a bytearray of 3 * width RGB bytes."""
    data = open(path, "rb").read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, width, height, channels = 8, b"", 0, 0, 3
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            if depth != 8 or colour not in (2, 6):
                raise ValueError(f"{path}: not 8-bit RGB(A) (depth {depth}, colour type {colour})")
            channels = 3 if colour == 2 else 4
        if kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    stride = channels * width
    rows, prev = [], bytearray(stride)
    for y in range(height):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - channels] if i >= channels else 0
            b = prev[i]
            c = prev[i - channels] if i >= channels else 0
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
        rows.append(line)
        prev = line
    if channels == 4:
        rows = [bytearray(v for x in range(width) for v in line[4 * x:4 * x + 3]) for line in rows]
    return width, height, rows


def count(image, region, predicate):
    width, height, rows = image
    x0, y0, x1, y1 = region
    x0, x1 = (x0 % width if x0 < 0 else x0), (x1 % width if x1 < 0 else min(x1, width))
    y0, y1 = (y0 % height if y0 < 0 else y0), (y1 % height if y1 < 0 else min(y1, height))
    n = 0
    for y in range(y0, y1):
        line = rows[y]
        for x in range(x0, x1):
            if predicate(line[3 * x], line[3 * x + 1], line[3 * x + 2]):
                n += 1
    return n


if __name__ == "__main__":
    image = read_rgb(sys.argv[1])
    for spec in sys.argv[2:]:
        name, rest = spec.split("=", 1)
        parts = rest.split(",", 4)
        region = tuple(int(v) for v in parts[:4])
        predicate = eval("lambda r, g, b: " + parts[4])
        print(name, count(image, region, predicate))
