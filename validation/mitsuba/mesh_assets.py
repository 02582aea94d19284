"""The assets of the Mitsuba mesh scenes (mesh-plain-glass.toml, mesh-waveguide.toml): two OBJ
meshes sharing one material library and one small sRGB PNG texture.

  mesh-quad.obj      a unit square in z = 0 facing +z (x, y in [-0.5, 0.5]), uv (0, 0) at the
                     bottom left in OBJ convention (v up), i.e. the image's top row at +y
  mesh-box.obj       a unit cube centred at the origin, 24 vertices (one per face corner), an
                     outward normal per face and the whole texture on every face
  mesh.mtl           material "textured": Kd 1 1 1, map_Kd mesh-texture.png (Lambertian)
  mesh-texture.png   32 x 32 RGB, 8 bit, sRGB-encoded: a 4 x 4 grid of 8 x 8-texel blocks of
                     different colours (linear values 0.06-0.72, no grey, no 0 or 1 component)
                     and no symmetry, so a flip or a rotation of the texture changes the image

Both renderers decode the PNG with the sRGB curve and filter it bilinearly. Two deliberately
wrong versions of the texture feed the failure tests of tests/it/mitsuba_reference.rs:

  mesh-texture-undecoded.png  decodes to the original's code values / 255: what a renderer
                              that forgot the sRGB decoding would use (colours too light)
  mesh-texture-flipped.png    the original upside down: what a renderer that forgot to flip
                              OBJ's v (or flipped it twice) would show

Run `python mesh_assets.py` to (re)write the files; only the standard library is needed.
"""
import os
import struct
import zlib

TEX = 32
BLOCK = 8

# Linear sRGB colours of the 4 x 4 blocks, row 0 = top of the image.
PALETTE = [
    [(0.62, 0.20, 0.10), (0.15, 0.45, 0.16), (0.10, 0.20, 0.56), (0.55, 0.50, 0.12)],
    [(0.45, 0.15, 0.40), (0.12, 0.40, 0.46), (0.36, 0.30, 0.24), (0.70, 0.55, 0.40)],
    [(0.08, 0.10, 0.13), (0.25, 0.60, 0.35), (0.50, 0.25, 0.62), (0.66, 0.36, 0.20)],
    [(0.20, 0.26, 0.32), (0.40, 0.55, 0.66), (0.30, 0.12, 0.10), (0.56, 0.66, 0.30)],
]


def srgb_encode(v):
    v = min(max(v, 0.0), 1.0)
    e = 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055
    return int(round(255 * e))


def texture_codes():
    """32 x 32 x 3 8-bit sRGB codes, row 0 = top."""
    rows = []
    for r in range(TEX):
        row = []
        for c in range(TEX):
            row.append(tuple(srgb_encode(v) for v in PALETTE[r // BLOCK][c // BLOCK]))
        rows.append(row)
    return rows


def write_png_rgb(path, rows):
    h, w = len(rows), len(rows[0])
    raw = b"".join(b"\x00" + bytes(v for px in row for v in px) for row in rows)

    def chunk(tag, data):
        c = struct.pack(">I", len(data)) + tag + data
        return c + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


QUAD = """# Unit square in z = 0 facing +z; validation/mitsuba/mesh_assets.py writes this file.
mtllib mesh.mtl
o quad
v -0.5 -0.5 0
v 0.5 -0.5 0
v 0.5 0.5 0
v -0.5 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl textured
f 1/1/1 2/2/1 3/3/1
f 1/1/1 3/3/1 4/4/1
"""


def box_obj():
    # (normal, u axis, v axis): corners c = n/2 + (u-1/2) U + (v-1/2) V, counter-clockwise
    # seen from outside (U x V = n).
    faces = [
        ((0, 0, 1), (1, 0, 0), (0, 1, 0)),
        ((0, 0, -1), (-1, 0, 0), (0, 1, 0)),
        ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
        ((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
        ((0, 1, 0), (1, 0, 0), (0, 0, -1)),
        ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    ]
    out = ["# Unit cube centred at the origin, the whole texture on every face;",
           "# validation/mitsuba/mesh_assets.py writes this file.", "mtllib mesh.mtl", "o box"]
    for k, (n, U, V) in enumerate(faces):
        for (u, v) in ((0, 0), (1, 0), (1, 1), (0, 1)):
            p = [0.5 * n[i] + (u - 0.5) * U[i] + (v - 0.5) * V[i] for i in range(3)]
            out.append("v %g %g %g" % tuple(p))
    out += ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1"]
    for n, _, _ in faces:
        out.append("vn %g %g %g" % n)
    out.append("usemtl textured")
    for k in range(6):
        a, b, c, d = (4 * k + i + 1 for i in range(4))
        out.append(f"f {a}/1/{k + 1} {b}/2/{k + 1} {c}/3/{k + 1}")
        out.append(f"f {a}/1/{k + 1} {c}/3/{k + 1} {d}/4/{k + 1}")
    return "\n".join(out) + "\n"


MTL = """# validation/mitsuba/mesh_assets.py writes this file.
newmtl textured
Kd 1 1 1
Ka 0 0 0
Ks 0 0 0
illum 1
map_Kd mesh-texture.png
"""

def undecoded(rows):
    """Codes whose sRGB decoding gives the given codes / 255."""
    return [[tuple(srgb_encode(v / 255.0) for v in px) for px in row] for row in rows]


if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    codes = texture_codes()
    write_png_rgb(os.path.join(here, "mesh-texture.png"), codes)
    write_png_rgb(os.path.join(here, "mesh-texture-undecoded.png"), undecoded(codes))
    write_png_rgb(os.path.join(here, "mesh-texture-flipped.png"), codes[::-1])
    for name, text in (("mesh-quad.obj", QUAD), ("mesh-box.obj", box_obj()), ("mesh.mtl", MTL)):
        with open(os.path.join(here, name), "w") as f:
            f.write(text)
    print("wrote mesh-texture{,-undecoded,-flipped}.png mesh-quad.obj mesh-box.obj mesh.mtl")
