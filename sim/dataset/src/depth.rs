//! Planar objects at random depths (recipe `[depth]`, matrix mode): H of the object plane at
//! each depth of the grid.
//!
//! Model: as `stscam matrix --depth-mm D`, the display (object) plane is moved to z = −D and
//! everything else (camera focus included) stays as the scene gives it, so an object off the
//! focus plane is seen defocused; g = H_D f + offset_D. All depths of one discrete scene share
//! one seed, so they see the same camera rays: H_D is then what a one-pass depth stack (every
//! replica branch meeting every plane, docs/design.md "Depth") gives, and [`depth_matrices`] is the
//! one place to switch to it. Assumption: the plane at each depth is the scene's display (same
//! size, black level and spectrum), only moved.

use crate::matrix::SystemMatrix;
use crate::render::RenderSettings;
use crate::system::System;

/// The system with its object plane at `depth_mm` from the plate (camera focus unchanged).
pub fn at_depth(sys: &System, depth_mm: f64) -> System {
    let mut s = sys.clone();
    s.display.z_mm = -depth_mm;
    s
}

/// H and the offset of the object plane at each of `depths_mm` (in that order), all with the
/// same camera rays (`settings.seed`): one pass over the camera paths
/// (`matrix::compute_matrix_stack`), each H bit-identical to `compute_matrix` at its depth.
pub fn depth_matrices(
    sys: &System,
    depths_mm: &[f64],
    settings: &RenderSettings,
) -> Vec<SystemMatrix> {
    crate::matrix::compute_matrix_stack(sys, settings, depths_mm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matrix::compute_matrix;
    use crate::scene::load_scene;

    #[test]
    fn each_depth_is_the_matrix_of_the_moved_plane() {
        let set = [
            "sensor.crop_px=24".to_string(),
            "sensor.pitch_um=60".to_string(),
            "display.image=black@8".to_string(),
        ];
        let ls = load_scene(None, &set).unwrap();
        let sys = System::build(&ls).unwrap();
        let settings = RenderSettings::lattice(2, 7, false);
        let ms = depth_matrices(&sys, &[300.0, 700.0], &settings);
        assert_eq!(ms.len(), 2);
        let direct = compute_matrix(&at_depth(&sys, 700.0), &settings);
        assert_eq!(ms[1].h.data, direct.h.data);
        assert_eq!(ms[1].h.indices, direct.h.indices);
        // A different depth is a different H (the replicas land on other object pixels).
        assert_ne!(ms[0].h.indices, ms[1].h.indices);
        assert_eq!(at_depth(&sys, 300.0).display.z_mm, -300.0);
        assert_eq!(
            at_depth(&sys, 300.0).camera.focus_distance_mm,
            sys.camera.focus_distance_mm
        );
    }
}
