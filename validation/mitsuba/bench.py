"""Run time against error for Mitsuba 3 on the waveguide scene that matches
validation/mitsuba/waveguide.toml, for `stscam bench render --extra`.

Each point renders two independent halves of the samples (scenes.render with passes=2) and
reports the wall time of both and eps = ||A - B|| / (2 ||(A + B)/2||), the relative RMS Monte
Carlo error of their mean: the same measure as `stscam bench render --error halves`.
A warm-up render (JIT compilation in the LLVM variants) is not counted.

usage: python bench.py --out FILE.json [--budget-s 300] [--max-spp 8192]
"""
import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scenes  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--scene", default="waveguide")
    ap.add_argument("--budget-s", type=float, default=300.0)
    ap.add_argument("--max-spp", type=int, default=8192)
    ap.add_argument("--focus-mm", type=float, required=True)
    ap.add_argument("--sensor-mm", type=float, required=True)
    a = ap.parse_args()
    variant, libllvm = scenes.choose_variant()
    if libllvm:
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
    scenes.render(a.scene, 2, 99, variant, a.focus_mm, a.sensor_mm)  # warm-up
    points, spent, spp = [], 0.0, 2
    while spp <= a.max_spp and spent < a.budget_s:
        _, (eps, _), t, done = scenes.render(a.scene, spp, 1 + spp, variant, a.focus_mm, a.sensor_mm, passes=2)
        spent += t
        points.append({"spp": done, "seconds": t, "relative_rmse": eps})
        print(f"mitsuba {variant}: {done} spp, {t:.3f} s, error {100 * eps:.2f} %", file=sys.stderr)
        if eps < 0.005:
            break
        spp *= 2
    import mitsuba as mi
    what = "Python vHOE BSDF" if "waveguide" in a.scene else "plain glass"
    out = {"name": f"Mitsuba {mi.__version__} ({variant}, {what})", "variant": variant,
           "error": "halves", "points": points}
    with open(a.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
