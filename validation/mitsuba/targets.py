"""The two display targets of the Mitsuba comparison, as 64x64 8-bit grey PNG files.

Both are binary (0 or 255), so the display gamma does not matter. Row 0 is the top (+y) and
column 0 the left (-x) as seen from the camera, as in stscam's display (`sim/world/src/display.rs`).
  target-glyph.png  an "F"-like glyph, asymmetric in x and y (orientation check, plain glass)
  target-lines.png  four horizontal lines, 1 target pixel tall, of different lengths, so that
                    each line's replicas are separated in the waveguide image (replica check)
Run `python targets.py` to (re)write them; only the standard library is needed.
"""
import os
import struct
import zlib

SIZE = 64


def glyph():
    img = [[0] * SIZE for _ in range(SIZE)]
    def rect(r0, r1, c0, c1):
        for r in range(r0, r1):
            for c in range(c0, c1):
                img[r][c] = 255
    rect(8, 56, 14, 24)   # stem, on the left
    rect(8, 18, 14, 52)   # top bar, long, to the right
    rect(28, 37, 14, 42)  # middle bar, shorter
    rect(50, 56, 40, 48)  # a small block at the bottom right (breaks any symmetry)
    return img


def lines():
    img = [[0] * SIZE for _ in range(SIZE)]
    for row, c0, c1 in ((8, 4, 60), (24, 4, 32), (40, 32, 60), (56, 4, 48)):
        for c in range(c0, c1):
            img[row][c] = 255
    return img


def write_png(path, img):
    h, w = len(img), len(img[0])
    raw = b"".join(b"\x00" + bytes(row) for row in img)
    def chunk(tag, data):
        c = struct.pack(">I", len(data)) + tag + data
        return c + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


TARGETS = {"target-glyph.png": glyph, "target-lines.png": lines}

if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    for name, fn in TARGETS.items():
        write_png(os.path.join(here, name), fn())
        print("wrote", name)
