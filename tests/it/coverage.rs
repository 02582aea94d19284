//! Which object rows and columns the crop sees (`stscam info`'s `object_coverage`): the paper
//! scene's centred crop misses the strong replicas of the 64×64 target's bottom rows 60–63, a
//! crop moved 48 px down sees them all, and `matrix` warns when part of the object is unseen.

use crate::common::{stscam, stscam_json};

fn unseen(json: &serde_json::Value, key: &str) -> Vec<u64> {
    json["object_coverage"][key]
        .as_array()
        .expect(key)
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect()
}

#[test]
fn info_reports_the_rows_the_crop_does_not_see() {
    let centred = stscam_json(&["info", "--json"]);
    assert_eq!(unseen(&centred, "rows_unseen"), vec![60, 61, 62, 63]);
    assert!(unseen(&centred, "cols_unseen").is_empty());
    assert_eq!(
        centred["object_coverage"]["object_px"],
        serde_json::json!([64, 64])
    );
    let framed = stscam_json(&["info", "--json", "--set", "sensor.crop_offset_px=[0,-48]"]);
    assert!(unseen(&framed, "rows_unseen").is_empty());
    assert!(unseen(&framed, "cols_unseen").is_empty());
    // A crop moved far up loses the top rows instead; a narrow crop loses side columns.
    let up = stscam_json(&["info", "--json", "--set", "sensor.crop_offset_px=[0,40]"]);
    let rows = unseen(&up, "rows_unseen");
    assert!(rows.contains(&63) && !rows.contains(&0), "{rows:?}");
    let narrow = stscam_json(&[
        "info",
        "--json",
        "--set",
        "sensor.crop_px=[120,440]",
        "--set",
        "sensor.crop_offset_px=[0,-48]",
    ]);
    let cols = unseen(&narrow, "cols_unseen");
    assert!(
        cols.contains(&0) && cols.contains(&63) && !cols.contains(&32),
        "{cols:?}"
    );
}

#[test]
fn matrix_warns_when_part_of_the_object_is_unseen() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m");
    let o = stscam(&["matrix", "--spp", "1", "--out", out.to_str().unwrap()]);
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("warning: object rows 60-63 (of 0-63)"),
        "{err}"
    );
    let o = stscam(&[
        "matrix",
        "--spp",
        "1",
        "--out",
        dir.path().join("m2").to_str().unwrap(),
        "--set",
        "sensor.crop_offset_px=[0,-48]",
    ]);
    assert!(o.status.success());
    assert!(!String::from_utf8_lossy(&o.stderr).contains("warning: object"));
}
