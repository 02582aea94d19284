#!/usr/bin/env bash
# Dataset generation speed at the paper's size (64x64 objects, 440x440 captures, 8-bit sensor
# noise, every file written): datasets/paper-small.toml in matrix mode (300 samples) with 2 and
# 1 threads, and the same recipe in render mode at 64 spp (RENDER_SAMPLES samples). Prints the
# median samples/s of the sample phase (H excluded) and of the whole process over RUNS runs.
#   validation/bench-dataset.sh [RUNS] [RENDER_SAMPLES]
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-5}
render_samples=${2:-8}
cargo build --release --quiet
bin=target/release/stscam
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
sed -e 's/^name = .*/name = "bench-render"/' -e 's/^mode = .*/mode = "render"/' \
    -e "s/^samples = .*/samples = $render_samples/" datasets/paper-small.toml > "$tmp/render.toml"
median() { sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }
bench() { # label recipe samples runs threads
    local label=$1 recipe=$2 n=$3 r=$4 t=$5 rates=() walls=()
    for i in $(seq "$r"); do
        rm -rf "$tmp/out"
        local t0 t1 line
        t0=$(date +%s.%N)
        line=$("$bin" dataset "$recipe" --out "$tmp/out" --threads "$t" 2>&1 | tail -1)
        t1=$(date +%s.%N)
        rates+=("$(sed -E 's/.* = ([0-9.]+) samples\/s.*/\1/' <<<"$line")")
        walls+=("$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.2f", b - a }')")
    done
    printf '%s, %s threads: sample phase %s samples/s; whole process %s s for %s samples (%s samples/s) — medians of %s runs\n' \
        "$label" "$t" "$(printf '%s\n' "${rates[@]}" | median)" "$(printf '%s\n' "${walls[@]}" | median)" "$n" \
        "$(awk -v n="$n" -v w="$(printf '%s\n' "${walls[@]}" | median)" 'BEGIN { printf "%.1f", n / w }')" "$r"
}
bench "matrix mode (paper-small.toml)" datasets/paper-small.toml 300 "$runs" 2
bench "matrix mode (paper-small.toml)" datasets/paper-small.toml 300 "$runs" 1
bench "render mode, 64 spp" "$tmp/render.toml" "$render_samples" 1 2
