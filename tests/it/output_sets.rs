//! Issue 29, item 2: a run's output set (capture, frontal, depth, mask, sidecar) appears whole
//! or not at all, whatever else writes to the folder. Two concurrent renders into one folder
//! leave the complete set of one of them; a SIGKILL before or inside the commit leaves the
//! previous set or the new one, never a mix, with no recovery (issue 45, item 4: the commit is
//! one directory exchange); a SIGKILL after the data are written but before the
//! commit leaves the previous set and nothing else (the data sit in unnamed files); links
//! planted at the output names or the lock are not followed. `STSCAM_TEST_COMMIT_DELAY_MS` (sim/io/src/atomic.rs) slows the commit to hit its
//! windows.
//!
//! Every fixture is written into a temporary folder by the test itself.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::stscam_ok;

const SCENE: &str = "[display]\nenabled = false\n[[object]]\nmesh = \"quad\"\nposition_mm = [0.0, 0.0, -400.0]\n[[light]]\nkind = \"environment\"\nscale = 0.5\n";

fn args<'a>(scene: &'a str, out: &'a str, seed: &'a str) -> Vec<&'a str> {
    vec![
        "render",
        scene,
        "--out",
        out,
        "--spp",
        "2",
        "--seed",
        seed,
        "--set",
        "sensor.crop_px=[24,24]",
        "--frontal-px",
        "24x24",
    ]
}

fn spawn(scene: &Path, out: &Path, seed: &str, delay_ms: u64) -> Child {
    Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(args(scene.to_str().unwrap(), out.to_str().unwrap(), seed))
        .env("STSCAM_TEST_COMMIT_DELAY_MS", delay_ms.to_string())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// Every entry of a folder (names starting with '.' included), with its bytes.
fn entries(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            let bytes = std::fs::read(e.path()).unwrap_or_default();
            (e.file_name().to_string_lossy().into_owned(), bytes)
        })
        .collect()
}

/// The reference sets of seeds 1 and 2, rendered alone.
fn references(d: &Path, scene: &Path) -> [BTreeMap<String, Vec<u8>>; 2] {
    ["1", "2"].map(|seed| {
        let out = d.join(format!("ref{seed}"));
        stscam_ok(&args(scene.to_str().unwrap(), out.to_str().unwrap(), seed));
        entries(&out)
    })
}

/// The folder holds exactly one reference set (capture.json compared by its seed, the other
/// files byte for byte) and nothing else; returns which.
fn which_set(dir: &Path, refs: &[BTreeMap<String, Vec<u8>>; 2]) -> usize {
    let got = entries(dir);
    let names: Vec<_> = got.keys().cloned().collect();
    let want: Vec<_> = refs[0].keys().cloned().collect();
    assert_eq!(names, want, "the folder holds other files than one set");
    let seed = |b: &[u8]| serde_json::from_slice::<serde_json::Value>(b).unwrap()["seed"].clone();
    let matches = |r: &BTreeMap<String, Vec<u8>>| {
        got.iter().all(|(n, b)| {
            if n == "capture.json" {
                seed(b) == seed(&r[n])
            } else {
                *b == r[n]
            }
        })
    };
    match (matches(&refs[0]), matches(&refs[1])) {
        (true, false) => 0,
        (false, true) => 1,
        _ => panic!("the folder holds a mix of two runs' files"),
    }
}

fn wait(mut c: Child) -> bool {
    c.wait().unwrap().success()
}

/// Two renders into one folder, one slowed at its commit: both succeed and the folder holds the
/// complete set of one of them (the one that committed last), whichever starts first.
#[test]
fn concurrent_renders_leave_one_complete_set() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("s.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let refs = references(d, &scene);
    assert_ne!(
        refs[0]["capture.exr"], refs[1]["capture.exr"],
        "the seeds must differ"
    );
    let out = d.join("out");
    for (slow, fast) in [("1", "2"), ("2", "1")] {
        let a = spawn(&scene, &out, slow, 150);
        std::thread::sleep(Duration::from_millis(30));
        let b = spawn(&scene, &out, fast, 0);
        assert!(wait(a) && wait(b));
        which_set(&out, &refs);
    }
}

/// SIGKILL at several points of a render that replaces a complete set: during the render
/// (before its commit), and at pseudo-random instants *inside* the commit (slowed by the test
/// hook to 150 ms per linked file and before the exchange, so that it spans about 1.3 s). Every
/// trial shows, without any recovery, the old set or the new one, never a mix: the commit
/// builds the new folder beside the old one and swaps them with one
/// `renameat2(RENAME_EXCHANGE)`. What a killed run leaves (an unfinished or old sibling
/// folder, hidden, beside `--out`) is removed by the next writer or `recover_folder`.
#[test]
fn sigkill_leaves_the_old_or_the_new_set_without_recovery() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("s.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let refs = references(d, &scene);
    let out = d.join("out");
    // What a reader sees: the set's names (a killed run's stale lock `.stscam-commit` may sit
    // in the folder until the next writer takes it over).
    let visible = |dir: &Path| -> BTreeMap<String, Vec<u8>> {
        entries(dir)
            .into_iter()
            .filter(|(n, _)| !n.starts_with('.'))
            .collect()
    };
    let siblings = || -> Vec<PathBuf> {
        std::fs::read_dir(d)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| {
                e.file_name()
                    .to_string_lossy()
                    .starts_with(".out.stscam-swap-")
            })
            .map(|e| e.path())
            .collect()
    };
    // (a) Killed early (loading or tracing): the previous set stays.
    for after_ms in [5, 40, 120] {
        let _ = std::fs::remove_dir_all(&out);
        stscam_ok(&args(scene.to_str().unwrap(), out.to_str().unwrap(), "1"));
        let mut c = spawn(&scene, &out, "2", 0);
        std::thread::sleep(Duration::from_millis(after_ms));
        c.kill().unwrap();
        let _ = c.wait();
        let set = which_set_visible(&visible(&out), &refs);
        stscam::io::atomic::recover_folder(&out).unwrap();
        assert_eq!(which_set(&out, &refs), set, "killed after {after_ms} ms");
    }
    // (b) Killed inside the commit, at instants spread over it (a fixed pseudo-random draw).
    let mut seen = [0usize; 2];
    let mut x: u64 = 0x5eed;
    for trial in 0..8 {
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let at_ms = (x >> 33) % 1400;
        let _ = std::fs::remove_dir_all(&out);
        stscam_ok(&args(scene.to_str().unwrap(), out.to_str().unwrap(), "1"));
        assert!(siblings().is_empty(), "a sibling left before trial {trial}");
        let mut c = spawn(&scene, &out, "2", 150);
        let start = Instant::now();
        // The commit starts when the sibling folder appears (under the lock, data written).
        while siblings().is_empty() {
            assert!(start.elapsed() < Duration::from_secs(60), "no commit seen");
            assert!(
                c.try_wait().unwrap().is_none(),
                "the run ended before its commit was seen"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
        std::thread::sleep(Duration::from_millis(at_ms));
        c.kill().unwrap();
        let _ = c.wait();
        // No recovery: what a reader sees right away.
        let set = which_set_visible(&visible(&out), &refs);
        seen[set] += 1;
        eprintln!("trial {trial}: killed {at_ms} ms into the commit: set {set}");
        stscam::io::atomic::recover_folder(&out).unwrap();
        assert!(siblings().is_empty(), "recover_folder left a sibling");
        assert_eq!(
            which_set(&out, &refs),
            set,
            "the recovery changed the visible set"
        );
    }
    // The draw spans the commit: both outcomes occur.
    assert!(seen[0] > 0 && seen[1] > 0, "{seen:?}");
}

/// SIGKILL while the run's data are written but not yet committed (the writer is held by the
/// test hook before it takes the lock, with its files open): the folder holds exactly the
/// previous set, with no temporary or staging name, without any recovery. A writer that named
/// its files before the commit (the fallback for file systems without unnamed files) fails
/// this test.
#[cfg(target_os = "linux")]
#[test]
fn sigkill_before_the_commit_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("s.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let refs = references(d, &scene);
    let out = d.join("out");
    stscam_ok(&args(scene.to_str().unwrap(), out.to_str().unwrap(), "1"));
    if !stscam::io::atomic::unnamed_files_supported(&out) {
        // The documented fallback (named staging) cannot give this guarantee.
        eprintln!("skipped: the test folder's file system has no O_TMPFILE");
        return;
    }
    let mut c = spawn(&scene, &out, "2", 3000);
    let fds = PathBuf::from(format!("/proc/{}/fd", c.id()));
    let start = Instant::now();
    // Wait until the writer holds every one of its files open, unnamed, in `out`.
    loop {
        let unnamed = std::fs::read_dir(&fds)
            .map(|it| {
                it.filter_map(|e| e.ok())
                    .filter_map(|e| std::fs::read_link(e.path()).ok())
                    .filter(|t| t.starts_with(&out) && t.to_string_lossy().ends_with("(deleted)"))
                    .count()
            })
            .unwrap_or(0);
        if unnamed == refs[0].len() {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the writer never held its files"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    c.kill().unwrap();
    let _ = c.wait();
    assert_eq!(which_set(&out, &refs), 0, "the previous set was not kept");
}

/// Which reference a folder's visible files match (capture.json by seed); 2 if none.
fn which_set_visible(
    v: &BTreeMap<String, Vec<u8>>,
    refs: &[BTreeMap<String, Vec<u8>>; 2],
) -> usize {
    let seed = |b: &[u8]| serde_json::from_slice::<serde_json::Value>(b).unwrap()["seed"].clone();
    for (i, r) in refs.iter().enumerate() {
        if v.len() == r.len()
            && v.iter().all(|(n, b)| {
                r.get(n).is_some_and(|rb| {
                    if n == "capture.json" {
                        seed(b) == seed(rb)
                    } else {
                        b == rb
                    }
                })
            })
        {
            return i;
        }
    }
    panic!(
        "the visible files are not one complete set: {:?}",
        v.keys().collect::<Vec<_>>()
    );
}

/// Links planted at every output name and at the commit lock, pointing outside `--out`: the
/// render replaces the links by its own files and no file outside `--out` changes.
#[test]
fn planted_links_are_not_followed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("s.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let refs = references(d, &scene);
    let out = d.join("out");
    std::fs::create_dir(&out).unwrap();
    let outside = d.join("outside");
    std::fs::create_dir(&outside).unwrap();
    let mut names: Vec<String> = refs[0].keys().cloned().collect();
    names.push(".stscam-commit".into());
    for n in &names {
        let victim = outside.join(n.trim_start_matches('.'));
        std::fs::write(&victim, b"precious").unwrap();
        std::os::unix::fs::symlink(&victim, out.join(n)).unwrap();
    }
    stscam_ok(&args(scene.to_str().unwrap(), out.to_str().unwrap(), "1"));
    for (n, b) in entries(&outside) {
        assert_eq!(b, b"precious", "{n} outside --out was changed");
    }
    assert_eq!(which_set(&out, &refs), 0);
    for n in refs[0].keys() {
        assert!(
            std::fs::symlink_metadata(out.join(n)).unwrap().is_file(),
            "{n} is still a link"
        );
    }
}
