//! OBJ/MTL files as Windows tools write them: texture paths with backslashes and options
//! before the name, and Latin-1 bytes in the OBJ and MTL text (material and texture names).
//! Each test writes a quad, an MTL and a uniform 2×2 PNG, and checks from the frontal image that
//! the texture was applied: a red texture makes the quad red-dominant (mean R > 3 × mean G with
//! the rgb-bayer sensor) where the untextured white quad has R/G < 1.5.

use std::path::Path;

use super::common::stscam;

/// A 2×2 PNG of one sRGB colour (16 bit).
fn png(rgb: [u16; 3]) -> Vec<u8> {
    let px: Vec<u16> = (0..4).flat_map(|_| rgb).collect();
    stscam::io::encode_png16(2, 2, 3, &px, stscam::io::PngTransfer::Srgb).unwrap()
}

const RED: [u16; 3] = [65535, 0, 0];
const WHITE: [u16; 3] = [65535; 3];

/// A unit quad with texture coordinates using material `mat` (raw bytes) of `m.mtl`.
fn quad_obj(mat: &[u8]) -> Vec<u8> {
    let mut o = b"mtllib m.mtl\nusemtl ".to_vec();
    o.extend_from_slice(mat);
    o.extend_from_slice(
        b"\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
          f 1/1 2/2 3/3 4/4\n",
    );
    o
}

/// Mean (R, G, B) of the frontal image (rgb-bayer, 16×16, 8 spp) of `dir/m.obj` filling the
/// frame in a flat white environment.
fn frontal_mean(dir: &Path) -> [f64; 3] {
    let toml = "[display]\nenabled = false\n[sensor]\nresponse = \"rgb-bayer\"\n[[object]]\n\
                mesh = \"m.obj\"\nscale = 200.0\nposition_mm = [0.0, 0.0, -400.0]\n\
                [[light]]\nkind = \"environment\"\nspectrum = \"flat\"\n";
    let p = dir.join("scene.toml");
    std::fs::write(&p, toml).unwrap();
    let sets = [
        "sensor.crop_px=[16,16]".to_string(),
        "sensor.pitch_um=52.8".to_string(),
    ];
    let ls = stscam::scene::load_scene(Some(&p), &sets).unwrap();
    let sys = stscam::system::System::build(&ls).unwrap();
    let f = stscam::world::frontal::render_frontal(&sys, 16, 16, 8, 5).unwrap();
    assert!(f.mask.iter().all(|m| *m == 1), "the quad fills the frame");
    let mean = |ch: &[f32]| ch.iter().map(|v| f64::from(*v)).sum::<f64>() / ch.len() as f64;
    [
        mean(&f.channels[0]),
        mean(&f.channels[1]),
        mean(&f.channels[2]),
    ]
}

/// Writes `m.obj` (material `mat`), `m.mtl` (`mtl`) and the given files into a new folder.
fn case(mat: &[u8], mtl: &[u8], files: &[(&[u8], Vec<u8>)]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("m.obj"), quad_obj(mat)).unwrap();
    std::fs::write(d.join("m.mtl"), mtl).unwrap();
    for (name, bytes) in files {
        let p = d.join(raw_name(name));
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
    dir
}

/// A file name given as raw bytes (Unix; the tests below run there).
fn raw_name(bytes: &[u8]) -> std::path::PathBuf {
    use std::os::unix::ffi::OsStrExt;
    std::path::PathBuf::from(std::ffi::OsStr::from_bytes(bytes))
}

fn is_red(c: [f64; 3]) -> bool {
    c[0] > 3.0 * c[1] && c[0] > 3.0 * c[2]
}

/// Backslash paths (`.\red.png`, `textures\red.png`) and `map_Kd` options before the name
/// (`-s 1 1 1`, `-bm 0.5`) find the texture in the MTL's folder; the untextured quad is not
/// red (so the check can fail), and read as written the backslash names are no files.
#[test]
fn backslash_texture_paths_and_options() {
    let white = frontal_mean(case(b"a", b"newmtl a\nKd 1 1 1\n", &[]).path());
    assert!(white[0] < 1.5 * white[1] && white[0] > 0.0, "{white:?}");
    for spec in [
        r".\red.png",
        r"textures\red.png",
        r".\textures\red.png",
        r"-s 1 1 1 textures\red.png",
        "-bm 0.5 red.png",
        r"C:\Users\someone\maps\red.png",
    ] {
        let mtl = format!("newmtl a\nKd 1 1 1\nmap_Kd {spec}\n");
        let dir = case(
            b"a",
            mtl.as_bytes(),
            &[(b"red.png", png(RED)), (b"textures/red.png", png(RED))],
        );
        let c = frontal_mean(dir.path());
        assert!(is_red(c), "map_Kd {spec}: {c:?}");
        let last = spec.split_whitespace().last().unwrap();
        assert!(!dir.path().join(last).exists() || !last.contains('\\'));
    }
    // A file whose name really contains the backslash is preferred (white, beside a red one).
    let dir = case(
        b"a",
        b"newmtl a\nKd 1 1 1\nmap_Kd textures\\red.png\n",
        &[
            (b"textures\\red.png", png(WHITE)),
            (b"textures/red.png", png(RED)),
        ],
    );
    let c = frontal_mean(dir.path());
    assert!(c[0] < 1.5 * c[1], "literal backslash name: {c:?}");
}

/// Latin-1 bytes (0xEA 'ê') in the material name (OBJ and MTL) and in the texture name: the
/// texture is found whether the file on disk is named by the Latin-1 bytes or in UTF-8, and
/// `stscam render` exits 0. The texts are not UTF-8 (the former reading refused the OBJ).
#[test]
fn latin1_bytes_in_obj_and_mtl() {
    let mtl: &[u8] = b"newmtl t\xeate\nKd 1 1 1\nmap_Kd t\xeate.png\n";
    assert!(String::from_utf8(mtl.to_vec()).is_err());
    for on_disk in [&b"t\xeate.png"[..], "tête.png".as_bytes()] {
        let dir = case(b"t\xeate", mtl, &[(on_disk, png(RED))]);
        let c = frontal_mean(dir.path());
        assert!(is_red(c), "{on_disk:?}: {c:?}");
    }
    let dir = case(b"t\xeate", mtl, &[(b"t\xeate.png", png(RED))]);
    assert!(is_red(frontal_mean(dir.path())));
    let out = dir.path().join("out");
    let o = stscam(&[
        "render",
        dir.path().join("scene.toml").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--set",
        "sensor.crop_px=[8,8]",
        "--spp",
        "1",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A backslash path to a missing texture is refused with exit 2 in one line naming the MTL file,
/// the material and the path as written.
#[test]
fn missing_backslash_texture_is_refused_clearly() {
    let dir = case(
        b"a",
        b"newmtl a\nKd 1 1 1\nmap_Kd .\\textures\\gone.png\n",
        &[(b"textures/red.png", png(RED))],
    );
    std::fs::write(
        dir.path().join("scene.toml"),
        "[display]\nenabled = false\n[[object]]\nmesh = \"m.obj\"\n\
         position_mm = [0.0, 0.0, -400.0]\n[[light]]\nkind = \"environment\"\n",
    )
    .unwrap();
    let o = stscam(&[
        "render",
        dir.path().join("scene.toml").to_str().unwrap(),
        "--out",
        dir.path().join("out").to_str().unwrap(),
        "--set",
        "sensor.crop_px=[8,8]",
        "--spp",
        "1",
    ]);
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(
        e.contains("m.mtl") && e.contains(r".\textures\gone.png") && e.contains("map_Kd"),
        "{e}"
    );
}
