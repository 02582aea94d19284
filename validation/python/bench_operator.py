#!/usr/bin/env python3
"""Speed of stscam.Operator against plain scipy, per frame (medians of repeated runs).

Usage: bench_operator.py [--crop N] [--object N] [--spp S] [--batch B] [--runs R]

Builds H for an N x N crop of the paper camera looking at an object of the given size, then
times per frame: forward H f (one frame and a batch of B, per frame), adjoint Hᵀ g, the same
products with scipy's CSR matrix directly, `Operator.reconstruct(method="cg")` on a batch
(set-up once) against `stscam.reconstruct` per frame (set-up every call), and, if torch is
importable, the torch adapter. Prints one line per measurement.
"""
import argparse
import statistics
import time

import numpy as np

import stscam


def median_time(fn, runs):
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--crop", type=int, default=440)
    ap.add_argument("--object", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    scene = stscam.Scene(overrides={"sensor.crop_px": [a.crop, a.crop],
                                    "display.image": f"letter:F@{a.object}"})
    t0 = time.perf_counter()
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        H, off = stscam.matrix(scene, spp=a.spp)
    print(f"H {H.shape[0]}x{H.shape[1]}, nnz {H.nnz}, computed in {time.perf_counter() - t0:.2f} s")
    op = stscam.Operator(H, off, object_shape=(a.object, a.object))
    rng = np.random.default_rng(0)
    F = rng.random((a.batch, a.object, a.object))
    G = op.capture(F)
    H64, HT64 = H.astype(np.float64).tocsr(), H.astype(np.float64).T.tocsr()
    ms = 1e3
    r = a.runs
    print(f"forward, 1 frame:   Operator {median_time(lambda: op.forward(F[0]), r) * ms:.3f} ms, scipy H @ f {median_time(lambda: H64 @ F[0].ravel(), r) * ms:.3f} ms")
    print(f"forward, batch {a.batch}, per frame: Operator {median_time(lambda: op.forward(F), r) / a.batch * ms:.3f} ms, scipy loop {median_time(lambda: [H64 @ f.ravel() for f in F], r) / a.batch * ms:.3f} ms")
    print(f"adjoint, 1 frame:   Operator {median_time(lambda: op.adjoint(G[0]), r) * ms:.3f} ms, scipy H.T @ g {median_time(lambda: HT64 @ G[0], r) * ms:.3f} ms")
    print(f"adjoint, batch {a.batch}, per frame: Operator {median_time(lambda: op.adjoint(G), r) / a.batch * ms:.3f} ms")
    t0 = time.perf_counter()
    op.reconstruct(G[:1], method="cg", iters=1, regularisation="fixed")
    print(f"set-up (Hᵀ, HᵀH) once: {(time.perf_counter() - t0) * ms:.1f} ms")
    per = median_time(lambda: op.reconstruct(G, method="cg", regularisation="fixed"), max(1, r // 2)) / a.batch
    one = median_time(lambda: stscam.reconstruct(H, G[0], method="cg", offset=off, regularisation="fixed"), max(1, r // 2))
    print(f"CG (default iterations), per frame: Operator batch {per * ms:.1f} ms, stscam.reconstruct per call (set-up each time) {one * ms:.1f} ms")
    try:
        import torch
    except ImportError:
        print("torch: not installed, adapter not timed")
        return
    A = op.torch()
    X = torch.from_numpy(F)
    print(f"torch adapter forward, batch {a.batch}, per frame: {median_time(lambda: A(X), r) / a.batch * ms:.3f} ms")
    Ht = torch.sparse_csr_tensor(torch.from_numpy(H64.indptr.astype(np.int64)), torch.from_numpy(H64.indices.astype(np.int64)), torch.from_numpy(H64.data), H64.shape)
    print(f"torch CPU sparse H @ X, batch {a.batch}, per frame: {median_time(lambda: Ht @ X.reshape(a.batch, -1).T, r) / a.batch * ms:.3f} ms")


if __name__ == "__main__":
    main()
