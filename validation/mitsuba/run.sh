#!/usr/bin/env bash
# Mitsuba 3 cross-check of stscam (README.md in this folder).
#   validation/mitsuba/run.sh                      re-render both scenes with Mitsuba (moderate
#                                                  spp), render them with stscam, compare
#   validation/mitsuba/run.sh --update-references  re-render the committed references (high spp)
# Creates out/mitsuba-venv (mitsuba 3.9.1, numpy 2.2.6) if missing. Variant: llvm_ad_spectral if
# libLLVM 19 works (probed in a subprocess: old LLVM aborts the process), else scalar_spectral.
set -euo pipefail
cd "$(dirname "$0")/../.."
mode=check
if [[ "${1:-}" == "--update-references" ]]; then mode=update; fi
here=validation/mitsuba
venv="$PWD/out/mitsuba-venv"
work=out/mitsuba-check
mkdir -p "$work" out/mitsuba-home
cargo build --release --quiet     # before HOME changes (rustup reads $HOME)
# Dr.Jit caches kernels under $HOME/.drjit: keep it in a disposable place.
export HOME="$PWD/out/mitsuba-home"

if ! "$venv/bin/python" -c "import mitsuba, numpy; assert mitsuba.__version__ == '3.9.1'" >/dev/null 2>&1; then
    rm -rf "$venv"
    if python3 -m venv "$venv" >/dev/null 2>&1 && "$venv/bin/python" -m pip --version >/dev/null 2>&1; then
        "$venv/bin/python" -m pip install --quiet --disable-pip-version-check mitsuba==3.9.1 numpy==2.2.6
    else
        # Debian without python3-venv (no ensurepip): a pip-less venv filled by the pip of
        # out/ci-venv (.ci/run bootstraps it) or of the host.
        rm -rf "$venv"
        python3 -m venv --without-pip "$venv"
        if [[ -x out/ci-venv/bin/python ]] && out/ci-venv/bin/python -m pip --version >/dev/null 2>&1; then
            pipper=out/ci-venv/bin/python
        else
            pipper=python3
        fi
        "$pipper" -m pip --python "$venv/bin/python" install --quiet --disable-pip-version-check mitsuba==3.9.1 numpy==2.2.6
    fi
fi
py="$venv/bin/python"

# MITSUBA_VARIANT=scalar_spectral forces the CPU fallback (what a machine without libLLVM 19 runs).
variant=${MITSUBA_VARIANT:-$(cd "$here" && "$py" -c "import scenes; v, _ = scenes.choose_variant(); print(v)")}
if [[ "$variant" == llvm_ad_spectral ]] && [[ -e /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 ]]; then
    export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
fi
echo "mitsuba: variant $variant"

stscam=target/release/stscam
info="$work/info.json"
"$stscam" info "$here/waveguide.toml" --json > "$info"
focus=$("$py" -c "import json; print(json.load(open('$info'))['focus_distance_mm'])")
d0=$("$py" -c "import json; print(json.load(open('$info'))['sensor_distance_mm'])")

# Sample counts. scalar_spectral (2 cores): plain glass ~0.14 s/spp, waveguide ~1 s/spp.
if [[ "$mode" == update ]]; then
    spp_plain=4096; spp_wg=8192; passes_plain=16; passes_wg=32; dest="$here/reference"
elif [[ "$variant" == llvm_ad_spectral ]]; then
    spp_plain=1024; spp_wg=2048; passes_plain=4; passes_wg=8; dest="$work"
else
    spp_plain=256; spp_wg=160; passes_plain=2; passes_wg=2; dest="$work"
fi

status=0
for scene in plain-glass waveguide; do
    if [[ $scene == plain-glass ]]; then spp=$spp_plain; passes=$passes_plain; else spp=$spp_wg; passes=$passes_wg; fi
    t0=$(date +%s)
    "$py" "$here/scenes.py" --scene "$scene" --spp "$spp" --passes "$passes" --seed 7 \
        --variant "$variant" --focus-mm "$focus" --sensor-mm "$d0" --out "$dest/$scene.npy" 2>&1 | grep -v 'terrible performance' || true
    test -s "$dest/$scene.npy"
    echo "mitsuba: $scene rendered in $(( $(date +%s) - t0 )) s ($variant, $spp spp)"
    for seed in 1 2; do
        "$stscam" render "$here/$scene.toml" --out "$work/stscam-$scene-$seed" --spp 128 --seed "$seed" >/dev/null
    done
    if "$py" "$here/compare.py" --scene "$scene" --mitsuba "$dest/$scene.npy" \
        --stscam "$work/stscam-$scene-1/capture.exr" "$work/stscam-$scene-2/capture.exr" \
        --json "$work/$scene-compare.json"; then
        echo "mitsuba: $scene agrees with stscam"
    else
        echo "mitsuba: $scene DISAGREES with stscam (see $work/$scene-compare.json)" >&2
        status=1
    fi
done
exit $status
