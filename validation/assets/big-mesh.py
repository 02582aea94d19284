#!/usr/bin/env python3
"""Writes a binary glTF (.glb) displaced-sphere mesh of at least N triangles (default 10^6)
for the load-time and peak-memory measurement of docs/assets.md (standard library only).

usage: big-mesh.py OUT.glb [N]
Then: /usr/bin/time -v stscam render SCENE (mesh = OUT.glb) --spp 1 ... and read
"Maximum resident set size"; capture.json's world section holds the BVH build time.
"""
import json
import math
import struct
import sys


def main():
    out = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 1_000_000
    # A UV sphere with rings x segs quads (2 triangles each, minus the pole fans).
    segs = int(math.ceil(math.sqrt(n / 2.0 * 2.0)))
    rings = segs // 2 + 1
    while 2 * segs * (rings - 1) < n:
        rings += 1
    pos = bytearray()
    for r in range(rings + 1):
        th = math.pi * r / rings
        for s in range(segs):
            ph = 2 * math.pi * s / segs
            rad = 0.05 * (1.0 + 0.02 * math.sin(7 * th) * math.cos(5 * ph))
            pos += struct.pack("<3f", rad * math.sin(th) * math.cos(ph), rad * math.cos(th),
                               rad * math.sin(th) * math.sin(ph))
    idx = bytearray()
    ntri = 0
    for r in range(rings):
        for s in range(segs):
            a = r * segs + s
            b = r * segs + (s + 1) % segs
            c = a + segs
            d = b + segs
            idx += struct.pack("<3I", a, c, b)
            idx += struct.pack("<3I", b, c, d)
            ntri += 2
    nv = (rings + 1) * segs
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(pos) + len(idx)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
            {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": nv, "type": "VEC3",
             "min": [-0.06, -0.06, -0.06], "max": [0.06, 0.06, 0.06]},
            {"bufferView": 1, "componentType": 5125, "count": 3 * ntri, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binc = bytes(pos + idx)
    binc += b"\0" * (-len(binc) % 4)
    total = 12 + 8 + len(js) + 8 + len(binc)
    with open(out, "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, total))
        f.write(struct.pack("<I4s", len(js), b"JSON") + js)
        f.write(struct.pack("<I4s", len(binc), b"BIN\0") + binc)
    print(f"{out}: {ntri} triangles, {nv} vertices")


if __name__ == "__main__":
    main()
