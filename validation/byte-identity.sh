#!/usr/bin/env bash
# Byte identity of two stscam binaries over the outputs of every command (render mono, spectral,
# the samplers, RGB, two gratings, adaptive; 3-D eye contact direct, padded and from the
# camera-side table; matrix and a depth stack; calibrate; reconstruct CG/ADMM-TV/depth; demo and
# colour demo; datasets 2-D, depth and 3-D; sweep with PSNR; tolerance; grating; info, probe;
# bench recon), at small sizes. Every file each command writes (and its stdout) is compared with
# cmp; JSON files and stdout are compared after removing timing fields (keys ending in `_s`,
# `_ms`, `second(s)`, `elapsed`, `*_per_s`, `threads`, peak memory; numbers with a time or
# memory unit in text), which are the only parts allowed to differ.
#
# Usage: validation/byte-identity.sh BIN_A BIN_B [WORKDIR]   (prints one line per command and
# "N identical, M differ"; exit 1 if any differ).
set -uo pipefail
a=$(realpath "$1"); b=$(realpath "$2")
work=${3:-$(mktemp -d)}
repo=$(cd "$(dirname "$0")/.." && pwd)
cd "$repo"
mkdir -p "$work"

strip_json() { python3 - "$1" "$work" <<'PY'
import json, re, sys
def clean(v):
    if isinstance(v, dict):
        return {k: clean(x) for k, x in v.items()
                if not re.search(r'(_s|_ms|seconds?|elapsed|_per_s|threads|time|memory_mib|peak_rss\w*)$', k)}
    if isinstance(v, list):
        return [clean(x) for x in v]
    return v
txt = open(sys.argv[1], errors="replace").read()
for side in ("a", "b"):
    txt = txt.replace(sys.argv[2] + "/" + side + "/", "WORK/")
try:
    print(json.dumps(clean(json.loads(txt)), sort_keys=True))
except ValueError:
    # JSON lines, or text: drop numbers that follow a time word.
    out = []
    for line in txt.splitlines():
        try:
            out.append(json.dumps(clean(json.loads(line)), sort_keys=True))
        except ValueError:
            out.append(re.sub(r'(\d+(\.\d+)?\s*(s|ms|min|MiB|GiB)\b|[\d.]+ ?[kM]?(paths|rays|samples)/s)', 'T', line))
    print("\n".join(out))
PY
}
same=0; differ=0
run() { # NAME ARGS... (use OUT for the output folder)
    local name=$1; shift
    for side in a b; do
        local bin=${!side} dir="$work/$side/$name"
        rm -rf "$dir"; mkdir -p "$dir"
        local args=("${@//OUT/$dir/out}")
        export STSCAM_CACHE_DIR="$dir/cache"
        "$bin" "${args[@]}" > "$dir/stdout.txt" 2> "$dir/stderr.txt"
        echo $? > "$dir/exit.txt"
    done
    local bad=()
    while IFS= read -r f; do
        local fa="$work/a/$name/$f" fb="$work/b/$name/$f"
        [ "$f" = stderr.txt ] && continue
        if [ ! -f "$fb" ]; then bad+=("$f (only in A)"); continue; fi
        if cmp -s "$fa" "$fb"; then continue; fi
        case "$f" in
            *.json|*.jsonl|*.txt|*.md|*.csv)
                if [ "$(strip_json "$fa")" = "$(strip_json "$fb")" ]; then continue; fi;;
        esac
        bad+=("$f")
    done < <(cd "$work/a/$name" && find . -type f | sed 's#^\./##' | sort)
    while IFS= read -r f; do
        [ -f "$work/a/$name/$f" ] || bad+=("$f (only in B)")
    done < <(cd "$work/b/$name" && find . -type f | sed 's#^\./##' | sort)
    if [ ${#bad[@]} -eq 0 ]; then
        same=$((same + 1)); echo "identical  $name"
    else
        differ=$((differ + 1)); echo "DIFFER     $name: ${bad[*]}"
    fi
}
small='--set sensor.crop_px=[96,96]'
run render-mono render --spp 16 --out OUT
run render-spectral render --spp 8 --spectral --out OUT
run render-independent render --spp 8 --sampler independent --out OUT
run render-sobol render --spp 8 --sampler sobol --out OUT
run render-rgb render --spp 8 --set display.image=rgb:letter:F@32+black@32+letter:A@32 --set display.primaries=lcd --out OUT
run render-two-grating render scenes/two-grating.toml --spp 8 --out OUT
run render-rgb-multiplex render scenes/rgb-multiplex.toml --spp 4 $small --out OUT
run render-adaptive render --spp 32 --adaptive --out OUT
run eye-contact render scenes/eye-contact.toml --spp 4 --set sensor.crop_px=96 --set sensor.pitch_um=40 --frontal-px 48 --out OUT
run eye-contact-padded render scenes/eye-contact.toml --spp 4 --user-side padded --set sensor.crop_px=64 --set sensor.pitch_um=60 --out OUT
run eye-contact-table render scenes/eye-contact.toml --spp 8 --set sensor.crop_px=64 --set sensor.pitch_um=60 --camera-table OUTtables --table-spp 16 --table-reps 4 --out OUT
run matrix matrix --spp 8 $small --set display.image=letter:F@32 --out OUT
run matrix-stack matrix --spp 4 $small --set display.image=letter:F@32 --depth-mm 500,550,600 --out OUT
run calibrate calibrate --spp 4 $small --set display.image=letter:F@16 --out OUT
run info info
run info-json info --json
run probe probe --pixel 220,220 --json
run grating grating --lambda-nm 520:545:26 --json
run grating-rcwa grating --model rcwa --lambda-nm 525:540:4 --json
run sweep sweep --vary bottom_hoe.height_mm=20:60:3 --psnr letter:F --psnr-spp 4 $small --json --out OUT
run tolerance tolerance --draw hoe.shrinkage=normal\(0,0.005\) --samples 6 --seed 3 --out OUT
run tolerance-psnr tolerance --draw hoe.shrinkage=uniform\(0,0.01\) --samples 3 --psnr --psnr-spp 4 $small --out OUT
run demo demo --spp 4 --out OUT
run demo-colour demo --colour --spp 2 --out OUT
run dataset-small dataset validation/python/noiseless.toml --out OUT
run dataset-paper dataset datasets/paper-small.toml --out OUT
run dataset-depth dataset validation/python/depth-tiny.toml --out OUT
run dataset-meshes dataset validation/python/meshes-tiny.toml --out OUT
run bench-recon bench recon $small --set display.image=letter:F@16
# reconstruct from A's own matrix and a capture (both sides read the same inputs)
inp="$work/inputs"; rm -rf "$inp"; mkdir -p "$inp"
"$a" matrix --spp 8 $small --set display.image=letter:F@32 --out "$inp/m" >/dev/null 2>&1
"$a" render --spp 8 --seed 2 $small --set display.image=letter:F@32 --out "$inp/r" >/dev/null 2>&1
"$a" matrix --spp 4 $small --set display.image=letter:F@32 --depth-mm 500,550,600 --out "$inp/s" >/dev/null 2>&1
run reconstruct-cg reconstruct --matrix "$inp/m/H.npz" --capture "$inp/r/capture.exr" --method cg --truth letter:F --out OUT
run reconstruct-admm reconstruct --matrix "$inp/m/H.npz" --capture "$inp/r/capture.exr" --method admm-tv --truth letter:F --out OUT
run reconstruct-depth reconstruct --matrix "$inp/s/H_stack.npz" --capture "$inp/r/capture.exr" --method depth --out OUT
echo "$same identical, $differ differ"
[ "$differ" -eq 0 ]
