#!/usr/bin/env python3
"""Where Kogelnik is good enough: max over wavelength of |eta_Kogelnik - eta_RCWA| over the
paper design's field, for the bulk and contact stacks, from `stscam grating --json`.

For every field angle (X, Y) on a grid both models are run over the band; per polarisation the
largest absolute difference over wavelengths and over the orders both report (reflected +1,
transmitted 0 and -1) is kept, and the relative error of the integral of the reflected +1
efficiency over the band. Writes OUT/kogelnik-map.svg (a heat map per stack and polarisation),
OUT/kogelnik-map.json and OUT/kogelnik-map.md. No plotting package needed.

Usage: kogelnik_map.py [--stscam PATH] [--out DIR] [--band START:STOP:N] [--fields NX,NY]
"""

import argparse
import json
import os
import subprocess


def run(exe, model, stack, x, y, band):
    out = subprocess.run(
        [exe, "grating", "--model", model, "--stack", stack, "--json", "--lambda-nm", band,
         # The map's (x, y) are the light's travel direction (tan x, tan y, 1); --field-deg is
         # the viewing direction, the opposite (docs/cli.md).
         f"--field-deg={-x},{-y}"], check=True, capture_output=True, text=True).stdout
    rep = json.loads(out)
    return {(o["side"], o["order"]): o for o in rep["orders"]}, rep["lambda_nm"]


def compare(exe, stack, x, y, band):
    k, lam = run(exe, "kogelnik", stack, x, y, band)
    r, _ = run(exe, "rcwa", stack, x, y, band)
    worst = [0.0, 0.0]
    for key in [("reflected", 1), ("transmitted", 0), ("transmitted", -1)]:
        a, b = k.get(key), r.get(key)
        if a is None or b is None:
            continue
        for p, name in enumerate(["eta_te", "eta_tm"]):
            for i in range(len(lam)):
                # Orders that cannot leave (trapped, direction null) are not compared.
                if a["direction"][i] is None or b["direction"][i] is None:
                    continue
                worst[p] = max(worst[p], abs(a[name][i] - b[name][i]))
    integ = []
    for p, name in enumerate(["eta_te", "eta_tm"]):
        ia = sum(k[("reflected", 1)][name]) if ("reflected", 1) in k else 0.0
        ib = sum(r[("reflected", 1)][name]) if ("reflected", 1) in r else 0.0
        integ.append(abs(ia - ib) / ib if ib > 1e-9 else 0.0)
    return worst, integ


def colour(v, vmax):
    t = min(1.0, v / vmax) if vmax > 0 else 0.0
    # white -> orange -> dark red
    r = 255 - int(80 * t)
    g = int(255 * (1 - t) ** 1.5)
    b = int(255 * (1 - t) ** 3)
    return f"rgb({r},{g},{b})"


def svg(xs, ys, panels, vmax):
    cw, ch, pad, top = 34, 14, 60, 40
    pw = cw * len(xs) + pad
    ph = ch * len(ys) + top + 40
    width = pw * len(panels) + 20
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{ph + 30}" '
             'font-family="sans-serif" font-size="10">']
    for pi, (title, grid) in enumerate(panels):
        ox = 10 + pi * pw + pad - 20
        parts.append(f'<text x="{ox}" y="20" font-size="12">{title}</text>')
        for yi, yv in enumerate(reversed(ys)):
            parts.append(f'<text x="{ox - 4}" y="{top + yi * ch + 10}" text-anchor="end">{yv:g}</text>')
            for xi, _ in enumerate(xs):
                v = grid[len(ys) - 1 - yi][xi]
                parts.append(f'<rect x="{ox + xi * cw}" y="{top + yi * ch}" width="{cw}" '
                             f'height="{ch}" fill="{colour(v, vmax)}"><title>{v:.4f}</title></rect>')
                parts.append(f'<text x="{ox + xi * cw + cw / 2}" y="{top + yi * ch + 10}" '
                             f'text-anchor="middle" font-size="8">{v * 1000:.0f}</text>')
        for xi, xv in enumerate(xs):
            parts.append(f'<text x="{ox + xi * cw + cw / 2}" y="{top + len(ys) * ch + 12}" '
                         f'text-anchor="middle">{xv:g}</text>')
        parts.append(f'<text x="{ox}" y="{top + len(ys) * ch + 28}">field X (deg); rows: field Y (deg)</text>')
    parts.append(f'<text x="10" y="{ph + 20}">cells: max over the band of |eta_K - eta_RCWA| x 1000 '
                 f'(colour scale 0 .. {vmax:g})</text></svg>')
    return "\n".join(parts)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stscam", default="target/release/stscam")
    ap.add_argument("--out", default="validation/results/rcwa")
    ap.add_argument("--band", default="450:650:201")
    ap.add_argument("--fields", default="5,18", help="NX,NY grid points over [-17, 17] deg")
    a = ap.parse_args()
    nx, ny = (int(v) for v in a.fields.split(","))
    xs = [round(-17 + 34 * i / (nx - 1), 3) for i in range(nx)]
    ys = [round(-17 + 34 * i / (ny - 1), 3) for i in range(ny)]
    result = {"band_nm": a.band, "field_x_deg": xs, "field_y_deg": ys, "stacks": {}}
    panels = []
    md = ["| stack | polarisation | max over field and band of abs(d eta) | median over field | "
          "max rel. error of the band integral of eta(R+1) |", "| --- | --- | --- | --- | --- |"]
    for stack in ["bulk", "contact"]:
        grids = [[[0.0] * nx for _ in ys], [[0.0] * nx for _ in ys]]
        integ = [0.0, 0.0]
        for yi, y in enumerate(ys):
            for xi, x in enumerate(xs):
                worst, ie = compare(a.stscam, stack, x, y, a.band)
                for p in range(2):
                    grids[p][yi][xi] = worst[p]
                    integ[p] = max(integ[p], ie[p])
        result["stacks"][stack] = {"max_abs_d_eta_te": grids[0], "max_abs_d_eta_tm": grids[1],
                                   "max_rel_integral_error": integ}
        for p, pol in enumerate(["TE", "TM"]):
            flat = sorted(v for row in grids[p] for v in row)
            md.append(f"| {stack} | {pol} | {flat[-1]:.4f} | {flat[len(flat) // 2]:.4f} | "
                      f"{100 * integ[p]:.2f} % |")
            panels.append((f"{stack}, {pol}", grids[p]))
    os.makedirs(a.out, exist_ok=True)
    vmax = max(max(max(row) for row in g) for _, g in panels)
    with open(os.path.join(a.out, "kogelnik-map.svg"), "w") as f:
        f.write(svg(xs, ys, panels, vmax))
    with open(os.path.join(a.out, "kogelnik-map.json"), "w") as f:
        json.dump(result, f, indent=1)
    with open(os.path.join(a.out, "kogelnik-map.md"), "w") as f:
        f.write("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
