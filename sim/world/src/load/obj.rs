//! Wavefront OBJ + MTL loading: the size checks before parsing, the models, the material
//! libraries and their textures, and the Latin-1 fallback for text and file names.

use std::cell::RefCell;
use std::collections::HashMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec2, DVec3};

use super::{
    BYTES_PER_TRIANGLE, LoadError, LoadOptions, MAX_TRIANGLES, MAX_VERTICES, check_regular_file,
    file_name,
};
use crate::io::IoError;
use crate::mesh::{Asset, AssetMaterial, Mesh, SurfaceModel};
use crate::texture::Texture;

/// What the MTL loader callback saw.
#[derive(Default)]
struct MtlLog {
    /// Successfully parsed libraries: path and number of materials, in merge order.
    loaded: Vec<(PathBuf, usize)>,
    /// The first failure.
    error: Option<LoadError>,
}

/// Counts the vertices and the triangles (a face of k corners makes k − 2) of an OBJ file by
/// scanning its lines, without building anything: the size check before parsing.
fn obj_counts(path: &Path) -> Result<(u64, u64), LoadError> {
    use std::io::BufRead;
    let file = std::fs::File::open(path).map_err(|e| LoadError::new(path, e))?;
    let mut reader = BufReader::with_capacity(1 << 16, file);
    let (mut vertices, mut triangles) = (0u64, 0u64);
    let mut line = Vec::new();
    loop {
        line.clear();
        let n = reader
            .read_until(b'\n', &mut line)
            .map_err(|e| LoadError::new(path, e))?;
        if n == 0 {
            break;
        }
        let mut words = line
            .split(|c| c.is_ascii_whitespace())
            .filter(|w| !w.is_empty());
        match words.next() {
            Some(b"v") => vertices += 1,
            Some(b"f") => triangles += (words.count() as u64).saturating_sub(2),
            _ => {}
        }
    }
    Ok((vertices, triangles))
}

/// Reads a Wavefront OBJ file with its material libraries: counts checked before reading
/// ([`obj_counts`]), the models read and triangulated ([`read_obj_models`]), then each model a
/// part of one mesh with its converted material ([`obj_part`]).
pub(super) fn load_obj(path: &Path, options: &LoadOptions) -> Result<Asset, LoadError> {
    let (nv, nt) = obj_counts(path)?;
    if nt > MAX_TRIANGLES as u64 || nv > MAX_VERTICES as u64 {
        return Err(LoadError::new(
            path,
            format!(
                "{nt} triangles and {nv} vertices: more than the {MAX_TRIANGLES} triangles or {MAX_VERTICES} vertices accepted (about {BYTES_PER_TRIANGLE} bytes a triangle)"
            ),
        ));
    }
    if nt == 0 {
        return Err(LoadError::new(
            path,
            "no triangles (no face has three corners)",
        ));
    }
    let (models, materials, log) = read_obj_models(path, options)?;
    // Which library each tobj material came from (for texture paths).
    let mut lib_of = Vec::with_capacity(materials.len());
    for (p, n) in &log.loaded {
        lib_of.extend(std::iter::repeat_n(p.as_path(), *n));
    }
    let mut asset = Asset::default();
    let mut converted: HashMap<Option<usize>, u32> = HashMap::new();
    let mut cache: HashMap<PathBuf, Arc<Texture>> = HashMap::new();
    for model in &models {
        let m = &model.mesh;
        let n = m.positions.len() / 3;
        if m.indices.is_empty() || n == 0 {
            continue;
        }
        let key = m.material_id.filter(|&i| i < materials.len());
        let mat_id = match converted.get(&key) {
            Some(&id) => id,
            None => {
                let mat = match key {
                    Some(i) => {
                        let mtl = lib_of.get(i).copied().unwrap_or(path);
                        obj_material(&materials[i], mtl, path, &mut cache)?
                    }
                    None => AssetMaterial::default(),
                };
                let id = asset.materials.len() as u32;
                asset.materials.push(mat);
                converted.insert(key, id);
                id
            }
        };
        if m.indices.len() % 3 != 0 {
            return Err(LoadError::new(path, "a face was not triangulated"));
        }
        if let Some(&i) = m.indices.iter().find(|&&i| i as usize >= n) {
            return Err(LoadError::new(
                path,
                format!("face index {i} is out of range"),
            ));
        }
        let part = obj_part(m, mat_id, options.obj_unit_mm);
        asset.mesh.append(&part, 0);
    }
    Ok(asset)
}

/// The models and materials of OBJ file `path` (faces triangulated by ear clipping) and the
/// log of its material libraries, with the sizes checked before any f64 array is built.
fn read_obj_models(
    path: &Path,
    options: &LoadOptions,
) -> Result<(Vec<tobj::Model>, Vec<tobj::Material>, MtlLog), LoadError> {
    let file = std::fs::File::open(path).map_err(|e| LoadError::new(path, e))?;
    let mut reader = Utf8Lines {
        inner: BufReader::new(file),
        line: Vec::new(),
        pos: 0,
    };
    let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let log = RefCell::new(MtlLog::default());
    let opts = tobj::LoadOptions {
        // Polygons are triangulated below by ear clipping (`obj_features`).
        triangulate: false,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let result = tobj::load_obj_buf(&mut reader, &opts, |mtl: &Path| {
        load_mtl(mtl, &dir, path, options, &mut log.borrow_mut())
    });
    let log = log.into_inner();
    if let Some(e) = log.error {
        return Err(e);
    }
    let (mut models, materials) =
        result.map_err(|e| LoadError::new(path, format!("not a readable OBJ file ({e})")))?;
    for m in &mut models {
        crate::obj_features::triangulate_faces(&mut m.mesh);
    }
    let materials = materials.unwrap_or_default();
    // Size checks before building the f64 arrays.
    let (mut nv, mut nt) = (0usize, 0usize);
    for m in &models {
        nv += m.mesh.positions.len() / 3;
        nt += m.mesh.indices.len() / 3;
    }
    if nt > MAX_TRIANGLES || nv > MAX_VERTICES {
        return Err(LoadError::new(
            path,
            format!("more than {MAX_TRIANGLES} triangles or {MAX_VERTICES} vertices"),
        ));
    }
    Ok((models, materials, log))
}

/// Reads material library `mtl` (named in OBJ file `path`, resolved against its folder `dir`)
/// for tobj, noting it in `log`; a missing library is tolerated with
/// `options.allow_missing_mtl`, any other failure is logged (the first one) and fails the load.
fn load_mtl(
    mtl: &Path,
    dir: &Path,
    path: &Path,
    options: &LoadOptions,
    log: &mut MtlLog,
) -> tobj::MTLLoadResult {
    let full = mtl
        .to_str()
        .and_then(|s| resolve_reference(dir, s, false))
        .unwrap_or_else(|| dir.join(mtl));
    let opened = check_regular_file(&full).and_then(|_| read_mtl_text(&full));
    match opened {
        Err(e) => {
            // Only a library that does not exist is tolerated: a folder, FIFO, device or
            // broken file in its place is an error even then.
            let missing =
                std::fs::metadata(&full).is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound);
            if options.allow_missing_mtl && missing {
                return Ok((Vec::new(), Default::default()));
            }
            if log.error.is_none() {
                log.error = Some(LoadError::new(
                    &e.path,
                    format!(
                        "cannot open material library (used by {}): {}",
                        file_name(path),
                        e.message
                    ),
                ));
            }
            Err(tobj::LoadError::OpenFileFailed)
        }
        Ok(text) => {
            let r = tobj::load_mtl_buf(&mut text.as_bytes());
            match &r {
                Ok((mats, _)) => log.loaded.push((full, mats.len())),
                Err(e) => {
                    if log.error.is_none() {
                        log.error = Some(LoadError::new(
                            &full,
                            format!("not a readable material library ({e})"),
                        ));
                    }
                }
            }
            r
        }
    }
}

/// One OBJ model's mesh with material `mat_id`, in mm (`unit` mm per OBJ unit): unit normals
/// where the model has one per vertex (else computed), v flipped to the texture's rows.
fn obj_part(m: &tobj::Mesh, mat_id: u32, unit: f64) -> Mesh {
    let n = m.positions.len() / 3;
    let positions_mm = m
        .positions
        .chunks_exact(3)
        .map(|p| DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) * unit)
        .collect();
    let normals: Vec<DVec3> = if m.normals.len() == 3 * n {
        m.normals
            .chunks_exact(3)
            .map(|p| {
                let v = DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                let len = v.length();
                if len > 0.0 && len.is_finite() {
                    v / len
                } else {
                    DVec3::ZERO
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let uvs = if m.texcoords.len() == 2 * n {
        m.texcoords
            .chunks_exact(2)
            .map(|t| DVec2::new(f64::from(t[0]), 1.0 - f64::from(t[1])))
            .collect()
    } else {
        Vec::new()
    };
    let triangles: Vec<[u32; 3]> = m
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let mut part = Mesh {
        positions_mm,
        normals,
        uvs,
        material_ids: vec![mat_id; triangles.len()],
        triangles,
        colors: crate::obj_features::vertex_colours(m),
        alphas: Vec::new(),
        tangents: Vec::new(),
    };
    if part.normals.is_empty() {
        part.compute_normals();
    }
    part
}

/// Largest material library read, bytes.
const MAX_MTL_BYTES: u64 = crate::io::input::MAX_TEXT_BYTES;

/// Reads a material library (a regular file of at most [`MAX_MTL_BYTES`]) and checks the arity
/// of its colour lines (`Ka`, `Kd`, `Ks`, `Ke`: three numbers r g b), which the parser
/// would otherwise panic on; an error names the line.
fn read_mtl_text(path: &Path) -> Result<String, LoadError> {
    let bytes = crate::io::input::read_input(path, MAX_MTL_BYTES).map_err(|e| match e {
        IoError::Io { source, .. } => LoadError::new(path, source),
        IoError::Format { message, .. } => LoadError::new(path, message),
    })?;
    let text = decode_text(&bytes).into_owned();
    check_mtl_arity(&text).map_err(|m| LoadError::new(path, m))?;
    Ok(text)
}

/// The first colour line of an MTL text without exactly three numbers, as a message.
fn check_mtl_arity(text: &str) -> Result<(), String> {
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() else {
            continue;
        };
        let values = words.count();
        if values < 3 {
            return Err(format!(
                "line {}: {:?}: {key} needs three numbers (r g b), got {}",
                n + 1,
                line.trim(),
                values
            ));
        }
    }
    Ok(())
}

/// Decodes a text line or file: as UTF-8 when it is valid, otherwise as Latin-1 (each byte
/// to the code point of the same value), as files written by Windows tools often are.
fn decode_text(bytes: &[u8]) -> std::borrow::Cow<'_, str> {
    match std::str::from_utf8(bytes) {
        Ok(s) => s.into(),
        Err(_) => bytes
            .iter()
            .map(|&b| char::from(b))
            .collect::<String>()
            .into(),
    }
}

/// A reader handing each line on as UTF-8 ([`decode_text`]), for the OBJ parser, which
/// refuses other bytes.
struct Utf8Lines<R> {
    inner: R,
    line: Vec<u8>,
    pos: usize,
}

impl<R: std::io::BufRead> std::io::Read for Utf8Lines<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        use std::io::BufRead;
        let buf = self.fill_buf()?;
        let n = buf.len().min(out.len());
        out[..n].copy_from_slice(&buf[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl<R: std::io::BufRead> std::io::BufRead for Utf8Lines<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.pos >= self.line.len() {
            self.line.clear();
            self.pos = 0;
            self.inner.read_until(b'\n', &mut self.line)?;
            if let std::borrow::Cow::Owned(s) = decode_text(&self.line) {
                self.line = s.into_bytes();
            }
        }
        Ok(&self.line[self.pos..])
    }
    fn consume(&mut self, n: usize) {
        self.pos = (self.pos + n).min(self.line.len());
    }
}

/// Resolves a file reference of an MTL or OBJ file (`mtllib`, `map_Kd`) against `base`, the
/// folder of the referring file: the name as written if such a file exists, else with
/// backslashes read as folder separators (Windows tools write `.\tex.jpg`); with
/// `options_before_name`, also only the last word (`map_Kd -s 1 1 1 tex.png`); for an absolute
/// Windows path (`C:\maps\tex.png`), the file name in `base`. Each name is also tried as the
/// raw Latin-1 bytes of its characters (a file named in Latin-1 on disk). `None` if none exists.
pub(super) fn resolve_reference(
    base: &Path,
    spec: &str,
    options_before_name: bool,
) -> Option<PathBuf> {
    let spec = spec.trim();
    let mut names = vec![spec.to_owned(), spec.replace('\\', "/")];
    if options_before_name && let Some(last) = spec.split_whitespace().last() {
        names.push(last.to_owned());
        names.push(last.replace('\\', "/"));
    }
    let windows_absolute = |n: &str| {
        let b = n.as_bytes();
        n.starts_with('/') || (b.len() > 2 && b[0].is_ascii_alphabetic() && b[1] == b':')
    };
    let tails: Vec<String> = names
        .iter()
        .filter(|n| n.contains('/') && windows_absolute(n))
        .filter_map(|n| n.rsplit('/').next().map(str::to_owned))
        .collect();
    names.extend(tails);
    names.into_iter().filter(|n| !n.is_empty()).find_map(|n| {
        let as_written = base.join(&n);
        if as_written.exists() {
            return Some(as_written);
        }
        latin1_path(&n)
            .map(|raw| base.join(raw))
            .filter(|p| p.exists())
    })
}

/// The path whose bytes are the Latin-1 codes of `name`'s characters, if `name` has a
/// character above ASCII and none above U+00FF (Unix only: elsewhere names are not bytes).
fn latin1_path(name: &str) -> Option<PathBuf> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStringExt;
        if name.is_ascii() || name.chars().any(|c| u32::from(c) > 0xFF) {
            return None;
        }
        let bytes = name.chars().map(|c| u32::from(c) as u8).collect();
        Some(PathBuf::from(std::ffi::OsString::from_vec(bytes)))
    }
    #[cfg(not(unix))]
    {
        let _ = name;
        None
    }
}

/// Converts a material of the library `mtl` (used by `obj`).
fn obj_material(
    m: &tobj::Material,
    mtl: &Path,
    obj: &Path,
    cache: &mut HashMap<PathBuf, Arc<Texture>>,
) -> Result<AssetMaterial, LoadError> {
    let base = mtl.parent().unwrap_or(Path::new(""));
    let mut load = |key: &str, spec: &str| -> Result<Arc<Texture>, LoadError> {
        let Some(p) = resolve_reference(base, spec, true) else {
            return Err(LoadError::new(
                mtl,
                format!(
                    "material {:?}: {key} \"{}\": no such texture file next to it (used by {})",
                    m.name,
                    spec.trim(),
                    file_name(obj)
                ),
            ));
        };
        if let Some(t) = cache.get(&p) {
            return Ok(t.clone());
        }
        if p.is_dir() {
            return Err(LoadError::new(
                &p,
                format!("texture (used by {}) is a directory", file_name(obj)),
            ));
        }
        let t = Arc::new(Texture::load(&p).map_err(|e| LoadError::texture(e, obj))?);
        cache.insert(p, t.clone());
        Ok(t)
    };
    let parse3 = |s: &str| -> Option<[f64; 3]> {
        let v: Vec<f64> = s
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()
            .ok()?;
        match v.as_slice() {
            [r, g, b] => Some([*r, *g, *b]),
            [g] => Some([*g; 3]),
            _ => None,
        }
    };
    let f3 = |v: [f32; 3]| v.map(f64::from);
    let emissive = m
        .emissive
        .map(f3)
        .or_else(|| m.unknown_param.get("Ke").and_then(|s| parse3(s)))
        .unwrap_or([0.0; 3]);
    let base_color = m
        .diffuse
        .map(f3)
        .unwrap_or(AssetMaterial::default().base_color);
    for (what, v) in [("Kd", base_color), ("Ke", emissive)] {
        if v.iter().any(|c| !c.is_finite() || *c < 0.0) {
            return Err(LoadError::new(
                obj,
                format!(
                    "material {:?}: {what} must be finite and non-negative",
                    m.name
                ),
            ));
        }
    }
    let base_color_texture = match &m.diffuse_texture {
        Some(s) => Some(load("map_Kd", s)?),
        None => None,
    };
    let emissive_texture = match m.unknown_param.get("map_Ke") {
        Some(s) => Some(load("map_Ke", s)?),
        None => None,
    };
    Ok(AssetMaterial {
        name: m.name.clone(),
        model: SurfaceModel::Diffuse,
        base_color,
        base_color_texture,
        emissive,
        emissive_texture,
        ..AssetMaterial::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::tests::{nested_gltf, write};
    use crate::load::{load_asset, load_asset_with};
    use serde_json::json;

    #[test]
    fn obj_units_and_default_material() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cm.obj");
        write(&p, "v 0 0 0\nv 1.5 0 0\nv 0 2 0\nf 1 2 3\n");
        let a = load_asset(&p, 10.0).unwrap();
        assert_eq!(a.mesh.positions_mm[1], DVec3::new(15.0, 0.0, 0.0));
        assert_eq!(a.mesh.positions_mm[2], DVec3::new(0.0, 20.0, 0.0));
        assert_eq!(a.mesh.normals, vec![DVec3::Z; 3]);
        assert!(a.mesh.uvs.is_empty());
        assert_eq!(a.materials.len(), 1);
        assert_eq!(a.materials[0].model, SurfaceModel::Diffuse);
        assert_eq!(a.materials[0].base_color, [0.8; 3]);
        let m = load_asset(&p, 1000.0).unwrap();
        assert_eq!(m.mesh.positions_mm[1].x, 1500.0);
        assert!(
            load_asset(&p, 0.0)
                .unwrap_err()
                .to_string()
                .contains("cm.obj")
        );
        // Emission from Ke, and a glTF primitive without material gets the glTF default.
        write(
            &dir.path().join("e.mtl"),
            "newmtl glow\nKd 0.5 0.25 0.125\nKe 2 3 4\n",
        );
        let p = dir.path().join("e.obj");
        write(
            &p,
            "mtllib e.mtl\nusemtl glow\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
        );
        let e = load_asset(&p, 1.0).unwrap();
        assert_eq!(e.mesh.triangles.len(), 2);
        assert_eq!(e.materials[0].emissive, [2.0, 3.0, 4.0]);
        assert_eq!(e.materials[0].base_color, [0.5, 0.25, 0.125]);
        let g = load_asset(&nested_gltf(dir.path(), "n.gltf", json!({})), 1.0).unwrap();
        let d = &g.materials[0];
        assert_eq!(
            (d.model, d.base_color, d.metallic, d.roughness),
            (SurfaceModel::MetallicRoughness, [1.0; 3], 1.0, 1.0)
        );
    }

    /// UTF-8 lines pass unchanged, other lines are Latin-1 (0xE9 → 'é', not U+FFFD as a lossy
    /// reading gives), line by line, through the reader the OBJ parser gets.
    #[cfg(unix)]
    #[test]
    fn text_decodes_as_utf8_or_latin1() {
        use std::io::BufRead;
        use std::os::unix::ffi::OsStrExt;
        assert_eq!(decode_text("tête".as_bytes()), "tête");
        assert_eq!(decode_text(b"t\xe9te"), "téte");
        assert_ne!(String::from_utf8_lossy(b"t\xe9te"), "téte");
        let r = Utf8Lines {
            inner: &b"usemtl \xe9\nusemtl \xc3\xa9\n"[..],
            line: Vec::new(),
            pos: 0,
        };
        let lines: Vec<String> = r.lines().map(Result::unwrap).collect();
        assert_eq!(lines, ["usemtl é", "usemtl é"]);
        assert_eq!(
            latin1_path("é"),
            Some(PathBuf::from(std::ffi::OsStr::from_bytes(b"\xe9")))
        );
        assert_eq!(latin1_path("e"), None);
        assert_eq!(latin1_path("頭"), None);
    }

    #[test]
    fn loads_the_shipped_face_mesh() {
        let path = stscam_base::repo_dir().join("scenes/assets/canonical_face_model.obj");
        if !path.is_file() {
            println!("skipped: {} is absent", path.display());
            return;
        }
        // The file names a material library that is not shipped.
        let strict = load_asset(&path, 10.0).unwrap_err().to_string();
        assert!(strict.contains("canonical_face_model.mtl"), "{strict}");
        let opts = LoadOptions {
            obj_unit_mm: 10.0,
            allow_missing_mtl: true,
        };
        let a = load_asset_with(&path, &opts).unwrap();
        assert_eq!(a.mesh.triangles.len(), 898);
        assert_eq!(a.mesh.uvs.len(), a.mesh.positions_mm.len());
        let (lo, hi) = a.mesh.positions_mm.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let size = hi - lo;
        assert!((150.0..=250.0).contains(&size.y), "height {size}");
        assert!((140.0..=170.0).contains(&size.x), "width {size}");
        // Faces toward +z: most vertex normals point forward.
        let forward = a.mesh.normals.iter().filter(|n| n.z > 0.0).count();
        assert!(forward * 2 > a.mesh.normals.len());
        assert!(
            a.mesh
                .normals
                .iter()
                .all(|n| (n.length() - 1.0).abs() < 1e-9)
        );
    }
}
