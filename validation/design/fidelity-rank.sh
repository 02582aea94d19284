#!/usr/bin/env bash
# How well does the fast search fidelity rank designs as the full fidelity does? The same N
# random designs of the paper problem (a Latin hypercube over studies/paper-dilemma.toml's six
# parameters: `[optimizer] initial = N` with budget N, so no model is involved and both runs
# draw the same points for the same seed) are evaluated once at the study's [search] fidelity
# and once with [search] set to its [final] fidelity; the Spearman rank correlation of each
# metric between the two is printed (goal >= 0.9 for PSNR and FOV). Usage:
# validation/design/fidelity-rank.sh [N] [SEED] [OUT] (defaults 30, 1, out/fidelity-rank);
# STSCAM names the binary (default target/release/stscam).
set -euo pipefail
n=${1:-30}
seed=${2:-1}
out=${3:-out/fidelity-rank}
bin=${STSCAM:-target/release/stscam}
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$out"
for f in search final; do
    # No constraints: every design counts in the ranking.
    python3 "$here/study_variant.py" "$here/../../studies/paper-dilemma.toml" \
        --objectives psnr_db,fov_capture_vertical_deg --search-fidelity "$f" --no-constraints \
        --optimizer "initial=$n" > "$out/$f.toml"
    rm -rf "$out/$f"
    "$bin" optimize "$out/$f.toml" --budget "$n" --seed "$seed" --out "$out/$f" --skip-final 2> "$out/$f.log" > /dev/null
done
python3 - "$out/search/history.jsonl" "$out/final/history.jsonl" <<'PY'
import json, sys
a = [json.loads(l) for l in open(sys.argv[1])]
b = [json.loads(l) for l in open(sys.argv[2])]
assert [r["params"] for r in a] == [r["params"] for r in b], "the two runs drew other designs"
def ranks(x):
    order = sorted(range(len(x)), key=lambda i: x[i])
    r = [0.0] * len(x)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and x[order[j + 1]] == x[order[i]]:
            j += 1
        for k in range(i, j + 1):
            r[order[k]] = (i + j) / 2.0
        i = j + 1
    return r
def spearman(x, y):
    rx, ry = ranks(x), ranks(y)
    mx, my = sum(rx) / len(rx), sum(ry) / len(ry)
    sxy = sum((p - mx) * (q - my) for p, q in zip(rx, ry))
    sxx = sum((p - mx) ** 2 for p in rx)
    syy = sum((q - my) ** 2 for q in ry)
    return sxy / (sxx * syy) ** 0.5
for m in ("psnr_db", "fov_capture_vertical_deg"):
    x = [r["metrics"][m] for r in a]
    y = [r["metrics"][m] for r in b]
    ok = [(p, q) for p, q in zip(x, y) if p is not None and q is not None]
    print(f"{m}: Spearman {spearman(*zip(*ok)):.3f} over {len(ok)} designs "
          f"(search {min(p for p, _ in ok):.2f}..{max(p for p, _ in ok):.2f}, "
          f"full {min(q for _, q in ok):.2f}..{max(q for _, q in ok):.2f})")
PY
