//! Built-in and procedural shapes of the user side, in millimetres in an object-local frame.
//!
//! Model: every shape faces +z (the camera/screen side; the user stands at z < 0) with +y up;
//! scenes place them later by position, rotation and scale. All closed shapes are watertight
//! once coincident vertices are welded, wound counter-clockwise seen from outside (positive
//! signed volume), with unit vertex normals.
//!
//! * `quad`: the unit square [−½, ½]² at z = 0, normal +z, texture coordinate (0, 0) at the
//!   top-left corner (−½, +½) (glTF convention, see [`super::mesh`]).
//! * `box`: the unit cube [−½, ½]³, flat-shaded (four vertices of its own per face), each face
//!   textured over [0, 1]² with (0, 0) at the face's top-left seen from outside.
//! * `sphere`: diameter 1, a UV sphere of 64 × 32 quads with analytic (smooth) normals,
//!   u = longitude from +z, v = colatitude from +y.
//! * `cylinder`: diameter 1, height 1 along y (y ∈ [−½, ½]), 64 sides, smooth side normals and
//!   flat caps.
//! * `head`: a procedural adult head at real size: crown at y = +115 mm, chin at y = −115 mm
//!   (230 mm chin to crown), about 150 mm wide (ears included) and about 200 mm deep (back of
//!   the skull to the nose tip), face toward +z, with a neck stub down to y = −140 mm. It is
//!   a star-shaped radial surface around the origin: the smooth union of a cranium ellipsoid,
//!   a jaw ellipsoid and a neck cylinder, plus Gaussian relief (nose, brow ridge, eye sockets,
//!   cheek bones, lips, chin, ears) added along the ray. It "reads as a face" in a render; it
//!   is not an anatomical model. About 43 k triangles, one closed manifold surface.
//! * `hand`: an articulated right hand at real size with the wrist at the origin, fingers along
//!   +y and the palm facing +z (so, seen from the camera, the thumb is on the +x side): a
//!   rounded-box palm (superellipsoid, 85 × 100 × 28 mm), four fingers of three capsule
//!   phalanges each (middle fingertip 190 mm from the wrist when straight) and a three-segment
//!   thumb. Each part is a closed surface; parts intersect at the joints. [`Pose`] sets the
//!   flexion of each finger (0° straight, 90° fist-like: the metacarpophalangeal and proximal
//!   interphalangeal joints each turn by the bend, the distal joint by ⅔ of it, all toward the
//!   palm side +z) and the fan-out of the fingers in the palm plane.
//!
//! Materials: `Diffuse` with linear albedo 0.8 grey, except `head` and `hand` which get the
//! skin-like linear RGB albedo [`SKIN_ALBEDO`] (≈ sRGB (203, 173, 155), a light skin tone;
//! a rendering stand-in, not a measured reflectance).
//!
//! Sources: dimensions from adult anthropometric averages (head breadth ≈ 150 mm, head length
//! ≈ 195 mm, menton–vertex height ≈ 230 mm; hand breadth ≈ 85 mm, hand length ≈ 190 mm).

use glam::{DQuat, DVec2, DVec3};

use super::mesh::{Asset, AssetMaterial, Mesh, SurfaceModel};

/// Linear RGB albedo given to the `head` and `hand` shapes (a light skin tone).
pub const SKIN_ALBEDO: [f64; 3] = [0.60, 0.42, 0.33];

/// Names accepted by [`builtin`].
const NAMES: &[&str] = &["quad", "box", "sphere", "cylinder", "head", "hand"];

/// The names of the built-in shapes [`builtin`] knows.
pub fn builtin_names() -> &'static [&'static str] {
    NAMES
}

/// The articulation of the procedural hand (ignored by the other shapes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Flexion of thumb, index, middle, ring and little finger in degrees: 0 straight, 90
    /// fist-like. Non-finite values count as 0; values are clamped to [−30°, 120°].
    pub bend_deg: [f64; 5],
    /// Fan-out between adjacent fingers in the palm plane, degrees (0 = fingers parallel).
    /// Non-finite counts as 0; clamped to [−20°, 30°].
    pub spread_deg: f64,
}

impl Default for Pose {
    /// A relaxed hand: every finger bent by 10°, fingers spread by 8°.
    fn default() -> Self {
        Pose {
            bend_deg: [10.0; 5],
            spread_deg: 8.0,
        }
    }
}

/// The built-in shape `name` (see the module documentation), or `None` for an unknown name.
/// `pose` is used by `hand` only.
pub fn builtin(name: &str, pose: &Pose) -> Option<Asset> {
    let (mesh, albedo) = match name {
        "quad" => (quad(), [0.8; 3]),
        "box" => (unit_box(), [0.8; 3]),
        "sphere" => (sphere(64, 32), [0.8; 3]),
        "cylinder" => (cylinder(64), [0.8; 3]),
        "head" => (head(), SKIN_ALBEDO),
        "hand" => (hand(pose), SKIN_ALBEDO),
        _ => return None,
    };
    let n = mesh.triangles.len();
    let mesh = Mesh {
        material_ids: vec![0; n],
        ..mesh
    };
    Some(Asset {
        mesh,
        materials: vec![AssetMaterial {
            name: name.to_string(),
            model: SurfaceModel::Diffuse,
            base_color: albedo,
            ..AssetMaterial::default()
        }],
    })
}

/// Unit square at z = 0 facing +z.
fn quad() -> Mesh {
    let mut m = Mesh::default();
    push_face(&mut m, DVec3::ZERO, DVec3::X, DVec3::Y);
    m
}

/// Appends a unit square face centred at `c` spanned by unit axes `u` (left→right) and `v`
/// (bottom→top), normal u × v, uv (0, 0) at the top-left.
fn push_face(m: &mut Mesh, c: DVec3, u: DVec3, v: DVec3) {
    let base = m.positions_mm.len() as u32;
    let n = u.cross(v);
    let corners = [
        (c - 0.5 * u + 0.5 * v, DVec2::new(0.0, 0.0)),
        (c - 0.5 * u - 0.5 * v, DVec2::new(0.0, 1.0)),
        (c + 0.5 * u - 0.5 * v, DVec2::new(1.0, 1.0)),
        (c + 0.5 * u + 0.5 * v, DVec2::new(1.0, 0.0)),
    ];
    for (p, uv) in corners {
        m.positions_mm.push(p);
        m.normals.push(n);
        m.uvs.push(uv);
    }
    m.triangles.push([base, base + 1, base + 2]);
    m.triangles.push([base, base + 2, base + 3]);
}

/// Unit cube, flat-shaded.
fn unit_box() -> Mesh {
    let mut m = Mesh::default();
    let (x, y, z) = (DVec3::X, DVec3::Y, DVec3::Z);
    for (n, u, v) in [
        (z, x, y),
        (-z, -x, y),
        (x, -z, y),
        (-x, z, y),
        (y, x, -z),
        (-y, x, z),
    ] {
        push_face(&mut m, 0.5 * n, u, v);
    }
    m
}

/// Direction at colatitude `theta` from +y and longitude `phi` from +z (toward +x).
#[inline]
fn direction(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * sp, ct, st * cp)
}

/// UV sphere of diameter 1 with `nu` longitudes and `nv` latitude bands; the seam and the
/// poles are duplicated per column for the texture coordinates (same positions bit for bit).
fn sphere(nu: usize, nv: usize) -> Mesh {
    let mut m = Mesh::default();
    let cols = nu + 1;
    for k in 0..=nv {
        let theta = std::f64::consts::PI * k as f64 / nv as f64;
        for j in 0..=nu {
            let phi = std::f64::consts::TAU * (j % nu) as f64 / nu as f64;
            let d = if k == 0 {
                DVec3::Y
            } else if k == nv {
                -DVec3::Y
            } else {
                direction(theta, phi)
            };
            m.positions_mm.push(0.5 * d);
            m.normals.push(d);
            m.uvs
                .push(DVec2::new(j as f64 / nu as f64, k as f64 / nv as f64));
        }
    }
    let id = |k: usize, j: usize| (k * cols + j) as u32;
    for k in 0..nv {
        for j in 0..nu {
            let (a, b, c, d) = (id(k, j), id(k + 1, j), id(k + 1, j + 1), id(k, j + 1));
            if k != nv - 1 {
                m.triangles.push([a, b, c]);
            }
            if k != 0 {
                m.triangles.push([a, c, d]);
            }
        }
    }
    m
}

/// Capped cylinder of diameter 1 and height 1 along y with `nu` sides.
fn cylinder(nu: usize) -> Mesh {
    let mut m = Mesh::default();
    let rim = |j: usize, y: f64| {
        let phi = std::f64::consts::TAU * (j % nu) as f64 / nu as f64;
        let (s, c) = phi.sin_cos();
        (DVec3::new(0.5 * s, y, 0.5 * c), DVec3::new(s, 0.0, c))
    };
    // Side: two rows of nu + 1 vertices (seam duplicated for u).
    for (row, y) in [(0.0, 0.5), (1.0, -0.5)] {
        for j in 0..=nu {
            let (p, n) = rim(j, y);
            m.positions_mm.push(p);
            m.normals.push(n);
            m.uvs.push(DVec2::new(j as f64 / nu as f64, row));
        }
    }
    let cols = (nu + 1) as u32;
    for j in 0..nu as u32 {
        let (a, b, c, d) = (j, cols + j, cols + j + 1, j + 1);
        m.triangles.push([a, b, c]);
        m.triangles.push([a, c, d]);
    }
    // Caps: a centre and a ring each, flat normals.
    for (y, n) in [(0.5, DVec3::Y), (-0.5, -DVec3::Y)] {
        let centre = m.positions_mm.len() as u32;
        m.positions_mm.push(DVec3::new(0.0, y, 0.0));
        m.normals.push(n);
        m.uvs.push(DVec2::splat(0.5));
        for j in 0..nu {
            let (p, _) = rim(j, y);
            m.positions_mm.push(p);
            m.normals.push(n);
            m.uvs.push(DVec2::new(0.5 + p.x, 0.5 - p.z * n.y));
        }
        for j in 0..nu as u32 {
            let (p, q) = (centre + 1 + j, centre + 1 + (j + 1) % nu as u32);
            if y > 0.0 {
                m.triangles.push([centre, p, q]);
            } else {
                m.triangles.push([centre, q, p]);
            }
        }
    }
    m
}

/// A closed surface of sphere topology from a top pole, rings of equal length (ordered from
/// the top; within a ring in increasing longitude, i.e. counter-clockwise seen from the top
/// pole side looking down −y in the local frame of [`direction`]) and a bottom pole. Normals
/// are the area-weighted averages of the faces.
fn closed_grid(top: DVec3, rings: &[Vec<DVec3>], bottom: DVec3) -> Mesh {
    let nu = rings.first().map_or(0, Vec::len);
    let mut m = Mesh::default();
    m.positions_mm.push(top);
    for r in rings {
        m.positions_mm.extend_from_slice(r);
    }
    let bottom_id = m.positions_mm.len() as u32;
    m.positions_mm.push(bottom);
    let id = |k: usize, j: usize| (1 + k * nu + j % nu) as u32;
    for j in 0..nu {
        m.triangles.push([0, id(0, j), id(0, j + 1)]);
    }
    for k in 0..rings.len().saturating_sub(1) {
        for j in 0..nu {
            let (a, b, c, d) = (id(k, j), id(k + 1, j), id(k + 1, j + 1), id(k, j + 1));
            m.triangles.push([a, b, c]);
            m.triangles.push([a, c, d]);
        }
    }
    let last = rings.len().saturating_sub(1);
    for j in 0..nu {
        m.triangles.push([id(last, j), bottom_id, id(last, j + 1)]);
    }
    m.compute_normals();
    m
}

/// A closed star-shaped surface around the origin: the point at distance `radius(d)` along
/// every direction d, sampled on `nu` longitudes × `nv` latitude bands.
fn radial_surface(nu: usize, nv: usize, radius: impl Fn(DVec3) -> f64) -> Mesh {
    let rings: Vec<Vec<DVec3>> = (1..nv)
        .map(|k| {
            let theta = std::f64::consts::PI * k as f64 / nv as f64;
            (0..nu)
                .map(|j| {
                    let d = direction(theta, std::f64::consts::TAU * j as f64 / nu as f64);
                    d * radius(d)
                })
                .collect()
        })
        .collect();
    closed_grid(
        DVec3::Y * radius(DVec3::Y),
        &rings,
        -DVec3::Y * radius(-DVec3::Y),
    )
}

/// Distance from the origin (inside) along unit `d` to the surface of the ellipsoid with
/// centre `c` and semi-axes `s`.
fn ellipsoid_exit(d: DVec3, c: DVec3, s: DVec3) -> f64 {
    let (ds, cs) = (d / s, c / s);
    let a = ds.length_squared();
    let b = -2.0 * ds.dot(cs);
    let cc = cs.length_squared() - 1.0;
    (-b + (b * b - 4.0 * a * cc).max(0.0).sqrt()) / (2.0 * a)
}

/// Polynomial smooth maximum with blend width `k`.
fn smooth_max(a: f64, b: f64, k: f64) -> f64 {
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.max(b) + h * h * k * 0.25
}

/// A Gaussian bump: amplitude `amp` mm at centre `c`, widths `sigma` mm per axis.
struct Bump {
    c: DVec3,
    sigma: DVec3,
    amp: f64,
}

impl Bump {
    fn at(&self, q: DVec3) -> f64 {
        let t = (q - self.c) / self.sigma;
        self.amp * (-0.5 * t.length_squared()).exp()
    }
}

/// The head's radial function: distance along unit `d` from the origin to the surface, mm.
fn head_radius(d: DVec3, bumps: &[Bump]) -> f64 {
    let cranium = ellipsoid_exit(
        d,
        DVec3::new(0.0, 15.0, -8.0),
        DVec3::new(70.0, 100.0, 90.0),
    );
    let jaw = ellipsoid_exit(
        d,
        DVec3::new(0.0, -50.0, 25.0),
        DVec3::new(56.0, 65.0, 62.0),
    );
    let mut r = smooth_max(cranium, jaw, 20.0);
    // Neck: the cylinder x² + (z − zc)² < rn², y > −140, seen along rays going down.
    if d.y < 0.0 {
        let (zc, rn, bottom) = (-15.0, 55.0, -140.0);
        let a = d.x * d.x + d.z * d.z;
        let side = if a > 1e-12 {
            let b = -2.0 * d.z * zc;
            let c = zc * zc - rn * rn;
            (-b + (b * b - 4.0 * a * c).sqrt()) / (2.0 * a)
        } else {
            f64::INFINITY
        };
        let neck = side.min(bottom / d.y);
        r = smooth_max(r, neck, 12.0);
    }
    let q = d * r;
    r + bumps.iter().map(|b| b.at(q)).sum::<f64>()
}

/// The facial relief of the head (symmetric in x).
fn head_bumps() -> Vec<Bump> {
    let b = |x: f64, y: f64, z: f64, sx: f64, sy: f64, sz: f64, amp: f64| Bump {
        c: DVec3::new(x, y, z),
        sigma: DVec3::new(sx, sy, sz),
        amp,
    };
    let mut v = vec![
        // Nose: bridge and body, tip, then the lips, the mouth line and the chin.
        b(0.0, -8.0, 85.0, 8.0, 22.0, 25.0, 12.0),
        b(0.0, -32.0, 88.0, 10.0, 9.0, 25.0, 12.0),
        b(0.0, -60.0, 85.0, 17.0, 5.0, 25.0, 3.0),
        b(0.0, -66.0, 87.0, 20.0, 1.8, 25.0, -2.5),
        b(0.0, -98.0, 68.0, 15.0, 11.0, 25.0, 6.0),
    ];
    for s in [-1.0, 1.0] {
        v.extend([
            // Nostril wings.
            b(s * 12.0, -36.0, 84.0, 6.0, 6.0, 25.0, 4.0),
            // Eye sockets.
            b(s * 31.0, 12.0, 82.0, 13.0, 9.0, 25.0, -9.0),
            // Brow ridge.
            b(s * 30.0, 29.0, 86.0, 18.0, 5.5, 25.0, 4.0),
            // Cheek bones.
            b(s * 47.0, -12.0, 66.0, 14.0, 14.0, 25.0, 5.0),
            // Ears.
            b(s * 69.0, 5.0, -5.0, 6.0, 28.0, 14.0, 6.0),
        ]);
    }
    v
}

/// The procedural head (see the module documentation).
fn head() -> Mesh {
    let bumps = head_bumps();
    radial_surface(192, 112, |d| head_radius(d, &bumps))
}

/// A capsule (lathe) from `p0` to `p1` of radius `r`, oriented by the unit `fwd` direction
/// (any direction not along the axis) — closed, outward wound.
fn capsule(p0: DVec3, p1: DVec3, r: f64, fwd: DVec3, nu: usize, ncap: usize) -> Mesh {
    let axis = p1 - p0;
    let len = axis.length();
    let up = if len > 0.0 { axis / len } else { DVec3::Y };
    let fwd = (fwd - up * fwd.dot(up))
        .try_normalize()
        .unwrap_or_else(|| up.any_orthonormal_vector());
    let right = up.cross(fwd);
    let place = |x: f64, y: f64, z: f64| p0 + right * x + up * y + fwd * z;
    let mut rings = Vec::with_capacity(2 * ncap);
    for (centre, lo, hi) in [(len, 1, ncap), (0.0, ncap, 2 * ncap - 1)] {
        for k in lo..=hi {
            let alpha = std::f64::consts::FRAC_PI_2 * k as f64 / ncap as f64;
            let (rad, y) = (r * alpha.sin(), centre + r * alpha.cos());
            rings.push(
                (0..nu)
                    .map(|j| {
                        let phi = std::f64::consts::TAU * j as f64 / nu as f64;
                        place(rad * phi.sin(), y, rad * phi.cos())
                    })
                    .collect(),
            );
        }
    }
    closed_grid(place(0.0, len + r, 0.0), &rings, place(0.0, -r, 0.0))
}

/// One digit of the hand: base joint, initial direction, palm-side direction, segment lengths
/// (mm), radii (mm) and the share of the bend each joint takes.
struct Digit {
    base: DVec3,
    up: DVec3,
    fwd: DVec3,
    lengths: [f64; 3],
    radii: [f64; 3],
    joint_share: [f64; 3],
}

/// Clamps a user angle, treating non-finite values as 0.
fn clean(v: f64, lo: f64, hi: f64) -> f64 {
    if v.is_finite() { v.clamp(lo, hi) } else { 0.0 }
}

/// The five digits (thumb, index, middle, ring, little) of the right hand in `pose`.
fn digits(pose: &Pose) -> [Digit; 5] {
    let spread = clean(pose.spread_deg, -20.0, 30.0).to_radians();
    let finger = |x: f64, y: f64, fan: f64, lengths: [f64; 3], r: f64| Digit {
        base: DVec3::new(x, y, 0.0),
        // Fan in the palm plane: rotating about +z by −fan tilts +y toward +x (thumb side).
        up: DQuat::from_rotation_z(-fan) * DVec3::Y,
        fwd: DVec3::Z,
        lengths,
        radii: [r, 0.95 * r, 0.9 * r],
        joint_share: [1.0, 1.0, 2.0 / 3.0],
    };
    let thumb_angle = 40f64.to_radians() + spread;
    let thumb_up = DVec3::new(thumb_angle.sin(), thumb_angle.cos(), 0.35).normalize();
    let thumb_fwd = DVec3::new(-1.0, 0.0, 1.0);
    [
        Digit {
            base: DVec3::new(22.0, 18.0, 4.0),
            up: thumb_up,
            fwd: (thumb_fwd - thumb_up * thumb_fwd.dot(thumb_up)).normalize(),
            lengths: [46.0, 32.0, 27.0],
            radii: [12.0, 10.5, 9.5],
            joint_share: [0.5, 1.0, 1.0],
        },
        finger(27.0, 92.0, spread, [42.0, 25.0, 20.0], 8.5),
        finger(9.0, 95.0, 0.0, [45.0, 28.0, 22.0], 9.0),
        finger(-10.0, 93.0, -spread, [43.0, 27.0, 21.0], 8.5),
        finger(-28.0, 86.0, -2.0 * spread, [33.0, 20.0, 18.0], 7.5),
    ]
}

/// The segments of one digit bent by `bend` radians: (start, end, direction, palm-side).
fn digit_segments(dg: &Digit, bend: f64) -> [(DVec3, DVec3, DVec3); 3] {
    let axis = dg.up.cross(dg.fwd).normalize();
    let (mut p, mut up, mut fwd) = (dg.base, dg.up, dg.fwd);
    std::array::from_fn(|i| {
        let q = DQuat::from_axis_angle(axis, bend * dg.joint_share[i]);
        up = q * up;
        fwd = q * fwd;
        let start = p;
        p += up * dg.lengths[i];
        (start, p, fwd)
    })
}

/// Fingertip positions (thumb, index, middle, ring, little) of the procedural hand in `pose`,
/// mm: the far end of each digit's rounded tip.
pub fn hand_fingertips(pose: &Pose) -> [DVec3; 5] {
    let ds = digits(pose);
    std::array::from_fn(|i| {
        let bend = clean(pose.bend_deg[i], -30.0, 120.0).to_radians();
        digit_segments(&ds[i], bend)[2].1
    })
}

/// The procedural right hand (see the module documentation).
fn hand(pose: &Pose) -> Mesh {
    // Palm: superellipsoid |x/a|⁴ + |y/b|⁴ + |z/c|⁴ = 1 centred at (0, 50, 0).
    let (a, b, c, n) = (42.5, 50.0, 14.0, 4.0);
    let centre = DVec3::new(0.0, 50.0, 0.0);
    let palm_r = |d: DVec3| {
        let s = (d.x / a).abs().powf(n) + (d.y / b).abs().powf(n) + (d.z / c).abs().powf(n);
        s.powf(-1.0 / n)
    };
    let mut mesh = radial_surface(64, 48, palm_r);
    for p in &mut mesh.positions_mm {
        *p += centre;
    }
    for (i, dg) in digits(pose).iter().enumerate() {
        let bend = clean(pose.bend_deg[i], -30.0, 120.0).to_radians();
        for (k, (p0, p1, fwd)) in digit_segments(dg, bend).into_iter().enumerate() {
            let r = dg.radii[k];
            // The last segment's rounded tip ends exactly at the fingertip.
            let p1 = if k == 2 {
                p1 - (p1 - p0).normalize() * r
            } else {
                p1
            };
            mesh.append(&capsule(p0, p1, r, fwd, 24, 6), 0);
        }
    }
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn asset(name: &str) -> Asset {
        builtin(name, &Pose::default()).unwrap()
    }

    /// Signed volume by the divergence theorem.
    fn volume(m: &Mesh) -> f64 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions_mm[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    fn bbox(m: &Mesh) -> (DVec3, DVec3) {
        m.positions_mm.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        )
    }

    /// Every undirected edge (after welding equal positions) is used by exactly two triangles,
    /// once in each direction (so the winding is consistent).
    fn assert_closed_manifold(m: &Mesh) {
        let key = |p: DVec3| (p + DVec3::ZERO).to_array().map(f64::to_bits);
        let mut weld: HashMap<[u64; 3], u32> = HashMap::new();
        let ids: Vec<u32> = m
            .positions_mm
            .iter()
            .map(|&p| {
                let n = weld.len() as u32;
                *weld.entry(key(p)).or_insert(n)
            })
            .collect();
        let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &m.triangles {
            let v = t.map(|i| ids[i as usize]);
            assert!(
                v[0] != v[1] && v[1] != v[2] && v[0] != v[2],
                "degenerate {t:?}"
            );
            for e in 0..3 {
                *edges.entry((v[e], v[(e + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "directed edge {a}->{b} used {n} times");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} is a boundary");
        }
    }

    fn assert_well_formed(a: &Asset) {
        let m = &a.mesh;
        assert_eq!(m.normals.len(), m.positions_mm.len());
        assert!(m.uvs.is_empty() || m.uvs.len() == m.positions_mm.len());
        assert_eq!(m.material_ids.len(), m.triangles.len());
        assert!(
            m.material_ids
                .iter()
                .all(|&i| (i as usize) < a.materials.len())
        );
        assert!(m.first_nonfinite_vertex().is_none());
        for n in &m.normals {
            assert!((n.length() - 1.0).abs() < 1e-9, "normal {n}");
        }
        for t in &m.triangles {
            assert!(t.iter().all(|&i| (i as usize) < m.positions_mm.len()));
        }
    }

    #[test]
    fn all_builtins_are_well_formed() {
        assert_eq!(builtin_names().len(), 6);
        for name in builtin_names() {
            let a = asset(name);
            assert_well_formed(&a);
            let expect = if matches!(*name, "head" | "hand") {
                SKIN_ALBEDO
            } else {
                [0.8; 3]
            };
            assert_eq!(a.materials[0].base_color, expect);
            assert_eq!(a.materials[0].model, SurfaceModel::Diffuse);
        }
        assert!(builtin("teapot", &Pose::default()).is_none());
    }

    #[test]
    fn quad_faces_plus_z_with_top_left_uv() {
        let m = asset("quad").mesh;
        assert_eq!(m.triangles.len(), 2);
        let [a, b, c] = m.triangles[0].map(|i| m.positions_mm[i as usize]);
        assert!((b - a).cross(c - a).z > 0.0);
        let i = m.uvs.iter().position(|&uv| uv == DVec2::ZERO).unwrap();
        assert_eq!(m.positions_mm[i], DVec3::new(-0.5, 0.5, 0.0));
        assert!(m.normals.iter().all(|&n| n == DVec3::Z));
    }

    #[test]
    fn closed_shapes_have_expected_volumes_and_are_manifold() {
        let b = asset("box").mesh;
        assert_eq!(volume(&b), 1.0);
        assert_closed_manifold(&b);
        // Flat shading: every triangle's vertex normals equal its face normal.
        for t in &b.triangles {
            let [p, q, r] = t.map(|i| b.positions_mm[i as usize]);
            let n = (q - p).cross(r - p).normalize();
            assert!(t.iter().all(|&i| b.normals[i as usize] == n));
        }
        let s = asset("sphere").mesh;
        assert!((volume(&s) / (std::f64::consts::PI / 6.0) - 1.0).abs() < 0.01);
        assert_closed_manifold(&s);
        let (lo, hi) = bbox(&s);
        assert!((hi - lo - DVec3::ONE).abs().max_element() < 1e-12);
        let c = asset("cylinder").mesh;
        assert!((volume(&c) / (std::f64::consts::PI / 4.0) - 1.0).abs() < 0.01);
        assert_closed_manifold(&c);
        let (lo, hi) = bbox(&c);
        assert_eq!((lo.y, hi.y), (-0.5, 0.5));
    }

    #[test]
    fn head_has_real_size_and_is_closed() {
        let m = asset("head").mesh;
        let n = m.triangles.len();
        assert!((20_000..=60_000).contains(&n), "{n} triangles");
        assert_closed_manifold(&m);
        assert!(volume(&m) > 0.0);
        let (lo, hi) = bbox(&m);
        let size = hi - lo;
        assert!((140.0..=165.0).contains(&size.x), "width {size}");
        assert!((180.0..=220.0).contains(&size.z), "depth {size}");
        // Crown at +115; chin (the lowest point in front of the neck) near −115.
        assert!((hi.y - 115.0).abs() < 5.0, "crown {hi}");
        assert!((lo.y + 140.0).abs() < 3.0, "neck {lo}");
        let chin = m
            .positions_mm
            .iter()
            .filter(|p| p.z > 55.0)
            .map(|p| p.y)
            .fold(f64::INFINITY, f64::min);
        assert!((-122.0..=-105.0).contains(&chin), "chin {chin}");
        // Symmetric in x and the face (nose tip) is the front-most point.
        assert!((hi.x + lo.x).abs() < 1.0);
        let front = m
            .positions_mm
            .iter()
            .max_by(|a, b| a.z.total_cmp(&b.z))
            .unwrap();
        assert!(
            front.x.abs() < 3.0 && (-45.0..=0.0).contains(&front.y),
            "nose {front}"
        );
        // The eye sockets are recessed relative to the brow above them.
        let depth_at = |x: f64, y: f64| {
            m.positions_mm
                .iter()
                .filter(|p| p.z > 0.0 && (p.x - x).abs() < 3.0 && (p.y - y).abs() < 3.0)
                .map(|p| p.z)
                .fold(f64::NEG_INFINITY, f64::max)
        };
        assert!(depth_at(31.0, 12.0) < depth_at(30.0, 30.0) - 3.0);
    }

    #[test]
    fn hand_size_and_articulation() {
        let straight = Pose {
            bend_deg: [0.0; 5],
            spread_deg: 0.0,
        };
        let h = builtin("hand", &straight).unwrap();
        assert_well_formed(&h);
        let (lo, hi) = bbox(&h.mesh);
        assert!(lo.y.abs() < 1e-9, "wrist {lo}");
        assert!((hi.y - 190.0).abs() < 1e-9, "fingertip {hi}");
        assert!((lo.x + 42.5).abs() < 0.5, "palm little-finger side {lo}");
        assert!(hi.x > 42.5, "thumb on the +x side {hi}");
        assert!((hi.z - lo.z) < 60.0);
        let tips = hand_fingertips(&straight);
        assert!((tips[2] - DVec3::new(9.0, 190.0, 0.0)).length() < 1e-9);
        // Each closed part has positive volume: the total is positive too.
        assert!(volume(&h.mesh) > 0.0);
        let fist = Pose {
            bend_deg: [90.0; 5],
            spread_deg: 0.0,
        };
        let bent = hand_fingertips(&fist);
        for i in 1..5 {
            assert!(bent[i].z > tips[i].z + 15.0, "finger {i} {}", bent[i]);
            assert!(bent[i].y < tips[i].y - 80.0, "finger {i} {}", bent[i]);
        }
        let (_, hi_fist) = bbox(&builtin("hand", &fist).unwrap().mesh);
        assert!(hi_fist.y < 170.0 && hi_fist.z > hi.z);
        // Spread fans the index toward the thumb and the little finger away from it.
        let wide = hand_fingertips(&Pose {
            bend_deg: [0.0; 5],
            spread_deg: 15.0,
        });
        assert!(wide[1].x > tips[1].x && wide[4].x < tips[4].x);
        // Absurd input does not produce NaN.
        let bad = Pose {
            bend_deg: [f64::NAN, 1e9, -1e9, f64::INFINITY, 0.0],
            spread_deg: f64::NAN,
        };
        assert_well_formed(&builtin("hand", &bad).unwrap());
    }
}
