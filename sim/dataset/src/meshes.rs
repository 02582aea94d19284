//! 3-D dataset samples (`generator = "meshes"`, render mode): a mesh with a random pose,
//! placement, material and lighting per sample, rendered through the waveguide (capture) and
//! by the ideal pinhole at the screen (frontal ground truth, depth map, mask;
//! `world/frontal.rs`).
//!
//! Draws: a ChaCha12 generator (`rand`, pinned exactly in Cargo.toml so the bytes stay fixed)
//! seeded per sample from `NoiseRng([sample seed, MESH_TAG])`, and `rand`'s `Uniform` and
//! `Bernoulli` distributions, in a fixed order: mesh (uniform over the built-ins, then the
//! folder's files), position (x, y, distance), rotation (each axis in ±max), scale, hand pose
//! (five bends, spread; drawn for every mesh so the stream does not depend on the choice),
//! base colour (r, g, b), roughness, metal or not, key light (azimuth in ±60°, elevation in
//! [15°, 60°], radiance scale, colour temperature), screen glow and environment.
//!
//! Scene of a sample: the recipe's scene plus one `[[object]]` (the drawn mesh, its material
//! overridden by the drawn colour, roughness and metalness) and up to three `[[light]]`s: the
//! key light, a 400 × 400 mm black-body rect panel facing the mesh origin from the drawn
//! direction t, at 0.6·(−o·t) from the origin o (so it stays on the user side and the camera
//! sees its back, which emits nothing and is invisible; if the mesh is so far off axis that
//! −o·t < 0.1·distance, at 0.06·distance); the screen's glow (a 518 × 324 mm
//! white-LED rect at z = −1 mm emitting toward the user, transparent from behind, like
//! `scenes/eye-contact.toml`); a uniform D65 environment. Lights of scale 0 are left out.
//! A mesh whose placed bounds would come closer than 5 mm to the plate is moved back along −z
//! ([`MeshDraw::settle`]). Assumption: one mesh per sample; the recipe scene's own objects and lights stay (mask
//! values count them first).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rand::SeedableRng;
use rand::distr::{Bernoulli, Distribution, Uniform};
use rand::rngs::ChaCha12Rng;
use serde::Serialize;

use crate::noise::NoiseRng;
use crate::scene::{LoadedScene, SceneError};
use crate::system::System;
use crate::world::desc::{
    BendSpec, LightDesc, MaterialDesc, ObjectDesc, PoseDesc, RgbOr, ScaleSpec,
};
use stscam_tracer::frontal::{Frontal, render_frontal_in};

use super::recipe::MeshSource;

/// Domain tag of the 3-D draw stream.
const MESH_TAG: u64 = 0x4D45_5348;
/// Side of the key light panel, mm.
const KEY_SIZE_MM: f64 = 400.0;
/// The screen's glow: size (mm) of the emitting rect at the plate.
const GLOW_SIZE_MM: [f64; 2] = [518.0, 324.0];
/// Frontal PNG full scale in the capture unit (1 = display white).
pub const FRONTAL_PNG_FULL_SCALE: f64 = 1.0;

/// The key light of a sample.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KeyLight {
    /// Centre, mm.
    pub position_mm: [f64; 3],
    /// Emitting direction (toward the mesh origin).
    pub normal: [f64; 3],
    /// Radiance scale (capture unit).
    pub scale: f64,
    /// Black-body temperature, kelvin.
    pub kelvin: f64,
}

/// Everything drawn for one 3-D sample (recorded in `metadata.jsonl`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshDraw {
    /// Built-in name, or the file as recorded (relative to the recipe's folder).
    pub mesh: String,
    /// The file (None for built-ins).
    #[serde(skip)]
    pub path: Option<PathBuf>,
    /// Position of the mesh origin, mm.
    pub position_mm: [f64; 3],
    /// Rotation about x, y, z, degrees.
    pub rotation_deg: [f64; 3],
    /// Uniform scale.
    pub scale: f64,
    /// Hand pose: flexion per finger (thumb first), degrees (drawn for every mesh, so the
    /// metadata columns have one type; applied to the built-in hand only).
    pub bend_deg: [f64; 5],
    /// Hand pose: spread, degrees (applied to the built-in hand only).
    pub spread_deg: f64,
    /// Linear RGB base colour.
    pub base_color: [f64; 3],
    /// GGX roughness.
    pub roughness: f64,
    /// Metalness (0 or 1).
    pub metallic: f64,
    /// Key light.
    pub key_light: KeyLight,
    /// Radiance scale of the screen's glow.
    pub screen_glow: f64,
    /// Radiance scale of the environment.
    pub environment: f64,
}

fn uniform(rng: &mut ChaCha12Rng, r: [f64; 2]) -> f64 {
    Uniform::new_inclusive(r[0], r[1]).map_or(r[0], |d| d.sample(rng))
}

/// Draws the 3-D scene of the sample with seed `sample_seed` from `src`, whose folder holds
/// `files` (path, recorded name).
pub fn draw(src: &MeshSource, files: &[(PathBuf, String)], sample_seed: u64) -> MeshDraw {
    let mut words = NoiseRng::new(&[sample_seed, MESH_TAG]);
    let mut seed = [0u8; 32];
    for chunk in seed.chunks_exact_mut(8) {
        chunk.copy_from_slice(&words.next_u64().to_le_bytes());
    }
    let mut rng = ChaCha12Rng::from_seed(seed);
    let pool = src.builtin.len() + files.len();
    let k = Uniform::new(0, pool.max(1)).map_or(0, |d| d.sample(&mut rng));
    let (mesh, path) = match k.checked_sub(src.builtin.len()) {
        None => (src.builtin[k].clone(), None),
        Some(j) => (files[j].1.clone(), Some(files[j].0.clone())),
    };
    let x = uniform(&mut rng, src.x_mm);
    let y = uniform(&mut rng, src.y_mm);
    let dist = uniform(&mut rng, src.distance_mm);
    let rotation_deg = src.rotation_deg.map(|m| uniform(&mut rng, [-m, m]));
    let scale = uniform(&mut rng, src.scale);
    let bend: [f64; 5] = std::array::from_fn(|_| uniform(&mut rng, src.bend_deg));
    let spread = uniform(&mut rng, src.spread_deg);
    let base_color: [f64; 3] = std::array::from_fn(|_| uniform(&mut rng, src.albedo));
    let roughness = uniform(&mut rng, src.roughness);
    let metal = Bernoulli::new(src.metallic_probability).is_ok_and(|b| b.sample(&mut rng));
    let az = uniform(&mut rng, [-60f64, 60.0]).to_radians();
    let el = uniform(&mut rng, [15f64, 60.0]).to_radians();
    let key_scale = uniform(&mut rng, src.key_light);
    let kelvin = uniform(&mut rng, src.key_light_kelvin).round();
    let screen_glow = uniform(&mut rng, src.screen_glow);
    let environment = uniform(&mut rng, src.environment);
    let toward = [az.sin() * el.cos(), el.sin(), az.cos() * el.cos()];
    let position_mm = [x, y, -dist];
    // 0.6 of the way from the mesh origin to the panel's plane through the camera, so that the
    // camera (origin) sees the panel's back: p·toward = 0.4·(origin·toward) < 0.
    let ahead = -(x * toward[0] + y * toward[1] - dist * toward[2]);
    let reach = 0.6 * ahead.max(0.1 * dist);
    MeshDraw {
        mesh,
        path,
        position_mm,
        rotation_deg,
        scale,
        bend_deg: bend,
        spread_deg: spread,
        base_color,
        roughness,
        metallic: if metal { 1.0 } else { 0.0 },
        key_light: KeyLight {
            position_mm: std::array::from_fn(|i| position_mm[i] + reach * toward[i]),
            normal: toward.map(|v| -v),
            scale: key_scale,
            kelvin,
        },
        screen_glow,
        environment,
    }
}

fn light(kind: &str) -> LightDesc {
    LightDesc {
        kind: kind.to_string(),
        position_mm: None,
        size_mm: None,
        normal: None,
        radius_mm: None,
        direction: None,
        cone_deg: None,
        falloff_deg: None,
        map: None,
        spectrum: None,
        scale: None,
    }
}

impl MeshDraw {
    /// The `[[object]]` of the draw (OBJ files in `units`).
    pub fn object(&self, units: Option<&str>) -> ObjectDesc {
        ObjectDesc {
            mesh: self
                .path
                .as_ref()
                .map_or_else(|| self.mesh.clone(), |p| p.display().to_string()),
            name: Some(self.mesh.clone()),
            position_mm: self.position_mm,
            rotation_deg: self.rotation_deg,
            scale: ScaleSpec::Uniform(self.scale),
            units: units.map(str::to_string),
            material: Some(MaterialDesc {
                base_color: Some(RgbOr::Rgb(self.base_color)),
                roughness: Some(self.roughness),
                metallic: Some(self.metallic),
                ..MaterialDesc::default()
            }),
            pose: (self.path.is_none() && self.mesh == "hand").then(|| PoseDesc {
                bend_deg: Some(BendSpec::Each(self.bend_deg)),
                spread_deg: Some(self.spread_deg),
            }),
        }
    }

    /// The `[[light]]`s of the draw (those of nonzero scale).
    pub fn lights(&self) -> Vec<LightDesc> {
        let k = &self.key_light;
        let mut out = Vec::new();
        if k.scale > 0.0 {
            out.push(LightDesc {
                position_mm: Some(k.position_mm),
                size_mm: Some([KEY_SIZE_MM; 2]),
                normal: Some(k.normal),
                spectrum: Some(format!("blackbody:{}", k.kelvin)),
                scale: Some(k.scale),
                ..light("rect")
            });
        }
        if self.screen_glow > 0.0 {
            out.push(LightDesc {
                position_mm: Some([0.0, 0.0, -1.0]),
                size_mm: Some(GLOW_SIZE_MM),
                normal: Some([0.0, 0.0, -1.0]),
                spectrum: Some("white-led".into()),
                scale: Some(self.screen_glow),
                ..light("rect")
            });
        }
        if self.environment > 0.0 {
            out.push(LightDesc {
                spectrum: Some("d65".into()),
                scale: Some(self.environment),
                ..light("environment")
            });
        }
        out
    }

    /// The sample's scene: `base` with the drawn object and lights added.
    pub fn scene(&self, base: &LoadedScene, units: Option<&str>) -> LoadedScene {
        let mut ls = base.clone();
        ls.scene.object.push(self.object(units));
        ls.scene.light.extend(self.lights());
        ls
    }

    /// World bounds [min, max] of the drawn mesh after placement, mm.
    pub fn bounds_mm(
        &self,
        base: &LoadedScene,
        units: Option<&str>,
    ) -> Result<[[f64; 3]; 2], SceneError> {
        let ls = self.scene(base, units);
        let i = ls.scene.object.len() - 1;
        let asset = crate::world::placed_object(&ls, i, &ls.scene.object[i])?;
        Ok(crate::world::bounds_mm(&asset.mesh))
    }

    /// Keeps the mesh on the user side: if its placed bounds reach beyond z = −[`CLEARANCE_MM`]
    /// (a rotated hand close to the screen can), the mesh is moved back along −z until they
    /// do not. Returns the bounds after the move (`position_mm` records it).
    pub fn settle(
        &mut self,
        base: &LoadedScene,
        units: Option<&str>,
    ) -> Result<[[f64; 3]; 2], SceneError> {
        let mut b = self.bounds_mm(base, units)?;
        let over = b[1][2] + CLEARANCE_MM;
        if over > 0.0 {
            self.position_mm[2] -= over;
            b[0][2] -= over;
            b[1][2] -= over;
        }
        Ok(b)
    }
}

/// Smallest distance between a drawn mesh and the plate, mm.
pub const CLEARANCE_MM: f64 = 5.0;

/// The sample's runtime system: `sys` (built from `base`) with the world of the drawn scene.
pub fn sample_system(
    base: &LoadedScene,
    sys: &System,
    draw: &MeshDraw,
    units: Option<&str>,
) -> Result<System, SceneError> {
    let ls = draw.scene(base, units);
    let world = crate::world::World::build(&ls, &sys.display)?;
    let mut s = sys.clone();
    s.scene = ls.scene;
    s.world = Some(Arc::new(world));
    Ok(s)
}

/// The capture (channel-major, f64) and the frontal ground truth (`size`², in `space`) of a
/// sample, at `[capture spp, frontal spp]`; the capture's camera side from `table` when given
/// (drawn for `sys`'s design, whose [`crate::render::camera_table::design_key`] comes with it).
pub fn render_sample(
    sys: &System,
    size: usize,
    [spp, frontal_spp]: [u32; 2],
    seed: u64,
    space: crate::world::colour::FrontalSpace,
    table: Option<(&crate::render::camera_table::CameraTable, [u64; 2])>,
) -> Result<(Vec<f64>, Frontal), crate::render::camera_table::TableError> {
    let settings = crate::render::RenderSettings::lattice(spp, seed, false);
    let cap = match table {
        Some((t, key)) => {
            crate::render::camera_table::render_with_table_keyed(sys, key, &settings, t)?
        }
        None => crate::render::render(sys, &settings),
    };
    let capture = cap
        .channels
        .iter()
        .flatten()
        .map(|&v| f64::from(v))
        .collect();
    // A world is always attached by `sample_system`; an empty frontal otherwise.
    let frontal =
        render_frontal_in(sys, size, size, frontal_spp, seed, space).unwrap_or_else(|| Frontal {
            width: size,
            height: size,
            channel_names: sys.response.names.clone(),
            space: crate::world::colour::FrontalSpace::Sensor,
            channels: vec![vec![0.0; size * size]; sys.response.names.len()],
            depth_mm: vec![f32::INFINITY; size * size],
            mask: vec![0; size * size],
            rays: 0,
        });
    Ok((capture, frontal))
}

/// What `metadata.jsonl` holds for a 3-D sample (the card's `loading.metadata_3d`).
pub const METADATA_3D: &str = "3-D samples (meshes): file_name (capture PNG), frontal_file_name (frontal PNG), mask_file_name (mask PNG), capture_npy, frontal_npy, depth_npy, id, split, seed, source, scene, the varied keys and the draw: mesh, position_mm, rotation_deg, scale, bend_deg and spread_deg (applied to the hand only), base_color, roughness, metallic, key_light {position_mm, normal, scale, kelvin}, screen_glow, environment, bounds_mm (the placed mesh's world bounds [min, max]) and mask_value (its value in the mask)";

/// The `metadata.jsonl` column added when `objects.frontal_space` is not `sensor`.
pub const METADATA_FRONTAL_SPACE: &str = "frontal_space: the colour space of frontal_npy and frontal_file_name (objects.frontal_space: xyz = CIE 1931 XYZ, channels X, Y, Z; linear-srgb = linear sRGB / Rec. 709, D65, channels R, G, B), as render --frontal-space writes frontal.exr";

/// Units and encodings of the 3-D sample files (the card's `units`), the frontal image in
/// `space`.
pub fn units(space: crate::world::colour::FrontalSpace) -> Vec<(&'static str, String)> {
    let frontal = match space {
        crate::world::colour::FrontalSpace::Sensor => crate::output::FRONTAL_UNITS.to_string(),
        s => format!(
            "{} (channels {})",
            crate::output::frontal_units(s),
            s.channel_names().unwrap_or_default().join(", ")
        ),
    };
    vec![
        ("frontal_npy", format!("float32 [h, w] (or [channels, h, w]), objects.size_px square: {frontal}")),
        ("frontal_png", format!("16-bit: round(65535 * clamp(frontal / {FRONTAL_PNG_FULL_SCALE}, 0, 1)), linear")),
        ("depth_npy", "float32 [h, w]: distance from the plate's front face along -z in mm of the first surface on each frontal pixel's centre ray; +inf where nothing is hit".to_string()),
        ("mask_png", "16-bit grey, same pixels as depth_npy: object index + 1 (metadata mask_value for the drawn mesh), 65535 the display, 0 nothing or a light".to_string()),
    ]
}

/// Mesh files (`.gltf`, `.glb`, `.obj`) of a folder, sorted, as (path, name recorded
/// relative to the recipe: `folder/file`).
pub fn list_meshes(dir: &Path, folder: &str) -> Result<Vec<(PathBuf, String)>, String> {
    let rd = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut out = Vec::new();
    for e in rd {
        let e = e.map_err(|e| format!("{}: {e}", dir.display()))?;
        let p = e.path();
        let name = e.file_name().to_string_lossy().into_owned();
        let lower = name.to_ascii_lowercase();
        if p.is_file() && [".gltf", ".glb", ".obj"].iter().any(|x| lower.ends_with(x)) {
            out.push((p, format!("{}/{name}", folder.trim_end_matches('/'))));
        }
    }
    out.sort_by(|a, b| a.1.cmp(&b.1));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recipe::{Source, parse_recipe};

    fn source() -> MeshSource {
        let text = "name = \"t\"\nseed = 1\nsamples = 4\nmode = \"render\"\n[split]\ntrain = 1.0\nval = 0.0\ntest = 0.0\n[objects]\nsize_px = 8\n[[objects.sources]]\ngenerator = \"meshes\"\nbuiltin = [\"head\", \"hand\", \"sphere\"]\ndistance_mm = [200.0, 400.0]\nenvironment = [0.0, 0.0]\n";
        match &parse_recipe(text).unwrap().objects.sources[0] {
            Source::Meshes(m) => (**m).clone(),
            _ => unreachable!(),
        }
    }

    #[test]
    fn draws_are_pure_functions_of_the_seed_within_the_ranges() {
        let src = source();
        let a = draw(&src, &[], 42);
        assert_eq!(a, draw(&src, &[], 42));
        let mut meshes = std::collections::BTreeSet::new();
        for seed in 0..64 {
            let d = draw(&src, &[], seed);
            meshes.insert(d.mesh.clone());
            assert!((-400.0..=-200.0).contains(&d.position_mm[2]), "{d:?}");
            assert!((-30.0..=30.0).contains(&d.position_mm[0]));
            assert!(d.rotation_deg[1].abs() <= 30.0);
            assert_eq!(d.object(None).pose.is_some(), d.mesh == "hand");
            assert!(d.bend_deg.iter().all(|b| (0.0..=70.0).contains(b)));
            assert!(d.base_color.iter().all(|c| (0.1..=0.8).contains(c)));
            assert_eq!(d.environment, 0.0);
            // The key light stays on the user side, faces the mesh origin and turns its back
            // (which emits nothing and is not seen) to the camera at the origin.
            let k = &d.key_light;
            assert!(k.position_mm[2] < 0.0);
            let back: f64 = (0..3).map(|i| -k.position_mm[i] * k.normal[i]).sum();
            assert!(back < 0.0, "{k:?}");
            let to: Vec<f64> = (0..3)
                .map(|i| d.position_mm[i] - k.position_mm[i])
                .collect();
            let dot: f64 = (0..3).map(|i| to[i] * k.normal[i]).sum();
            let len = to.iter().map(|v| v * v).sum::<f64>().sqrt();
            assert!((dot / len - 1.0).abs() < 1e-12);
        }
        assert_eq!(meshes.len(), 3, "{meshes:?}");
        assert_ne!(a, draw(&src, &[], 43));
        // Environment 0 and glow/key > 0: two rect lights.
        assert_eq!(a.lights().len(), 2);
    }
}
