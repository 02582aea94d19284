//! Closed-form geometry of the holographic waveguide across the whole field, and its
//! comparison with what stscam's tracer computes (`validation/analytic`).
//!
//! # Closed forms (all written here without calling the tracer or the grating code)
//!
//! Frame and units as in `docs/design.md`: millimetres, plate 0 ≤ z ≤ w, y up, camera at z > w
//! looking along −z. A field direction is the camera chief ray from the lens centre,
//! d = normalise(tan h, tan v, −1), with h and v the horizontal and vertical field angles in
//! air (the convention of `analysis::probe`). The physical light travels along −d; its
//! tangential optical direction cosines u = −(d_x, d_y) are conserved by every planar
//! interface (Snell).
//!
//! 1. **Bragg wavelength** (docs/physics.md §3.2): on-shell closure |ρ − K| = |ρ| with
//!    K = k0(ŝ_O − ŝ_R) gives λ_B = λ0 (s_z − s_y tan(θ_R/2)), where ŝ is the direction inside
//!    the film: s_y = u_y/n_f, s_z = √(1 − |u|²/n_f²). Independent of n_f for in-plane
//!    incidence when measured inside the medium; exactly λ0 cos(Θ + θ_R/2)/cos(θ_R/2) in-plane
//!    (§3.3).
//! 2. **Guided direction** (§2, §0.3): tangential k is conserved up to K_t, so the guided wave
//!    has u_g = u − (λ/2π)K_t = (u_x, u_y + n_f sin θ_R · λ/λ0); its normal component follows
//!    from |k| = 2πn_g/λ in the glass, so the guided angle is Θ' = asin(|u_g|/n_g(λ_B)).
//! 3. **Replica pitch** (§0.3 b, §5): one round trip (two plate crossings) shifts the guided
//!    ray by the vector p = 2w·u_g/√(n_g² − |u_g|²), of length 2w·tanΘ'. By the periscope
//!    property every replica leaves parallel to the entry ray, so consecutive replicas of one
//!    chief ray hit the display p apart.
//! 4. **Replica count** (§5): the chief ray meets the back face at P_b = L + d1·t
//!    (t = d_t/(−d_z)), crosses the plate to the front face at P_f = P_b + w·d_t/√(n_g² − |u|²),
//!    where the top vHOE diffracts it into the guided wave; traced backward, plate contact j
//!    lies at P_f − j·w·u_g/√(n_g² − |u_g|²), odd j on the back face. The number of replicas is
//!    the number of odd j ≥ 1 whose contact lies inside the bottom vHOE rectangle (closed on
//!    the minimum edges, open on the maximum ones): the intersection of one interval of j per
//!    axis, counted with floors. The j-th contact's replica leaves the front face at
//!    P_f − j·g + (P_f − P_b) and meets the display at that point + D·t.
//! 5. **Vertical FOV limits** (§3.4, §5): TIR needs |u_g| > 1 (the same condition at the
//!    glass→air and the film→air face, since u is conserved: Θ' > asin(1/n_g) and the film
//!    angle > asin(1/n_f)); in-plane this is Θ_f > asin(1/n_f) − θ_R, i.e. the camera angle
//!    v < asin(n_f sin(θ_R − asin(1/n_f))). The Bragg band ends where λ_B leaves the sampled
//!    band [λ_min, λ_max): in-plane Θ_f = ±acos(λ_edge cos(θ_R/2)/λ0) − θ_R/2. The top-vHOE
//!    aperture ends where P_f leaves the top rectangle; the bottom vHOE ends where no back-face
//!    contact is left; the sensor crop ends at |d0·t − offset| = half the crop. Aperture,
//!    contact and crop edges are found by bisection of these closed-form predicates.
//! 6. **Sensor rows of a point object**: for the chief ray through image height v of the crop's
//!    midline, the display point of contact j is the expression of item 4; the row at which
//!    a point at y_obj appears through contact j solves it for v (bisection).
//!
//! Assumptions: the scene's plain values (λ0, θ_R, n_f, w, vHOE rectangles, gap, camera
//! distance, focal length, focus, pixel pitch, crop, display distance, sampling band) and the
//! glass dispersion formula (`optics::glass::Glass::index`, a material table) are shared with
//! the simulator; everything else is computed here. The guided ray is an ideal chief ray (no
//! aperture), lossless TIR geometry, no fringe shrinkage.
//!
//! # Comparison
//!
//! [`compare`] puts these side by side with the tracer over ≥ 50 field angles spanning the
//! waveguide's field (vertical, horizontal and conical): Bragg wavelength, guided angle,
//! replica pitch (spacing of traced object points), the object point of the first replica,
//! replica count (traced without the weight cut-off), the sensor rows of a point at the display
//! centre (`analysis::point_replicas`), replica count against bottom-vHOE height, FOV edges
//! against `analysis::info` (its 0.05° scan) and against a bisection of the traced chief ray,
//! and the wavelength that maximises the traced chief-ray throughput (golden section) against
//! λ_B.

mod closed_forms;
mod report;

pub use closed_forms::{ClosedForm, FieldGeometry, Limit};
pub use report::{
    AnalyticReport, DETERMINISTIC_REL_TOL, Row, Summary, WEAK_INDEX_MODULATION, compare,
    compare_with, golden_max, peak_tolerance_nm, quantity,
};
