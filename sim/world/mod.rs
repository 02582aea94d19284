//! The user side of the camera (DESIGN.md "The user side"): everything beyond the front face
//! of the plate. The waveguide hands each replica branch's ray to this module and never sees
//! meshes; this module never sees the plate.

pub mod mesh;
pub mod texture;
