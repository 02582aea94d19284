//! A multiplexed film: several volume gratings recorded in one photopolymer layer (one
//! `[[hoe.grating]]` entry each), sharing its thickness, mean index and absorption.
//!
//! Model: the film's index is n(r) = n + Σ_j n1_j cos(K_j·r). Each grating is treated on its
//! own with Kogelnik's two-wave coupled-wave theory (Kogelnik 1969, "Coupled wave theory for
//! thick hologram gratings", Bell Syst. Tech. J. 48, 2909), each with its own grating vector
//! K_j (from its recording, [`VolumeGrating::from_recording_beams`]) and so its own Bragg
//! condition. Assumptions (independent gratings):
//! - an incident wave's orders of every grating are candidates at each film crossing, and each
//!   order's efficiency is the two-wave value of its grating alone;
//! - cross-coupling between gratings is neglected: a wave diffracted by grating j is not
//!   re-diffracted by grating k inside the same crossing, and the gratings do not deplete each
//!   other's pump within the film (Kogelnik's model has no such terms; a rigorous model of the
//!   whole modulation, RCWA, captures them). This is accurate when at most one grating is near
//!   Bragg for a given wave (well-separated Bragg bands or directions), which is how
//!   multiplexed films are designed (Case 1975, "Coupled-wave theory for multiply exposed
//!   thick holographic gratings", JOSA 65, 724, shows the cross terms matter only where two
//!   Bragg conditions coincide);
//! - what is not diffracted crosses the film: 1 − Σ_j Σ_{m=±1} η_{j,m}, clamped at 0, times the
//!   film's mean absorption (once: the film is shared).
//!
//! The set is a fixed-capacity array (at most [`MAX_GRATINGS`]), so the tracer allocates
//! nothing per path. With one grating every quantity is computed with exactly the operations
//! of [`VolumeGrating`]'s own methods (the single-grating scene keeps its bytes).

use glam::DVec2;

use super::grating::{Incident, VolumeGrating};

/// The most gratings one film may hold (`[[hoe.grating]]` entries): the tracer keeps a
/// fixed-capacity array of them, and each grating multiplies a path's cost.
pub const MAX_GRATINGS: usize = 8;

/// The gratings of one film, in scene order (grating index = position).
#[derive(Clone, Copy, Debug)]
pub struct GratingSet {
    gratings: [VolumeGrating; MAX_GRATINGS],
    len: usize,
}

impl GratingSet {
    /// A set of `list` (1 to [`MAX_GRATINGS`] gratings sharing one film: the same mean index,
    /// thickness and absorption). `None` for an empty or too long list, or one whose gratings
    /// do not share the film.
    pub fn new(list: &[VolumeGrating]) -> Option<GratingSet> {
        let first = *list.first()?;
        if list.len() > MAX_GRATINGS
            || list.iter().any(|g| {
                g.n_film != first.n_film
                    || g.thickness_nm != first.thickness_nm
                    || g.alpha0_per_nm != first.alpha0_per_nm
            })
        {
            return None;
        }
        let mut gratings = [first; MAX_GRATINGS];
        gratings[..list.len()].copy_from_slice(list);
        Some(GratingSet {
            gratings,
            len: list.len(),
        })
    }

    /// A film with one grating.
    pub fn single(g: VolumeGrating) -> GratingSet {
        GratingSet {
            gratings: [g; MAX_GRATINGS],
            len: 1,
        }
    }

    /// Number of gratings (at least 1).
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always false (a set holds at least one grating); for the `len` convention.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The gratings in order.
    #[inline]
    pub fn as_slice(&self) -> &[VolumeGrating] {
        &self.gratings[..self.len]
    }

    /// The gratings in order, to change (tests that perturb a design).
    pub fn as_mut_slice(&mut self) -> &mut [VolumeGrating] {
        &mut self.gratings[..self.len]
    }

    /// Grating `i` (panics if out of range, like a slice).
    #[inline]
    pub fn get(&self, i: usize) -> &VolumeGrating {
        &self.as_slice()[i]
    }

    /// The first grating: it carries the film's shared properties (index, thickness,
    /// absorption) like every other.
    #[inline]
    pub fn film(&self) -> &VolumeGrating {
        &self.gratings[0]
    }

    /// The plane wave (u, z_sign) at `lambda_nm` inside the film, the same for every grating
    /// (it depends on the film's index only).
    #[inline]
    pub fn incident(&self, u: DVec2, z_sign: f64, lambda_nm: f64) -> Option<Incident> {
        self.film().incident(u, z_sign, lambda_nm)
    }

    /// Fraction [TE, TM] of a wave (u, z_sign) that crosses the film undiffracted by any
    /// grating, with the film's mean absorption (module notes).
    pub fn undiffracted(&self, u: DVec2, z_sign: f64, lambda_nm: f64) -> [f64; 2] {
        self.undiffracted_from(self.incident(u, z_sign, lambda_nm), u, None)
    }

    /// [`Self::undiffracted`] of the wave `incident` (= `self.incident(u, …)`); `known`
    /// supplies one (grating, order)'s efficiency already computed.
    #[inline]
    pub fn undiffracted_from(
        &self,
        incident: Option<Incident>,
        u: DVec2,
        known: Option<(usize, i32, [f64; 2])>,
    ) -> [f64; 2] {
        if self.len == 1 {
            // Exactly the single grating's operations.
            return self.gratings[0].undiffracted_from(
                incident,
                u,
                known.map(|(_, order, eta)| (order, eta)),
            );
        }
        let mut t = [1.0, 1.0];
        for (j, g) in self.as_slice().iter().enumerate() {
            for order in [1, -1] {
                let eta = match known {
                    Some((kj, o, eta)) if kj == j && o == order => eta,
                    _ => incident
                        .and_then(|w| w.order(g, order))
                        .map_or([0.0, 0.0], |d| d.eta),
                };
                t[0] -= eta[0];
                t[1] -= eta[1];
            }
        }
        let att = self.film().film_attenuation(u);
        [t[0].max(0.0) * att, t[1].max(0.0) * att]
    }

    /// Bragg wavelength (nm) of each grating for the in-coupling of a wave with tangential
    /// direction cosines `u` ([`VolumeGrating::bragg_wavelength_nm`]); entries past `len()` are
    /// `None`.
    #[inline]
    pub fn bragg_wavelengths_nm(&self, u: DVec2) -> [Option<f64>; MAX_GRATINGS] {
        let mut out = [None; MAX_GRATINGS];
        for (o, g) in out.iter_mut().zip(self.as_slice()) {
            *o = g.bragg_wavelength_nm(u);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn film(lambda0: f64, theta: f64, n1: f64) -> VolumeGrating {
        VolumeGrating::from_recording(lambda0, theta, 1.5, 16.0, n1, 0.0)
    }

    /// One grating: bit-identical to the grating's own undiffracted fraction.
    #[test]
    fn single_grating_is_the_grating() {
        let g = film(532.0, 61.2, 0.015);
        let set = GratingSet::single(g);
        for (u, z, lam) in [
            (DVec2::new(0.0, 0.1), 1.0, 530.0),
            (DVec2::new(0.2, 1.2), -1.0, 512.0),
        ] {
            assert_eq!(
                set.undiffracted(u, z, lam).map(f64::to_bits),
                g.undiffracted(u, z, lam).map(f64::to_bits)
            );
        }
    }

    /// Two gratings: the undiffracted fraction is 1 − the sum of both gratings' orders,
    /// computed independently here from each grating's own `undiffracted` (1 − its orders).
    #[test]
    fn two_gratings_remove_both_gratings_orders() {
        let a = film(532.0, 61.2, 0.015);
        let b = film(460.0, 61.2, 0.012);
        let set = GratingSet::new(&[a, b]).unwrap();
        let mut checked = 0;
        for i in 0..200 {
            let lam = 430.0 + i as f64;
            let u = DVec2::new(0.0, 0.05);
            let (ta, tb) = (a.undiffracted(u, 1.0, lam), b.undiffracted(u, 1.0, lam));
            let want = [0, 1].map(|p| (1.0 - (1.0 - ta[p]) - (1.0 - tb[p])).max(0.0));
            let got = set.undiffracted(u, 1.0, lam);
            for p in 0..2 {
                assert!((got[p] - want[p]).abs() < 1e-12, "{lam}: {got:?} {want:?}");
            }
            checked += usize::from(ta[0] < 0.5 || tb[0] < 0.5);
        }
        // Both gratings' Bragg bands were crossed (near 532 and near 460 nm).
        assert!(checked >= 4, "{checked}");
        let bad = GratingSet::new(&[
            a,
            VolumeGrating::from_recording(460.0, 61.2, 1.6, 16.0, 0.01, 0.0),
        ]);
        assert!(bad.is_none(), "gratings of different films");
    }
}
