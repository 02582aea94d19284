#!/usr/bin/env bash
# Speed of 3-D scenes, regenerating validation/results/{eye-contact,mesh-plain-glass}/:
#  1. BVH: build time and closest-hit rays/s with 1 and 2 threads on a 1M-triangle mesh
#     (`stscam bench bvh`, medians of 3 seeds) -> validation/results/scenes3d/bench-bvh.json;
#  2. the eye-contact scene at 440x440: run time against relative RMSE (two independent half
#     renders; time to 5 % and to 1 %);
#  3. the mesh scenes matched with Mitsuba 3 (validation/mitsuba/mesh-plain-glass.toml, through
#     plain glass, and validation/mitsuba/mesh-waveguide.toml, through the waveguide): stscam
#     and, where out/mitsuba-venv exists (validation/mitsuba/run.sh makes it), Mitsuba 3, with
#     the same reference-free error measure, side by side.
# Usage: validation/bench-scenes3d.sh [BUDGET_S]     (default 120)
set -euo pipefail
cd "$(dirname "$0")/.."
budget=${1:-120}
cargo build --release --quiet
bin=target/release/stscam
mkdir -p validation/results/scenes3d
"$bin" bench bvh > validation/results/scenes3d/bench-bvh.json
"$bin" bench render scenes/eye-contact.toml --crop 440 --error halves --target 0.01 \
    --budget-s "$budget" --out validation/results/eye-contact >/dev/null
for scene in mesh-plain-glass mesh-waveguide; do
    extra=()
    if [[ -x out/mitsuba-venv/bin/python ]]; then
        validation/mitsuba/curve.sh "$scene" "out/bench-mitsuba-$scene.json" "$((budget * 3))"
        extra=(--extra "out/bench-mitsuba-$scene.json")
    fi
    "$bin" bench render "validation/mitsuba/$scene.toml" --error halves --budget-s "$budget" \
        "${extra[@]}" --out "validation/results/$scene" >/dev/null
done
cat validation/results/scenes3d/bench-bvh.json validation/results/eye-contact/bench-render.md \
    validation/results/mesh-plain-glass/bench-render.md validation/results/mesh-waveguide/bench-render.md
