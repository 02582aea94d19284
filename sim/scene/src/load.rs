//! Loading a scene: its TOML merged over the embedded paper scene, the `--set` overrides
//! applied, deserialised (an error names the key) and validated.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crate::error::SceneError;
use crate::scene::{
    HoeDesc, LIST_SECTIONS, LoadedScene, MAX_GRATINGS, SINGLE_GRATING_KEYS, Scene, is_overridden,
    single_form_keys,
};
use crate::validate::validate;
use crate::{EMBEDDED_NAME, PAPER_SCENE_TOML};

fn line_col(text: &str, offset: usize) -> String {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |s| s.chars().count()) + 1;
    format!("line {line}, column {col}")
}

fn parse_table(text: &str, file: &str) -> Result<toml::Table, SceneError> {
    text.parse::<toml::Table>().map_err(|e| SceneError::Syntax {
        file: file.to_string(),
        location: e.span().map_or_else(
            || "unknown position".to_string(),
            |s| line_col(text, s.start),
        ),
        message: e.message().trim().replace('\n', " "),
    })
}

/// Merges `over` into `base`; every key of `over` must exist in `base`.
fn merge(
    base: &mut toml::Table,
    over: toml::Table,
    prefix: &str,
    file: &str,
) -> Result<(), SceneError> {
    if prefix == "hoe" && over.contains_key("grating") {
        take_grating_list(base, &over, file)?;
    }
    for (k, v) in over {
        if prefix == "hoe" && k == "grating" {
            // Checked and prepared by `take_grating_list`.
            base.insert(k, v);
            continue;
        }
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        if prefix.is_empty() && LIST_SECTIONS.contains(&k.as_str()) {
            if !matches!(&v, toml::Value::Array(a) if a.iter().all(toml::Value::is_table)) {
                return Err(SceneError::Key {
                    file: file.to_string(),
                    key,
                    message: format!("expected [[{k}]] tables"),
                });
            }
            base.insert(k, v);
            continue;
        }
        let unknown = (!base.contains_key(&k)).then(|| unknown_key_message(prefix, &k, base));
        match (base.get_mut(&k), v) {
            (None, _) => {
                return Err(SceneError::Key {
                    file: file.to_string(),
                    key,
                    message: unknown.unwrap_or_default(),
                });
            }
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o, &key, file)?,
            (Some(toml::Value::Table(_)), _) => {
                return Err(SceneError::Key {
                    file: file.to_string(),
                    key,
                    message: "expected a table".into(),
                });
            }
            (Some(slot), v) => *slot = v,
        }
    }
    Ok(())
}

/// A scene's `[hoe]` table `over` lists `[[hoe.grating]]` entries: checks they are tables, at
/// most [`MAX_GRATINGS`], and that `over` does not also give a single-grating key; removes the
/// embedded scene's single-grating keys from `base` (the list replaces them).
fn take_grating_list(
    base: &mut toml::Table,
    over: &toml::Table,
    file: &str,
) -> Result<(), SceneError> {
    let fail = |key: &str, message: String| SceneError::Key {
        file: file.to_string(),
        key: key.to_string(),
        message,
    };
    if let Some(single) = single_form_keys().find(|k| over.contains_key(*k)) {
        return Err(fail(
            &format!("hoe.{single}"),
            format!(
                "give either [[hoe.grating]] entries or the single-grating keys {}, not both",
                SINGLE_GRATING_KEYS
                    .iter()
                    .map(|k| format!("hoe.{k}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    }
    match over.get("grating") {
        Some(toml::Value::Array(a)) if !a.is_empty() && a.iter().all(toml::Value::is_table) => {
            if a.len() > MAX_GRATINGS {
                return Err(fail(
                    "hoe.grating",
                    format!("{} gratings; a film holds at most {MAX_GRATINGS}", a.len()),
                ));
            }
        }
        _ => {
            return Err(fail(
                "hoe.grating",
                "expected one or more [[hoe.grating]] tables".into(),
            ));
        }
    }
    for k in single_form_keys() {
        base.remove(k);
    }
    Ok(())
}

/// "unknown key", with the nearest key of `table` (the section `prefix`) as a suggestion.
fn unknown_key_message(prefix: &str, key: &str, table: &toml::Table) -> String {
    let full = |k: &str| {
        if prefix.is_empty() {
            k.to_string()
        } else {
            format!("{prefix}.{k}")
        }
    };
    let names: Vec<String> = table.keys().map(|k| full(k)).collect();
    format!(
        "unknown key{}",
        crate::suggest::did_you_mean(&full(key), names.iter().map(String::as_str))
    )
}

/// Parses a `--set` value: TOML syntax if it parses (numbers, booleans, arrays, quoted
/// strings), otherwise the raw text as a string.
fn parse_override_value(raw: &str) -> toml::Value {
    let doc = format!("v = {raw}");
    match doc.parse::<toml::Table>() {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or_else(|| toml::Value::String(raw.to_string())),
        Err(_) => toml::Value::String(raw.to_string()),
    }
}

/// Applies one `KEY=VALUE` override to a full scene table. Array elements are addressed by
/// index (`object.0.position_mm`); inside an `[[object]]` or `[[light]]` element a key the
/// element does not list yet may be set (its name is checked when the scene is read).
fn apply_override(table: &mut toml::Table, spec: &str) -> Result<String, SceneError> {
    let Some((key, raw)) = spec.split_once('=') else {
        return Err(SceneError::Key {
            file: "--set".into(),
            key: spec.to_string(),
            message: "expected KEY=VALUE".into(),
        });
    };
    let key = key.trim();
    let fail = |message: String| SceneError::Key {
        file: format!("--set {key}"),
        key: key.to_string(),
        message,
    };
    let unknown = || fail("unknown key".into());
    let parts: Vec<&str> = key.split('.').collect();
    let in_list = (parts.len() > 2 && LIST_SECTIONS.contains(&parts[0]))
        || (parts.len() > 3 && parts[0] == "hoe" && parts[1] == "grating");
    if !table.contains_key(parts[0]) {
        return Err(if LIST_SECTIONS.contains(&parts[0]) {
            fail(format!("the scene has no [[{}]] elements to set", parts[0]))
        } else {
            fail(unknown_key_message("", parts[0], table))
        });
    }
    let mut cur: &mut toml::Value = table.get_mut(parts[0]).ok_or_else(unknown)?;
    for (depth, part) in parts.iter().enumerate().skip(1) {
        let last = depth + 1 == parts.len();
        cur = match cur {
            toml::Value::Array(a) => {
                let i: usize = part
                    .parse()
                    .map_err(|_| fail(format!("{part:?} is not an element index")))?;
                let n = a.len();
                a.get_mut(i)
                    .ok_or_else(|| fail(format!("index {i} is out of range ({n} elements)")))?
            }
            toml::Value::Table(t) => {
                if !t.contains_key(*part) {
                    if depth == 1 && parts[0] == "hoe" {
                        if let Some(m) = grating_form_mismatch(t, part) {
                            return Err(fail(m));
                        }
                    }
                    if !in_list {
                        return Err(fail(unknown_key_message(
                            &parts[..depth].join("."),
                            part,
                            t,
                        )));
                    }
                    let fill = if last {
                        toml::Value::Boolean(false)
                    } else {
                        toml::Value::Table(toml::Table::new())
                    };
                    t.insert((*part).to_string(), fill);
                }
                t.get_mut(*part).ok_or_else(unknown)?
            }
            _ => return Err(unknown()),
        };
    }
    if parts.len() == 1 || cur.is_table() || (cur.is_array() && parts.len() == 1) {
        return Err(fail("is a section; set one of its keys".into()));
    }
    *cur = parse_override_value(raw.trim());
    Ok(key.to_string())
}

/// Why `--set hoe.PART…` cannot apply to the `[hoe]` table `t`: a single-grating key on a
/// film that lists `[[hoe.grating]]` entries, or a grating entry on one that does not.
fn grating_form_mismatch(t: &toml::Table, part: &str) -> Option<String> {
    if t.contains_key("grating") && single_form_keys().any(|k| k == part) {
        Some(format!(
            "the scene lists [[hoe.grating]] entries; set hoe.grating.N.{part} (N from 0)"
        ))
    } else if part == "grating" && !t.contains_key("grating") {
        Some(
            "the scene has no [[hoe.grating]] entries to set; its one grating is \
             hoe.recording_wavelength_nm, hoe.reference_angle_deg, hoe.index_modulation"
                .into(),
        )
    } else {
        None
    }
}

/// Loads a scene: the embedded paper scene, merged with `path` if given, then the overrides.
/// The result is validated.
pub fn load_scene(path: Option<&Path>, overrides: &[String]) -> Result<LoadedScene, SceneError> {
    match path {
        Some(p) => {
            let file = p.display().to_string();
            let text = crate::io::read_text(p).map_err(|e| SceneError::Read {
                file: file.clone(),
                message: match e {
                    crate::io::IoError::Io { source, .. } => source.to_string(),
                    crate::io::IoError::Format { message, .. } => message,
                },
            })?;
            let dir = p.parent().map(Path::to_path_buf).unwrap_or_default();
            load_scene_text(Some((&text, &file, &dir)), overrides)
        }
        None => load_scene_text(None, overrides),
    }
}

/// Where a scene comes from, for jobs that load it more than once (a sweep loads it per grid
/// point): a file (or, with `None`, the embedded paper scene alone), or TOML text in memory
/// (the Python module's scenes built from dicts).
#[derive(Clone, Copy, Debug)]
pub enum SceneSource<'a> {
    /// [`load_scene`]'s file.
    File(Option<&'a Path>),
    /// [`load_scene_text`]'s (text, name to blame in messages, directory of relative paths).
    Text(&'a str, &'a str, &'a Path),
}

impl SceneSource<'_> {
    /// Loads the scene with `overrides` applied, as [`load_scene`] or [`load_scene_text`].
    pub fn load(&self, overrides: &[String]) -> Result<LoadedScene, SceneError> {
        match *self {
            SceneSource::File(path) => load_scene(path, overrides),
            SceneSource::Text(text, name, dir) => {
                load_scene_text(Some((text, name, dir)), overrides)
            }
        }
    }
}

/// As [`load_scene`], for a scene held in memory: `user` is (TOML text, the name to blame in
/// messages, the directory its relative asset paths resolve against), merged over the paper
/// scene; `None` is the paper scene alone.
pub fn load_scene_text(
    user: Option<(&str, &str, &Path)>,
    overrides: &[String],
) -> Result<LoadedScene, SceneError> {
    let mut table = parse_table(PAPER_SCENE_TOML, EMBEDDED_NAME)?;
    let (source, base_dir) = match user {
        Some((text, file, dir)) => {
            let user = parse_table(text, file)?;
            merge(&mut table, user, "", file)?;
            (file.to_string(), dir.to_path_buf())
        }
        None => (EMBEDDED_NAME.to_string(), PathBuf::from(".")),
    };
    let mut overridden = BTreeSet::new();
    for spec in overrides {
        overridden.insert(apply_override(&mut table, spec)?);
    }
    let mut loaded = LoadedScene {
        scene: placeholder_free_deserialize(table, &source, &overridden)?,
        source,
        base_dir,
        overridden,
    };
    if loaded.base_dir.as_os_str().is_empty() {
        loaded.base_dir = PathBuf::from(".");
    }
    validate(&loaded)?;
    canonical_single_grating(&mut loaded.scene.hoe);
    Ok(loaded)
}

/// A one-entry `[[hoe.grating]]` list with the object beam normal to the film is the same film
/// as the single-grating keys: it is stored in that form, so the scene (and every output that
/// records it) is the same whichever form the file used.
fn canonical_single_grating(h: &mut HoeDesc) {
    if let [g] = h.grating.as_slice() {
        if g.object_angle_deg == 0.0 {
            h.recording_wavelength_nm = Some(g.recording_wavelength_nm);
            h.reference_angle_deg = Some(g.reference_angle_deg);
            h.index_modulation = Some(g.index_modulation);
            h.index_modulation_shortfall = g.index_modulation_shortfall;
            h.reference_angle_error_deg = g.reference_angle_error_deg;
            h.grating.clear();
        }
    }
}

/// `object[0].mesh` → `object.0.mesh`: keys inside `[[object]]` and `[[light]]` are named as
/// `--set` takes them (other array elements keep serde's `key[i]` form).
fn dotted_path(path: &str) -> String {
    if LIST_SECTIONS
        .iter()
        .any(|l| path.starts_with(&format!("{l}[")))
    {
        path.replace("].", ".").replace('[', ".").replace(']', "")
    } else {
        path.to_string()
    }
}

fn placeholder_free_deserialize(
    table: toml::Table,
    source: &str,
    overridden: &BTreeSet<String>,
) -> Result<Scene, SceneError> {
    serde_path_to_error::deserialize::<_, Scene>(table).map_err(|e| {
        let key = dotted_path(&e.path().to_string());
        let file = if is_overridden(overridden, &key) {
            format!("--set {key}")
        } else {
            source.to_string()
        };
        SceneError::Key {
            file,
            key,
            message: e.inner().to_string().replace('\n', " "),
        }
    })
}
