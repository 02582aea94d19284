//! Optical elements: glass dispersion and absorption, planar interfaces, and the volume
//! grating (k-closure + Kogelnik coupled-wave efficiencies) and a film of several multiplexed
//! gratings, and the fabrication errors of a recorded film.
//!
//! Layer: optical kernels on plain numbers: glass, interfaces, volume gratings (Kogelnik), multiplexed films, fabrication errors, RCWA.
//! May depend on: stscam-base (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod fabrication;
pub mod glass;
pub mod grating;
pub mod interface;
pub mod kogelnik;
pub mod multiplex;
pub mod packet;
pub mod rcwa;
// The layers below, under the names this crate's modules use (`crate::io::…`).
#[cfg(test)]
use stscam_base::sampler;
use stscam_base::spectra;

/// How the tracer computes the vHOEs' efficiencies (`hoe.model`; also `stscam grating --model`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum GratingModel {
    /// Kogelnik's two-wave coupled-wave theory, each grating on its own (closed form).
    #[default]
    Kogelnik,
    /// Rigorous coupled-wave analysis of the whole film (tables built once per design).
    Rcwa,
}

impl GratingModel {
    /// True for the default (Kogelnik): the key is left out of written scenes.
    pub fn is_kogelnik(&self) -> bool {
        *self == GratingModel::Kogelnik
    }
}

/// A directory as a blob store for this crate's tests (the real one, `stscam_io::DirStore`,
/// writes atomically and is a layer above).
#[cfg(test)]
pub(crate) struct TestDir(pub std::path::PathBuf);

#[cfg(test)]
impl stscam_base::store::BlobStore for TestDir {
    fn load(&self, name: &str) -> Option<Vec<u8>> {
        std::fs::read(self.0.join(name)).ok()
    }

    fn save(&self, name: &str, bytes: &[u8]) -> Result<std::path::PathBuf, String> {
        std::fs::create_dir_all(&self.0).map_err(|e| e.to_string())?;
        std::fs::write(self.0.join(name), bytes).map_err(|e| e.to_string())?;
        Ok(self.0.join(name))
    }

    fn location(&self, name: &str) -> std::path::PathBuf {
        self.0.join(name)
    }
}
