//! Optical elements: glass dispersion and absorption, planar interfaces, and the volume
//! grating (k-closure + Kogelnik coupled-wave efficiencies) and a film of several multiplexed
//! gratings, and the fabrication errors of a recorded film.

pub mod fabrication;
pub mod glass;
pub mod grating;
pub mod interface;
pub mod kogelnik;
pub mod multiplex;
pub mod rcwa;
