"""Mitsuba 3 (3.9.1) versions of the four stscam scenes in this folder, an independent vHOE BSDF
and a hero-wavelength integrator.  Usage:

    python scenes.py --scene plain-glass|waveguide|mesh-plain-glass|mesh-waveguide --spp N
                     --seed S --out IMG.npy [--variant V] [--focus-mm F] [--sensor-mm D0]

writes a 128x128 float32 image in stscam's unit (1 = a white display pixel seen on axis through
lossless optics with a vanishing aperture, flat spectrum and response), cos^4 falloff included.

Model (written from docs/physics.md, not from the Rust code):
* Frame and units: millimetres, plate 0 <= z <= w (front face z = 0 on the user side), y up,
  the display at z = -550 emitting toward +z, the camera at (0, 40, w + 32) looking along -z.
* Faces are separate rectangles with outward normals.  Plain faces: `dielectric` 1.5 / 1.0.
  vHOE faces: the Python BSDF `vhoe` below.  The slab's four side faces: black.
* vHOE (docs/physics.md 0.2, 1.2, 1.5, 2.1, 2.2(b), 2.3): an infinitely thin film (d = 16 um,
  n = 1.50 = glass, n1 = 0.015) on the face.  K = k0 (s_O - s_R), s_O = (0,0,1),
  s_R = (0, sin 61.2, -cos 61.2), k0 = 2 pi n / 532 nm.  For a wave rho = beta s (beta = 2 pi n/lam)
  and order m: sigma = rho - m K, k_d,t = sigma_t, k_d,z = sign(sigma_z) sqrt(beta^2 - |k_d,t|^2)
  (evanescent: eta = 0), |xi| = |k_d,z - sigma_z| d / 2, nu = pi n1 d / (lam sqrt(|c_R| |c_S|)),
  c_R = rho_z/beta, c_S = k_d,z/beta; reflection type when c_R c_S < 0:
  eta = nu^2 / (xi^2 + G(nu^2 - xi^2)^2) (the stable form of Kogelnik Eq. 57), transmission type:
  eta = sin^2(sqrt(nu^2 + xi^2)) / (1 + xi^2/nu^2).  TM: nu -> nu |rho_hat . k_d_hat|.
  Hit from the glass side, the film offers (Mitsuba traces backward; the lossless Kogelnik
  efficiency is reciprocal, eta(rho -> k_d) = eta(-k_d -> -rho), so the backward ray is used as
  the incident wave):
    - each reflection-type order: new direction k_d / beta, weight eta_m;
    - specular reflection at the film/air (or film/tape) face: Fresnel R (1 under TIR) times the
      two-pass factor (1 - sum_m eta_m(pass toward the face)) (1 - sum_m eta_m(pass back)),
      docs/physics.md 2.3;
    - everything else (transmission-type orders, light leaving through the face) is lost: on the
      back face it leaves toward the camera side, where nothing is; on the front face the top
      vHOE is covered by absorbing tape.  TIR under the tape is not frustrated.
  Hit from the air side: absorbed (no camera ray meets a vHOE from outside in these scenes).
* Polarisation: TE and TM are carried in the spectrum slots (0, 2: TE; 1, 3: TM) at one common
  wavelength (hero wavelength); the lobe is chosen with the TE/TM-averaged weights and each slot
  gets its own weight / probability.  The plain `dielectric` faces use the unpolarised Fresnel
  factor for both (the difference is < 0.2 % at the <= 10 deg camera angles here).
* Wavelengths: the `hero` integrator draws one wavelength per camera ray over the band, mixing a
  uniform part with a window of +-15 nm around the Bragg wavelength of the camera ray's own
  direction in the glass (docs/physics.md 3.2: lam_B = lam0 (s_z - s_y tan(theta_R/2))), and returns
  the unpolarised mean of the TE and TM estimates divided by the density.
* Mesh scenes (mesh-*.toml, display off): the plate and camera as above; the user side is the
  file's [[object]] (OBJ meshes, textured two-sided Lambertian) and [[light]] (rect, flat
  spectrum) entries, see `user_side`; Mitsuba's own `path` integrator (NEE + MIS) traces it.
* Radiance: the display is a rectangle area emitter with a 1-channel raw float bitmap (flat
  spectrum); `specfilm` with one box channel over the band gives the integral over lambda, which
  is divided by the band width; the thin-lens camera measures radiance, so the image is multiplied
  by E[cos^4] of each pixel (exact quadrature over pixel and aperture) to match stscam's
  irradiance weighting.
"""
import argparse
import json
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

# ---- scene parameters (the values of the two .toml files merged over scenes/paper-2022.toml) ----
W_MM = 2.0                    # plate thickness
N_GLASS = 1.5
N_FILM = 1.5
FILM_D_NM = 16000.0
N1 = 0.015
LAMBDA0 = 532.0
THETA_R = math.radians(61.2)
BOTTOM = (-25.0, 25.0, -25.0, 25.0)      # x0, x1, y0, y1 on the back face (z = w)
TOP = (-25.0, 25.0, 30.0, 50.0)          # on the front face (z = 0): 25 + gap 5 .. + 20
CAMERA_Y = 40.0                          # top vHOE centre
CAMERA_Z = W_MM + 32.0
FOCAL_MM = 6.0
F_NUMBER = 4.0
PITCH_MM = 0.0165
RES = 128
DISPLAY_Z = -550.0
DISPLAY_PX_MM = 2.7                      # 10 LCD pixels of 0.27 mm per target pixel
BAND = (480.0, 600.0)
# Wavelength window of the hero integrator: +-8 nm around the ray's Bragg wavelength holds the
# main lobe of the end-to-end filter eta_in * eta_out (first zeros of Kogelnik's reflection
# response at |xi| = sqrt(nu^2 + pi^2) = 3.7, i.e. +-4.5 nm with d xi / d lambda = 0.819 / nm,
# docs/physics.md 3.5) and its first side lobes; the uniform quarter covers the rest of the band.
# Measured on the waveguide at 512 spp: relative noise 13 % with +-8 nm against 18 % with +-15 nm.
IS_HALF_WIDTH_NM = 8.0
IS_UNIFORM_FRACTION = 0.25
NEAR_CLIP_MM = 1.0

SCENES = {
    "plain-glass": dict(n1=0.0, covered=False, target="target-glyph.png", display_center=(0.0, 40.0)),
    "waveguide": dict(n1=N1, covered=True, target="target-lines.png", display_center=(0.0, 0.0)),
    # 3-D scenes (display off): the [[object]] and [[light]] entries of the .toml file
    "mesh-plain-glass": dict(n1=0.0, covered=False, toml="mesh-plain-glass.toml"),
    "mesh-waveguide": dict(n1=N1, covered=True, toml="mesh-waveguide.toml"),
}
WAVEGUIDE_SCENES = ("waveguide", "mesh-waveguide")
# Central crop whose noise estimates the JSON also records (the Rust test renders only it).
CROP = 64


def default_focus_mm():
    # stscam's "auto" focus: d1 + 2 w / n(532) + D (also printed by `stscam info --json`)
    return 32.0 + 2.0 * W_MM / N_GLASS + 550.0


def grating_k():
    k0 = 2.0 * math.pi * N_FILM / LAMBDA0
    return (0.0, -k0 * math.sin(THETA_R), k0 * (1.0 + math.cos(THETA_R)))


def load_png_gray(path):
    """8-bit grey PNG (as written by targets.py) -> float array in [0, 1]."""
    import zlib
    import struct
    data = open(path, "rb").read()
    pos, idat, w, h = 8, b"", 0, 0
    while pos < len(data):
        n, tag = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if tag == b"IHDR":
            w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and ctype == 0, "targets are 8-bit grey PNGs"
        elif tag == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    rows, prev = [], bytearray(w)
    for r in range(h):
        f, line = raw[r * (w + 1)], bytearray(raw[r * (w + 1) + 1:(r + 1) * (w + 1)])
        for i in range(w):
            a = line[i - 1] if i else 0
            b, c = prev[i], (prev[i - 1] if i else 0)
            if f == 1: line[i] = (line[i] + a) & 255
            elif f == 2: line[i] = (line[i] + b) & 255
            elif f == 3: line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(bytes(line))
        prev = line
    return np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(h, w).astype(np.float32) / 255.0


def cos4_map(sensor_mm, res=RES, pitch=PITCH_MM, aperture=FOCAL_MM / (2 * F_NUMBER), n=12):
    """E[cos^4 theta] per pixel over the pixel area and the aperture disc (theta between the
    sensor-point -> lens-point ray and the axis): the irradiance factor stscam applies."""
    g = (np.arange(n) + 0.5) / n
    # aperture: polar midpoint rule (area-uniform)
    rr = np.sqrt((np.arange(n) + 0.5) / n) * aperture
    ph = 2 * np.pi * (np.arange(2 * n) + 0.5) / (2 * n)
    lx = (rr[:, None] * np.cos(ph)[None, :]).ravel()
    ly = (rr[:, None] * np.sin(ph)[None, :]).ravel()
    out = np.zeros((res, res))
    xs = ((np.arange(res)[:, None] + g[None, :]) - res / 2) * pitch      # (res, n)
    for r in range(res):
        ys = (res / 2 - (r + g)) * pitch                                  # (n,)
        dx = xs[:, :, None, None] + lx[None, None, None, :]               # (res, n, 1, L)
        dy = ys[None, None, :, None] + ly[None, None, None, :]            # (1, 1, n, L)
        c2 = sensor_mm ** 2 / (dx ** 2 + dy ** 2 + sensor_mm ** 2)
        out[r] = (c2 ** 2).mean(axis=(1, 2, 3))
    return out


def sample_cos4(ray, focus_mm, sensor_mm):
    """cos^4 of the angle between the camera axis (-z) and the ray from the sample's sensor point
    to its lens point (docs/physics.md 6.2: each sample aims from its aperture point x_l at the
    in-focus point -(s_o/d0) x_s at distance s_o, weighted by cos^4).  Mitsuba's thin lens starts
    the ray at x_l moved NEAR_CLIP_MM along the ray; the in-focus point p_f lies at s_o along the
    axis; the sensor point is x_s = -(d0/s_o) p_f (transverse, from the lens centre), so
    tan^2 theta = |x_l - x_s|^2 / d0^2.  Works on drjit and plain-float rays."""
    import drjit as dr
    dz = -ray.d.z
    lx = ray.o.x - ray.d.x * (NEAR_CLIP_MM / dz)
    ly = ray.o.y - ray.d.y * (NEAR_CLIP_MM / dz) - CAMERA_Y
    fx = lx + ray.d.x * (focus_mm / dz)
    fy = ly + ray.d.y * (focus_mm / dz)
    tx = lx + fx * (sensor_mm / focus_mm)
    ty = ly + fy * (sensor_mm / focus_mm)
    c2 = sensor_mm * sensor_mm / (sensor_mm * sensor_mm + tx * tx + ty * ty)
    return c2 * c2


def g_f(x):
    if abs(x) < 1e-3:
        return 1.0 + x / 3.0 - x * x / 45.0 + 2.0 * x * x * x / 945.0
    if x > 0:
        r = math.sqrt(x)
        return r / math.tanh(min(r, 40.0))
    r = math.sqrt(-x)
    return r * math.cos(r) / math.sin(r)

def order_f(s, lam, m, K, n1):
    """Plain-float twin of `order` in `setup` (scalar variants: about 10x faster than drjit
    scalars; also used by known_differences.py).  s: unit direction of the wave in the film
    (frame of the face, z along its normal), K: grating vector in that frame."""
    beta = 2.0 * math.pi * N_FILM / lam
    sx, sy, sz = beta * s[0] - m * K[0], beta * s[1] - m * K[1], beta * s[2] - m * K[2]
    kt2 = sx * sx + sy * sy
    if not (kt2 < beta * beta * (1.0 - 1e-9)) or n1 <= 0:
        return False, False, None, 0.0, 0.0
    kdz = math.copysign(math.sqrt(beta * beta - kt2), 1.0 if sz >= 0 else -1.0)
    xi = abs(kdz - sz) * (FILM_D_NM * 0.5)
    c_r = max(abs(s[2]), 1e-9)
    c_s = max(abs(kdz) / beta, 1e-9)
    nu = math.pi * n1 * FILM_D_NM / (lam * math.sqrt(c_r * c_s))
    refl = (s[2] * kdz) < 0
    dot = (s[0] * sx + s[1] * sy + s[2] * kdz) / beta
    etas = []
    for nu_p in (nu, nu * abs(dot)):
        nu2 = max(nu_p * nu_p, 1e-30)
        if refl:
            gg = g_f(nu2 - xi * xi)
            etas.append(nu2 / (xi * xi + gg * gg))
        else:
            etas.append(math.sin(math.sqrt(nu2 + xi * xi)) ** 2 / (1.0 + xi * xi / nu2))
    return True, refl, (sx / beta, sy / beta, kdz / beta), etas[0], etas[1]

def fresnel_f(cos_i, eta):
    cos_i = abs(cos_i)
    sin2_t = eta * eta * max(0.0, 1.0 - cos_i * cos_i)
    if sin2_t >= 1.0:
        return 1.0, 1.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return rs * rs, rp * rp


def choose_variant():
    """llvm_ad_spectral if a probe in a subprocess works (old libLLVM aborts the process),
    else scalar_spectral."""
    import subprocess
    env = dict(os.environ)
    llvm19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
    if os.path.exists(llvm19):
        env["DRJIT_LIBLLVM_PATH"] = llvm19
    probe = ("import mitsuba as mi; mi.set_variant('llvm_ad_spectral'); import drjit as dr;"
             "s = mi.load_dict({'type':'scene','i':{'type':'path'},'e':{'type':'constant'},"
             "'s':{'type':'perspective','film':{'type':'hdrfilm','width':4,'height':4}}});"
             "mi.render(s, spp=1); print('ok')")
    try:
        r = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                           timeout=300)
        if r.returncode == 0 and "ok" in r.stdout:
            return "llvm_ad_spectral", env.get("DRJIT_LIBLLVM_PATH")
    except Exception:
        pass
    return "scalar_spectral", None


def setup(variant):
    import mitsuba as mi
    import drjit as dr
    mi.set_variant(variant)
    kx, ky, kz = grating_k()

    def fresnel_sp(cos_i, eta):
        """Fresnel reflectance (R_s, R_p) from the medium of index eta (relative to the outside
        medium) toward the outside, |cos_i| inside; 1 under TIR (docs/physics.md 4.3)."""
        cos_i = dr.abs(cos_i)
        sin2_t = eta * eta * dr.maximum(0.0, 1.0 - cos_i * cos_i)
        tir = sin2_t >= 1.0
        cos_t = dr.safe_sqrt(1.0 - sin2_t)
        n1, n2 = eta, 1.0
        rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
        rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
        return dr.select(tir, 1.0, rs * rs), dr.select(tir, 1.0, rp * rp)

    def g_of(x):
        """G(x) = sqrt(x) coth sqrt(x) (x > 0), sqrt(-x) cot sqrt(-x) (x < 0), 1 at 0."""
        sp = dr.safe_sqrt(dr.maximum(x, 1e-12))
        sn = dr.safe_sqrt(dr.maximum(-x, 1e-12))
        gp = sp / dr.tanh(dr.minimum(sp, 40.0))
        gn = sn * dr.cos(sn) / dr.sin(sn)
        series = 1.0 + x / 3.0 - x * x / 45.0 + 2.0 * x * x * x / 945.0
        return dr.select(dr.abs(x) < 1e-3, series, dr.select(x > 0, gp, gn))

    def order(s, lam, m, K, n1):
        """Wave of unit direction s (local frame, film index N_FILM) meeting the film, order m.
        Returns (valid, reflection, k_d unit direction, eta_TE, eta_TM)."""
        beta = 2.0 * math.pi * N_FILM / lam
        sx, sy, sz = beta * s.x - m * K.x, beta * s.y - m * K.y, beta * s.z - m * K.z
        kt2 = sx * sx + sy * sy
        valid = kt2 < beta * beta * (1.0 - 1e-9)
        kdz = dr.select(sz >= 0, 1.0, -1.0) * dr.safe_sqrt(beta * beta - kt2)
        xi = dr.abs(kdz - sz) * (FILM_D_NM * 0.5)
        c_r = dr.maximum(dr.abs(s.z), 1e-9)
        c_s = dr.maximum(dr.abs(kdz) / beta, 1e-9)
        nu = math.pi * n1 * FILM_D_NM / (lam * dr.sqrt(c_r * c_s))
        refl = (s.z * kdz) < 0
        dot = (s.x * sx + s.y * sy + s.z * kdz) / beta       # rho_hat . k_d_hat
        etas = []
        for nu_p in (nu, nu * dr.abs(dot)):
            nu2 = dr.maximum(nu_p * nu_p, 1e-30)
            x = nu2 - xi * xi
            gg = g_of(x)
            eta_r = nu2 / (xi * xi + gg * gg)
            a = dr.sqrt(nu2 + xi * xi)
            eta_t = dr.sin(a) ** 2 / (1.0 + xi * xi / nu2)
            e = dr.select(refl, eta_r, eta_t)
            etas.append(dr.select(valid & (n1 > 0), e, 0.0))
        kd = mi.Vector3f(sx, sy, kdz) / beta
        return valid, refl, kd, etas[0], etas[1]

    scalar = variant.startswith("scalar")

    class VHOE(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.n1 = float(props.get("n1", N1))
            refl = mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.BackSide | mi.BSDFFlags.FrontSide
            self.m_components = [refl, refl, refl]
            self.m_flags = refl

        def sample(self, ctx, si, sample1, sample2, active=True):
            if scalar and not getattr(self, "force_dr", False):
                return self.sample_f(si, float(sample1))
            return self.sample_dr(ctx, si, sample1, sample2, active)

        def sample_f(self, si, u):
            bs = mi.BSDFSample3f()
            bs.eta = 1.0
            bs.sampled_type = +mi.BSDFFlags.DeltaReflection
            wi = si.wi
            wi = (float(wi.x), float(wi.y), float(wi.z))
            if wi[2] >= 0:
                bs.pdf = 0.0
                return bs, mi.Spectrum(0.0)
            lam = float(si.wavelengths[0])
            Kl = si.to_local(mi.Vector3f(kx, ky, kz))
            K = (float(Kl.x), float(Kl.y), float(Kl.z))
            d = (-wi[0], -wi[1], -wi[2])
            wr = (-wi[0], -wi[1], wi[2])
            lobes = []
            sum_d = [0.0, 0.0]
            for m in (1.0, -1.0):
                v, r, kd, e_te, e_tm = order_f(d, lam, m, K, self.n1)
                sum_d[0] += e_te
                sum_d[1] += e_tm
                if v and r:
                    lobes.append((kd, e_te, e_tm))
                else:
                    lobes.append((None, 0.0, 0.0))
            sum_r = [0.0, 0.0]
            for m in (1.0, -1.0):
                _, _, _, e_te, e_tm = order_f(wr, lam, m, K, self.n1)
                sum_r[0] += e_te
                sum_r[1] += e_tm
            rs, rp = fresnel_f(wi[2], N_FILM)
            lobes.append((wr, max(rs * (1 - sum_d[0]) * (1 - sum_r[0]), 0.0),
                          max(rp * (1 - sum_d[1]) * (1 - sum_r[1]), 0.0)))
            ps = [0.5 * (a + b) for _, a, b in lobes]
            tot = sum(ps)
            if tot <= 0:
                bs.pdf = 0.0
                return bs, mi.Spectrum(0.0)
            x = u * tot
            i = 0 if x < ps[0] else (1 if x < ps[0] + ps[1] else 2)
            if ps[i] <= 0:
                i = 2
            wo, w_te, w_tm = lobes[i]
            prob = ps[i] / tot
            bs.wo = mi.Vector3f(*wo)
            bs.pdf = prob
            bs.sampled_component = i
            return bs, mi.Spectrum(w_te / prob, w_tm / prob, w_te / prob, w_tm / prob)

        def sample_dr(self, ctx, si, sample1, sample2, active=True):
            lam = si.wavelengths[0]
            K = si.to_local(mi.Vector3f(kx, ky, kz))
            wi = si.wi
            from_glass = wi.z < 0
            d = -wi                                   # backward ray direction (toward the face)
            wr = mi.reflect(wi)                       # its mirror image (back into the glass)
            va, ra, kda, ea_te, ea_tm = order(d, lam, 1.0, K, self.n1)
            vb, rb, kdb, eb_te, eb_tm = order(d, lam, -1.0, K, self.n1)
            # pass toward the face (the backward ray) and pass back (its mirror): all orders
            _, _, _, pa_te, pa_tm = order(wr, lam, 1.0, K, self.n1)
            _, _, _, pb_te, pb_tm = order(wr, lam, -1.0, K, self.n1)
            rs, rp = fresnel_sp(wi.z, N_FILM)
            wr_te = rs * (1.0 - ea_te - eb_te) * (1.0 - pa_te - pb_te)
            wr_tm = rp * (1.0 - ea_tm - eb_tm) * (1.0 - pa_tm - pb_tm)
            da_ok = va & ra
            db_ok = vb & rb
            wa_te, wa_tm = dr.select(da_ok, ea_te, 0.0), dr.select(da_ok, ea_tm, 0.0)
            wb_te, wb_tm = dr.select(db_ok, eb_te, 0.0), dr.select(db_ok, eb_tm, 0.0)
            wr_te, wr_tm = dr.maximum(wr_te, 0.0), dr.maximum(wr_tm, 0.0)
            pa = 0.5 * (wa_te + wa_tm)
            pb = 0.5 * (wb_te + wb_tm)
            pr = 0.5 * (wr_te + wr_tm)
            tot = pa + pb + pr
            ok = from_glass & (tot > 0)
            tot = dr.select(ok, tot, 1.0)
            u = sample1 * tot
            pick_a = u < pa
            pick_b = (u >= pa) & (u < pa + pb)
            bs = mi.BSDFSample3f()
            bs.wo = dr.select(pick_a, kda, dr.select(pick_b, kdb, wr))
            prob = dr.select(pick_a, pa, dr.select(pick_b, pb, pr)) / tot
            w_te = dr.select(pick_a, wa_te, dr.select(pick_b, wb_te, wr_te))
            w_tm = dr.select(pick_a, wa_tm, dr.select(pick_b, wb_tm, wr_tm))
            bs.pdf = dr.select(ok, prob, 0.0)
            bs.eta = 1.0
            bs.sampled_component = dr.select(pick_a, 0, dr.select(pick_b, 1, 2))
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaReflection)
            inv = dr.select(ok & (prob > 0), 1.0 / dr.maximum(prob, 1e-30), 0.0)
            weight = mi.Spectrum(w_te * inv, w_tm * inv, w_te * inv, w_tm * inv)
            return bs, weight

        def eval(self, ctx, si, wo, active=True):
            return mi.Spectrum(0.0)

        def pdf(self, ctx, si, wo, active=True):
            return 0.0

        def eval_pdf(self, ctx, si, wo, active=True):
            return mi.Spectrum(0.0), 0.0

        def to_string(self):
            return "VHOE[]"

    mi.register_bsdf("vhoe", lambda props: VHOE(props))

    class Hero(mi.SamplingIntegrator):
        """One wavelength per camera ray, importance-sampled around the ray's Bragg wavelength;
        returns the TE/TM mean / density in slot 0 (x4: the film averages the 4 slots)."""

        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            self.nested = props.get("nested")
            self.window = bool(props.get("window", True))
            # "sample": weight each sample by its own cos^4 (what stscam does); "pixel": return
            # radiance (the caller multiplies by the pixel's mean cos^4, cos4_map).
            self.cos4 = props.get("cos4", "sample")
            self.focus_mm = float(props.get("focus_mm", default_focus_mm()))
            self.sensor_mm = float(props.get("sensor_mm", FOCAL_MM * self.focus_mm / (self.focus_mm - FOCAL_MM)))

        def sample(self, scene, sampler, ray, medium=None, active=True):
            lo, hi = BAND
            b = hi - lo
            xi = sampler.next_1d()
            if self.window:
                # camera ray in air -> physical light direction in the glass
                st_x = -ray.d.x / N_GLASS
                st_y = -ray.d.y / N_GLASS
                st_z = dr.safe_sqrt(1.0 - st_x * st_x - st_y * st_y)
                lam_b = LAMBDA0 * (st_z - st_y * math.tan(0.5 * THETA_R))
                w0 = dr.clip(lam_b - IS_HALF_WIDTH_NM, lo, hi)
                w1 = dr.clip(lam_b + IS_HALF_WIDTH_NM, lo, hi)
                ww = w1 - w0
                f = dr.select(ww > 1e-6, IS_UNIFORM_FRACTION, 1.0)
                use_u = xi < f
                lam = dr.select(use_u, lo + b * (xi / f), w0 + ww * ((xi - f) / dr.maximum(1.0 - f, 1e-9)))
                lam = dr.clip(lam, lo, hi)
                in_w = (lam >= w0) & (lam <= w1) & (ww > 1e-6)
                pdf = f / b + dr.select(in_w, (1.0 - f) / dr.maximum(ww, 1e-9), 0.0)
            else:
                lam = lo + b * xi
                pdf = 1.0 / b
            ray = mi.RayDifferential3f(ray)
            ray.wavelengths = mi.Spectrum(lam)
            L, valid, aovs = self.nested.sample(scene, sampler, ray, medium, active)
            val = 0.5 * (L[0] + L[1]) / (pdf * b)
            if self.cos4 == "sample":
                val = val * sample_cos4(ray, self.focus_mm, self.sensor_mm)
            return mi.Spectrum(4.0 * val, 0.0, 0.0, 0.0), valid, aovs

        def aov_names(self):
            return []

        def to_string(self):
            return "Hero[]"

    mi.register_integrator("hero", lambda props: Hero(props))
    return mi


def rect(mi, x0, x1, y0, y1, z, normal_sign, bsdf):
    """Axis-aligned rectangle in a z-plane with the normal along normal_sign * z."""
    T = mi.ScalarTransform4f
    tf = T().translate([0.5 * (x0 + x1), 0.5 * (y0 + y1), z]) @ T().scale([0.5 * (x1 - x0), 0.5 * (y1 - y0), 1.0])
    if normal_sign < 0:
        tf = tf @ T().rotate([1, 0, 0], 180.0)
    return {"type": "rectangle", "to_world": tf, "bsdf": bsdf}


def side(mi, center, axis_from, scale, black):
    T = mi.ScalarTransform4f
    tf = T().translate(center) @ axis_from @ T().scale(scale)
    return {"type": "rectangle", "to_world": tf, "bsdf": black}


def user_side(mi, toml_path, black):
    """The [[object]] and [[light]] entries of an stscam scene file as Mitsuba shapes, written
    from stscam's documented scene semantics (README.md, "Mesh scenes"), not from its code:
    * object: an OBJ file (millimetres) placed by to_world = translate(position_mm) . Rz . Ry .
      Rx . scale (rotation_deg about x, then y, then z, extrinsic, right-handed), with a
      two-sided Lambertian BSDF whose reflectance is the MTL's map_Kd texture (8-bit sRGB PNG:
      Mitsuba decodes the sRGB curve and upsamples each texel with its Jakob-Hanika table;
      bilinear filtering, repeat wrap); Mitsuba's OBJ loader flips v (OBJ v up, image row 0 at
      the top), as stscam's does;
    * light, kind "rect": a one-sided area emitter on a rectangle centred at position_mm, width
      along the direction perpendicular to the normal closest to +x, height along normal x
      width; spectrum "flat" (stscam normalises it to mean 1 over 380-780 nm, i.e. 1 at every
      wavelength), so the radiance is `scale` in stscam's unit (display white = 1)."""
    import tomllib
    base = os.path.dirname(toml_path)
    with open(toml_path, "rb") as f:
        desc = tomllib.load(f)
    T = mi.ScalarTransform4f
    out = {}
    allowed_obj = {"mesh", "position_mm", "rotation_deg", "scale"}
    for i, o in enumerate(desc.get("object", [])):
        extra = set(o) - allowed_obj
        if extra or not o["mesh"].endswith(".obj"):
            raise ValueError(f"object {i}: only OBJ meshes with {sorted(allowed_obj)} are modelled, got {sorted(o)}")
        sc = o.get("scale", 1.0)
        sc = [float(sc)] * 3 if isinstance(sc, (int, float)) else [float(v) for v in sc]
        rx, ry, rz = (float(v) for v in o.get("rotation_deg", [0.0, 0.0, 0.0]))
        tf = (T().translate([float(v) for v in o.get("position_mm", [0.0, 0.0, 0.0])])
              @ T().rotate([0, 0, 1], rz) @ T().rotate([0, 1, 0], ry) @ T().rotate([1, 0, 0], rx)
              @ T().scale(sc))
        obj = os.path.join(base, o["mesh"])
        tex = obj_texture(obj)
        out[f"object_{i}"] = {
            "type": "obj", "filename": obj, "to_world": tf,
            "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {
                "type": "bitmap", "filename": tex, "filter_type": "bilinear", "wrap_mode": "repeat"}}},
        }
    allowed_light = {"kind", "position_mm", "size_mm", "normal", "spectrum", "scale"}
    for i, l in enumerate(desc.get("light", [])):
        extra = set(l) - allowed_light
        if extra or l["kind"] != "rect" or l.get("spectrum", "d65") != "flat":
            raise ValueError(f"light {i}: only rect lights with a flat spectrum are modelled, got {l}")
        n = np.array(l.get("normal", [0.0, 0.0, 1.0]), dtype=float)
        n /= np.linalg.norm(n)
        ex = np.array([1.0, 0.0, 0.0]) - n * n[0]
        if ex @ ex < 1e-12:
            ex = np.array([0.0, 1.0, 0.0]) - n * n[1]
        ex /= np.linalg.norm(ex)
        ey = np.cross(n, ex)
        w, h = (float(v) for v in l["size_mm"])
        c = np.array(l["position_mm"], dtype=float)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = ex * 0.5 * w, ey * 0.5 * h, n, c
        out[f"light_{i}"] = {
            "type": "rectangle", "to_world": T(m.tolist()), "bsdf": black,
            "emitter": {"type": "area", "radiance": {"type": "uniform", "value": float(l.get("scale", 1.0))}},
        }
    return out


def obj_texture(obj_path):
    """The map_Kd texture of an OBJ file's material library (one library, one material, Kd 1)."""
    base = os.path.dirname(obj_path)
    lib = next(line.split(None, 1)[1].strip() for line in open(obj_path) if line.startswith("mtllib"))
    tex, kd = None, None
    for line in open(os.path.join(base, lib)):
        parts = line.split()
        if parts and parts[0] == "map_Kd":
            tex = os.path.join(base, parts[-1])
        elif parts and parts[0] == "Kd":
            kd = [float(v) for v in parts[1:4]]
    assert tex and kd == [1.0, 1.0, 1.0], f"{lib}: expected Kd 1 1 1 and a map_Kd texture"
    return tex


def build_scene(mi, name, focus_mm, sensor_mm, max_depth, cos4="sample", sampler="multijitter"):
    cfg = SCENES[name]
    T = mi.ScalarTransform4f
    diel = {"type": "dielectric", "int_ior": N_GLASS, "ext_ior": 1.0}
    black = {"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.0}}
    vhoe = {"type": "vhoe", "n1": cfg["n1"]}
    x0, x1 = -25.0, 25.0
    y0, y1 = -25.0, 50.0
    scene = {"type": "scene"}
    # front face z = 0 (normal -z): top vHOE region and plain glass below it
    scene["front_top"] = rect(mi, *TOP, 0.0, -1, vhoe if cfg["covered"] else diel)
    scene["front_rest"] = rect(mi, x0, x1, y0, TOP[2], 0.0, -1, diel)
    # back face z = w (normal +z): bottom vHOE and plain glass above it
    scene["back_bottom"] = rect(mi, *BOTTOM, W_MM, +1, vhoe)
    scene["back_rest"] = rect(mi, x0, x1, BOTTOM[3], y1, W_MM, +1, diel)
    # black side faces
    zc = 0.5 * W_MM
    scene["side_ymin"] = side(mi, [0, y0, zc], T().rotate([1, 0, 0], 90), [0.5 * (x1 - x0), 0.5 * W_MM, 1], black)
    scene["side_ymax"] = side(mi, [0, y1, zc], T().rotate([1, 0, 0], -90), [0.5 * (x1 - x0), 0.5 * W_MM, 1], black)
    scene["side_xmin"] = side(mi, [x0, 0.5 * (y0 + y1), zc], T().rotate([0, 1, 0], -90), [0.5 * W_MM, 0.5 * (y1 - y0), 1], black)
    scene["side_xmax"] = side(mi, [x1, 0.5 * (y0 + y1), zc], T().rotate([0, 1, 0], 90), [0.5 * W_MM, 0.5 * (y1 - y0), 1], black)
    if "toml" in cfg:
        scene.update(user_side(mi, os.path.join(HERE, cfg["toml"]), black))
    else:
        # display: a 64 x 64 target of 2.7 mm pixels, emitting toward +z; rectangle uv has v = 0
        # at -y while bitmap row 0 is at v = 0, so flip the rows (target row 0 is the top, +y)
        img = load_png_gray(os.path.join(HERE, cfg["target"]))
        half = 0.5 * img.shape[1] * DISPLAY_PX_MM
        cx, cy = cfg["display_center"]
        scene["display"] = {
            "type": "rectangle",
            "to_world": T().translate([cx, cy, DISPLAY_Z]) @ T().scale([half, half, 1.0]),
            "bsdf": black,
            "emitter": {"type": "area", "radiance": {
                "type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(np.flipud(img))[:, :, None]),
                "raw": True, "filter_type": "nearest", "wrap_mode": "clamp"}},
        }
    fov = 2.0 * math.degrees(math.atan(0.5 * RES * PITCH_MM / sensor_mm))
    lo, hi = BAND
    scene["sensor"] = {
        "type": "thinlens",
        "fov": fov, "fov_axis": "x",
        "aperture_radius": FOCAL_MM / (2.0 * F_NUMBER),
        "focus_distance": focus_mm,
        "near_clip": NEAR_CLIP_MM, "far_clip": 5000.0,
        "to_world": T().look_at(origin=[0, CAMERA_Y, CAMERA_Z], target=[0, CAMERA_Y, CAMERA_Z - 1], up=[0, 1, 0]),
        "film": {"type": "specfilm", "width": RES, "height": RES, "component_format": "float32",
                 "rfilter": {"type": "box"},
                 "band": {"type": "regular", "wavelength_min": lo, "wavelength_max": hi, "values": "1, 1"}},
        "sampler": {"type": sampler},
    }
    scene["integrator"] = {"type": "hero", "window": name in WAVEGUIDE_SCENES, "cos4": cos4,
                           "focus_mm": focus_mm, "sensor_mm": sensor_mm,
                           "nested": {"type": "path", "max_depth": max_depth, "rr_depth": max_depth + 1}}
    return mi.load_dict(scene)


def render(name, spp, seed, variant, focus_mm, sensor_mm, max_depth=64, passes=2, return_halves=False,
           cos4="sample", sampler="multijitter"):
    """Renders `passes` independent passes (seeds seed*1000 + i) of spp/passes samples and
    returns (mean image, noise estimate, seconds, samples per pixel).  Noise estimate: with A and
    B the means of the even and odd passes, eps = ||A - B|| / (2 ||(A + B)/2||) estimates the
    relative RMS Monte Carlo error ||mean - truth|| / ||truth|| of the mean image.
    Sampler: Mitsuba's `multijitter` (Kensler's correlated multi-jittered sampling, jittered and
    randomly permuted per pass seed, so each pass is an unbiased estimate independent of the
    others and the even/odd estimate above stays valid; it rounds a pass's sample count up to a
    product of two near-equal integers, and the count actually used is what is returned) or
    `independent`.  cos4: "sample" weights each sample by its own cos^4 (as stscam does),
    "pixel" multiplies the radiance image by the pixel's mean cos^4 (kept for the measurement of
    that difference, README.md)."""
    mi = setup(variant)
    scene = build_scene(mi, name, focus_mm, sensor_mm, max_depth, cos4=cos4, sampler=sampler)
    passes = max(2, passes)
    per = max(1, spp // passes)
    imgs = []
    t0 = time.time()
    for i in range(passes):
        img = np.array(mi.render(scene, spp=per, seed=seed * 1000 + i))[:, :, 0].astype(np.float64)
        imgs.append(img)
    t = time.time() - t0
    per = int(scene.sensors()[0].sampler().sample_count())
    scale = (cos4_map(sensor_mm) if cos4 == "pixel" else 1.0) / (BAND[1] - BAND[0])
    a = np.mean(imgs[0::2], axis=0) * scale
    b = np.mean(imgs[1::2], axis=0) * scale
    mean = 0.5 * (a + b)
    eps = float(np.linalg.norm(a - b) / (2.0 * np.linalg.norm(mean)))
    binned = [x.reshape(RES // 4, 4, RES // 4, 4).mean(axis=(1, 3)) for x in (a, b)]
    eps_b = float(np.linalg.norm(binned[0] - binned[1]) / np.linalg.norm(binned[0] + binned[1]))
    if return_halves:
        return mean.astype(np.float32), (eps, eps_b), t, per * passes, (a, b)
    return mean.astype(np.float32), (eps, eps_b), t, per * passes


def crop_noise(a, b, crop=CROP):
    """Noise estimates (full, 4x4-binned) of the central crop x crop pixels of halves a, b: what
    a centred stscam crop of that size is compared with."""
    c0 = (RES - crop) // 2
    ca, cb = (x[c0:c0 + crop, c0:c0 + crop] for x in (a, b))
    eps_c = float(np.linalg.norm(ca - cb) / np.linalg.norm(ca + cb))
    cbin = [x.reshape(crop // 4, 4, crop // 4, 4).mean(axis=(1, 3)) for x in (ca, cb)]
    eps_cb = float(np.linalg.norm(cbin[0] - cbin[1]) / np.linalg.norm(cbin[0] + cbin[1]))
    return eps_c, eps_cb


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", required=True, choices=sorted(SCENES))
    ap.add_argument("--spp", type=int, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--variant", default="auto")
    ap.add_argument("--focus-mm", type=float, default=None)
    ap.add_argument("--sensor-mm", type=float, default=None)
    ap.add_argument("--max-depth", type=int, default=64)
    ap.add_argument("--passes", type=int, default=2)
    ap.add_argument("--sampler", default="multijitter", choices=["multijitter", "independent"])
    ap.add_argument("--cos4", default="sample", choices=["sample", "pixel"],
                    help="cos^4 per sample (as stscam) or the pixel's mean cos^4 times the radiance")
    a = ap.parse_args()
    variant = a.variant
    if variant == "auto":
        variant, libllvm = choose_variant()
        if libllvm:
            os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
    focus = a.focus_mm or default_focus_mm()
    d0 = a.sensor_mm or FOCAL_MM * focus / (focus - FOCAL_MM)
    img, eps, t, spp, (ha, hb) = render(a.scene, a.spp, a.seed, variant, focus, d0, a.max_depth,
                                        a.passes, return_halves=True, cos4=a.cos4, sampler=a.sampler)
    eps = eps + crop_noise(ha, hb)
    np.save(a.out, img)
    import mitsuba as mi
    meta = {"scene": a.scene, "variant": variant, "spp": spp, "passes": max(2, a.passes),
            "seed": a.seed, "noise_rel_rms": round(eps[0], 5), "noise_rel_rms_binned4": round(eps[1], 5),
            f"noise_rel_rms_center{CROP}": round(eps[2], 5),
            f"noise_rel_rms_binned4_center{CROP}": round(eps[3], 5),
            "render_s": round(t, 2), "mitsuba": mi.__version__, "focus_mm": focus, "sensor_mm": d0,
            "band_nm": list(BAND), "max_depth": a.max_depth, "sampler": a.sampler, "cos4": a.cos4,
            "window_half_width_nm": IS_HALF_WIDTH_NM if a.scene in WAVEGUIDE_SCENES else None}
    with open(os.path.splitext(a.out)[0] + ".json", "w") as f:
        json.dump(meta, f, indent=1)
    print(json.dumps(meta))


if __name__ == "__main__":
    main()
