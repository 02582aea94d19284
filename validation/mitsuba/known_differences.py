"""The known differences between the Mitsuba waveguide scene of this folder and stscam, each
estimated on its own (README.md, "Known differences"), and a check that the allowance delta of
compare.py for the waveguide is at least twice the sum of their maxima.  Usage:

    python known_differences.py [--reference reference/waveguide.npy] [--json OUT]

Nothing here looks at a comparison between the two renderers: the estimates come from the
formulas (Fresnel, Kogelnik, geometry, float32 rounding) and, for intensity weighting, from the
Mitsuba reference image alone.  The script also checks the per-sample cos^4 of the Mitsuba
camera ray (scenes.sample_cos4) against cos^4 computed from the sample's own film and aperture
positions (Mitsuba's scalar variant, 2000 random samples).

Items (per camera ray, relative to the pixel value):
 1. Unpolarised Fresnel on the plain faces.  Mitsuba's `dielectric` gives both polarisation
    slots the mean F = (R_s + R_p)/2; stscam uses R_s for TE and R_p for TM.  The waveguide ray
    crosses two plain faces at the same air angle theta (the camera ray leaving the back face and,
    by the periscope, the display ray entering the front face), so with A_TE, A_TM the TE and TM
    vHOE throughputs, Mitsuba / stscam - 1 = (R_s - R_p) p / (1 - F)^2 to first order, with
    p = (A_TE - A_TM)/(A_TE + A_TM).  p is taken from Kogelnik's efficiencies at normal incidence
    over the band, A = integral of eta_in * eta_out (docs/physics.md 3.5); |p| <= 1 bounds it.
 2. Fresnel ghosts Mitsuba keeps and stscam drops: a second reflection inside the plate (film
    reflection of the camera ray, then the back face) adds a copy of the image of relative weight
    at most R_film(theta_g) R_face(theta_g), below R^2 for the field's angles.
 3. Depth: Mitsuba stops at 64 interactions; the longest contributing waveguide path (camera,
    back face, top vHOE, guided contacts down to the far end of the bottom vHOE at the field's
    flattest guided angle, front face, display) is counted: below 64 the limit changes nothing.
 4. stscam drops a guided path below a weight of 1e-7: at most 1e-7 per contact.
 5. Mitsuba's film accumulates in float32: at most (samples per pass) x 2^-24 relative.
 6. cos^4: both weight each sample by the cos^4 of its own sensor-to-lens ray (checked here);
    before, Mitsuba's image was multiplied by the pixel's mean cos^4, which differs where the
    radiance varies over the aperture (measured in README.md; now zero by construction).
"""
import argparse
import json
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import scenes  # noqa: E402
from compare import DELTA  # noqa: E402


def chief_ray_angles(sensor_mm):
    """Air angle (rad) of each pixel's chief ray (pixel centre through the lens centre)."""
    c = (np.arange(scenes.RES) + 0.5 - scenes.RES / 2) * scenes.PITCH_MM
    r = np.hypot(c[:, None], c[None, :])
    return np.arctan(r / sensor_mm)


def fresnel_s_p(theta_air):
    """(R_s, R_p) of an air/glass face at the air angle theta (same on either side)."""
    n = scenes.N_GLASS
    ci = np.cos(theta_air)
    ct = np.sqrt(1.0 - (np.sin(theta_air) / n) ** 2)
    rs = (ci - n * ct) / (ci + n * ct)
    rp = (n * ci - ct) / (n * ci + ct)
    return rs * rs, rp * rp


def polarisation_contrast():
    """p = (A_TE - A_TM)/(A_TE + A_TM), A = integral over the band of eta(lambda)^2 for the
    display ray at normal incidence in-coupled by the bottom vHOE (order +1), eta_in = eta_out
    by the periscope's reciprocity."""
    K = scenes.grating_k()
    lo, hi = scenes.BAND
    lams = np.linspace(lo, hi, 4801)
    te, tm = [], []
    for lam in lams:
        _, refl, _, e_te, e_tm = scenes.order_f((0.0, 0.0, 1.0), lam, 1.0, K, scenes.N1)
        te.append(e_te if refl else 0.0)
        tm.append(e_tm if refl else 0.0)
    a_te = float(np.trapezoid(np.square(te), lams))
    a_tm = float(np.trapezoid(np.square(tm), lams))
    return (a_te - a_tm) / (a_te + a_tm), max(te), max(tm)


def weighted_rms(x, w):
    return float(np.sqrt((w * x * x).sum() / w.sum()))


def longest_path(sensor_mm):
    """Interactions of the longest contributing waveguide path (see the module docstring)."""
    half_field = math.atan(0.5 * scenes.RES * scenes.PITCH_MM / sensor_mm)
    theta_glass = math.asin(math.sin(half_field) / scenes.N_GLASS)
    guided_min = scenes.THETA_R - theta_glass          # flattest guided angle (docs/physics.md 3.3)
    step = scenes.W_MM * math.tan(guided_min)          # advance per face contact
    run = scenes.TOP[3] - scenes.BOTTOM[2]             # top of the top vHOE to the bottom end
    return 4 + math.ceil(run / step)


def check_sample_cos4(n=2000):
    """Largest |cos^4(ray) - cos^4(film and aperture positions)| over n random samples."""
    import mitsuba as mi
    mi.set_variant("scalar_spectral")
    scenes.setup("scalar_spectral")
    focus = scenes.default_focus_mm()
    d0 = scenes.FOCAL_MM * focus / (focus - scenes.FOCAL_MM)
    sensor = scenes.build_scene(mi, "plain-glass", focus, d0, 64).sensors()[0]
    rng = np.random.default_rng(1)
    half = 0.5 * scenes.RES * scenes.PITCH_MM
    radius = scenes.FOCAL_MM / (2 * scenes.F_NUMBER)
    worst = 0.0
    for _ in range(n):
        u, a = rng.random(2), rng.random(2)
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(*u), mi.Point2f(*a))
        disk = mi.warp.square_to_uniform_disk_concentric(mi.Point2f(*a))
        # in world x, y: the aperture point (look_at(-z, up +y) has camera x = -world x) and the
        # sensor point, the image point ((u - 1/2) W, (1/2 - v) W) inverted through the lens centre
        xl = np.array([-float(disk.x), float(disk.y)]) * radius
        xs = -np.array([(u[0] - 0.5) * 2 * half, (0.5 - u[1]) * 2 * half])
        t2 = ((xl - xs) ** 2).sum() / d0 ** 2
        worst = max(worst, abs(scenes.sample_cos4(ray, focus, d0) - 1.0 / (1.0 + t2) ** 2))
    return worst


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--reference", default=os.path.join(HERE, "reference", "waveguide.npy"),
                    help="Mitsuba image used only as the intensity weight of the RMS")
    ap.add_argument("--samples-per-pass", type=int, default=1024)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    focus = scenes.default_focus_mm()
    d0 = scenes.FOCAL_MM * focus / (focus - scenes.FOCAL_MM)
    w = np.load(a.reference).astype(np.float64) ** 2
    theta = chief_ray_angles(d0)
    rs, rp = fresnel_s_p(theta)
    f = 0.5 * (rs + rp)
    p, eta_te, eta_tm = polarisation_contrast()
    fres = (rs - rp) * p / (1.0 - f) ** 2
    fres_bound = (rs - rp) / (1.0 - f) ** 2
    theta_g = np.arcsin(np.sin(theta) / scenes.N_GLASS)
    ghost = float((0.5 * (rs + rp)).max() ** 2)      # R_film R_face, both at most R(theta_max)
    depth = longest_path(d0)
    items = {
        "fresnel_unpolarised_rms": weighted_rms(fres, w),
        "fresnel_unpolarised_max": float(np.abs(fres).max()),
        "fresnel_unpolarised_max_bound_p1": float(np.abs(fres_bound).max()),
        "ghost_max": ghost,
        "depth_limit": 0.0 if depth < 64 else 1.0,
        "weight_cutoff": 1e-7 * depth,
        "float32_film": a.samples_per_pass * 2.0 ** -24,
    }
    total = (items["fresnel_unpolarised_max"] + items["ghost_max"] + items["depth_limit"]
             + items["weight_cutoff"] + items["float32_film"])
    total_bound = total - items["fresnel_unpolarised_max"] + items["fresnel_unpolarised_max_bound_p1"]
    cos4_err = check_sample_cos4()
    out = {
        "polarisation_contrast_p": round(p, 4), "eta_te_bragg": round(eta_te, 4), "eta_tm_bragg": round(eta_tm, 4),
        "max_air_angle_deg": round(math.degrees(float(theta.max())), 2),
        "max_glass_angle_deg": round(math.degrees(float(theta_g.max())), 2),
        "longest_path_interactions": depth,
        "items": {k: float(f"{v:.3g}") for k, v in items.items()},
        "sum_of_maxima": float(f"{total:.3g}"), "sum_with_p_1": float(f"{total_bound:.3g}"),
        "delta_at_least_2x_sum_of_maxima": float(f"{2 * total:.3g}"),
        "delta_used_by_compare_py": DELTA["waveguide"],
        "sample_cos4_max_abs_error": float(f"{cos4_err:.3g}"),
    }
    print(json.dumps(out, indent=1))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    ok = cos4_err < 1e-5 and depth < 64 and DELTA["waveguide"] >= 2 * total
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
