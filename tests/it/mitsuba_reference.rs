//! stscam against independent Mitsuba 3 references (validation/mitsuba/README.md).
//!
//! The references `validation/mitsuba/reference/{plain-glass,waveguide}.npy` (128×128 float32,
//! stscam's pixel unit) were rendered by `validation/mitsuba/run.sh --update-references` from
//! the Mitsuba scenes of `validation/mitsuba/scenes.py` (own vHOE BSDF written from
//! docs/physics.md); their JSON holds the Monte Carlo noise estimate. Here the same scenes
//! (`validation/mitsuba/*.toml`) are rendered in-process with two seeds and compared with the
//! rules of `validation/mitsuba/compare.py`:
//!  1. relative RMSE ‖s − m‖/‖m‖ ≤ 2·√(ε_s² + ε_m²) + δ at full resolution,
//!  2. the same on 4×4-binned images,
//!  3. waveguide: the row-profile peaks (replica positions) agree one to one within 1 px;
//!
//! with ε the relative RMS noise of each mean image (from two independent halves) and δ the
//! allowance for known model differences (0.01 plain glass, 0.015 waveguide: at least twice
//! the sum of the itemised estimates of validation/mitsuba/README.md, "Known differences").
//! Deliberately wrong inputs must fail: the grating vector with the wrong sign (by a wide
//! margin), the stscam image 10 % too bright, and the film's index modulation 10 % too high.
//!
//! The mesh scenes `validation/mitsuba/mesh-{plain-glass,waveguide}.toml` (two textured OBJ
//! meshes lit by a rect area light, display off; references `reference/mesh-*.npy`) are
//! compared the same way (rules 1 and 2; δ 0.01 and 0.03) on the central 64×64 pixels only, at
//! 64 spp, to keep the path-traced user side fast; the references' JSON holds the noise of that
//! crop. Deliberately wrong inputs (the light 10 % too bright, the texture without its sRGB
//! decoding, the texture upside down) must fail the mesh plain-glass comparison.

use std::path::{Path, PathBuf};

use stscam::render::{RenderSettings, render};
use stscam::sampler::SamplerKind;
use stscam::scene::load_scene;
use stscam::system::System;

const SPP: u32 = 128;
const NOISE_FACTOR: f64 = 2.0;
const PEAK_FRACTION: f64 = 0.10;
const PEAK_TOLERANCE_PX: f64 = 1.0;

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("validation/mitsuba")
}

/// Minimal .npy reader: little-endian float32, C order, 2-D.
fn read_npy(path: &Path) -> (usize, usize, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[..6], b"\x93NUMPY", "not an .npy file");
    let (hlen, start) = if bytes[6] == 1 {
        (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10)
    } else {
        (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        )
    };
    let header = std::str::from_utf8(&bytes[start..start + hlen]).unwrap();
    assert!(header.contains("'descr': '<f4'"), "{header}");
    assert!(header.contains("'fortran_order': False"), "{header}");
    let shape = &header[header.find("'shape': (").unwrap() + 10..];
    let dims: Vec<usize> = shape[..shape.find(')').unwrap()]
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse().unwrap())
        .collect();
    assert_eq!(dims.len(), 2, "{header}");
    let data: Vec<f64> = bytes[start + hlen..]
        .chunks_exact(4)
        .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
        .collect();
    assert_eq!(data.len(), dims[0] * dims[1]);
    (dims[0], dims[1], data)
}

/// A number from the reference's JSON (flat object, written by scenes.py).
fn json_number(path: &Path, key: &str) -> f64 {
    let text = std::fs::read_to_string(path).unwrap();
    let at = text
        .find(&format!("\"{key}\""))
        .unwrap_or_else(|| panic!("{key} missing in {}", path.display()));
    let rest = &text[at + key.len() + 2..];
    let rest = rest[rest.find(':').unwrap() + 1..].trim_start();
    let end = rest.find([',', '}', '\n']).unwrap();
    rest[..end].trim().parse().unwrap()
}

fn system(scene: &str) -> System {
    system_with(scene, &[])
}

/// The scene with `--set` overrides.
fn system_with(scene: &str, overrides: &[String]) -> System {
    let ls = load_scene(Some(&dir().join(format!("{scene}.toml"))), overrides).expect("scene");
    System::build(&ls).expect("system")
}

/// Side of the central crop the mesh scenes are rendered and compared on.
const MESH_CROP: usize = 64;
/// Samples per pixel (per seed) of the mesh scenes.
const MESH_SPP: u32 = 64;

/// A mesh scene cropped to its central `MESH_CROP` pixels, with further overrides.
fn mesh_system(scene: &str, overrides: &[&str]) -> System {
    let mut o = vec![format!("sensor.crop_px=[{MESH_CROP},{MESH_CROP}]")];
    o.extend(overrides.iter().map(|s| s.to_string()));
    system_with(scene, &o)
}

fn render_y(sys: &System, seed: u64, spp: u32, n: usize) -> Vec<f64> {
    let cap = render(
        sys,
        &RenderSettings {
            spp,
            seed,
            sampler: SamplerKind::Lattice,
            user_side: Default::default(),
            spectral_bins: None,
            progress: false,
            estimator: Default::default(),
            adaptive: false,
        },
    );
    assert_eq!((cap.width, cap.height), (n, n));
    cap.channels[0].iter().map(|&v| f64::from(v)).collect()
}

/// The central `c`×`c` pixels of an `n`×`n` image.
fn crop_center(a: &[f64], n: usize, c: usize) -> Vec<f64> {
    let o = (n - c) / 2;
    (o..o + c)
        .flat_map(|r| a[r * n + o..r * n + o + c].iter().copied())
        .collect()
}

fn norm(a: &[f64]) -> f64 {
    a.iter().map(|v| v * v).sum::<f64>().sqrt()
}

fn diff(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| x - y).collect()
}

fn mean2(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| 0.5 * (x + y)).collect()
}

fn noise(a: &[f64], b: &[f64]) -> f64 {
    let m = norm(&mean2(a, b));
    if m > 0.0 {
        norm(&diff(a, b)) / (2.0 * m)
    } else {
        0.0
    }
}

fn bin4(a: &[f64], n: usize) -> Vec<f64> {
    let m = n / 4;
    let mut out = vec![0.0; m * m];
    for r in 0..n {
        for c in 0..n {
            out[(r / 4) * m + c / 4] += a[r * n + c] / 16.0;
        }
    }
    out
}

fn peaks(img: &[f64], n: usize) -> Vec<f64> {
    let prof: Vec<f64> = (0..n)
        .map(|r| img[r * n..(r + 1) * n].iter().sum())
        .collect();
    let thr = PEAK_FRACTION * prof.iter().cloned().fold(f64::MIN, f64::max);
    let mut out = Vec::new();
    for i in 1..n - 1 {
        let (y0, y1, y2) = (prof[i - 1], prof[i], prof[i + 1]);
        if y1 >= thr && y1 > y0 && y1 >= y2 {
            let den = y0 - 2.0 * y1 + y2;
            out.push(
                i as f64
                    + if den != 0.0 {
                        0.5 * (y0 - y2) / den
                    } else {
                        0.0
                    },
            );
        }
    }
    out
}

fn peak_offset(test: &[f64], reference: &[f64]) -> f64 {
    if test.is_empty() || reference.is_empty() {
        return f64::INFINITY;
    }
    let nearest = |p: f64, set: &[f64]| set.iter().map(|q| (p - q).abs()).fold(f64::MAX, f64::min);
    let d1 = reference
        .iter()
        .map(|&p| nearest(p, test))
        .fold(0.0, f64::max);
    let d2 = test
        .iter()
        .map(|&p| nearest(p, reference))
        .fold(0.0, f64::max);
    d1.max(d2)
}

#[derive(Debug)]
struct Outcome {
    rel_rmse: f64,
    tolerance: f64,
    rel_rmse_binned: f64,
    tolerance_binned: f64,
    peak_offset_px: f64,
    peaks_equal: bool,
}

impl Outcome {
    fn pass(&self) -> bool {
        self.rel_rmse <= self.tolerance
            && self.rel_rmse_binned <= self.tolerance_binned
            && self.peak_offset_px <= PEAK_TOLERANCE_PX
            && self.peaks_equal
    }
}

fn compare(scene: &str, sys: &System) -> Outcome {
    compare_at(scene, sys, 128, SPP)
}

/// Compares `sys` (rendered at `w`×`w`, the centre of the reference's 128×128, with `spp`
/// samples per seed) with the reference of `scene`.
fn compare_at(scene: &str, sys: &System, w: usize, spp: u32) -> Outcome {
    compare_scaled(scene, sys, w, spp, 1.0)
}

/// [`compare_at`] with the stscam image multiplied by `gain` (1 = as rendered; other values
/// make a deliberately wrong input).
fn compare_scaled(scene: &str, sys: &System, w: usize, spp: u32, gain: f64) -> Outcome {
    let (h, n, m) = read_npy(&dir().join(format!("reference/{scene}.npy")));
    assert_eq!((h, n), (128, 128));
    let m = crop_center(&m, n, w);
    let meta = dir().join(format!("reference/{scene}.json"));
    let (key, key_bin) = if w == n {
        (
            "noise_rel_rms".to_string(),
            "noise_rel_rms_binned4".to_string(),
        )
    } else {
        (
            format!("noise_rel_rms_center{w}"),
            format!("noise_rel_rms_binned4_center{w}"),
        )
    };
    let eps_m = json_number(&meta, &key);
    let eps_m_bin = json_number(&meta, &key_bin);
    let delta = match scene {
        "plain-glass" | "mesh-plain-glass" => 0.01,
        "waveguide" => 0.015,
        _ => 0.03,
    };
    let scaled = |v: Vec<f64>| v.into_iter().map(|x| gain * x).collect::<Vec<f64>>();
    let (a, b) = (
        scaled(render_y(sys, 1, spp, w)),
        scaled(render_y(sys, 2, spp, w)),
    );
    let s = mean2(&a, &b);
    let eps_s = noise(&a, &b);
    let eps_s_bin = noise(&bin4(&a, w), &bin4(&b, w));
    // Replica positions: only the waveguide has replicas (the glyph's row profile is flat).
    let (pm, ps) = if scene == "waveguide" {
        (peaks(&m, w), peaks(&s, w))
    } else {
        (vec![0.0], vec![0.0])
    };
    let out = Outcome {
        rel_rmse: norm(&diff(&s, &m)) / norm(&m),
        tolerance: NOISE_FACTOR * eps_s.hypot(eps_m) + delta,
        rel_rmse_binned: norm(&diff(&bin4(&s, w), &bin4(&m, w))) / norm(&bin4(&m, w)),
        tolerance_binned: NOISE_FACTOR * eps_s_bin.hypot(eps_m_bin) + delta,
        peak_offset_px: peak_offset(&ps, &pm),
        peaks_equal: pm.len() == ps.len(),
    };
    eprintln!(
        "{scene}: {out:?}; noise stscam {eps_s:.4} (binned {eps_s_bin:.4}), mitsuba {eps_m:.4} \
         (binned {eps_m_bin:.4}); peaks mitsuba {pm:.2?} stscam {ps:.2?}; flux ratio {:.4}",
        s.iter().sum::<f64>() / m.iter().sum::<f64>()
    );
    out
}

#[test]
fn plain_glass_matches_the_mitsuba_reference() {
    let out = compare("plain-glass", &system("plain-glass"));
    assert!(out.pass(), "{out:?}");
}

#[test]
fn waveguide_matches_the_mitsuba_reference() {
    let out = compare("waveguide", &system("waveguide"));
    assert!(out.pass(), "{out:?}");
}

/// The comparison has teeth: with the grating vector's sign flipped (a plausible sign error,
/// docs/physics.md §0.2) the waveguide image no longer matches, by a wide margin.
#[test]
fn waveguide_with_the_wrong_sign_of_k_fails_the_comparison() {
    let mut sys = system("waveguide");
    let g = &mut sys.waveguide.gratings.as_mut_slice()[0];
    g.k_rad_per_nm = -g.k_rad_per_nm;
    let out = compare("waveguide", &sys);
    assert!(!out.pass(), "{out:?}");
    assert!(
        out.rel_rmse > 3.0 * out.tolerance && out.rel_rmse_binned > 3.0 * out.tolerance_binned,
        "{out:?}"
    );
}

/// Subtler wrong inputs fail too: the stscam image 10 % too bright (a wrong normalisation) and
/// the film's index modulation n1 10 % too high (0.0165 instead of 0.015), each with the binned
/// relative RMSE above its tolerance.
#[test]
fn waveguide_with_small_wrong_inputs_fails_the_comparison() {
    let bright = compare_scaled("waveguide", &system("waveguide"), 128, SPP, 1.10);
    assert!(
        !bright.pass() && bright.rel_rmse_binned > bright.tolerance_binned,
        "10 % too bright: {bright:?}"
    );
    let n1 = ["hoe.index_modulation=0.0165".to_string()];
    let strong = compare("waveguide", &system_with("waveguide", &n1));
    assert!(
        !strong.pass() && strong.rel_rmse_binned > strong.tolerance_binned,
        "n1 10 % too high: {strong:?}"
    );
}

#[test]
fn mesh_plain_glass_matches_the_mitsuba_reference() {
    let out = compare_at(
        "mesh-plain-glass",
        &mesh_system("mesh-plain-glass", &[]),
        MESH_CROP,
        MESH_SPP,
    );
    assert!(out.pass(), "{out:?}");
}

#[test]
fn mesh_waveguide_matches_the_mitsuba_reference() {
    let out = compare_at(
        "mesh-waveguide",
        &mesh_system("mesh-waveguide", &[]),
        MESH_CROP,
        MESH_SPP,
    );
    assert!(out.pass(), "{out:?}");
}

/// The mesh comparison has teeth: plausible input or decoding errors fail it clearly (the
/// binned relative RMSE at least 3× its tolerance): the light 10 % too bright, the texture read
/// without its sRGB decoding (validation/mitsuba/mesh-texture-undecoded.png holds what such a
/// reader would see), and the texture upside down (an OBJ v flip missed or done twice).
#[test]
fn mesh_scene_with_wrong_inputs_fails_the_comparison() {
    let undecoded = [
        "object.0.material.base_color=\"mesh-texture-undecoded.png\"",
        "object.1.material.base_color=\"mesh-texture-undecoded.png\"",
    ];
    let flipped = [
        "object.0.material.base_color=\"mesh-texture-flipped.png\"",
        "object.1.material.base_color=\"mesh-texture-flipped.png\"",
    ];
    for (what, overrides) in [
        ("light 10 % too bright", &["light.0.scale=22.0"][..]),
        ("texture not sRGB-decoded", &undecoded[..]),
        ("texture upside down", &flipped[..]),
    ] {
        let out = compare_at(
            "mesh-plain-glass",
            &mesh_system("mesh-plain-glass", overrides),
            MESH_CROP,
            MESH_SPP,
        );
        assert!(!out.pass(), "{what}: {out:?}");
        assert!(
            out.rel_rmse_binned > 3.0 * out.tolerance_binned,
            "{what}: {out:?}"
        );
    }
}
