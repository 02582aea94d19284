//! stscam's bottom layer: numbers every layer shares: formatting, spectra, built-in targets, input limits, the addressable sampler, sensor noise, CSR matrices, CIE colour, progress, cancellation and caches as handles passed in.
//! May depend on: nothing of stscam (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod cancel;
pub mod cie;
pub mod limits;
pub mod noise;
pub mod numfmt;
#[cfg(feature = "clap")]
pub mod options;
pub mod progress;
pub mod rows;
pub mod sampler;
pub mod sparse;
pub mod spectra;
pub mod store;
pub mod suggest;
pub mod targets;

/// The stscam version, recorded in every output.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// The repository's root folder at build time (the scenes and assets that tests and the
/// examples read): two levels above this crate's manifest.
pub fn repo_dir() -> &'static std::path::Path {
    let m = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    m.parent().and_then(std::path::Path::parent).unwrap_or(m)
}
