//! Optical elements: glass dispersion and absorption, planar interfaces, and the volume
//! grating (k-closure + Kogelnik coupled-wave efficiencies) and a film of several multiplexed
//! gratings, and the fabrication errors of a recorded film.

pub mod fabrication;
pub mod glass;
pub mod grating;
pub mod interface;
pub mod kogelnik;
pub mod multiplex;
pub(crate) mod packet;
pub mod rcwa;

/// How the tracer computes the vHOEs' efficiencies (`hoe.model`; also `stscam grating --model`).
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
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
