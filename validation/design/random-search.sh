#!/usr/bin/env bash
# Does the Bayesian search beat random search on the paper problem? The same single-objective
# study (the paper's six design parameters, maximise the mean ADMM-TV PSNR of the demo's four
# targets at 550 mm under captured vertical FOV >= 15 deg, search fidelity) is run with the
# default optimiser (a Latin hypercube of 2d + 2 = 14 points, then egobox-ego) and as pure random
# search (`[optimizer] initial = BUDGET`: every evaluation a Latin-hypercube point, no model),
# for seeds 1..SEEDS with the same budget, and the best feasible PSNR of each run is printed
# with the medians. Usage: validation/design/random-search.sh [BUDGET] [SEEDS] [OUT]
# (defaults 30, 5, out/random-search); STSCAM names the binary (default target/release/stscam).
set -euo pipefail
budget=${1:-30}
seeds=${2:-5}
out=${3:-out/random-search}
bin=${STSCAM:-target/release/stscam}
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$out"
variant() { python3 "$here/study_variant.py" "$here/../../studies/paper-dilemma.toml" --objectives psnr_db "$@"; }
variant > "$out/ego.toml"
variant --optimizer "initial=$budget" > "$out/random.toml"
best() { python3 -c 'import json,sys; s=json.load(open(sys.argv[1])); h=[json.loads(l) for l in open(sys.argv[2])]; b=s["best"]; print("nan" if b is None else h[b]["metrics"]["psnr_db"])' "$1/summary.json" "$1/history.jsonl"; }
printf 'seed\tego_psnr_db\trandom_psnr_db\n' > "$out/table.tsv"
for seed in $(seq 1 "$seeds"); do
    for m in ego random; do
        rm -rf "$out/$m-$seed"
        "$bin" optimize "$out/$m.toml" --budget "$budget" --seed "$seed" --out "$out/$m-$seed" --skip-final 2> "$out/$m-$seed.log" > /dev/null
    done
    printf '%s\t%s\t%s\n' "$seed" "$(best "$out/ego-$seed")" "$(best "$out/random-$seed")" | tee -a "$out/table.tsv"
done
python3 - "$out/table.tsv" <<'PY'
import statistics, sys
rows = [l.split("\t") for l in open(sys.argv[1]).read().split("\n")[1:] if l]
ego = [float(r[1]) for r in rows]; rnd = [float(r[2]) for r in rows]
print(f"median best PSNR over {len(rows)} seeds: EGO {statistics.median(ego):.2f} dB, random {statistics.median(rnd):.2f} dB; EGO better in {sum(e > r for e, r in zip(ego, rnd))} of {len(rows)}")
PY
