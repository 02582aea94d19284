#!/usr/bin/env python3
"""Independent check of stscam's RCWA (`stscam grating --model rcwa --json`) against grcwa.

grcwa (Jin et al., ACS Photonics 7, 2350 (2020); PyPI `grcwa`) is a separate RCWA code: 2-D
lattice, eigenmodes per layer from numpy, S-matrices built layer by layer, fluxes by Poynting
vector. Here each design's film is given to grcwa as a stack of grid layers, slice j holding
eps(x) = (n + sum_i n1_i cos(p_i G x + Kz_i z_j))^2 sampled on Nx points at the slice's middle
z_j (the same staircase stscam uses: N_s = ceil(d * S * max|Kz| / 2pi) slices of d/N_s), with
the grating vectors recomputed here from the recording geometry (object beam along the film
normal, reference at the given angle inside the film: K = 2 pi n / lambda0 * (s_O - s_R)).
The incidence (u, media) is taken from stscam's JSON. Every order's TE and TM efficiency,
reflected and transmitted, must agree to TOL (2e-3 absolute); both codes must conserve energy
to 1e-6 (lossless films). A deliberately wrong slant (K_z scaled by WRONG_SLANT in grcwa) must
fail the same comparison; the script exits 1 if it does not, or if any design fails.

Usage: check_grcwa.py [--stscam PATH]   (default: target/release/stscam)
"""

import argparse
import json
import math
import subprocess
import sys
import time

import numpy as np
import grcwa

TOL = 2e-3
ENERGY_TOL = 1e-6
WRONG_SLANT = 1.02

# RGB multiplex: three gratings sharing the green grating's in-plane period (reference angles
# from sin(theta_i) = lambda_i / 532 * sin(55 deg)), so the film is periodic with that period.
_S55 = math.sin(math.radians(55.0))
RGB = [
    f"460,{math.degrees(math.asin(460.0 / 532.0 * _S55)):.12f},0.01",
    "532,55,0.01",
    f"620,{math.degrees(math.asin(620.0 / 532.0 * _S55)):.12f},0.01",
]

# name, stscam arguments, wavelengths (START:STOP:N)
DESIGNS = [
    ("paper film (16 um, n1 0.015, normal incidence)", [], "528:532:2"),
    ("RGB multiplex (3 gratings, 5 um)",
     ["--set", "hoe.film_thickness_um=5"] + sum((["--grating", g] for g in RGB), []),
     "460:620:3"),
    ("index modulation 0.05", ["--set", "hoe.index_modulation=0.05"], "532:540:2"),
    ("5 um film", ["--set", "hoe.film_thickness_um=5"], "525:532:2"),
    # --field-deg is the viewing direction (docs/cli.md): light travelling along +10 deg in x.
    ("10 deg conical incidence", ["--field-deg", "-10,0"], "526:530:2"),
    ("TM near Brewster (incident and diffracted waves ~perpendicular, contact stack)",
     ["--field-deg", "0,-21.9", "--stack", "contact"], "436:438:2"),
]
HARMONICS = 4
SLICES = 12


def stscam_json(exe, extra, lambdas):
    cmd = [exe, "grating", "--model", "rcwa", "--json", "--lambda-nm", lambdas,
           "--harmonics", str(HARMONICS), "--slices-per-period", str(SLICES)] + extra
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def grating_vectors(rep):
    """K (rad/um) of each grating, scene frame (x, y, z), from the recording geometry."""
    n = rep["mean_index"]
    ks = []
    for g in rep["gratings"]:
        k0 = 2 * math.pi * n / (g["recording_wavelength_nm"] * 1e-3)
        th = math.radians(g["reference_angle_deg"])
        ks.append((np.array([0.0, -k0 * math.sin(th), k0 * (1 + math.cos(th))]),
                   g["index_modulation"]))
    return ks


def grcwa_orders(rep, li, slant=1.0):
    """{(reflected, m): (eta_TE, eta_TM)} and the energy sums from grcwa at wavelength li."""
    lam_um = rep["lambda_nm"][li] * 1e-3
    n, d = rep["mean_index"], rep["film_thickness_um"]
    ks = grating_vectors(rep)
    kt = [k[1] for k, _ in ks]  # all along y
    g_common = abs(kt[0])
    e_sign = math.copysign(1.0, kt[0])  # e = (0, sign) in the scene frame
    p = [round(k / g_common) for k in kt]
    assert all(abs(k / g_common - q) < 1e-6 for k, q in zip(kt, p)), "gratings not commensurate"
    lx = 2 * math.pi / g_common
    kz = [k[2] * slant for k, _ in ks]
    n_s = max(1, math.ceil(d * SLICES * max(abs(z) for z in kz) / slant / (2 * math.pi)))
    dz = d / n_s
    ux, uy = rep["u"]
    # grcwa's frame: its grid samples eps(x) at x along e (the grating vector's in-plane
    # direction, scene y * sign) but its Fourier convention is the mirror image of stscam's, so
    # the incident k_x is -u.e and grcwa's order index G[:, 0] equals stscam's m. (The other
    # sign fails the off-axis designs by ~eta; normal incidence only swaps the labels.)
    kx0, ky0 = -uy * e_sign, -ux * e_sign
    n_in, n_out = rep["n_in"][li], rep["n_out"][li]
    sin_t = math.hypot(kx0, ky0) / n_in
    theta, phi = math.asin(sin_t), math.atan2(ky0, kx0)
    ng = 2 * HARMONICS + 1
    # grcwa's circular truncation keeps 2M+1 orders (m = -M..M, all along x) when asked 2M+2.
    obj = grcwa.obj(ng + 1, [lx, 0.0], [0.0, lx / 40.0], 1.0 / lam_um, theta, phi, verbose=0)
    obj.Add_LayerUniform(0.0, n_in ** 2)
    nx = 8 * HARMONICS + 8 * max(abs(q) for q in p) + 8
    for _ in range(n_s):
        obj.Add_LayerGrid(dz, nx, 1)
    obj.Add_LayerUniform(0.0, n_out ** 2)
    obj.Init_Setup(Gmethod=0)
    assert obj.nG == ng, f"grcwa kept {obj.nG} orders, wanted {ng}"
    x = np.arange(nx) / nx * lx
    eps = []
    for j in range(n_s):
        z = (j + 0.5) * dz
        f = n + sum(n1 * np.cos(q * g_common * x + kzi * z)
                    for (_, n1), q, kzi in zip(ks, p, kz))
        eps.append(f ** 2)
    obj.GridLayer_geteps(np.concatenate(eps))
    res = {}
    energy = []
    for pol, (p_amp, s_amp) in enumerate([(0.0, 1.0), (1.0, 0.0)]):
        obj.MakeExcitationPlanewave(p_amp, 0.0, s_amp, 0.0, order=0)
        r, t = obj.RT_Solve(normalize=1, byorder=1)
        energy.append(float(np.sum(r) + np.sum(t)))
        for gi in range(obj.nG):
            m = int(obj.G[gi, 0])  # stscam's order: k_t = k_inc - m G e (see above)
            for refl, val in ((True, r[gi]), (False, t[gi])):
                res.setdefault((refl, m), [0.0, 0.0])[pol] = float(np.real(val))
    return res, energy


def compare(rep, slant=1.0):
    worst, worst_energy = 0.0, 0.0
    for li in range(len(rep["lambda_nm"])):
        ref, energy = grcwa_orders(rep, li, slant)
        worst_energy = max(worst_energy, *(abs(e - 1) for e in energy),
                           abs(rep["energy_te"][li] - 1), abs(rep["energy_tm"][li] - 1))
        mine = {(o["side"] == "reflected", o["order"]): (o["eta_te"][li], o["eta_tm"][li])
                for o in rep["orders"]}
        for key in set(ref) | set(mine):
            a = mine.get(key, (0.0, 0.0))
            b = ref.get(key, (0.0, 0.0))
            worst = max(worst, abs(a[0] - b[0]), abs(a[1] - b[1]))
    return worst, worst_energy


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stscam", default="target/release/stscam")
    args = ap.parse_args()
    failed = False
    t0 = time.time()
    for name, extra, lambdas in DESIGNS:
        rep = stscam_json(args.stscam, extra, lambdas)
        worst, energy = compare(rep)
        ok = worst <= TOL and energy <= ENERGY_TOL
        failed |= not ok
        peak = max(max(o["eta_te"] + o["eta_tm"]) for o in rep["orders"]
                   if not (o["side"] == "transmitted" and o["order"] == 0))
        print(f"{'ok  ' if ok else 'FAIL'} {name}: max |d eta| {worst:.2e} (tol {TOL:g}), "
              f"max |sum eta - 1| {energy:.1e} (tol {ENERGY_TOL:g}), peak diffracted eta {peak:.4f}")
    # The check must be able to fail: grcwa given a slant 2 % off must disagree.
    rep = stscam_json(args.stscam, [], "528:532:2")
    worst, _ = compare(rep, slant=WRONG_SLANT)
    wrong_fails = worst > TOL
    print(f"{'ok  ' if wrong_fails else 'FAIL'} deliberately wrong slant (K_z x {WRONG_SLANT}) in "
          f"grcwa: max |d eta| {worst:.2e} {'>' if wrong_fails else '<='} tol: the check "
          f"{'fails as it should' if wrong_fails else 'did NOT detect it'}")
    failed |= not wrong_fails
    print(f"grcwa check took {time.time() - t0:.0f} s")
    if failed:
        sys.exit(1)


if __name__ == "__main__":
    main()
