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
    validation/mitsuba/curve.sh waveguide out/bench-mitsuba.json "$((budget * 5))"
    extra=(--extra out/bench-mitsuba.json)
fi
"$bin" bench render validation/mitsuba/waveguide.toml --error halves --budget-s "$budget" \
    "${extra[@]}" --out validation/results/matched >/dev/null
cat validation/results/paper/bench-render.md validation/results/matched/bench-render.md
