//! Scene description of the user side (pure data, serde): `[[object]]` meshes with placement
//! and material overrides, and `[[light]]` emitters. Validation names every key as
//! `object.N.key` / `light.N.key`, the form `--set` accepts.
//!
//! Units: lengths in mm, angles in degrees. Radiometric scales are relative to the capture
//! unit of stscam, the radiance of a white display pixel (docs/physics.md §6.1): an area light or
//! environment of `scale` 1 with a spectrum normalised to mean 1 over 380–780 nm has the
//! spectral radiance of the display's white. A point or spot light's `scale` is a radiant
//! intensity in that radiance unit × mm²: at r mm it gives the irradiance of a 1 mm² patch of
//! display white seen face-on from r mm, scale/r².

use serde::{Deserialize, Serialize};

/// A number or three numbers (per-axis scale).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "a number or [x, y, z]")]
pub enum ScaleSpec {
    /// Uniform scale.
    Uniform(f64),
    /// Per-axis scale.
    Axes([f64; 3]),
}

impl ScaleSpec {
    /// The scale per axis.
    pub fn axes(&self) -> [f64; 3] {
        match self {
            ScaleSpec::Uniform(s) => [*s; 3],
            ScaleSpec::Axes(a) => *a,
        }
    }
}

impl Default for ScaleSpec {
    fn default() -> Self {
        ScaleSpec::Uniform(1.0)
    }
}

/// A linear RGB triple or a string (texture path or spectrum name).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "[r, g, b] or a string")]
pub enum RgbOr {
    /// Linear RGB.
    Rgb([f64; 3]),
    /// A path (base colour texture) or a spectrum name (emission).
    Text(String),
}

/// A number for all five fingers or one per finger (thumb first).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "a number or five numbers (thumb to little finger)"
)]
pub enum BendSpec {
    /// Same bend for every finger.
    All(f64),
    /// Thumb, index, middle, ring, little.
    Each([f64; 5]),
}

/// `[object.material]`: overrides of the asset's own material (every triangle of the object).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDesc {
    /// Linear RGB base colour in [0, 1], or a texture path (relative to the scene file).
    pub base_color: Option<RgbOr>,
    /// Emission: linear RGB (RGB × the D65 illuminant, as Mitsuba 3), or a spectrum name
    /// (`d65`, `white-led`, `ccfl`, `flat`, `blackbody:T`, or a CSV path) whose radiance is
    /// modulated by the luminance of `emission_texture` if there is one.
    pub emission: Option<RgbOr>,
    /// Emission texture path (linear RGB after sRGB decoding), modulating `emission`.
    pub emission_texture: Option<String>,
    /// Multiplies the emission (default 1).
    pub emission_scale: Option<f64>,
    /// GGX roughness in [0, 1]; setting it (or `metallic`) selects the metallic-roughness model.
    pub roughness: Option<f64>,
    /// Metalness in [0, 1].
    pub metallic: Option<f64>,
    /// Spectral reflectance CSV (nm, value in [0, 1]); replaces the base colour.
    pub reflectance: Option<String>,
    /// Texture filtering: "linear" (bilinear, default) or "nearest".
    pub texture_filter: Option<String>,
}

/// `[object.pose]`: the articulated hand's pose.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseDesc {
    /// Finger flexion in degrees (0 = straight, 90 = fist-like).
    pub bend_deg: Option<BendSpec>,
    /// Spread between neighbouring fingers in degrees.
    pub spread_deg: Option<f64>,
}

/// `[[object]]`: a mesh file or built-in shape placed in the scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDesc {
    /// `.gltf`, `.glb` or `.obj` path relative to the scene file, or a built-in shape
    /// (`quad`, `box`, `sphere`, `cylinder`, `head`, `hand`).
    pub mesh: String,
    /// Name used in the JSON sidecar (default: the mesh).
    #[serde(default)]
    pub name: Option<String>,
    /// Translation in mm (docs/design.md frame: the user side is z < 0).
    #[serde(default)]
    pub position_mm: [f64; 3],
    /// Rotation in degrees about x, then y, then z (extrinsic).
    #[serde(default)]
    pub rotation_deg: [f64; 3],
    /// Scale (number or per axis), applied first.
    #[serde(default)]
    pub scale: ScaleSpec,
    /// What one OBJ file unit is: `mm` (default), `cm`, `m` or `in`. glTF is always metres.
    #[serde(default)]
    pub units: Option<String>,
    /// Material overrides.
    #[serde(default)]
    pub material: Option<MaterialDesc>,
    /// Hand pose.
    #[serde(default)]
    pub pose: Option<PoseDesc>,
}

/// `[[light]]`: an emitter of the user side.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightDesc {
    /// `rect`, `sphere`, `point`, `spot` or `environment`.
    pub kind: String,
    /// Centre (rect, sphere) or position (point, spot), mm.
    #[serde(default)]
    pub position_mm: Option<[f64; 3]>,
    /// Rect: size [width, height] in mm.
    #[serde(default)]
    pub size_mm: Option<[f64; 2]>,
    /// Rect: direction it emits into (default [0, 0, 1], toward the screen).
    #[serde(default)]
    pub normal: Option<[f64; 3]>,
    /// Sphere: radius in mm.
    #[serde(default)]
    pub radius_mm: Option<f64>,
    /// Spot: direction of the cone axis.
    #[serde(default)]
    pub direction: Option<[f64; 3]>,
    /// Spot: half-angle of the cone, degrees (default 30).
    #[serde(default)]
    pub cone_deg: Option<f64>,
    /// Spot: half-angle where the smooth falloff to the edge starts, degrees (default
    /// 0.8 × cone).
    #[serde(default)]
    pub falloff_deg: Option<f64>,
    /// Environment: equirectangular EXR (or PNG) map, RGB × the light's spectrum.
    #[serde(default)]
    pub map: Option<String>,
    /// Spectrum: `d65` (default), `white-led`, `ccfl`, `flat`, `blackbody:T` or a CSV path;
    /// normalised to mean 1 over 380–780 nm.
    #[serde(default)]
    pub spectrum: Option<String>,
    /// Radiance (rect, sphere, environment) or intensity (point, spot) scale; see the module
    /// documentation for the unit. Default 1.
    #[serde(default)]
    pub scale: Option<f64>,
}

/// Light kinds `light.N.kind` accepts.
pub const LIGHT_KINDS: &[&str] = &["rect", "sphere", "point", "spot", "environment"];
/// Units `object.N.units` accepts, with their size in mm.
pub const UNITS: &[(&str, f64)] = &[("mm", 1.0), ("cm", 10.0), ("m", 1000.0), ("in", 25.4)];

/// Millimetres per file unit of an `units` value (None for an unknown word).
pub fn unit_mm(units: Option<&str>) -> Option<f64> {
    let u = units.unwrap_or("mm");
    UNITS.iter().find(|(n, _)| *n == u).map(|(_, v)| *v)
}

fn finite_all(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// A problem with a scene's `[[object]]` or `[[light]]` values: the key (`object.0.mesh`) and
/// what is wrong; `scene::validate` turns it into a `SceneError` naming the source.
#[derive(Clone, Debug, PartialEq)]
pub struct WorldProblem {
    /// The key, e.g. `light.1.scale`.
    pub key: String,
    /// What is wrong with its value.
    pub message: String,
}

/// Checks the objects and lights of a scene; every failure names its key.
pub fn validate_world(objects: &[ObjectDesc], lights: &[LightDesc]) -> Result<(), WorldProblem> {
    for (i, o) in objects.iter().enumerate() {
        validate_object(i, o)?;
    }
    for (i, l) in lights.iter().enumerate() {
        validate_light(i, l)?;
    }
    Ok(())
}

/// `Err` of the problem `message` with `key`.
fn problem<T>(key: String, message: String) -> Result<T, WorldProblem> {
    Err(WorldProblem { key, message })
}

/// Object `i` (`object.i.*`): mesh, placement, units, then its material and pose.
fn validate_object(i: usize, o: &ObjectDesc) -> Result<(), WorldProblem> {
    let err = problem;
    let k = |name: &str| format!("object.{i}.{name}");
    if o.mesh.trim().is_empty() {
        return err(
            k("mesh"),
            "must name a mesh file or a built-in shape".into(),
        );
    }
    if !finite_all(&o.position_mm) {
        return err(k("position_mm"), "must be finite".into());
    }
    crate::limits::check_coords(&k("position_mm"), &o.position_mm).map_err(|e| WorldProblem {
        key: e.setting,
        message: e.message,
    })?;
    if !finite_all(&o.rotation_deg) {
        return err(k("rotation_deg"), "must be finite".into());
    }
    let sc = o.scale.axes();
    if !sc.iter().all(|v| v.is_finite() && *v > 0.0 && *v < 1e9) {
        return err(
            k("scale"),
            format!("must be positive and finite, got {sc:?}"),
        );
    }
    if unit_mm(o.units.as_deref()).is_none() {
        let names: Vec<_> = UNITS.iter().map(|u| u.0).collect();
        return err(
            k("units"),
            format!(
                "unknown unit {:?}; expected one of {names:?}",
                o.units.as_deref().unwrap_or("")
            ),
        );
    }
    if let Some(m) = &o.material {
        validate_material(&k, m)?;
    }
    if let Some(p) = &o.pose {
        validate_pose(&k, p)?;
    }
    Ok(())
}

/// An object's `material` (`k("material.…")`): colours, scales and the texture filter.
fn validate_material(k: &dyn Fn(&str) -> String, m: &MaterialDesc) -> Result<(), WorldProblem> {
    let err = problem;
    if let Some(RgbOr::Rgb(c)) = &m.base_color
        && !c.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v))
    {
        return err(
            k("material.base_color"),
            format!("RGB components must be in [0, 1], got {c:?}"),
        );
    }
    if let Some(RgbOr::Rgb(c)) = &m.emission
        && !c.iter().all(|v| v.is_finite() && *v >= 0.0 && *v < 1e12)
    {
        return err(
            k("material.emission"),
            format!("RGB components must be finite and >= 0, got {c:?}"),
        );
    }
    for (name, v, lo, hi) in [
        ("material.emission_scale", m.emission_scale, 0.0, 1e12),
        ("material.roughness", m.roughness, 0.0, 1.0),
        ("material.metallic", m.metallic, 0.0, 1.0),
    ] {
        if let Some(v) = v
            && !(v.is_finite() && v >= lo && v <= hi)
        {
            return err(k(name), format!("must be in [{lo}, {hi}], got {v}"));
        }
    }
    if let Some(f) = &m.texture_filter
        && f != "linear"
        && f != "nearest"
    {
        return err(
            k("material.texture_filter"),
            format!("expected \"linear\" or \"nearest\", got {f:?}"),
        );
    }
    Ok(())
}

/// An object's `pose` (`k("pose.…")`): the bend and spread angles.
fn validate_pose(k: &dyn Fn(&str) -> String, p: &PoseDesc) -> Result<(), WorldProblem> {
    let err = problem;
    let bends = match &p.bend_deg {
        Some(BendSpec::All(b)) => vec![*b],
        Some(BendSpec::Each(b)) => b.to_vec(),
        None => vec![],
    };
    if !bends
        .iter()
        .all(|b| b.is_finite() && (-30.0..=120.0).contains(b))
    {
        return err(
            k("pose.bend_deg"),
            format!("must be in [-30, 120] degrees, got {bends:?}"),
        );
    }
    if let Some(sp) = p.spread_deg
        && !(sp.is_finite() && (-20.0..=30.0).contains(&sp))
    {
        return err(
            k("pose.spread_deg"),
            format!("must be in [-20, 30] degrees, got {sp}"),
        );
    }
    Ok(())
}

/// Light `i` (`light.i.*`): kind, position, scale, directions, its kind's shape, and a map
/// only on an environment light.
fn validate_light(i: usize, l: &LightDesc) -> Result<(), WorldProblem> {
    let err = problem;
    let k = |name: &str| format!("light.{i}.{name}");
    if !LIGHT_KINDS.contains(&l.kind.as_str()) {
        return err(
            k("kind"),
            format!(
                "unknown light kind {:?}; expected one of {LIGHT_KINDS:?}",
                l.kind
            ),
        );
    }
    let needs_pos = l.kind != "environment";
    match l.position_mm {
        Some(p) if !finite_all(&p) => return err(k("position_mm"), "must be finite".into()),
        Some(p) => {
            crate::limits::check_coords(&k("position_mm"), &p).map_err(|e| WorldProblem {
                key: e.setting,
                message: e.message,
            })?
        }
        None if needs_pos => {
            return err(
                k("position_mm"),
                format!("a {} light needs a position", l.kind),
            );
        }
        _ => {}
    }
    if let Some(s) = l.scale
        && !(s.is_finite() && (0.0..1e15).contains(&s))
    {
        return err(k("scale"), format!("must be finite and >= 0, got {s}"));
    }
    let unit_vec = |v: Option<[f64; 3]>, name: &str| -> Result<(), WorldProblem> {
        if let Some(v) = v
            && !(finite_all(&v) && v.iter().map(|x| x * x).sum::<f64>() > 1e-24)
        {
            return err(k(name), "must be a finite nonzero vector".into());
        }
        Ok(())
    };
    unit_vec(l.normal, "normal")?;
    unit_vec(l.direction, "direction")?;
    validate_light_shape(&k, l)?;
    if l.map.is_some() && l.kind != "environment" {
        return err(k("map"), "only an environment light takes a map".into());
    }
    Ok(())
}

/// The shape keys of a rect, sphere or spot light.
fn validate_light_shape(k: &dyn Fn(&str) -> String, l: &LightDesc) -> Result<(), WorldProblem> {
    let err = problem;
    match l.kind.as_str() {
        "rect" => match l.size_mm {
            Some([w, h])
                if w > 0.0
                    && h > 0.0
                    && w <= crate::limits::MAX_COORD_MM
                    && h <= crate::limits::MAX_COORD_MM => {}
            Some(s) => {
                return err(
                    k("size_mm"),
                    format!(
                        "must be two positive sizes up to {:e} mm, got {s:?}",
                        crate::limits::MAX_COORD_MM
                    ),
                );
            }
            None => {
                return err(
                    k("size_mm"),
                    "a rect light needs size_mm = [width, height]".into(),
                );
            }
        },
        "sphere" => match l.radius_mm {
            Some(r) if r > 0.0 && r <= crate::limits::MAX_COORD_MM => {}
            Some(r) => {
                return err(
                    k("radius_mm"),
                    format!(
                        "must be positive and at most {:e} mm, got {r}",
                        crate::limits::MAX_COORD_MM
                    ),
                );
            }
            None => return err(k("radius_mm"), "a sphere light needs radius_mm".into()),
        },
        "spot" => {
            let cone = l.cone_deg.unwrap_or(30.0);
            if !(cone.is_finite() && cone > 0.0 && cone < 90.0) {
                return err(k("cone_deg"), format!("must be in (0, 90), got {cone}"));
            }
            if let Some(f) = l.falloff_deg
                && !(f.is_finite() && f >= 0.0 && f <= cone)
            {
                return err(
                    k("falloff_deg"),
                    format!("must be in [0, cone_deg], got {f}"),
                );
            }
        }
        _ => {}
    }
    Ok(())
}
