#!/usr/bin/env bash
# Time as users feel it, with and without the camera-side table (render --camera-table):
#  1. eye contact at 440x440: run time against relative RMSE for the direct estimator and for
#     renders from a table (the table's time apart), against a 1,024-spp reference
#     -> validation/results/camera-table/eye-contact/bench-render.{md,json,png};
#  2. the paper scene (display only): the first render of the design with a table (drawn and
#     written) and a further display target read from it, against a direct 212-spp render and
#     an adaptive one at a mean of 24 spp (render --adaptive), both about 1 %;
#  3. the 3-D dataset datasets/meshes-small.toml (SAMPLES samples, default 24) direct at its 16
#     spp and with [camera_table] at 12 user-side paths (the same capture error on its scenes,
#     docs/datasets.md) and the frontal ground truth at 16 spp as in the direct run, the table
#     drawn in the run;
#  4. a 15-point sweep with --psnr (designs vary, so every point pays its own camera side).
# Whole-process wall times from `date`; the machine's cores are printed first.
# Usage: validation/bench-camera-table.sh [BUDGET_S [SAMPLES]]     (defaults 60 and 24)
set -euo pipefail
cd "$(dirname "$0")/.."
budget=${1:-60}
samples=${2:-24}
cargo build --release --quiet
bin=target/release/stscam
res=validation/results/camera-table
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$res"
echo "cores: $(nproc)"
secs() { local t0=$SECONDS; "$@" >/dev/null 2>"$tmp/err" || { cat "$tmp/err"; exit 1; }; echo $((SECONDS - t0)); }
ms() { local t0; t0=$(date +%s.%N); "$@" >/dev/null 2>"$tmp/err" || { cat "$tmp/err"; exit 1; }; python3 -c "print(round($(date +%s.%N) - $t0, 3))"; }

"$bin" bench render scenes/eye-contact.toml --crop 440 --ref-spp 1024 --budget-s "$budget" \
    --out "$res/eye-contact" >/dev/null

echo "paper scene, direct render at 212 spp (1 %): $(ms "$bin" render --spp 212 --out "$tmp/direct") s"
echo "paper scene, adaptive render at a mean of 24 spp (1 %): $(ms "$bin" render --spp 24 --adaptive --out "$tmp/adaptive") s"
echo "paper scene, first render with a table (drawn, 1,024 samples/pixel): $(ms "$bin" render --spp 1 --camera-table "$tmp/ct" --out "$tmp/first") s"
echo "paper scene, further target from the table: $(ms "$bin" render --spp 1 --camera-table "$tmp/ct" --set display.image=siemens:16 --out "$tmp/further") s"

sed "s/^samples = .*/samples = $samples/" datasets/meshes-small.toml > "$tmp/direct.toml"
# The table run keeps the frontal ground truth at the direct run's spp (objects.frontal_spp).
direct_spp=$(sed -n 's/^spp = \([0-9]*\).*/\1/p' "$tmp/direct.toml")
sed -e 's/^name = .*/name = "meshes-small-table"/' -e 's/^spp = .*/spp = 12/' \
    -e "s/^size_px = \\(.*\\)/size_px = \\1\\nfrontal_spp = $direct_spp/" "$tmp/direct.toml" > "$tmp/table.toml"
printf '\n[camera_table]\n' >> "$tmp/table.toml"
echo "meshes-small, $samples samples, direct 16 spp: $(secs "$bin" dataset "$tmp/direct.toml" --out "$tmp/ds-direct") s"
echo "meshes-small, $samples samples, [camera_table], 12 paths: $(secs "$bin" dataset "$tmp/table.toml" --out "$tmp/ds-table") s"

echo "sweep, 15 points, --psnr letter:A: $(secs "$bin" sweep --vary bottom_hoe.height_mm=10:80:15 --psnr letter:A --out "$tmp/sweep") s"
cat "$res/eye-contact/bench-render.md"
