#!/usr/bin/env python3
"""A learned baseline end to end with the stscam Python package and PyTorch (CPU).

1. A small paper camera (the paper scene at half scale: 32 x 32 object, 220 x 220 crop of
   9.6 um pixels, the crop framed on the object as `stscam demo` frames it; `--tiny`: quarter
   scale, 16 x 16 object, 96 x 96 crop).
2. H (seed 1) for the reconstructions and an independent H' (seed 2) for the captures, so the
   captures do not share H's Monte Carlo noise (no inverse crime).
3. A dataset: built-in targets (letters, shapes, Siemens stars, smooth fields) flipped, turned
   and scaled at random, plus random rectangles and disks; captures H'f + o' measured by the
   scene's sensor model (`stscam.sensor_noise`: 8-bit, white peak at 80 % of full scale, shot
   and read noise), one noise seed per sample. Train and held-out objects come from disjoint
   random streams; the held-out set also holds the demo's four targets.
4. Baselines with the package's solver (`Operator.reconstruct`): CG and ADMM-TV, each with its
   one parameter (CG iterations, ADMM-TV tau_rel) chosen on training samples, as the network
   is trained on them.
5. The network: CG's reconstruction + a small residual CNN, then one data-consistency step
   x <- x - a * H^T (H x - g) with the package's torch operator (`Operator.torch()`, autograd
   through H and H^T) and a learned step a. Trained with Adam on the MSE for a fixed time.
6. Held-out PSNR (peak 1, reconstructions clipped to [0, 1], linear intensity, as `stscam
   demo`) of CG, ADMM-TV and the network: printed as a table and written as JSON and Markdown.

Usage: python examples/learned_baseline.py [--tiny] [--out DIR] [--minutes M]
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np

import stscam

SIZES = {
    # object px, crop px, pixel pitch um, LCD px per object px, crop offset, spp, train, test,
    # training time cap (min), epochs cap
    "tiny": dict(obj=16, crop=96, pitch=19.2, lcd=40, offset=[0, -12], spp=4, n_train=128,
                 n_test=24, minutes=0.75, epochs=60),
    "default": dict(obj=32, crop=220, pitch=9.6, lcd=20, offset=[0, -24], spp=16, n_train=1024,
                    n_test=96, minutes=4.0, epochs=400),
}
DEMO_TARGETS = ["letter:A", "shape:heart", "siemens:12", "smooth:7"]
LETTERS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"
SHAPES = ["disk", "ring", "triangle", "star", "cross", "heart"]


def psnr(x: np.ndarray, truth: np.ndarray) -> float:
    """PSNR (peak 1) of x clipped to [0, 1] against truth, as stscam's metrics."""
    mse = float(np.mean((np.clip(x, 0.0, 1.0) - truth) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def linear(code: np.ndarray, gamma: float = 2.2) -> np.ndarray:
    """Display code values -> linear intensity (the display's gamma, as the demo's targets)."""
    return np.clip(code, 0.0, 1.0).astype(np.float64) ** gamma


def random_object(rng: np.random.Generator, n: int) -> np.ndarray:
    """One object (linear intensity, n x n) of the dataset's distribution."""
    kind = rng.integers(4)
    if kind == 0:
        spec = f"letter:{LETTERS[rng.integers(len(LETTERS))]}"
    elif kind == 1:
        spec = f"shape:{SHAPES[rng.integers(len(SHAPES))]}"
    elif kind == 2:
        spec = f"siemens:{int(rng.integers(4, 17))}" if rng.random() < 0.5 else f"smooth:{int(rng.integers(1000))}"
    else:
        spec = None
    if spec is not None:
        img = stscam.target(f"{spec}@{n}").astype(np.float64)
        img = np.rot90(img, int(rng.integers(4)))
        if rng.random() < 0.5:
            img = img[:, ::-1]
    else:
        img = np.full((n, n), rng.uniform(0.0, 0.3))
        yy, xx = np.mgrid[0:n, 0:n]
        for _ in range(int(rng.integers(1, 4))):
            v = rng.uniform(0.2, 1.0)
            if rng.random() < 0.5:
                r0, c0 = rng.integers(0, n - 2, 2)
                h, w = rng.integers(2, n // 2 + 1, 2)
                img[r0:r0 + h, c0:c0 + w] = v
            else:
                cy, cx = rng.uniform(0, n, 2)
                rad = rng.uniform(n / 10, n / 3)
                img[(yy - cy) ** 2 + (xx - cx) ** 2 <= rad * rad] = v
    lo, hi = rng.uniform(0.0, 0.15), rng.uniform(0.7, 1.0)
    return linear(lo + (hi - lo) * img)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tiny", action="store_true", help="quarter scale, CI-sized (< 2 min on 2 cores)")
    ap.add_argument("--out", default=None, help="output folder (default out/learned-baseline[-tiny])")
    ap.add_argument("--minutes", type=float, default=None, help="training time cap")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    import torch

    size = "tiny" if args.tiny else "default"
    cfg = dict(SIZES[size])
    if args.minutes is not None:
        cfg["minutes"] = args.minutes
    out = pathlib.Path(args.out or f"out/learned-baseline{'-tiny' if args.tiny else ''}")
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.time()
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    n = cfg["obj"]

    # 1-2. The camera, H and H'.
    scene = stscam.Scene(overrides={
        "sensor.crop_px": [cfg["crop"], cfg["crop"]], "sensor.pitch_um": cfg["pitch"],
        "display.image": f"letter:A@{n}", "display.lcd_pixels_per_image_pixel": cfg["lcd"],
        "sensor.crop_offset_px": cfg["offset"]})
    if scene.coverage_warning() is not None:
        raise SystemExit(f"the crop does not frame the object: {scene.coverage_warning()}")
    t0 = time.time()
    H, off = stscam.matrix(scene, spp=cfg["spp"], seed=1)
    H2, off2 = stscam.matrix(scene, spp=cfg["spp"], seed=2)
    op = stscam.Operator(H, off, object_shape=(n, n))
    op2 = stscam.Operator(H2, off2, object_shape=(n, n))
    t_matrix = time.time() - t0

    # 3. The dataset.
    t0 = time.time()
    white_peak = float(op2.capture(np.ones((n, n))).max())

    def captures(objs: np.ndarray, seed0: int) -> np.ndarray:
        clean = op2.capture(objs)
        return np.stack([stscam.sensor_noise(scene, c, seed=seed0 + i, white_peak=white_peak)
                         for i, c in enumerate(clean)]).astype(np.float64)

    train_f = np.stack([random_object(rng, n) for _ in range(cfg["n_train"])])
    test_rng = np.random.default_rng(10_000 + args.seed)
    demo_f = np.stack([linear(stscam.target(f"{s}@{n}").astype(np.float64)) for s in DEMO_TARGETS])
    test_f = np.concatenate([demo_f, np.stack([random_object(test_rng, n) for _ in range(cfg["n_test"] - 4)])])
    train_g = captures(train_f, 1_000_000)
    test_g = captures(test_f, 2_000_000)
    t_data = time.time() - t0

    # 4. Baselines, parameters chosen on training samples.
    t0 = time.time()
    pick = slice(0, min(32, cfg["n_train"]))

    def mean_psnr(x: np.ndarray, f: np.ndarray) -> float:
        return float(np.mean([psnr(a, b) for a, b in zip(x, f)]))

    cg_iters = max([5, 10, 20, 30, 50], key=lambda k: mean_psnr(
        op.reconstruct(train_g[pick], method="cg", iters=k, regularisation="fixed"), train_f[pick]))
    tau = max([1e-4, 3e-4, 1e-3, 3e-3, 1e-2], key=lambda t: mean_psnr(
        op.reconstruct(train_g[pick], method="admm-tv", tau=t, regularisation="fixed"), train_f[pick]))
    t_tune = time.time() - t0
    t0 = time.time()
    test_cg = op.reconstruct(test_g, method="cg", iters=cg_iters, regularisation="fixed")
    t_cg = (time.time() - t0) / len(test_g)
    t0 = time.time()
    test_admm = op.reconstruct(test_g, method="admm-tv", tau=tau, regularisation="fixed")
    t_admm = (time.time() - t0) / len(test_g)
    train_cg = op.reconstruct(train_g, method="cg", iters=cg_iters, regularisation="fixed")

    # 5. The network.
    A = op.torch()
    # ||H||^2 by power iteration: the data-consistency step is a / ||H||^2.
    v = np.ones((n, n))
    for _ in range(30):
        v = op.adjoint(op.forward(v))
        lip = float(np.linalg.norm(v))
        v /= lip

    class Net(torch.nn.Module):
        def __init__(self, ch: int = 32):
            super().__init__()
            layers: list[torch.nn.Module] = [torch.nn.Conv2d(1, ch, 3, padding=1), torch.nn.ReLU()]
            for _ in range(3):
                layers += [torch.nn.Conv2d(ch, ch, 3, padding=1), torch.nn.ReLU()]
            layers += [torch.nn.Conv2d(ch, 1, 3, padding=1)]
            self.cnn = torch.nn.Sequential(*layers)
            self.step = torch.nn.Parameter(torch.tensor(0.0))

        def forward(self, x0: "torch.Tensor", g: "torch.Tensor") -> "torch.Tensor":
            x = x0 + self.cnn(x0[:, None])[:, 0]
            # Data consistency with the operator in the graph: one gradient step on ||Hx - g||^2.
            return x - torch.nn.functional.softplus(self.step) / lip * A.adjoint(A(x) - g)

    net = Net()
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    g_off = lambda g: torch.tensor(g - off.astype(np.float64), dtype=torch.float32)  # noqa: E731
    X0, G, F = (torch.tensor(train_cg, dtype=torch.float32), g_off(train_g),
                torch.tensor(train_f, dtype=torch.float32))
    t0 = time.time()
    epochs, losses = 0, []
    while epochs < cfg["epochs"] and time.time() - t0 < 60.0 * cfg["minutes"]:
        perm = torch.randperm(len(X0))
        total = 0.0
        for b in range(0, len(X0), 16):
            i = perm[b:b + 16]
            opt.zero_grad()
            loss = torch.mean((net(X0[i], G[i]) - F[i]) ** 2)
            loss.backward()
            opt.step()
            total += loss.item() * len(i)
        losses.append(total / len(X0))
        epochs += 1
    t_train = time.time() - t0
    with torch.no_grad():
        t0 = time.time()
        test_net = net(torch.tensor(test_cg, dtype=torch.float32), g_off(test_g)).double().numpy()
        t_net = (time.time() - t0) / len(test_g) + t_cg

    # 6. The table.
    names = ["CG", "ADMM-TV", "CG + CNN + data consistency"]
    params = [f"{cg_iters} iterations", f"tau_rel {tau:g}, 50 iterations", f"{epochs} epochs, {t_train:.0f} s"]
    recs = [test_cg, test_admm, test_net]
    per = [[psnr(x, f) for x, f in zip(r, test_f)] for r in recs]
    ms = [t_cg, t_admm, t_net]
    rows = [{"method": nm, "parameters": pa, "mean_psnr_db": float(np.mean(p)),
             "demo_targets_psnr_db": dict(zip(["glyph", "heart", "siemens", "smooth"], map(float, p[:4]))),
             "ms_per_frame": 1e3 * t} for nm, pa, p, t in zip(names, params, per, ms)]
    md = [f"Held-out PSNR (peak 1, clipped to [0, 1]) over {len(test_f)} objects ({size} size: {n} x {n} object, "
          f"{cfg['crop']} x {cfg['crop']} crop, H at {cfg['spp']} spp, captures through an independent H', "
          f"8-bit sensor noise), {len(train_f)} training objects:", "",
          "| method | parameters (chosen on training data) | mean PSNR | glyph | heart | siemens | smooth | ms / frame |",
          "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        d = r["demo_targets_psnr_db"]
        md.append(f"| {r['method']} | {r['parameters']} | {r['mean_psnr_db']:.2f} dB | {d['glyph']:.2f} | "
                  f"{d['heart']:.2f} | {d['siemens']:.2f} | {d['smooth']:.2f} | {r['ms_per_frame']:.1f} |")
    total = time.time() - t_all
    md += ["", f"Times: H and H' {t_matrix:.1f} s, dataset {t_data:.1f} s, baseline tuning {t_tune:.1f} s, "
           f"training {t_train:.1f} s; total {total:.1f} s (torch {torch.__version__}, "
           f"{torch.get_num_threads()} threads)."]
    text = "\n".join(md) + "\n"
    print(text)
    (out / "table.md").write_text(text)
    (out / "table.json").write_text(json.dumps({
        "size": size, "config": cfg, "rows": rows, "train_loss": losses,
        "timings_s": {"matrix": t_matrix, "dataset": t_data, "tuning": t_tune, "training": t_train, "total": total},
        "stscam_version": getattr(stscam, "__version__", None), "torch_version": torch.__version__}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
