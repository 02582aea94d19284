#!/usr/bin/env python3
"""Check a dataset written by `stscam dataset`, independently of stscam, as a newcomer loads it.

Usage: check_dataset.py [--noiseless] [--hf] DIR

With numpy (always):
  * dataset.json: format tag, counts per split add up to `samples`, and the SHA-256 and size of
    every listed file match (hashlib), and no sample file is missing from the list;
  * each SPLIT/metadata.jsonl: one line per sample, ids in order, files exist; the object .npy is
    float32 [h, w] in [0, 1], the capture .npy float32 with the card's capture_shape, finite;
  * the 16-bit capture PNG equals round(65535 * clamp(capture / capture_full_scale, 0, 1)), as the
    card states (PNG decoded by Pillow when it is installed, else by a zlib reader written here).
With scipy (always): each scene's H.npz loads with scipy.sparse.load_npz and, with --noiseless,
  H @ object.ravel() + offset equals the capture to float32 rounding (relative 1e-5 of the
  capture's peak); otherwise the capture minus H f - offset has mean ~0 (noise only).
3-D datasets (`meshes`, detected by the `frontal_npy` column): instead of the object, the
  frontal .npy is float32 with the card's object_shape (and channels), the depth .npy float32
  [h, w], the mask 16-bit PNG [h, w]; the frontal PNG equals round(65535 * clamp(frontal / 1));
  aligned: the mask is nonzero only where the depth is finite, the drawn mesh's mask value
  (metadata mask_value) lies within its world bounds (metadata bounds_mm, -z) and is in view
  in at least one sample, and with a black background (environment 0, display off) the frontal is 0 wherever the
  mask and its 8 neighbours are 0.
With --hf: datasets.load_dataset("imagefolder", data_dir=DIR) gives the splits with the card's
  counts, an `image` column (the capture PNG, 16-bit, capture size) and the metadata columns
  (for 3-D datasets also the frontal and mask PNGs as images of the frontal size).

Prints one line per check group and exits 0, or prints the failures and exits 1.
"""

import hashlib
import json
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import scipy.sparse as sp

SPLITS = ["train", "val", "test"]


def read_png16(path: Path) -> np.ndarray:
    """Minimal PNG reader for the 16-bit grey/RGB, non-interlaced files stscam writes."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat, ihdr = 8, b"", None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    w, h, depth, color, _, _, interlace = ihdr
    assert depth == 16 and color in (0, 2) and interlace == 0, f"unsupported PNG {ihdr}"
    ch = 1 if color == 0 else 3
    bpp, stride = 2 * ch, 2 * ch * w
    raw = zlib.decompress(idat)
    out = bytearray(h * stride)
    prev = bytearray(stride)
    for y in range(h):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1 : (y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            if f == 1:
                line[i] = (line[i] + a) & 255
            elif f == 2:
                line[i] = (line[i] + b) & 255
            elif f == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + pred) & 255
        out[y * stride : (y + 1) * stride] = line
        prev = line
    arr = np.frombuffer(bytes(out), dtype=">u2").astype(np.uint16)
    return arr.reshape(h, w) if ch == 1 else arr.reshape(h, w, ch)


def load_png16(path: Path) -> np.ndarray:
    """16-bit samples of a PNG: with Pillow for 16-bit grey (mode I;16); Pillow reduces 16-bit
    RGB to 8 bits, so RGB (and everything without Pillow) goes through read_png16."""
    try:
        from PIL import Image  # noqa: PLC0415

        with Image.open(path) as im:
            if im.mode in ("I;16", "I;16B", "I"):
                return np.array(im).astype(np.uint16)
    except ImportError:
        pass
    return read_png16(path)


def check_3d(d: Path, x: dict, obj_shape: tuple, black: bool, check) -> bool:
    """Files and alignment of one 3-D sample (see the module docstring); True if its mesh is in view."""
    fr = np.load(d / x["frontal_npy"])
    z = np.load(d / x["depth_npy"])
    m = load_png16(d / x["mask_file_name"])
    check(fr.dtype == np.float32 and fr.shape[-2:] == obj_shape, f"{x['frontal_npy']}: {fr.dtype} {fr.shape}")
    check(z.dtype == np.float32 and z.shape == obj_shape, f"{x['depth_npy']}: {z.dtype} {z.shape}")
    check(m.shape == obj_shape, f"{x['mask_file_name']}: {m.shape}")
    check(bool(np.all(np.isfinite(fr)) and np.all(fr >= 0)), f"{x['frontal_npy']}: not finite or negative")
    check(bool(np.all(np.isfinite(z[m > 0]))), f"{x['mask_file_name']}: nonzero where the depth is +inf")
    check(bool(np.all(np.isnan(z) == False)), f"{x['depth_npy']}: NaN")  # noqa: E712
    mine = m == x["mask_value"]
    lo, hi = -x["bounds_mm"][1][2], -x["bounds_mm"][0][2]
    zs = z[mine].astype(np.float64)
    tol = 1e-5 * hi
    check(bool(np.all((zs >= lo - tol) & (zs <= hi + tol))), f"{x['depth_npy']}: mesh depths outside [{lo:.1f}, {hi:.1f}] mm")
    png = load_png16(d / x["frontal_file_name"])
    want = np.round(65535 * np.clip(fr.astype(np.float64), 0, 1))
    if fr.ndim == 3:
        want = np.moveaxis(want, 0, -1)
    check(np.abs(png.astype(np.float64) - want).max() <= 1, f"{x['frontal_file_name']}: PNG differs from the npy")
    if black:
        empty = np.pad(m == 0, 1, constant_values=True)
        h, w = obj_shape
        far = np.all([empty[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
        lum = fr if fr.ndim == 2 else fr.sum(axis=0)
        check(bool(np.all(lum[far] == 0)), f"{x['frontal_npy']}: light outside the mask on a black background")
    return bool(mine.any())


def main(argv: list[str]) -> int:
    args = [a for a in argv[1:] if not a.startswith("--")]
    noiseless = "--noiseless" in argv
    hf = "--hf" in argv
    if len(args) != 1:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    root = Path(args[0])
    fails: list[str] = []

    def check(ok: bool, msg: str) -> None:
        if not ok:
            fails.append(msg)

    card = json.loads((root / "dataset.json").read_text())
    check(card["format"] == "stscam-dataset/1", f"format {card['format']}")
    check(sum(card["counts"].values()) == card["samples"], "counts do not add up")
    for rel, e in card["files"].items():
        b = (root / rel).read_bytes()
        check(len(b) == e["bytes"], f"{rel}: size")
        check(hashlib.sha256(b).hexdigest() == e["sha256"], f"{rel}: sha256")
    print(f"check_dataset: {len(card['files'])} files match their SHA-256 in dataset.json")

    mats = {}
    for s in card["scenes"]:
        if s.get("matrix"):
            h = sp.load_npz(root / s["matrix"])
            off = np.load(root / s["id"] / "offset.npy")
            check(h.dtype == np.float32 and off.shape == (h.shape[0],), f"{s['id']}: H/offset")
            mats[s["id"]] = (h.tocsr(), off.astype(np.float64))
    full_scale = card["exposure"]["capture_full_scale"]
    cap_shape = tuple(card["capture_shape"])
    obj_shape = tuple(card["object_shape"])
    n_seen, worst, resid, n_3d, in_view = 0, 0.0, [], 0, 0
    for split in SPLITS:
        meta = root / split / "metadata.jsonl"
        if card["counts"].get(split, 0) == 0:
            check(not meta.exists(), f"{split}: metadata for an empty split")
            continue
        lines = [json.loads(x) for x in meta.read_text().splitlines()]
        check(len(lines) == card["counts"][split], f"{split}: {len(lines)} lines")
        ids = [x["id"] for x in lines]
        check(ids == sorted(ids), f"{split}: ids not in order")
        for x in lines:
            d = root / split
            is_3d = "frontal_npy" in x
            keys = ("file_name", "capture_npy") + (
                ("frontal_npy", "frontal_file_name", "depth_npy", "mask_file_name") if is_3d else ("object_file_name", "object_npy")
            )
            for k in keys:
                check(f"{split}/{x[k]}" in card["files"], f"{split}/{x[k]} not in the card")
            g = np.load(d / x["capture_npy"])
            check(g.dtype == np.float32 and g.shape == cap_shape, f"{x['capture_npy']}: {g.dtype} {g.shape}")
            check(bool(np.all(np.isfinite(g))), f"{x['capture_npy']}: not finite")
            if is_3d:
                display_off = "display.enabled=false" in card["recipe"]["scene"]["set"]
                in_view += check_3d(d, x, obj_shape, display_off and x["environment"] == 0, check)
                n_3d += 1
            else:
                f = np.load(d / x["object_npy"])
                check(f.dtype == np.float32 and f.shape == obj_shape, f"{x['object_npy']}: {f.dtype} {f.shape}")
                check(bool(np.all((f >= 0) & (f <= 1))), f"{x['object_npy']}: outside [0, 1]")
            if n_seen < 24:  # PNG decoding in pure Python is slow: a sample of them
                png = load_png16(d / x["file_name"])
                want = np.round(65535 * np.clip(g.astype(np.float64) / full_scale, 0, 1))
                if g.ndim == 3:
                    want = np.moveaxis(want, 0, -1)
                diff = np.abs(png.astype(np.float64) - want).max()
                check(diff <= 1, f"{x['file_name']}: PNG differs from the npy by {diff}")
            if x.get("matrix"):
                h, off = mats[x["scene"]]
                pred = h @ f.astype(np.float64).ravel() + off
                err = g.astype(np.float64).ravel() - pred
                peak = max(float(np.abs(pred).max()), 1e-30)
                worst = max(worst, float(np.abs(err).max()) / peak)
                resid.append(float(err.mean()) / peak)
            n_seen += 1
    check(n_seen == card["samples"], f"saw {n_seen} samples, card says {card['samples']}")
    if mats:
        if noiseless:
            check(worst < 1e-5, f"capture != H f + offset: worst relative difference {worst:.3g}")
            print(f"check_dataset: {n_seen} noiseless captures = H @ object + offset (scipy), worst {worst:.2e} of the peak")
        else:
            m = abs(float(np.mean(resid)))
            check(m < 1e-2, f"mean noise {m:.3g} of the peak is not ~0")
            print(f"check_dataset: {n_seen} noisy captures scatter around H @ object + offset (mean {m:.2e} of the peak)")
    if n_3d:
        check(in_view > 0, "no 3-D sample shows its mesh")
        print(f"check_dataset: the drawn mesh is in view in {in_view} of {n_3d} 3-D samples")
        print(f"check_dataset: {n_3d} 3-D samples: frontal, depth and mask {obj_shape} aligned (mask only where the depth is finite, mesh depths within its bounds)")
    print(f"check_dataset: {n_seen} samples load with numpy (object {obj_shape}, capture {cap_shape}, float32)")

    if hf:
        from datasets import load_dataset  # noqa: PLC0415

        ds = load_dataset("imagefolder", data_dir=str(root))
        names = {"train": "train", "val": "validation", "test": "test"}
        for split, n in card["counts"].items():
            if n == 0:
                continue
            part = ds[names[split]]
            check(part.num_rows == n, f"HF {names[split]}: {part.num_rows} rows, card {n}")
            row = part[0]
            img = row["image"]
            check(img.size == (cap_shape[-1], cap_shape[-2]), f"HF image size {img.size}")
            for col in ("id", "seed", "scene", "object_draw", "capture_npy"):
                check(col in row, f"HF column {col} missing")
            for col in ("frontal_file_name", "mask_file_name"):
                if col in row or col.removesuffix("_file_name") in row:
                    im = row.get(col.removesuffix("_file_name"), row.get(col))
                    check(getattr(im, "size", None) == (obj_shape[-1], obj_shape[-2]), f"HF {col}: {im!r}")
            a = np.array(img).astype(np.float64)
            g = np.load(root / split / row["capture_npy"]).astype(np.float64)
            want = np.round(65535 * np.clip(g / full_scale, 0, 1))
            if g.ndim == 3:
                want = np.moveaxis(want, 0, -1)
            if img.mode == "RGB":  # Pillow keeps the high byte of 16-bit RGB samples
                want = np.floor(want / 256)
            check(np.abs(a - want).max() <= 1, "HF image differs from the capture npy")
        print(f"check_dataset: Hugging Face imagefolder loads {dict((k, v.num_rows) for k, v in ds.items())}")

    for f in fails:
        print(f"check_dataset: FAIL {f}", file=sys.stderr)
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
