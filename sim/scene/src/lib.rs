//! Scene description: serde structs (pure data, units in every name), loading from TOML,
//! `--set KEY=VALUE` overrides and validation.
//!
//! A scene file may list only the keys it changes: it is merged over the embedded paper scene
//! (`scenes/paper-2022.toml`), so every key always exists. Keys that the embedded scene does
//! not have are errors, as are values of the wrong type or out of range; each error names the
//! file (or `--set`), the dotted key and the problem.
//!
//! Layer: scene descriptions (serde, pure data): parsing, merge, `--set` overrides, validation, the embedded scenes.
//! May depend on: stscam-base, stscam-io, stscam-optics (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod desc;

mod error;
mod load;
mod scene;
mod validate;

// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{limits, noise, numfmt, suggest};
use stscam_io as io;
use stscam_optics as optics;

pub use self::error::SceneError;
pub use self::load::{SceneSource, load_scene, load_scene_text};
pub use self::scene::{
    AutoOr, BottomHoeDesc, CameraDesc, CropSpec, DEFAULT_FILM_EXPANSION_PER_K,
    DEFAULT_INDEX_CHANGE_PER_K, DEFAULT_MAX_DEPTH, DEFAULT_SUBSTRATE_EXPANSION_PER_K, DisplayDesc,
    GlassSpec, GratingDesc, HoeDesc, LIST_SECTIONS, LoadedScene, MAX_GRATINGS, NoiseDesc,
    PlateDesc, PolarizationSpec, SINGLE_GRATING_FABRICATION_KEYS, SINGLE_GRATING_KEYS,
    SamplingDesc, Scene, SensorDesc, TopHoeDesc,
};
pub use self::validate::{
    GLASS_NAMES, MAX_WAVELENGTH_NM, MIN_WAVELENGTH_NM, PRIMARIES_NAMES, RESPONSE_NAMES,
    SPECTRUM_NAMES, validate,
};

/// The paper's setup, compiled into the binary.
pub const PAPER_SCENE_TOML: &str = include_str!("../../../scenes/paper-2022.toml");

/// The scenes shipped in `scenes/` by name (file name without `.toml`), with their TOML text.
pub const SHIPPED_SCENES: &[(&str, &str)] = &[
    ("paper-2022", PAPER_SCENE_TOML),
    (
        "eye-contact",
        include_str!("../../../scenes/eye-contact.toml"),
    ),
    ("gesture", include_str!("../../../scenes/gesture.toml")),
];
/// The full-colour design of `scenes/rgb-multiplex.toml`, compiled into the binary for
/// `stscam demo --colour`.
pub const RGB_MULTIPLEX_TOML: &str = include_str!("../../../scenes/rgb-multiplex.toml");
/// Name used in messages for the embedded RGB design.
pub const RGB_MULTIPLEX_NAME: &str = "<embedded scenes/rgb-multiplex.toml>";

/// Name used in messages for the embedded scene.
pub const EMBEDDED_NAME: &str = "<embedded scenes/paper-2022.toml>";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_scene_loads_and_has_paper_values() {
        let ls = load_scene(None, &[]).unwrap();
        let s = &ls.scene;
        assert_eq!(s.plate.thickness_mm, 2.0);
        assert_eq!(s.hoe.reference_angle_deg, Some(61.2));
        assert_eq!(s.hoe.gratings().len(), 1);
        assert_eq!(s.bottom_hoe.height_mm, 50.0);
        assert_eq!(s.sensor.crop_px.size(), (440, 440));
        assert_eq!(s.display.distance_mm, 550.0);
        assert!(s.display.enabled);
        assert_eq!(s.sampling.max_depth, DEFAULT_MAX_DEPTH);
        // Display-only scenes serialise without the 3-D keys (their outputs keep their bytes)
        // and read back equal.
        let json = serde_json::to_string(s).unwrap();
        assert!(
            !json.contains("enabled") && !json.contains("max_depth") && !json.contains("object")
        );
        let back: Scene = serde_json::from_str(&json).unwrap();
        assert_eq!(&back, s);
    }

    #[test]
    fn overrides_change_values_and_types() {
        let ls = load_scene(
            None,
            &[
                "plate.glass=1.5".into(),
                "plate.thickness_mm=3".into(),
                "sensor.crop_px=64".into(),
                "display.image=checker:8".into(),
            ],
        )
        .unwrap();
        assert_eq!(ls.scene.plate.glass, GlassSpec::Index(1.5));
        assert_eq!(ls.scene.plate.thickness_mm, 3.0);
        assert_eq!(ls.scene.sensor.crop_px.size(), (64, 64));
        assert_eq!(ls.scene.display.image, "checker:8");
    }

    /// Fabrication keys: out-of-range values name their key; a one-entry `[[hoe.grating]]`
    /// list keeps its per-grating errors in the single-grating form; a list refuses the
    /// single-grating form's per-grating keys.
    #[test]
    fn fabrication_keys_are_checked() {
        for (set, want) in [
            (
                "hoe.shrinkage=0.6",
                "--set hoe.shrinkage: hoe.shrinkage: must be in [-0.5, 0.5]",
            ),
            (
                "hoe.thickness_error_um=-16",
                "hoe.thickness_error_um: hoe.film_thickness_um + hoe.thickness_error_um must be positive",
            ),
            (
                "hoe.reference_angle_error_deg=30",
                "hoe.reference_angle_error_deg: the recorded reference angle 61.2 + 30",
            ),
            (
                "hoe.index_modulation_shortfall=1.5",
                "hoe.index_modulation_shortfall: must be in [-1, 1]",
            ),
            (
                "hoe.temperature_change_k=1e4",
                "hoe.temperature_change_k: must be in [-200, 200]",
            ),
        ] {
            let e = load_scene(None, &[set.into()]).unwrap_err().to_string();
            assert!(e.contains(want), "{set}: {e}");
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.toml");
        std::fs::write(
            &p,
            "[[hoe.grating]]\nrecording_wavelength_nm = 532.0\nreference_angle_deg = 61.2\n\
             index_modulation = 0.015\nindex_modulation_shortfall = 0.2\n",
        )
        .unwrap();
        let h = load_scene(Some(&p), &[]).unwrap().scene.hoe;
        assert!(h.grating.is_empty());
        assert_eq!(h.index_modulation_shortfall, 0.2);
        assert_eq!(h.gratings()[0].index_modulation_shortfall, 0.2);
        let e = load_scene(Some(&p), &["hoe.reference_angle_error_deg=0.1".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("set hoe.grating.N.reference_angle_error_deg"),
            "{e}"
        );
    }

    #[test]
    fn errors_name_source_and_key() {
        let e = load_scene(None, &["plate.nope=1".into()])
            .unwrap_err()
            .to_string();
        assert_eq!(e, "--set plate.nope: plate.nope: unknown key");
        let e = load_scene(None, &["plate.thickness_mm=-1".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("--set plate.thickness_mm: plate.thickness_mm: must be a positive"),
            "{e}"
        );
        let e = load_scene(None, &["plate.thickness_mm=thick".into()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("plate.thickness_mm"), "{e}");
        let e = load_scene(None, &["plate.glass=flint".into()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("plate.glass: unknown glass"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.toml");
        std::fs::write(&p, "[plate]\nthickness_mm = 1.0\n[hoe]\ncolour = 3\n").unwrap();
        let e = load_scene(Some(&p), &[]).unwrap_err().to_string();
        assert_eq!(e, format!("{}: hoe.colour: unknown key", p.display()));
        std::fs::write(&p, "[plate\nthickness_mm = 1.0\n").unwrap();
        let e = load_scene(Some(&p), &[]).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}: line 1, column", p.display()))
                && e.contains("malformed TOML"),
            "{e}"
        );
        std::fs::write(&p, "[plate]\nthickness_mm = 1.5\n").unwrap();
        let ls = load_scene(Some(&p), &[]).unwrap();
        assert_eq!(ls.scene.plate.thickness_mm, 1.5);
        assert_eq!(ls.scene.hoe.film_thickness_um, 16.0);
    }
}
