#!/usr/bin/env bash
# Render benchmark of the paper scene: wall time and paths/s at 440x440 and 64 spp with 1 and
# 2 threads (median of RUNS runs), then relative RMSE against a high-spp reference for several
# spp, to find the time to 1 % error. Usage: validation/bench-render.sh [RUNS] [REF_SPP]
# Needs only cargo and python3. Results go to out/bench-render/.
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-5}
ref_spp=${2:-2048}
out=out/bench-render
mkdir -p "$out"
cargo build --release --quiet
bin=target/release/stscam
median() { python3 -c 'import sys,statistics; print(statistics.median(float(x) for x in sys.argv[1:]))' "$@"; }
field() { python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(d[sys.argv[2]] if sys.argv[2] in d else d["stats"][sys.argv[2]])' "$1" "$2"; }
echo "threads  render_s(median)  wall_s(median)  camera_paths_per_s(median)  replica_paths_per_s(median)"
for t in 1 2; do
  rs=(); ws=(); ps=(); bs=()
  for i in $(seq "$runs"); do
    "$bin" render --spp 64 --threads "$t" --out "$out/t$t" 2>/dev/null
    j="$out/t$t/capture.json"
    rs+=("$(field "$j" render_time_s)"); ws+=("$(field "$j" wall_time_s)"); ps+=("$(field "$j" paths_per_second)")
    b=$(field "$j" branches); c=$(field "$j" camera_paths); r=$(field "$j" render_time_s)
    bs+=("$(python3 -c "print($b/$r)")")
  done
  printf '%7s  %16.3f  %14.3f  %26.3e  %27.3e\n' "$t" "$(median "${rs[@]}")" "$(median "${ws[@]}")" "$(median "${ps[@]}")" "$(median "${bs[@]}")"
done
echo
echo "reference: $ref_spp spp"
"$bin" render --spp "$ref_spp" --seed 999 --out "$out/ref" 2>/dev/null
echo "spp  render_s  relative_rmse"
for spp in 8 16 32 64 128; do
  "$bin" render --spp "$spp" --out "$out/s$spp" 2>/dev/null
  printf '%4s  %8.3f  %s\n' "$spp" "$(field "$out/s$spp/capture.json" render_time_s)" "$("$bin" compare "$out/s$spp/capture.exr" "$out/ref/capture.exr" --json | python3 -c 'import json,sys; print(round(json.load(sys.stdin)["relative_rmse"],5))')"
done
