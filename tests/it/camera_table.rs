//! The camera-side table (`render --camera-table`): a render that takes its camera side from a
//! per-design table estimates the same image as the direct estimator (4-SEM rule on per-pixel
//! differences, and a 3 % too bright table render must fail it) on the paper scene, eye
//! contact, gesture and a mesh scene through the waveguide; the table is the same for any
//! thread count, survives its file, is rebuilt when the file is damaged, and is keyed by the
//! design only.

use std::path::Path;

use stscam::render::camera_table::{TableSettings, build, design_key, render_with_table};
use stscam::render::table_file::{CachedTable, TableOrigin, cached, read, to_bytes};
use stscam::render::{RenderSettings, render};
use stscam::system::System;

use crate::common::{crop_system, mean_sem, stscam, with_threads};

/// The table render (table seed 11, `paths` user-side paths, render seed 12) against the
/// direct estimator (`spp`, seed 13): per-pixel differences within 4 standard errors of zero,
/// and the table render made 3 % brighter outside them. Returns (relative mean difference,
/// its standard error).
fn check_unbiased(name: &str, sys: &System, ts: TableSettings, paths: u32, spp: u32) -> (f64, f64) {
    let dir = tempfile::tempdir().unwrap();
    let (table, info) = CachedTable::load_or_build(sys, &ts, dir.path(), false).expect("table");
    assert!(info.entries > 0);
    let tabled = table
        .render(sys, &RenderSettings::lattice(paths, 12, false))
        .expect("table render");
    let direct = render(sys, &RenderSettings::lattice(spp, 13, false));
    let (a, b): (Vec<f64>, Vec<f64>) = tabled
        .channels
        .iter()
        .flatten()
        .zip(direct.channels.iter().flatten())
        .map(|(&x, &y)| (f64::from(x), f64::from(y)))
        .unzip();
    let level = b.iter().sum::<f64>() / b.len() as f64;
    assert!(level > 0.0);
    let diff = |scale: f64| {
        let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| scale * x - y).collect();
        let (m, sem) = mean_sem(&d);
        (m / level, sem / level)
    };
    let (m, sem) = diff(1.0);
    assert!(m.abs() < 4.0 * sem, "table vs direct: {m} ± {sem}");
    let (m3, sem3) = diff(1.03);
    eprintln!(
        "{name}: table − direct {:+.3} % ± {:.3} % (3 % brighter: {:+.3} %)",
        100.0 * m,
        100.0 * sem,
        100.0 * m3
    );
    assert!(
        m3.abs() > 4.0 * sem3,
        "3 % too bright must fail: {m3} ± {sem3}"
    );
    (m, sem)
}

const SMALL: TableSettings = TableSettings {
    spp: 64,
    reps: 16,
    seed: 11,
};

#[test]
fn table_render_is_unbiased_on_eye_contact() {
    let sys = crop_system("scenes/eye-contact.toml", 40, &[]);
    check_unbiased("eye contact", &sys, SMALL, 32, 64);
}

#[test]
fn table_render_is_unbiased_on_gesture() {
    let sys = crop_system("scenes/gesture.toml", 40, &[]);
    check_unbiased("gesture", &sys, SMALL, 32, 64);
}

#[test]
fn table_render_is_unbiased_on_a_mesh_through_the_waveguide() {
    let sys = crop_system("validation/mitsuba/mesh-waveguide.toml", 40, &[]);
    check_unbiased("mesh through the waveguide", &sys, SMALL, 32, 64);
}

/// The paper's display scene (a white target, so that every pixel carries signal): its table
/// is H at the table's samples, and a target's capture H·f + offset.
#[test]
fn table_render_is_unbiased_on_the_paper_scene() {
    let sys = crop_system("scenes/paper-2022.toml", 40, &["display.image=white"]);
    assert!(sys.world.is_none());
    let ts = TableSettings {
        spp: 256,
        reps: 32,
        seed: 11,
    };
    check_unbiased("paper scene", &sys, ts, 1, 256);
}

/// One and two threads draw the same table and render the same image from it.
#[test]
fn table_and_its_render_are_the_same_for_any_thread_count() {
    let sys = crop_system("scenes/eye-contact.toml", 24, &[]);
    let run = |threads: usize| {
        with_threads(threads, || {
            let t = build(&sys, &SMALL, false).unwrap();
            let img = render_with_table(&sys, &RenderSettings::lattice(8, 3, false), &t)
                .unwrap()
                .channels;
            (to_bytes(&t), img)
        })
    };
    assert!(run(1) == run(2));
}

/// The file round trip, the cache's read / build / rebuild, and the key: a damaged file is
/// rebuilt, another design gets another file, a light does not change the key.
#[test]
fn table_file_round_trip_and_cache() {
    let dir = tempfile::tempdir().unwrap();
    let sys = crop_system("scenes/eye-contact.toml", 16, &[]);
    let ts = TableSettings {
        spp: 16,
        reps: 8,
        seed: 5,
    };
    let first = cached(&sys, &ts, dir.path(), false).unwrap();
    assert_eq!(first.origin, TableOrigin::Built);
    let again = cached(&sys, &ts, dir.path(), false).unwrap();
    assert_eq!(again.origin, TableOrigin::Read);
    assert_eq!(to_bytes(&again.table), to_bytes(&first.table));
    // Other table settings are refused by the reader.
    assert!(read(&first.path, &sys, &TableSettings { seed: 6, ..ts }).is_err());
    // One flipped bit in the middle: the check word catches it and the cache rebuilds.
    let mut bytes = std::fs::read(&first.path).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x10;
    std::fs::write(&first.path, &bytes).unwrap();
    assert!(read(&first.path, &sys, &ts).is_err());
    let rebuilt = cached(&sys, &ts, dir.path(), false).unwrap();
    assert_eq!(rebuilt.origin, TableOrigin::Rebuilt);
    assert_eq!(to_bytes(&rebuilt.table), to_bytes(&first.table));
    // A truncated file is refused before anything is allocated for it.
    std::fs::write(&first.path, &bytes[..bytes.len() - 3]).unwrap();
    assert!(read(&first.path, &sys, &ts).is_err());
    // A file resealed with a valid check word around a NaN, an infinite or a huge value (or a
    // wavelength out of range) is refused by its values and the cache rebuilds; resealed
    // unchanged it is read (the reseal is right, so the check can fail).
    let rebuilt = cached(&sys, &ts, dir.path(), false).unwrap();
    assert_eq!(rebuilt.origin, TableOrigin::Rebuilt);
    let good = std::fs::read(&rebuilt.path).unwrap();
    let words = good.len() / 8;
    let word = |b: &[u8], i: usize| u64::from_le_bytes(b[8 * i..8 * i + 8].try_into().unwrap());
    let n_reps = word(&good, 1 + 8) as usize;
    let pixels = words - 13 - 9 * n_reps;
    let first_rep = 1 + 10 + pixels + 1;
    let reseal = |b: &mut Vec<u8>| {
        let body = b.len() - 8;
        let d = <sha2::Sha256 as sha2::Digest>::digest(&b[..body]);
        b[body..].copy_from_slice(&d[..8]);
    };
    let mut same = good.clone();
    reseal(&mut same);
    assert!(same == good, "the reseal is not the file's own check word");
    for (slot, v) in [
        (6, f64::NAN),
        (7, f64::INFINITY),
        (6, 1e38),
        (5, 1e9),
        (0, f64::NAN),
    ] {
        let mut b = good.clone();
        let i = first_rep + 9 * (n_reps / 2) + slot;
        b[8 * i..8 * i + 8].copy_from_slice(&v.to_bits().to_le_bytes());
        reseal(&mut b);
        std::fs::write(&rebuilt.path, &b).unwrap();
        let e = read(&rebuilt.path, &sys, &ts).err().expect("refused");
        assert!(e.to_string().contains("out of range"), "{e}");
        let again = cached(&sys, &ts, dir.path(), false).unwrap();
        assert_eq!(again.origin, TableOrigin::Rebuilt, "slot {slot} = {v}");
    }
    // The key follows the design, not the scene's user side.
    let thicker = crop_system("scenes/eye-contact.toml", 16, &["plate.thickness_mm=3.2"]);
    assert_ne!(design_key(&thicker), design_key(&sys));
    let brighter = crop_system("scenes/eye-contact.toml", 16, &["light.0.scale=0.8"]);
    assert_eq!(design_key(&brighter), design_key(&sys));
    // A table of another design is not used.
    let t = build(&sys, &ts, false).unwrap();
    assert!(render_with_table(&thicker, &RenderSettings::lattice(4, 1, false), &t).is_err());
    // A display-only scene's table (H) is cached the same way: built, read, rebuilt when
    // damaged, and shared by every target on the display.
    let paper = crop_system("scenes/paper-2022.toml", 16, &[]);
    let set = RenderSettings::lattice(1, 1, false);
    let (t1, i1) = CachedTable::load_or_build(&paper, &ts, dir.path(), false).unwrap();
    assert_eq!((i1.kind, i1.origin), ("matrix", TableOrigin::Built));
    let (t2, i2) = CachedTable::load_or_build(&paper, &ts, dir.path(), false).unwrap();
    assert_eq!(i2.origin, TableOrigin::Read);
    assert_eq!(
        t1.render(&paper, &set).unwrap().channels,
        t2.render(&paper, &set).unwrap().channels
    );
    let mut bytes = std::fs::read(&i1.file).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x01;
    std::fs::write(&i1.file, &bytes).unwrap();
    let (_, i3) = CachedTable::load_or_build(&paper, &ts, dir.path(), false).unwrap();
    assert_eq!(i3.origin, TableOrigin::Rebuilt);
    let other = crop_system("scenes/paper-2022.toml", 16, &["display.image=siemens:16"]);
    let (_, i4) = CachedTable::load_or_build(&other, &ts, dir.path(), false).unwrap();
    assert_eq!((i4.origin, &i4.file), (TableOrigin::Read, &i1.file));
}

/// The CLI: the second render reads the table the first one wrote and gives the same capture;
/// `--spectral` is refused with exit 2 before any table is drawn.
#[test]
fn cli_writes_then_reads_the_table() {
    let dir = tempfile::tempdir().unwrap();
    let d = |s: &str| dir.path().join(s).to_string_lossy().into_owned();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/eye-contact.toml");
    let scene = scene.to_string_lossy();
    let args = |out: &str| {
        vec![
            "render".to_string(),
            scene.to_string(),
            "--set".into(),
            "sensor.crop_px=16".into(),
            "--set".into(),
            "sensor.pitch_um=132".into(),
            "--spp".into(),
            "8".into(),
            "--camera-table".into(),
            d("cache"),
            "--table-spp".into(),
            "16".into(),
            "--out".into(),
            d(out),
        ]
    };
    let run = |out: &str, extra: &[&str]| {
        let mut a = args(out);
        a.extend(extra.iter().map(|s| s.to_string()));
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        stscam(&a)
    };
    // A table whose drawing would gather 10⁹ samples of a pixel per thread (issue 45: an
    // abort at 4.3 GB): refused in one line naming the flag, before anything is written.
    let mut a = args("h");
    let at = a.iter().position(|s| s == "--table-spp").unwrap() + 1;
    a[at] = "1000000000".into();
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    let huge = stscam(&a);
    assert_eq!(huge.status.code(), Some(2));
    let err = String::from_utf8_lossy(&huge.stderr);
    assert!(
        err.contains("--table-spp") && err.lines().count() == 1,
        "{err}"
    );
    assert!(!dir.path().join("cache").exists() && !dir.path().join("h").exists());
    let spectral = run("s", &["--spectral"]);
    assert_eq!(spectral.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&spectral.stderr).contains("--spectral"));
    assert!(!dir.path().join("cache").exists());
    // A cache path that is a file: bad input, refused before any table is drawn.
    std::fs::write(dir.path().join("file"), b"x").unwrap();
    let mut a = args("f");
    let at = a.iter().position(|s| s == "--camera-table").unwrap() + 1;
    a[at] = d("file");
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    let o = stscam(&a);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("not a directory"));
    for out in ["a", "b"] {
        let o = run(out, &[]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let side = |out: &str| -> serde_json::Value {
        serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(out).join("capture.json")).unwrap(),
        )
        .unwrap()
    };
    assert_eq!(side("a")["camera_table"]["origin"], "built");
    assert_eq!(side("b")["camera_table"]["origin"], "read");
    assert_eq!(
        std::fs::read(dir.path().join("a/capture.exr")).unwrap(),
        std::fs::read(dir.path().join("b/capture.exr")).unwrap()
    );
}
