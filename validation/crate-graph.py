#!/usr/bin/env python3
"""Draws the workspace's crate graph from `cargo metadata` as docs/crate-graph.svg.

Each member is a box on the row of its layer (above every crate it uses, and just below the
lowest crate that uses it); an arrow points from a crate to each member it depends on, after
transitive reduction (an edge implied by a longer path is left out, so the picture shows the
layering rather than every import), dev-only edges dashed. Run from anywhere:
`python3 validation/crate-graph.py [--out docs/crate-graph.svg]`; it needs only cargo and the
standard library.
"""
import argparse
import json
import os
import subprocess
import sys
from xml.sax.saxutils import escape

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def graph():
    meta = json.loads(subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
        cwd=ROOT, check=True, capture_output=True, text=True).stdout)
    names = {p["name"] for p in meta["packages"]}
    deps, dev, desc = {}, {}, {}
    for p in meta["packages"]:
        n = p["name"]
        desc[n] = p.get("description") or ""
        deps[n] = {d["name"] for d in p["dependencies"] if d["name"] in names and d["kind"] is None}
        dev[n] = {d["name"] for d in p["dependencies"] if d["name"] in names and d["kind"] == "dev"} - deps[n]
    return deps, dev, desc


def layers(deps):
    level = {}

    def lv(n, stack=()):
        if n in stack:
            sys.exit(f"loop: {' -> '.join(stack + (n,))}")
        if n not in level:
            level[n] = 1 + max((lv(d, stack + (n,)) for d in deps[n]), default=-1)
        return level[n]

    for n in deps:
        lv(n)
    # As late as possible: a crate sits just below the lowest crate that uses it, so an arrow
    # to a crate used only high up (reconstruction) does not cross the rows between.
    users = {n: [m for m in deps if n in deps[m]] for n in deps}
    for n in sorted(deps, key=lambda n: -level[n]):
        if users[n]:
            level[n] = min(level[m] for m in users[n]) - 1
    return level


def reduce(deps):
    def reach(n, seen=None):
        seen = set() if seen is None else seen
        for d in deps[n]:
            if d not in seen:
                seen.add(d)
                reach(d, seen)
        return seen

    out = {}
    for n, ds in deps.items():
        out[n] = {d for d in ds if not any(d in reach(o) for o in ds if o != d)}
    return out


def svg(deps, dev, desc):
    level = layers(deps)
    red = reduce(deps)
    rows = {}
    for n, l in sorted(level.items(), key=lambda kv: (kv[1], kv[0])):
        rows.setdefault(l, []).append(n)
    bw, bh, gx, gy = 150, 34, 30, 70
    rail = 70  # side margins for the arrows that skip rows
    width = max(len(r) for r in rows.values()) * (bw + gx) + gx + 2 * rail
    top = max(rows)
    height = (top + 1) * (bh + gy) + gy
    pos = {}
    for l, ns in rows.items():
        x0 = (width - (len(ns) * (bw + gx) - gx)) / 2
        y = gy / 2 + (top - l) * (bh + gy)
        for i, n in enumerate(ns):
            pos[n] = (x0 + i * (bw + gx), y)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" height="{height:.0f}" '
           f'font-family="sans-serif" font-size="13">',
           '<defs><marker id="a" viewBox="0 0 10 10" refX="10" refY="5" markerWidth="7" '
           'markerHeight="7" orient="auto"><path d="M0,0 L10,5 L0,10 z" fill="#555"/></marker></defs>',
           '<rect width="100%" height="100%" fill="white"/>']
    def edge(a, b, dash):
        (xa, ya), (xb, yb) = pos[a], pos[b]
        style = ' stroke-dasharray="5,4"' if dash else ''
        x1, y1, x2, y2 = xa + bw / 2, ya + bh, xb + bw / 2, yb
        if level[a] - level[b] > 1:
            # Skips rows: round the boxes between along the nearer side margin.
            side = rail / 2 if x1 + x2 < width else width - rail / 2
            d = f"M{x1:.1f},{y1:.1f} C{side:.1f},{y1 + gy:.1f} {side:.1f},{y2 - gy:.1f} {x2:.1f},{y2:.1f}"
        else:
            d = f"M{x1:.1f},{y1:.1f} L{x2:.1f},{y2:.1f}"
        out.append(f'<path d="{d}" fill="none" stroke="#555" stroke-width="1.2"{style} '
                   'marker-end="url(#a)"/>')
    for a in sorted(red):
        for b in sorted(red[a]):
            edge(a, b, False)
        for b in sorted(dev[a]):
            edge(a, b, True)
    for n, (x, y) in pos.items():
        out.append(f'<g><title>{escape(desc[n])}</title><rect x="{x:.1f}" y="{y:.1f}" width="{bw}" '
                   f'height="{bh}" rx="6" fill="#eef3fb" stroke="#2b5797"/>'
                   f'<text x="{x + bw / 2:.1f}" y="{y + bh / 2 + 4:.1f}" text-anchor="middle">'
                   f'{escape(n)}</text></g>')
    out.append('</svg>')
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "crate-graph.svg"))
    a = ap.parse_args()
    deps, dev, desc = graph()
    text = svg(deps, dev, desc)
    tmp = a.out + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, a.out)
    print(f"wrote {a.out}: {len(deps)} crates, {sum(map(len, deps.values()))} dependency edges")


if __name__ == "__main__":
    main()
