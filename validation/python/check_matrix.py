#!/usr/bin/env python3
"""Check the output of `stscam matrix` with numpy/scipy, independently of the Rust reader.

Usage: check_matrix.py DIR

Loads DIR/H.npz with scipy.sparse.load_npz, DIR/offset.npy with numpy and DIR/H.json, and
checks: shape and nnz agree with H.json; float32 data; int32 indices and indptr; canonical
format (sorted indices, no duplicates); scipy's full format check; finite, non-negative
values; one offset per row. Then it forms the capture of an all-white object,
H @ ones(cols) + offset, which must be finite, non-negative and positive somewhere
(the display image does not enter H, so any `stscam matrix` output serves).

Prints a one-line summary and exits 0, or prints every failure to stderr and exits 1.
"""

import json
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[1] in ("-h", "--help"):
        print(__doc__.strip(), file=sys.stderr)
        return 2
    d = Path(argv[1])
    failures: list[str] = []

    def check(cond: bool, msg: str) -> bool:
        if not cond:
            failures.append(msg)
        return cond

    try:
        meta = json.loads((d / "H.json").read_text())
        H = sp.load_npz(d / "H.npz")
        offset = np.load(d / "offset.npy", allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - report any load failure plainly
        print(f"check_matrix: FAIL: cannot load {d}: {type(e).__name__}: {e}", file=sys.stderr)
        return 1

    rows, cols = (int(v) for v in meta["shape"])
    check(H.format == "csr", f"H.npz holds a {H.format!r} matrix, expected 'csr'")
    check(H.shape == (rows, cols), f"H shape {H.shape} != H.json shape {(rows, cols)}")
    check(H.nnz == int(meta["nnz"]), f"H nnz {H.nnz} != H.json nnz {meta['nnz']}")
    check(H.dtype == np.float32, f"H dtype {H.dtype}, expected float32")
    check(H.indices.dtype == np.int32, f"H.indices dtype {H.indices.dtype}, expected int32")
    check(H.indptr.dtype == np.int32, f"H.indptr dtype {H.indptr.dtype}, expected int32")
    try:
        H.check_format(full_check=True)
    except Exception as e:  # noqa: BLE001
        failures.append(f"H.check_format(full_check=True) failed: {e}")
    # has_canonical_format is computed from the arrays when not cached (sorted, no duplicates).
    check(bool(H.has_canonical_format), "H is not in canonical format (unsorted or duplicate indices)")
    check(bool(np.all(np.isfinite(H.data))), "H has non-finite values")
    check(bool(np.all(H.data >= 0)), f"H has negative values (min {H.data.min() if H.nnz else 0})")
    check(H.nnz > 0, "H is empty")

    check(offset.dtype == np.float32, f"offset.npy dtype {offset.dtype}, expected float32")
    check(offset.shape == (rows,), f"offset.npy shape {offset.shape}, expected ({rows},)")
    check(bool(np.all(np.isfinite(offset))), "offset has non-finite values")
    check(bool(np.all(offset >= 0)), "offset has negative values")

    white = None
    if offset.shape == (rows,) and H.shape == (rows, cols):
        # Capture of an all-white object (every object pixel at 1).
        white = H @ np.ones(cols, dtype=np.float32) + offset
        check(bool(np.all(np.isfinite(white))), "H @ 1 + offset has non-finite values")
        check(bool(np.all(white >= 0)), "H @ 1 + offset has negative values")
        check(bool(np.any(white > 0)), "H @ 1 + offset is zero everywhere")

    if failures:
        for f in failures:
            print(f"check_matrix: FAIL: {f}", file=sys.stderr)
        print(f"check_matrix: {len(failures)} check(s) failed for {d}", file=sys.stderr)
        return 1

    density = H.nnz / (rows * cols) if rows * cols else 0.0
    print(
        f"check_matrix: ok {d}: shape {rows}x{cols}, nnz {H.nnz}, density {density:.4%}, "
        f"H min/max {H.data.min():.3e}/{H.data.max():.3e}, "
        f"offset min/max {offset.min():.3e}/{offset.max():.3e}, "
        f"white capture min/max {white.min():.3e}/{white.max():.3e}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
