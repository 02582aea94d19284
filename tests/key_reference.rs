//! The scene-key reference `docs/keys.md` against the code: every key a scene accepts must have
//! a row there, every row must name a key the code accepts, and every key the embedded paper
//! scene sets must show that scene's value as its default.
//!
//! The keys are enumerated from the serde description itself, not from a list kept by hand:
//! every scene struct denies unknown fields, so deserialising a `Scene` with a made-up field
//! inserted at some place fails with serde's "unknown field `…`, expected one of `a`, `b`, …",
//! which lists every field of the struct at that place, optional ones included. Each listed
//! field is then probed with a table (and, at the top level, an array of one table) holding a
//! made-up field: if that fails with the same "unknown field" message the field is itself a
//! struct (a section, `object.material`, …) and is walked in turn, else it is a leaf key.
//! Fields of `[[object]]` and `[[light]]` elements are named as `--set` takes them without the
//! index: `object.material.base_color`.
//!
//! The same file checks the command reference `docs/cli.md` against the binary's `--help`:
//! every command and every option it lists must appear in that command's section.

use std::collections::{BTreeMap, BTreeSet};

use stscam::scene::{PAPER_SCENE_TOML, Scene};

/// A field name no struct has.
const PROBE: &str = "zz_probe_not_a_key";

/// Where a probe goes: a path of table keys, `None` standing for "element 0 of an array".
type Path = Vec<Option<String>>;

/// The fields of the struct at `path` (through tables and one-element arrays), or `None` if
/// the value there is not a struct.
fn fields_at(path: &Path) -> Option<Vec<String>> {
    let mut table: toml::Table = PAPER_SCENE_TOML.parse().expect("embedded scene parses");
    let mut probe = toml::Table::new();
    probe.insert(PROBE.into(), toml::Value::Integer(0));
    // Build the value from the innermost level outward.
    let mut value = toml::Value::Table(probe);
    for step in path.iter().rev() {
        value = match step {
            None => toml::Value::Array(vec![value]),
            Some(name) => {
                let mut t = toml::Table::new();
                t.insert(name.clone(), value);
                toml::Value::Table(t)
            }
        };
    }
    let toml::Value::Table(top) = value else {
        unreachable!("a path starts with a key")
    };
    merge_into(&mut table, top);
    let err = match table.try_into::<Scene>() {
        Ok(_) => panic!("a scene with the made-up field {PROBE} at {path:?} was accepted"),
        Err(e) => e.to_string(),
    };
    parse_unknown_field(&err)
}

/// Inserts `over` into `base`, replacing leaves and descending into tables both have.
fn merge_into(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_into(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// The field list of serde's "unknown field `PROBE`, expected one of `a`, `b`" (or "expected
/// `a`" for a single field), or `None` if the message is about something else.
fn parse_unknown_field(message: &str) -> Option<Vec<String>> {
    let marker = format!("unknown field `{PROBE}`");
    let at = message.find(&marker)?;
    let rest = &message[at + marker.len()..];
    let list = rest
        .strip_prefix(", expected one of ")
        .or_else(|| rest.strip_prefix(", expected "))?;
    let list = list.lines().next().unwrap_or("");
    let names: Vec<String> = list
        .split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_string)
        .collect();
    (!names.is_empty()).then_some(names)
}

/// Every leaf key a scene accepts, dotted, array indices left out.
fn code_keys() -> BTreeSet<String> {
    let mut keys = BTreeSet::new();
    walk(&Vec::new(), "", &mut keys);
    keys
}

fn walk(path: &Path, dotted: &str, keys: &mut BTreeSet<String>) {
    let fields = fields_at(path)
        .unwrap_or_else(|| panic!("no field list for the struct at {path:?} ({dotted})"));
    for f in fields {
        let name = if dotted.is_empty() {
            f.clone()
        } else {
            format!("{dotted}.{f}")
        };
        let mut as_table = path.clone();
        as_table.push(Some(f.clone()));
        if fields_at(&as_table).is_some() {
            walk(&as_table, &name, keys);
            continue;
        }
        let mut as_array = as_table.clone();
        as_array.push(None);
        if fields_at(&as_array).is_some() {
            walk(&as_array, &name, keys);
            continue;
        }
        keys.insert(name);
    }
}

/// The keys of `docs/keys.md`: the first cell of every table row, if it is one backticked
/// dotted name, with the row's default cell (the third column of a four-column table).
fn doc_rows(text: &str) -> BTreeMap<String, Option<String>> {
    let mut rows = BTreeMap::new();
    for line in text.lines() {
        let line = line.trim();
        if !line.starts_with("| `") {
            continue;
        }
        let cells: Vec<&str> = line.trim_matches('|').split('|').map(str::trim).collect();
        let first = cells[0];
        let Some(key) = first
            .strip_prefix('`')
            .and_then(|s| s.strip_suffix('`'))
            .filter(|k| !k.contains('`') && !k.contains(' '))
        else {
            continue;
        };
        let default = cells.get(3).map(|s| s.to_string());
        let previous = rows.insert(key.to_string(), default);
        assert!(previous.is_none(), "docs/keys.md lists {key} twice");
    }
    rows
}

/// Keys in the code but not in the docs, and keys in the docs but not in the code.
fn differences(code: &BTreeSet<String>, docs: &BTreeSet<String>) -> (Vec<String>, Vec<String>) {
    (
        code.difference(docs).cloned().collect(),
        docs.difference(code).cloned().collect(),
    )
}

/// The paper scene's value of every leaf key it sets (not inside arrays of tables).
fn paper_values() -> BTreeMap<String, toml::Value> {
    fn go(prefix: &str, t: &toml::Table, out: &mut BTreeMap<String, toml::Value>) {
        for (k, v) in t {
            let key = if prefix.is_empty() {
                k.clone()
            } else {
                format!("{prefix}.{k}")
            };
            match v {
                toml::Value::Table(inner) => go(&key, inner, out),
                // Arrays of tables (`[[…]]` elements) have no single default.
                toml::Value::Array(a) if a.iter().any(toml::Value::is_table) => {}
                v => {
                    out.insert(key, v.clone());
                }
            }
        }
    }
    let table: toml::Table = PAPER_SCENE_TOML.parse().expect("embedded scene parses");
    let mut out = BTreeMap::new();
    go("", &table, &mut out);
    out
}

/// Whether a default cell (`` `2.0` ``, possibly followed by words) shows `value`.
fn default_matches(cell: &str, value: &toml::Value) -> bool {
    let Some(code) = cell.split('`').nth(1) else {
        return false;
    };
    match format!("v = {code}").parse::<toml::Table>() {
        Ok(t) => same(&t["v"], value),
        Err(_) => false,
    }
}

fn same(a: &toml::Value, b: &toml::Value) -> bool {
    use toml::Value::{Array, Float, Integer};
    match (a, b) {
        (Float(x), Float(y)) => x == y,
        (Integer(x), Integer(y)) => x == y,
        (Array(x), Array(y)) => x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same(p, q)),
        _ => a == b,
    }
}

fn docs_text() -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/keys.md");
    std::fs::read_to_string(path).expect("docs/keys.md is readable")
}

#[test]
fn every_scene_key_is_documented_and_every_documented_key_exists() {
    let code = code_keys();
    let docs: BTreeSet<String> = doc_rows(&docs_text()).into_keys().collect();
    let (undocumented, unknown) = differences(&code, &docs);
    assert!(
        undocumented.is_empty() && unknown.is_empty(),
        "docs/keys.md is out of date.\n  keys in the code but not in docs/keys.md: {undocumented:?}\n  \
         keys in docs/keys.md that the code does not accept: {unknown:?}"
    );
}

#[test]
fn every_default_in_the_reference_is_the_paper_scene_value() {
    let rows = doc_rows(&docs_text());
    let mut wrong = Vec::new();
    for (key, value) in paper_values() {
        let cell = rows.get(&key).cloned().flatten().unwrap_or_default();
        if !default_matches(&cell, &value) {
            wrong.push(format!(
                "{key}: docs say {cell:?}, the paper scene has {value}"
            ));
        }
    }
    assert!(
        wrong.is_empty(),
        "defaults in docs/keys.md differ:\n  {}",
        wrong.join("\n  ")
    );
}

/// The enumeration finds what it must: sections, keys the paper scene leaves out
/// (`display.enabled` has a serde default), and keys of nested structs inside array elements.
#[test]
fn the_enumeration_sees_optional_and_nested_keys() {
    let keys = code_keys();
    for k in [
        "plate.thickness_mm",
        "display.enabled",
        "sampling.max_depth",
        "object.mesh",
        "object.material.base_color",
        "object.pose.bend_deg",
        "light.kind",
        "light.falloff_deg",
    ] {
        assert!(keys.contains(k), "{k} was not enumerated: {keys:?}");
    }
    assert!(!keys.contains("plate"), "a section is not a key");
    assert!(!keys.contains("object"), "an array of tables is not a key");
    assert!(keys.len() > 60, "only {} keys enumerated", keys.len());
}

/// The check can fail: a made-up key in the docs and a key missing from them are both reported,
/// and a wrong default is caught.
#[test]
fn a_made_up_or_missing_key_and_a_wrong_default_are_reported() {
    let code = code_keys();
    let mut docs = code.clone();
    docs.insert("plate.made_up_mm".into());
    docs.remove("hoe.index_modulation");
    let (undocumented, unknown) = differences(&code, &docs);
    assert_eq!(undocumented, vec!["hoe.index_modulation".to_string()]);
    assert_eq!(unknown, vec!["plate.made_up_mm".to_string()]);

    let rows = doc_rows(
        "| key | meaning | unit | default |\n| --- | --- | --- | --- |\n\
         | `plate.thickness_mm` | w | mm | `2.5` |\n| `not a key` | x | | |\n",
    );
    assert_eq!(rows.len(), 1);
    let cell = rows["plate.thickness_mm"].clone().unwrap();
    assert!(!default_matches(&cell, &toml::Value::Float(2.0)));
    assert!(default_matches(&cell, &toml::Value::Float(2.5)));
    assert!(default_matches(
        "`[440, 440]`",
        &toml::Value::Array(vec![440.into(), 440.into()])
    ));
    assert!(
        !default_matches("`2`", &toml::Value::Float(2.0)),
        "2 and 2.0 are different TOML"
    );
}

/// The command reference `docs/cli.md` against the binary: every option a command's `--help`
/// lists appears in that command's section (`## \`stscam NAME\``; subcommands such as
/// `bench render` and `dataset merge` in their parent's section).
#[test]
fn every_command_and_option_is_in_cli_md() {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/cli.md"))
        .expect("docs/cli.md is readable");
    let mut missing = Vec::new();
    for command in commands(&[]) {
        let section = cli_section(&doc, &command[0]);
        let Some(section) = section else {
            missing.push(format!("no section \"## `stscam {}`\"", command[0]));
            continue;
        };
        for option in options(&command) {
            if !section.contains(&option) {
                missing.push(format!("stscam {} {option}", command.join(" ")));
            }
        }
    }
    assert!(missing.is_empty(), "docs/cli.md lacks: {missing:?}");
}

/// The help text of `stscam ARGS… --help`.
fn help(args: &[String]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(args)
        .arg("--help")
        .output()
        .expect("stscam runs");
    assert!(out.status.success(), "stscam {args:?} --help failed");
    String::from_utf8(out.stdout).expect("help is UTF-8")
}

/// Every leaf command (as its argument words) below `prefix`, from the "Commands:" lists.
fn commands(prefix: &[String]) -> Vec<Vec<String>> {
    let text = help(prefix);
    let mut subs = Vec::new();
    let mut in_list = false;
    for line in text.lines() {
        if line.starts_with("Commands:") {
            in_list = true;
            continue;
        }
        if in_list {
            let Some(name) = line
                .strip_prefix("  ")
                .and_then(|l| l.split_whitespace().next())
            else {
                break;
            };
            if line.starts_with("   ") || name == "help" {
                continue;
            }
            let mut c = prefix.to_vec();
            c.push(name.to_string());
            subs.push(c);
        }
    }
    let mut all = Vec::new();
    if !prefix.is_empty() {
        all.push(prefix.to_vec());
    }
    for c in subs {
        all.extend(commands(&c));
    }
    all
}

/// The `--long` options of a command's help, `--help` and `--version` left out.
fn options(command: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    for line in help(command).lines() {
        let t = line.trim_start();
        let t = t.strip_prefix("-h, ").unwrap_or(t);
        let t = if t.len() > 4 && t.starts_with('-') && t.as_bytes()[2] == b',' {
            t[4..].trim_start()
        } else {
            t
        };
        if let Some(rest) = t.strip_prefix("--") {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
                .collect();
            if !name.is_empty() && name != "help" && name != "version" {
                out.push(format!("--{name}"));
            }
        }
    }
    out.sort();
    out.dedup();
    out
}

/// The text of `## \`stscam NAME\`` (or a heading starting so) up to the next `## `.
fn cli_section<'a>(doc: &'a str, name: &str) -> Option<&'a str> {
    let heading = format!("## `stscam {name}");
    let start = doc.find(&heading)?;
    let rest = &doc[start + heading.len()..];
    Some(rest.find("\n## ").map_or(rest, |end| &rest[..end]))
}

/// The command check sees every command, and a section without an option is reported.
#[test]
fn the_command_check_sees_every_command_and_can_fail() {
    let all: Vec<String> = commands(&[]).iter().map(|c| c.join(" ")).collect();
    for c in [
        "render",
        "matrix",
        "dataset merge",
        "bench render",
        "validate analytic",
    ] {
        assert!(all.iter().any(|a| a == c), "{c} not enumerated: {all:?}");
    }
    let render = options(&["render".to_string()]);
    assert!(render.contains(&"--spectral".to_string()) && render.contains(&"--set".to_string()));
    let doc = "## `stscam render`\n\n`--set` `--out`\n\n## `stscam info`\n\n`--spectral`\n";
    let section = cli_section(doc, "render").unwrap();
    assert!(section.contains("--set") && !section.contains("--spectral"));
}

/// The dataset recipe reference (`docs/datasets.md`, "Recipe keys") against the code: every
/// field serde accepts in every recipe table (top level, `[scene]`, `[split]`, `[objects]`,
/// each generator of `[[objects.sources]]`, `[[vary]]`, `[depth]`, `[camera_table]`) is in a
/// table row of that section. The fields come from serde's own "unknown field" message for a
/// made-up field put into each table, so a new recipe key without a row fails here; a key
/// name that is not in the section (checked with a made-up name) fails too.
#[test]
fn every_recipe_key_is_in_the_datasets_reference() {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/datasets.md"))
        .expect("docs/datasets.md is readable");
    let section = doc
        .split("## Recipe keys")
        .nth(1)
        .and_then(|s| s.split("\n## ").next())
        .expect("docs/datasets.md has a Recipe keys section");
    let rows: BTreeSet<String> = section
        .lines()
        .filter(|l| l.starts_with("| `"))
        .flat_map(|l| {
            // The first cell may name several keys: `train`, `val`, `test`.
            let cell = l.split('|').nth(1).unwrap_or("");
            cell.split('`')
                .skip(1)
                .step_by(2)
                .map(str::to_string)
                .collect::<Vec<_>>()
        })
        .collect();
    let base = "name = \"t\"\nseed = 1\nsamples = 10\nmode = \"render\"\n\
                [split]\ntrain = 0.8\nval = 0.1\ntest = 0.1\n";
    let objects =
        |source: &str| format!("[objects]\nsize_px = 64\n[[objects.sources]]\n{source}\n");
    let probe = format!("{PROBE} = 0");
    let cases: Vec<(&str, String)> = vec![
        ("top level", format!("{probe}\n{base}{}", objects("generator = \"shapes\""))),
        ("[scene]", format!("{base}[scene]\n{probe}\n{}", objects("generator = \"shapes\""))),
        ("[split]", format!("{base}{probe}\n{}", objects("generator = \"shapes\""))),
        (
            "[objects]",
            format!("{base}[objects]\n{probe}\nsize_px = 64\n[[objects.sources]]\ngenerator = \"shapes\"\n"),
        ),
        ("[[vary]]", format!("{base}{}[[vary]]\n{probe}\n", objects("generator = \"shapes\""))),
        ("[depth]", format!("{base}{}[depth]\n{probe}\n", objects("generator = \"shapes\""))),
        (
            "[camera_table]",
            format!("{base}{}[camera_table]\n{probe}\n", objects("generator = \"shapes\"")),
        ),
    ]
    .into_iter()
    .chain(
        ["glyphs", "shapes", "siemens", "bars", "smooth", "images", "meshes"]
            .into_iter()
            .map(|g| ("[[objects.sources]]", format!("{base}{}", objects(&format!("generator = \"{g}\"\n{probe}"))))),
    )
    .collect();
    let mut missing = Vec::new();
    for (table, text) in &cases {
        let (_, msg) = stscam::dataset::recipe::parse_recipe(text)
            .err()
            .unwrap_or_else(|| panic!("{table}: a made-up key was accepted"));
        let fields = parse_unknown_field(&msg)
            .unwrap_or_else(|| panic!("{table}: not an unknown-field message: {msg}"));
        for f in fields {
            // A table is documented by its own heading (`[scene]`, `[[vary]]`).
            let heading = [format!("`[{f}]`"), format!("`[[{f}]]`")];
            if !rows.contains(&f) && !heading.iter().any(|h| section.contains(h.as_str())) {
                missing.push(format!("{table} {f}"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "recipe keys without a row in docs/datasets.md: {missing:?}"
    );
    // The check can fail: a made-up name is not in the section.
    assert!(!rows.contains(PROBE));
}
