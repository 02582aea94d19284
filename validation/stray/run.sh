#!/usr/bin/env bash
# The stray-light figures of docs/stray.md and validation/results/stray/: the paper camera (as
# published: the top vHOE taped over), the same with the tape removed, the RGB multiplex film,
# and the paper camera with the display behind the screen at full white (50 x 50 mm, 10 mm
# behind the back face, centred on the bottom vHOE) with a white target in front and with the
# letter F, the paper camera with polished plate edges, and with a film haze of 1 % (lobe g 0.9,
# assumed); each at 16 spp, seed 1, the default roulette threshold (about 6 min on 2 cores).
#   validation/stray/run.sh [STSCAM] [OUT]
set -euo pipefail
stscam=${1:-target/release/stscam}
out=${2:-validation/results/stray}
mkdir -p "$out"
run() {
    local name=$1
    shift
    "$stscam" stray "$@" --spp 16 --seed 1 --out "$out/$name.tmp"
    mkdir -p "$out/$name"
    # Kept in the repository: the report and its chart (the class images are written to
    # $out/$name.tmp and removed: run the command itself to keep them).
    for f in stray.json stray.md stray.png; do
        if [[ -f "$out/$name.tmp/$f" ]]; then cp "$out/$name.tmp/$f" "$out/$name/$f"; fi
    done
    rm -rf "$out/$name.tmp"
}
run paper
run paper-uncovered --set top_hoe.covered=false
run rgb-multiplex scenes/rgb-multiplex.toml
run paper-display-behind --set behind_display.enabled=true --set display.image=white
run paper-display-behind-target --set behind_display.enabled=true
run paper-polished-edges --set plate.edges=polished
run paper-haze --set hoe.haze_fraction=0.01
