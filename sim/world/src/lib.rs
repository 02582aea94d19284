//! The user side of the camera (docs/design.md "The user side"): everything beyond the front face
//! of the plate. The waveguide hands each replica branch's ray to this module and never sees
//! meshes; this module never sees the plate.
//!
//! One `World` is built per run from the scene's `[[object]]` and `[[light]]` entries: every
//! object's triangles (mesh files or built-in shapes, placed by scale, rotation and
//! translation) in one BVH, their materials, the lights, the environment and the display as an
//! emitter. A scene without objects and lights builds no world and renders on the display-only
//! fast path.
//!
//! Assumption: the plate is transparent to user-side light (its ≈ 4 % Fresnel reflection back
//! toward the user is neglected); the LCD is an opaque, non-reflecting surface over its area.
//!
//! Layer: the user side beyond the front face: meshes, BVH, materials, lights, loaders, the display, the spectral path tracer.
//! May depend on: stscam-base, stscam-io, stscam-scene (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod bench_bvh;
pub mod bsdf;
pub mod bvh;
pub mod coverage;
pub mod display;
pub mod gltf_features;
pub mod gltf_shape;
pub mod integrator;
pub mod light;
pub mod load;
pub mod material;
pub mod mesh;
pub mod normal_map;
pub mod obj_features;
pub mod polygon;
pub mod shading;
pub mod shapes;
pub mod spectra3d;
pub mod texture;
pub use stscam_base::cie as colour;
pub use stscam_scene::desc;
// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{limits, sampler, spectra};
use stscam_io as io;
use stscam_scene as scene;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DAffine3, DMat3, DVec2, DVec3};

use self::bvh::Accel;
use self::desc::{BendSpec, LightDesc, ObjectDesc, RgbOr, unit_mm};
use self::light::{DisplayLight, Environment, Light, rect_axes};
use self::material::{Emission, Material, Reflectance};
use self::mesh::{AssetMaterial, Mesh, SurfaceModel};
use self::texture::Texture;
use crate::display::Display;
use crate::scene::{LoadedScene, SceneError};
use crate::spectra::Spectrum;

/// Largest total triangle count of a scene.
pub const MAX_TRIANGLES: usize = load::MAX_TRIANGLES;

/// What the sidecar reports of one object.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ObjectInfo {
    /// Name (the `name` key or the mesh).
    pub name: String,
    /// Mask value of the object in `mask.png` (index + 1).
    pub mask_value: u16,
    /// Triangles.
    pub triangles: usize,
    /// Axis-aligned bounds in world mm: [min, max].
    pub bounds_mm: [[f64; 3]; 2],
    /// Material names.
    pub materials: Vec<String>,
}

/// An emitter that next-event estimation can pick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Emitter {
    /// `lights[i]`.
    Light(usize),
    /// The display.
    Display,
    /// The environment: never in [`World::emitters`] (it is found by BSDF sampling only; see
    /// `integrator`), named for the multiple-importance weight of a ray that escapes to it.
    Environment,
}

/// The runtime user-side scene.
#[derive(Debug)]
pub struct World {
    /// Objects, in scene order.
    pub objects: Vec<ObjectInfo>,
    /// All triangles of all objects.
    pub mesh: Mesh,
    /// Object index of each triangle.
    pub tri_object: Vec<u32>,
    /// Materials (indexed by `mesh.material_ids`).
    pub materials: Vec<Material>,
    /// BVH over `mesh` (None without objects).
    pub accel: Option<Accel>,
    /// Finite and delta lights.
    pub lights: Vec<Light>,
    /// Environment light.
    pub environment: Option<Environment>,
    /// The display as an emitter (None when `display.enabled = false`).
    pub display: Option<DisplayLight>,
    /// Emitters for next-event estimation (picked uniformly).
    pub emitters: Vec<Emitter>,
    /// `sampling.max_depth`.
    pub max_depth: u32,
    /// Some material can reject hits (alpha, single-sided): the scene queries filter
    /// ([`coverage`]).
    pub coverage_filter: bool,
}

fn resolve(base: &Path, p: &str) -> PathBuf {
    let q = Path::new(p);
    if q.is_absolute() {
        q.to_path_buf()
    } else {
        base.join(q)
    }
}

/// The object-to-world transform: scale, then rotations about x, y, z (extrinsic), then the
/// translation.
pub fn object_transform(o: &ObjectDesc) -> DAffine3 {
    let [rx, ry, rz] = o.rotation_deg.map(f64::to_radians);
    let r = DMat3::from_rotation_z(rz) * DMat3::from_rotation_y(ry) * DMat3::from_rotation_x(rx);
    let s = DMat3::from_diagonal(DVec3::from_array(o.scale.axes()));
    DAffine3::from_mat3_translation(r * s, DVec3::from_array(o.position_mm))
}

fn pose_of(o: &ObjectDesc) -> shapes::Pose {
    let mut pose = shapes::Pose::default();
    if let Some(p) = &o.pose {
        match &p.bend_deg {
            Some(BendSpec::All(b)) => pose.bend_deg = [*b; 5],
            Some(BendSpec::Each(b)) => pose.bend_deg = *b,
            None => {}
        }
        if let Some(s) = p.spread_deg {
            pose.spread_deg = s;
        }
    }
    pose
}

fn load_object(ls: &LoadedScene, i: usize, o: &ObjectDesc) -> Result<mesh::Asset, SceneError> {
    let key = format!("object.{i}.mesh");
    if let Some(a) = shapes::builtin(o.mesh.trim(), &pose_of(o)) {
        return Ok(a);
    }
    let path = resolve(&ls.base_dir, o.mesh.trim());
    let lower = o.mesh.to_ascii_lowercase();
    if !(lower.ends_with(".gltf") || lower.ends_with(".glb") || lower.ends_with(".obj")) {
        return Err(ls.key_error(
            &key,
            format!(
                "{:?} is neither a .gltf, .glb or .obj file nor a built-in shape ({})",
                o.mesh,
                shapes::builtin_names().join(", ")
            ),
        ));
    }
    let unit = unit_mm(o.units.as_deref()).unwrap_or(1.0);
    // A missing OBJ material library leaves the default material (common in the wild, e.g.
    // the MediaPipe face model); a library that exists but is broken is still an error.
    let options = load::LoadOptions {
        obj_unit_mm: unit,
        allow_missing_mtl: true,
    };
    load::load_asset_with(&path, &options).map_err(|e| ls.key_error(&key, e.to_string()))
}

/// Object `i` of a scene loaded (file or built-in shape, with normals) and placed in world mm.
pub fn placed_object(
    ls: &LoadedScene,
    i: usize,
    o: &ObjectDesc,
) -> Result<mesh::Asset, SceneError> {
    let mut asset = load_object(ls, i, o)?;
    if asset.mesh.normals.len() != asset.mesh.positions_mm.len() {
        asset.mesh.compute_normals();
    }
    asset.mesh.transform(&object_transform(o));
    if let Some(v) = asset.mesh.first_vertex_out_of_range() {
        return Err(ls.key_error(
            &format!("object.{i}.mesh"),
            format!(
                "vertex {v} lies at {:?} mm after placement (scale, rotation, position_mm), outside the working range of ±{:e} mm",
                asset.mesh.positions_mm[v].to_array(),
                crate::limits::MAX_COORD_MM
            ),
        ));
    }
    Ok(asset)
}

/// Axis-aligned bounds [min, max] of a mesh's vertices, mm.
pub fn bounds_mm(mesh: &Mesh) -> [[f64; 3]; 2] {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for p in &mesh.positions_mm {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    [lo.to_array(), hi.to_array()]
}

fn load_texture(ls: &LoadedScene, key: &str, p: &str) -> Result<Arc<Texture>, SceneError> {
    let path = resolve(&ls.base_dir, p);
    if path.is_dir() {
        return Err(ls.key_error(
            key,
            format!("{}: is a folder, not an image", path.display()),
        ));
    }
    Texture::load(&path)
        .map(Arc::new)
        .map_err(|e| ls.key_error(key, e.to_string()))
}

fn emission_spectrum(ls: &LoadedScene, key: &str, name: &str) -> Result<Spectrum, SceneError> {
    spectra3d::emission_spectrum(name, &ls.base_dir).map_err(|e| ls.key_error(key, e))
}

fn build_material(
    ls: &LoadedScene,
    i: usize,
    o: &ObjectDesc,
    a: &AssetMaterial,
) -> Result<Material, SceneError> {
    let k = |name: &str| format!("object.{i}.material.{name}");
    let ov = o.material.clone().unwrap_or_default();
    let mut model = a.model;
    let mut reflectance = match &a.base_color_texture {
        Some(t) => Reflectance::Texture(t.clone(), a.base_color),
        None => Reflectance::Rgb(spectra3d::reflectance_from_rgb(a.base_color)),
    };
    match &ov.base_color {
        Some(RgbOr::Rgb(c)) => reflectance = Reflectance::Rgb(spectra3d::reflectance_from_rgb(*c)),
        Some(RgbOr::Text(p)) => {
            reflectance = Reflectance::Texture(load_texture(ls, &k("base_color"), p)?, [1.0; 3]);
        }
        None => {}
    }
    if let Some(p) = &ov.reflectance {
        let path = resolve(&ls.base_dir, p);
        reflectance = Reflectance::Spectral(
            spectra3d::reflectance_csv(&path).map_err(|e| ls.key_error(&k("reflectance"), e))?,
        );
    }
    if ov.roughness.is_some() || ov.metallic.is_some() {
        model = SurfaceModel::MetallicRoughness;
    }
    let scale = ov.emission_scale.unwrap_or(1.0);
    let texture = match &ov.emission_texture {
        Some(p) => Some(load_texture(ls, &k("emission_texture"), p)?),
        None => a.emissive_texture.clone(),
    };
    let asset_rgb = a.emissive.map(|c| c * a.emissive_strength);
    // Emission from the mesh file (MTL `Ke`, glTF emissive factor × strength) times the
    // scene's scale: finite and at most MAX_EMISSION, or the images overflow.
    let strongest = asset_rgb.iter().fold(0.0f64, |m, v| m.max(v * scale));
    if !(strongest.is_finite() && asset_rgb.iter().all(|v| *v >= 0.0))
        || strongest > crate::limits::MAX_EMISSION
    {
        return Err(ls.key_error(
            &format!("object.{i}.mesh"),
            format!(
                "material {:?}: emission {:?} (times emission_scale {scale}) must be finite, >= 0 and at most {:e}",
                a.name,
                asset_rgb,
                crate::limits::MAX_EMISSION
            ),
        ));
    }
    let emission = match &ov.emission {
        Some(RgbOr::Rgb(c)) => Emission::Rgb {
            rgb: c.map(|v| v * scale),
            texture,
        },
        Some(RgbOr::Text(name)) => Emission::Spectral {
            spectrum: emission_spectrum(ls, &k("emission"), name)?.scaled(scale),
            texture,
        },
        None if ov.emission_texture.is_some() => Emission::Rgb {
            rgb: [scale; 3],
            texture,
        },
        None if asset_rgb.iter().any(|v| *v > 0.0) => Emission::Rgb {
            rgb: asset_rgb.map(|v| v * scale),
            texture,
        },
        None => Emission::None,
    };
    // Cut-outs and sides come from the file's material, whatever the scene overrides.
    let coverage = coverage::Coverage {
        mode: a.alpha_mode,
        factor: a.alpha,
        texture: a.base_color_texture.clone(),
        nearest: ov.texture_filter.as_deref() == Some("nearest"),
        single_sided: !a.double_sided,
    };
    Ok(Material {
        coverage,
        normal_map: a.normal_texture.clone().map(|t| (t, a.normal_scale)),
        name: a.name.clone(),
        model,
        reflectance,
        roughness: ov.roughness.unwrap_or(a.roughness),
        metallic: ov.metallic.unwrap_or(a.metallic),
        emission,
        nearest: ov.texture_filter.as_deref() == Some("nearest"),
        base_rgb: match (&ov.base_color, &ov.reflectance, &a.base_color_texture) {
            (_, Some(_), _) => None,
            (Some(RgbOr::Rgb(c)), _, _) => Some(*c),
            (Some(RgbOr::Text(_)), _, _) | (None, _, Some(_)) => None,
            (None, None, None) => Some(a.base_color),
        },
    })
}

fn build_light(
    ls: &LoadedScene,
    i: usize,
    l: &LightDesc,
) -> Result<(Option<Light>, Option<Environment>), SceneError> {
    let k = |name: &str| format!("light.{i}.{name}");
    let spectrum = emission_spectrum(ls, &k("spectrum"), l.spectrum.as_deref().unwrap_or("d65"))?
        .scaled(l.scale.unwrap_or(1.0));
    let pos = DVec3::from_array(l.position_mm.unwrap_or([0.0; 3]));
    let light = match l.kind.as_str() {
        "rect" => {
            let normal = DVec3::from_array(l.normal.unwrap_or([0.0, 0.0, 1.0])).normalize();
            let size = l.size_mm.unwrap_or([1.0, 1.0]);
            let (ex, ey) = rect_axes(normal, size);
            Light::Rect {
                center: pos,
                ex,
                ey,
                normal,
                area: size[0] * size[1],
                spectrum,
            }
        }
        "sphere" => Light::Sphere {
            center: pos,
            radius: l.radius_mm.unwrap_or(1.0),
            spectrum,
        },
        "point" => Light::Point {
            position: pos,
            spot: None,
            spectrum,
        },
        "spot" => {
            let axis = DVec3::from_array(l.direction.unwrap_or([0.0, 0.0, 1.0])).normalize();
            let cone = l.cone_deg.unwrap_or(30.0);
            let fall = l.falloff_deg.unwrap_or(0.8 * cone);
            Light::Point {
                position: pos,
                spot: Some((axis, cone.to_radians().cos(), fall.to_radians().cos())),
                spectrum,
            }
        }
        _ => {
            let map = match &l.map {
                Some(p) => Some(load_texture(ls, &k("map"), p)?),
                None => None,
            };
            return Ok((None, Some(Environment { spectrum, map })));
        }
    };
    Ok((Some(light), None))
}

impl World {
    /// Builds the user side of a scene that has objects or lights (`scene.has_world()`).
    pub fn build(ls: &LoadedScene, display: &Display) -> Result<World, SceneError> {
        let s = &ls.scene;
        let mut mesh = Mesh::default();
        let mut tri_object = Vec::new();
        let mut materials = Vec::new();
        let mut objects = Vec::new();
        for (i, o) in s.object.iter().enumerate() {
            let mut asset = placed_object(ls, i, o)?;
            let n = asset.mesh.triangles.len();
            if mesh.triangles.len() + n > MAX_TRIANGLES {
                return Err(ls.key_error(
                    &format!("object.{i}.mesh"),
                    format!("the scene would exceed {MAX_TRIANGLES} triangles"),
                ));
            }
            let [lo, hi] = bounds_mm(&asset.mesh);
            let offset = materials.len() as u32;
            let mut names = Vec::new();
            if asset.materials.is_empty() {
                asset.materials.push(AssetMaterial::default());
            }
            for a in &asset.materials {
                materials.push(build_material(ls, i, o, a)?);
                names.push(a.name.clone());
            }
            mesh.append(&asset.mesh, offset);
            tri_object.extend(std::iter::repeat_n(i as u32, n));
            objects.push(ObjectInfo {
                name: o.name.clone().unwrap_or_else(|| o.mesh.clone()),
                mask_value: (i + 1).min(usize::from(u16::MAX - 1)) as u16,
                triangles: n,
                bounds_mm: [lo, hi],
                materials: names,
            });
        }
        let mut lights = Vec::new();
        let mut environment = None;
        for (i, l) in s.light.iter().enumerate() {
            match build_light(ls, i, l)? {
                (Some(light), _) => lights.push(light),
                (None, Some(env)) => {
                    if environment.is_some() {
                        return Err(ls.key_error(
                            &format!("light.{i}.kind"),
                            "a scene has at most one environment light",
                        ));
                    }
                    environment = Some(env);
                }
                (None, None) => {}
            }
        }
        let accel = if mesh.triangles.is_empty() {
            None
        } else {
            let built = Accel::try_build(&mesh.positions_mm, &mesh.triangles);
            Some(built.map_err(|(tri, n)| {
                ls.key_error(
                    &format!("object.{}.mesh", tri_object[tri as usize]),
                    format!(
                        "{n} triangles share one bounding box (coincident copies), more than the {} accepted",
                        bvh::MAX_COINCIDENT
                    ),
                )
            })?)
        };
        let display_light = s.display.enabled.then(|| DisplayLight::new(display));
        let mut emitters: Vec<Emitter> = (0..lights.len()).map(Emitter::Light).collect();
        if display_light.is_some() {
            emitters.push(Emitter::Display);
        }
        let coverage_filter = materials.iter().any(|m| !m.coverage.counts_every_hit());
        Ok(World {
            coverage_filter,
            objects,
            mesh,
            tri_object,
            materials,
            accel,
            lights,
            environment,
            display: display_light,
            emitters,
            max_depth: s.sampling.max_depth,
        })
    }

    /// Vertex colour at a hit (None if the mesh has none).
    #[inline]
    pub fn color_at(&self, tri: u32, bary: [f64; 3]) -> Option<[f64; 3]> {
        if self.mesh.colors.is_empty() {
            return None;
        }
        let t = self.mesh.triangles[tri as usize];
        let c = t.map(|i| self.mesh.colors[i as usize]);
        Some((c[0] * bary[0] + c[1] * bary[1] + c[2] * bary[2]).to_array())
    }

    /// Texture coordinate at a hit.
    #[inline]
    pub fn uv_at(&self, tri: u32, bary: [f64; 3]) -> DVec2 {
        if self.mesh.uvs.is_empty() {
            return DVec2::ZERO;
        }
        let t = self.mesh.triangles[tri as usize];
        bvh::interp2(t.map(|i| self.mesh.uvs[i as usize]), bary)
    }
}

/// The mask value of the LCD in a frontal mask (objects are their index + 1, lights 0).
pub const MASK_DISPLAY: u16 = u16::MAX;

impl World {
    /// First surface a ray meets for the depth and mask: (t, mask value), where mask is the
    /// object index + 1, [`MASK_DISPLAY`] for the LCD, 0 for a light shape. Cut-outs and
    /// single-sided back faces are passed through; a blended surface counts as
    /// [`crate::coverage`] decides for the ray key `ray_key`.
    pub fn first_hit(
        &self,
        disp: &crate::display::Display,
        o: DVec3,
        d: DVec3,
        ray_key: u64,
    ) -> Option<(f64, u16)> {
        let mut best: Option<(f64, u16)> = None;
        if let Some(h) = self.mesh_hit(o, d, f64::INFINITY, None, ray_key) {
            best = Some((
                h.t,
                self.objects[self.tri_object[h.triangle as usize] as usize].mask_value,
            ));
        }
        let tmax = best.map_or(f64::INFINITY, |b| b.0);
        for l in &self.lights {
            if let Some((t, _)) = l.hit(o, d, tmax, 550.0)
                && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, 0));
            }
        }
        if self.display.is_some() && d.z < 0.0 {
            let t = (disp.z_mm - o.z) / d.z;
            if t > 0.0 && best.is_none_or(|b| t < b.0) && disp.on_lcd((o + d * t).truncate()) {
                best = Some((t, MASK_DISPLAY));
            }
        }
        best
    }
}
