//! The workspace's crate graph against the one documented in docs/design.md ("Crates"): every
//! member is listed there, and every dependency of a member on another member (normal, dev or
//! build) is one the table allows, so no change can add an upward edge or a loop without
//! changing the documented design first. The members' dependencies come from `cargo metadata`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

/// `crate → crates it may depend on`, read from the "Crates" table of docs/design.md: a row
/// `| `stscam-x` | role | `stscam-a`, `stscam-b` |` (a dash for none).
fn documented() -> BTreeMap<String, BTreeSet<String>> {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/design.md"))
            .expect("docs/design.md");
    let section = text
        .split("\n## Crates")
        .nth(1)
        .expect("a \"## Crates\" section in docs/design.md");
    let section = section.split("\n## ").next().unwrap_or(section);
    let mut out = BTreeMap::new();
    for line in section.lines().filter(|l| l.starts_with("| `stscam")) {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        let name = cells[1].trim_matches('`').to_string();
        let deps = cells[3]
            .split(',')
            .map(|d| d.trim().trim_matches('`').to_string())
            .filter(|d| d.starts_with("stscam"))
            .collect();
        out.insert(name, deps);
    }
    out
}

/// `member → members it depends on (any kind)`, from `cargo metadata`.
fn actual() -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run cargo metadata");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).expect("metadata json");
    let members: BTreeSet<String> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap().to_string())
        .collect();
    meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .map(|d| d["name"].as_str().unwrap().to_string())
                .filter(|d| members.contains(d))
                .collect();
            (p["name"].as_str().unwrap().to_string(), deps)
        })
        .collect()
}

/// What is wrong with `actual` against `allowed`: members missing from the table, edges it
/// does not allow, and a table that is not a one-way graph.
fn violations(
    allowed: &BTreeMap<String, BTreeSet<String>>,
    actual: &BTreeMap<String, BTreeSet<String>>,
) -> Vec<String> {
    let mut v = Vec::new();
    for (name, deps) in actual {
        let Some(ok) = allowed.get(name) else {
            v.push(format!("{name} is not in docs/design.md's table"));
            continue;
        };
        for d in deps.difference(ok) {
            v.push(format!(
                "{name} depends on {d}, which the table does not allow"
            ));
        }
    }
    // The table itself points one way: repeatedly remove crates with no remaining edges.
    let mut left = allowed.clone();
    while !left.is_empty() {
        let leaves: Vec<String> = left
            .iter()
            .filter(|(_, d)| d.iter().all(|x| !left.contains_key(x)))
            .map(|(k, _)| k.clone())
            .collect();
        if leaves.is_empty() {
            v.push(format!(
                "the table has a loop among {:?}",
                left.keys().collect::<Vec<_>>()
            ));
            break;
        }
        for l in leaves {
            left.remove(&l);
        }
    }
    v
}

#[test]
fn the_crate_graph_is_the_documented_one() {
    let (allowed, actual) = (documented(), actual());
    assert!(actual.len() >= 11, "members: {:?}", actual.keys());
    assert_eq!(
        allowed.keys().collect::<BTreeSet<_>>(),
        actual.keys().collect::<BTreeSet<_>>(),
        "docs/design.md's table and the workspace list the same crates"
    );
    let v = violations(&allowed, &actual);
    assert!(v.is_empty(), "{v:#?}");
    // Recon never sees the tracer, kernels never see scenes or files.
    assert!(!actual["stscam-recon"].contains("stscam-tracer"));
    assert!(!actual["stscam-optics"].contains("stscam-scene"));
    assert!(!actual["stscam-optics"].contains("stscam-io"));
}

/// The check can fail: an upward edge (optics on the scene), a loop in the table and an
/// undocumented crate are each reported.
#[test]
fn the_layer_check_can_fail() {
    let allowed = documented();
    let mut up = actual();
    up.get_mut("stscam-optics")
        .unwrap()
        .insert("stscam-scene".into());
    assert_eq!(
        violations(&allowed, &up),
        ["stscam-optics depends on stscam-scene, which the table does not allow"]
    );
    let mut looped = allowed.clone();
    looped
        .get_mut("stscam-base")
        .unwrap()
        .insert("stscam-cli".into());
    assert!(violations(&looped, &actual())[0].starts_with("the table has a loop"));
    let mut extra = actual();
    extra.insert("stscam-new".into(), BTreeSet::new());
    assert_eq!(
        violations(&allowed, &extra),
        ["stscam-new is not in docs/design.md's table"]
    );
}
