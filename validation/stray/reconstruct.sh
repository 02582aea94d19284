#!/usr/bin/env bash
# What stray light does to the reconstruction (docs/stray.md): the designed-path H of the
# paper camera (64 spp), and noise-free captures from stscam stray (64 spp, another seed): the
# signal class alone (what H models), every path together (all_paths: what the camera records),
# and every path with the display behind the screen at full white; each reconstructed by
# ADMM-TV with H and scored against the letter F. About 5 min on 2 cores.
#   validation/stray/reconstruct.sh [STSCAM] [OUT]
set -euo pipefail
stscam=${1:-target/release/stscam}
out=${2:-out/stray-reconstruct}
mkdir -p "$out"
"$stscam" matrix --spp 64 --out "$out/H"
"$stscam" stray --spp 64 --seed 2 --out "$out/stray"
"$stscam" stray --spp 64 --seed 2 --set behind_display.enabled=true --out "$out/stray-behind"
for c in stray/class_00_signal stray/all_paths stray-behind/all_paths; do
    "$stscam" reconstruct --matrix "$out/H/H.npz" --capture "$out/$c.exr" --truth letter:F \
        --out "$out/recon-${c//\//-}"
done
