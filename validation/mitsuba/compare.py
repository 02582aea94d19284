"""Compares stscam renders with Mitsuba renders of the same scene (validation/mitsuba).

    python compare.py --scene NAME --mitsuba M.npy [--mitsuba-noise EPS | M.json]
                      --stscam A/capture.exr B/capture.exr [--json OUT]
                      [--max-tolerance FULL BINNED]

The stscam image is the mean of the two captures (two seeds); its noise estimate is
eps_s = ||A - B|| / (2 ||(A + B)/2||) (the relative RMS Monte Carlo error of the mean); the
Mitsuba noise estimate eps_m comes from its JSON (same formula over even/odd passes).

Checks (all must pass; the same rules are in tests/it/mitsuba_reference.rs):
 1. relative RMSE r = ||s - m|| / ||m|| at full resolution <= 2 sqrt(eps_s^2 + eps_m^2) + delta;
 2. the same on 4x4-binned images (32x32), with the noise estimates of the binned images;
 3. waveguide only, replica positions: the peaks (local maxima above 10 % of the maximum, parabolic sub-pixel
    position) of the row profile (sum over all columns) agree one to one within 1 px (not for
    mesh-waveguide: a textured scene has no isolated replica lines).
delta is the allowance for the known model differences, at least twice the sum of their
itemised estimates (README.md, "Known differences"; known_differences.py computes the
waveguide's, 0.6 %, and checks the value here): 0.01 (plain glass and mesh-plain-glass), 0.015
(waveguide), 0.03 (mesh-waveguide, which adds the texture's spectral upsampling differences in
the waveguide's narrow Bragg bands).
With --max-tolerance the comparison also fails when the noise makes the tolerance itself larger
than FULL or BINNED: a check whose tolerance is 65 % would pass a 20 % error (run.sh asks for
at most 0.10 and 0.05 from the llvm_ad_spectral run, and .ci/run fails on it).
--stscam-gain G and --stscam-shift-rows N make the stscam input deliberately wrong (G times too
bright, moved down N rows) to show that the check fails on it (run.sh does, with G = 1.10).
"""
import argparse
import json
import sys

import numpy as np

# The mesh scenes keep the delta of their display-only twin: the extra model differences of the
# user side (RGB upsampling tables and the order of texture interpolation and upsampling, about
# 0.15 % through plain glass and 0.4-0.8 % in the narrow Bragg bands of the waveguide; README.md)
# are well inside it.
DELTA = {"plain-glass": 0.01, "waveguide": 0.015, "mesh-plain-glass": 0.01, "mesh-waveguide": 0.03}
NOISE_FACTOR = 2.0
PEAK_FRACTION = 0.10
PEAK_TOLERANCE_PX = 1.0


def read_exr_y(path):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    a = np.array(mi.Bitmap(path), dtype=np.float64)
    return a.reshape(a.shape[0], a.shape[1], -1)[:, :, 0]


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def bin4(x):
    h, w = x.shape
    return x.reshape(h // 4, 4, w // 4, 4).mean(axis=(1, 3))


def noise(a, b):
    m = np.linalg.norm(0.5 * (a + b))
    return float(np.linalg.norm(a - b) / (2.0 * m)) if m > 0 else 0.0


def peaks(img):
    prof = img.sum(axis=1)
    thr = PEAK_FRACTION * prof.max()
    out = []
    for i in range(1, len(prof) - 1):
        if prof[i] >= thr and prof[i] > prof[i - 1] and prof[i] >= prof[i + 1]:
            y0, y1, y2 = prof[i - 1], prof[i], prof[i + 1]
            den = y0 - 2 * y1 + y2
            out.append(i + (0.5 * (y0 - y2) / den if den != 0 else 0.0))
    return out


def match_peaks(p_test, p_ref):
    """Largest distance from each reference peak to the nearest test peak and vice versa."""
    if not p_test or not p_ref:
        return float("inf")
    d1 = max(min(abs(a - b) for a in p_test) for b in p_ref)
    d2 = max(min(abs(a - b) for a in p_ref) for b in p_test)
    return max(d1, d2)


def compare(scene, m, eps_m, eps_m_bin, s_a, s_b):
    s = 0.5 * (s_a + s_b)
    eps_s = noise(s_a, s_b)
    eps_s_bin = noise(bin4(s_a), bin4(s_b))
    r = rel(s, m)
    rb = rel(bin4(s), bin4(m))
    tol = NOISE_FACTOR * float(np.hypot(eps_s, eps_m)) + DELTA[scene]
    tol_b = NOISE_FACTOR * float(np.hypot(eps_s_bin, eps_m_bin)) + DELTA[scene]
    # replica positions: only the waveguide has replicas (the glyph's row profile is flat)
    pm, ps = (peaks(m), peaks(s)) if scene == "waveguide" else ([0.0], [0.0])
    dpk = match_peaks(ps, pm)
    res = {
        "scene": scene,
        "rel_rmse": round(r, 5), "tolerance": round(tol, 5),
        "noise_stscam": round(eps_s, 5), "noise_mitsuba": round(eps_m, 5),
        "rel_rmse_binned4": round(rb, 5), "tolerance_binned4": round(tol_b, 5),
        "noise_stscam_binned4": round(eps_s_bin, 5), "noise_mitsuba_binned4": round(eps_m_bin, 5),
        "mean_ratio_stscam_over_mitsuba": round(float(s.sum() / m.sum()), 5),
        "peaks_mitsuba": [round(p, 2) for p in pm], "peaks_stscam": [round(p, 2) for p in ps],
        "peak_max_offset_px": round(dpk, 3) if np.isfinite(dpk) else None,
        "peak_count_equal": len(pm) == len(ps),
    }
    res["pass"] = bool(r <= tol and rb <= tol_b and dpk <= PEAK_TOLERANCE_PX and len(pm) == len(ps))
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", required=True, choices=sorted(DELTA))
    ap.add_argument("--mitsuba", required=True, help=".npy (its .json beside it holds the noise)")
    ap.add_argument("--stscam", nargs=2, required=True, help="two captures (EXR), two seeds")
    ap.add_argument("--json", default=None)
    ap.add_argument("--max-tolerance", nargs=2, type=float, default=None, metavar=("FULL", "BINNED"),
                    help="fail if the tolerance (full resolution, 4x4-binned) exceeds these")
    ap.add_argument("--stscam-gain", type=float, default=1.0,
                    help="deliberately wrong input: multiply the stscam captures by this")
    ap.add_argument("--stscam-shift-rows", type=int, default=0,
                    help="deliberately wrong input: move the stscam captures down by this many rows")
    a = ap.parse_args()
    m = np.load(a.mitsuba).astype(np.float64)
    meta = json.load(open(a.mitsuba[:-4] + ".json"))
    s_a, s_b = (a.stscam_gain * np.roll(read_exr_y(p), a.stscam_shift_rows, axis=0) for p in a.stscam)
    res = compare(a.scene, m, meta["noise_rel_rms"], meta["noise_rel_rms_binned4"], s_a, s_b)
    res["mitsuba"] = {k: meta[k] for k in ("variant", "spp", "render_s", "sampler") if k in meta}
    if a.stscam_gain != 1.0 or a.stscam_shift_rows:
        res["deliberately_wrong"] = {"stscam_gain": a.stscam_gain, "stscam_shift_rows": a.stscam_shift_rows}
    if a.max_tolerance is not None:
        lim, lim_b = a.max_tolerance
        res["max_tolerance"] = [lim, lim_b]
        res["tolerance_within_limits"] = bool(res["tolerance"] <= lim and res["tolerance_binned4"] <= lim_b)
        if not res["tolerance_within_limits"]:
            print(f"mitsuba: {a.scene}: TOLERANCE ABOVE THE LIMITS ({100 * res['tolerance']:.2f} % / "
                  f"{100 * res['tolerance_binned4']:.2f} % binned against {100 * lim:.0f} % / {100 * lim_b:.0f} %): "
                  f"Mitsuba needs more samples here", file=sys.stderr)
        res["pass"] = res["pass"] and res["tolerance_within_limits"]
    print(json.dumps(res))
    limits = "" if a.max_tolerance is None else \
        f"; limits {100 * a.max_tolerance[0]:.0f} % / {100 * a.max_tolerance[1]:.0f} %"
    wrong = "" if "deliberately_wrong" not in res else \
        f" with a deliberately wrong stscam input (gain {a.stscam_gain:g}, shifted {a.stscam_shift_rows} rows)"
    print(f"mitsuba: {a.scene}{wrong} ({res['mitsuba'].get('variant', '?')}, {res['mitsuba'].get('spp', '?')} spp): "
          f"relative RMSE {100 * res['rel_rmse']:.2f} % (tolerance {100 * res['tolerance']:.2f} %), "
          f"4x4-binned {100 * res['rel_rmse_binned4']:.2f} % (tolerance {100 * res['tolerance_binned4']:.2f} %)"
          f"{limits}: {'passes' if res['pass'] else 'FAILS'}", file=sys.stderr)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)
    sys.exit(0 if res["pass"] else 1)


if __name__ == "__main__":
    main()
