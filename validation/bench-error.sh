#!/usr/bin/env bash
# Run time against error, regenerating validation/results/:
#  1. paper scene: stscam's default estimator against a plain spectral path tracer (uniform
#     wavelengths, analog Russian roulette), relative RMSE against a high-spp reference;
#  2. the waveguide scene matched with Mitsuba (validation/mitsuba/waveguide.toml): both stscam
#     estimators and, where out/mitsuba-venv exists (validation/mitsuba/run.sh makes it), Mitsuba
#     3, all with the same reference-free error measure (two independent half renders).
# Usage: validation/bench-error.sh [BUDGET_S] [REF_SPP]     (defaults 60 and 8192)
set -euo pipefail
cd "$(dirname "$0")/.."
budget=${1:-60}
ref=${2:-8192}
cargo build --release --quiet
bin=target/release/stscam
"$bin" bench render --budget-s "$budget" --ref-spp "$ref" --out validation/results/paper >/dev/null
extra=()
if [[ -x out/mitsuba-venv/bin/python ]]; then
    info=$("$bin" info validation/mitsuba/waveguide.toml --json)
    focus=$(python3 -c "import json,sys; print(json.loads(sys.argv[1])['focus_distance_mm'])" "$info")
    d0=$(python3 -c "import json,sys; print(json.loads(sys.argv[1])['sensor_distance_mm'])" "$info")
    if [[ -e /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 ]]; then
        export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
    fi
    mkdir -p out/mitsuba-home
    HOME="$PWD/out/mitsuba-home" out/mitsuba-venv/bin/python validation/mitsuba/bench.py \
        --out out/bench-mitsuba.json --budget-s "$((budget * 5))" --focus-mm "$focus" --sensor-mm "$d0"
    extra=(--extra out/bench-mitsuba.json)
fi
"$bin" bench render validation/mitsuba/waveguide.toml --error halves --budget-s "$budget" \
    "${extra[@]}" --out validation/results/matched >/dev/null
cat validation/results/paper/bench-render.md validation/results/matched/bench-render.md
