#!/usr/bin/env bash
# Mitsuba 3's run time against error on a matched scene, for `stscam bench render --extra`:
#   validation/mitsuba/curve.sh SCENE OUT.json BUDGET_S
# SCENE is waveguide, mesh-plain-glass or mesh-waveguide (validation/mitsuba/SCENE.toml). Needs
# out/mitsuba-venv (validation/mitsuba/run.sh makes it) and a built target/release/stscam (for
# the scene's focus and sensor distances). Uses llvm_ad_spectral where libLLVM 19 is installed.
set -euo pipefail
cd "$(dirname "$0")/../.."
scene=$1
out=$2
budget=$3
info=$(target/release/stscam info "validation/mitsuba/$scene.toml" --json)
focus=$(python3 -c "import json,sys; print(json.loads(sys.argv[1])['focus_distance_mm'])" "$info")
d0=$(python3 -c "import json,sys; print(json.loads(sys.argv[1])['sensor_distance_mm'])" "$info")
if [[ -e /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 ]]; then
    export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
fi
mkdir -p out/mitsuba-home
HOME="$PWD/out/mitsuba-home" out/mitsuba-venv/bin/python validation/mitsuba/bench.py \
    --scene "$scene" --out "$out" --budget-s "$budget" --focus-mm "$focus" --sensor-mm "$d0"
