//! Efficiency spectra of one vHOE film (`stscam grating`): every propagating order's TE and TM
//! efficiency over a wavelength range for one incidence direction, from Kogelnik's two-wave
//! model (`optics::grating`, each grating on its own) or from the RCWA (`optics::rcwa`, all
//! gratings together), in one of two stacks.
//!
//! Geometry: the light arrives from the user side travelling in air along
//! (tan X, tan Y, 1)/‖·‖ (x horizontal, y up, +z toward the plate); its tangential direction
//! cosines u are conserved into the glass and the film. Stacks: `bulk`, the film between
//! half-spaces of its own mean index (Kogelnik's assumptions); `contact`, glass | film | air with
//! the light arriving from the glass, as at a bottom-vHOE contact next to the TIR face. The
//! Kogelnik model ignores the interfaces in both stacks (only the media its orders leave into
//! change); a transmitted order that cannot propagate in air is reported as trapped (direction
//! absent). Kogelnik's TE/TM (relative to the plane of diffraction, as the tracer uses them) are
//! converted to the plane-of-incidence basis both models report
//! (`rcwa::kogelnik_in_incidence_basis`); the undiffracted order is 1 − Σ η per polarisation.
//! The film is the one fabricated (`optics::fabrication`: the scene's shrinkage, mean-index
//! change, thickness error, temperature and each grating's shortfall and angle error), as the
//! tracer sees it; with every fabrication key 0 it is the designed film bit for bit.

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use crate::optics::fabrication::{GratingRecording, fabricated_gratings};
use crate::optics::grating::VolumeGrating;
use crate::optics::rcwa::{self, Film, RcwaError, Settings, Stack};
use crate::scene::Scene;

/// One grating of a vHOE as recorded, with its own fabrication errors (the optics' recording;
/// serialised in the grating report).
pub type GratingSpec = GratingRecording;

/// The grating list of a scene: its `[[hoe.grating]]` entries, or the one grating of the
/// single-grating `[hoe]` keys.
pub fn scene_gratings(s: &Scene) -> Vec<GratingSpec> {
    s.hoe
        .gratings()
        .iter()
        .map(crate::scene::GratingDesc::recording)
        .collect()
}

/// The Kogelnik gratings of a list in the scene's film **as fabricated** (the `hoe.*`
/// fabrication keys of the scene and each entry's own errors, `optics::fabrication`; every key 0
/// gives the recorded design bit for bit), as the tracer builds them.
pub fn volume_gratings(s: &Scene, gratings: &[GratingSpec]) -> Vec<VolumeGrating> {
    fabricated_gratings(&s.hoe.fabrication(), gratings)
}

/// The mean index of the scene's film as fabricated (n + δn + (dn/dT)·ΔT).
pub fn fabricated_mean_index(s: &Scene) -> f64 {
    let f = s.hoe.fabrication();
    f.mean_index + f.mean_index_change + f.index_change_per_k * f.temperature_change_k
}

/// The RCWA film of a grating list in the scene's film as fabricated.
pub fn film(s: &Scene, gratings: &[GratingSpec]) -> Film {
    let vg = volume_gratings(s, gratings);
    Film {
        mean_index: fabricated_mean_index(s),
        alpha0_per_nm: s.hoe.amplitude_absorption_per_mm * 1e-6,
        thickness_nm: vg
            .first()
            .map_or(s.hoe.film_thickness_um * 1e3, |g| g.thickness_nm),
        gratings: vg.iter().map(rcwa::Grating::of).collect(),
    }
}

/// Grating model (the same enum as the scene key `hoe.model`).
pub use crate::optics::GratingModel as Model;

/// Layer stack around the film.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StackKind {
    /// Film between half-spaces of its own mean index.
    Bulk,
    /// Glass (the scene's plate) | film | air, light from the glass.
    Contact,
}

/// The media of a stack at one wavelength.
pub fn stack_media(s: &Scene, kind: StackKind, lambda_nm: f64) -> Stack {
    match kind {
        StackKind::Bulk => Stack {
            n_in: fabricated_mean_index(s),
            n_out: fabricated_mean_index(s),
        },
        StackKind::Contact => Stack {
            n_in: crate::system::glass_of(&s.plate.glass).index(lambda_nm),
            n_out: 1.0,
        },
    }
}

/// Tangential direction cosines u of the light of field angles `field_deg` (X, Y), the
/// viewing convention of every command (`analysis::field_direction`, docs/cli.md): the camera
/// looks along (tan X, tan Y, −1)/‖·‖, so the light from the user side travels along
/// (−tan X, −tan Y, 1)/‖·‖.
pub fn field_u(field_deg: [f64; 2]) -> DVec2 {
    let d = DVec3::new(
        -field_deg[0].to_radians().tan(),
        -field_deg[1].to_radians().tan(),
        1.0,
    )
    .normalize();
    d.truncate()
}

/// Identity of an order across wavelengths.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
pub struct OrderKey {
    /// True for an order leaving through the entrance side.
    pub reflected: bool,
    /// Grating (0-based) of a Kogelnik order; `None` for RCWA orders of the whole film.
    pub grating: Option<usize>,
    /// Order index.
    pub order: i32,
}

/// One order at one wavelength.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrderValue {
    /// Which order.
    pub key: OrderKey,
    /// Unit direction in the medium it leaves into; `None` if it cannot leave (trapped).
    pub direction: Option<DVec3>,
    /// TE and TM efficiency.
    pub eta: [f64; 2],
}

/// All orders at one wavelength.
#[derive(Clone, Debug, PartialEq)]
pub struct SpectrumPoint {
    /// Vacuum wavelength.
    pub lambda_nm: f64,
    /// Orders.
    pub orders: Vec<OrderValue>,
    /// Σ η over the orders that leave, TE and TM.
    pub total: [f64; 2],
}

/// Efficiencies of every order at each wavelength (computed in parallel, each wavelength on
/// its own: the result does not depend on the thread count).
pub fn spectrum(
    s: &Scene,
    gratings: &[GratingSpec],
    model: Model,
    kind: StackKind,
    lambdas_nm: &[f64],
    u: DVec2,
    settings: &Settings,
) -> Result<Vec<SpectrumPoint>, RcwaError> {
    lambdas_nm
        .par_iter()
        .map(|&l| point(s, gratings, model, kind, l, u, settings))
        .collect()
}

/// Efficiencies of every order at one wavelength.
pub fn point(
    s: &Scene,
    gratings: &[GratingSpec],
    model: Model,
    kind: StackKind,
    lambda_nm: f64,
    u: DVec2,
    settings: &Settings,
) -> Result<SpectrumPoint, RcwaError> {
    let media = stack_media(s, kind, lambda_nm);
    match model {
        Model::Rcwa => {
            let sol = rcwa::solve(&film(s, gratings), &media, lambda_nm, u, settings)?;
            let orders = sol
                .orders
                .iter()
                .map(|o| OrderValue {
                    key: OrderKey {
                        reflected: o.reflected,
                        grating: None,
                        order: o.order,
                    },
                    direction: Some(o.direction),
                    eta: o.eta,
                })
                .collect();
            Ok(SpectrumPoint {
                lambda_nm,
                orders,
                total: sol.total,
            })
        }
        Model::Kogelnik => Ok(kogelnik_point(s, gratings, media, lambda_nm, u)),
    }
}

fn kogelnik_point(
    s: &Scene,
    gratings: &[GratingSpec],
    media: Stack,
    lambda_nm: f64,
    u: DVec2,
) -> SpectrumPoint {
    let leave = |u: DVec2, reflected: bool| -> Option<DVec3> {
        let n = if reflected { media.n_in } else { media.n_out };
        let c2 = n * n - u.length_squared();
        (c2 > 0.0).then(|| {
            let z = if reflected { -c2.sqrt() } else { c2.sqrt() };
            (u.extend(z) / n).normalize()
        })
    };
    let mut orders = Vec::new();
    let mut zero = [1.0, 1.0];
    for (i, g) in volume_gratings(s, gratings).iter().enumerate() {
        for order in [-1, 1] {
            if let Some(d) = g.diffract(u, 1.0, lambda_nm, order) {
                // TE/TM relative to the plane of incidence, as the RCWA's.
                let eta = rcwa::kogelnik_in_incidence_basis(g.k_rad_per_nm, g.n_film, u, d.eta);
                zero[0] -= eta[0];
                zero[1] -= eta[1];
                orders.push(OrderValue {
                    key: OrderKey {
                        reflected: d.reflection,
                        grating: Some(i),
                        order,
                    },
                    direction: leave(d.u, d.reflection),
                    eta,
                });
            }
        }
    }
    let att = volume_gratings(s, gratings)
        .first()
        .map_or(1.0, |g| g.film_attenuation(u));
    orders.push(OrderValue {
        key: OrderKey {
            reflected: false,
            grating: None,
            order: 0,
        },
        direction: leave(u, false),
        eta: [zero[0].max(0.0) * att, zero[1].max(0.0) * att],
    });
    orders.sort_by_key(|o| o.key);
    let mut total = [0.0; 2];
    for o in orders.iter().filter(|o| o.direction.is_some()) {
        total[0] += o.eta[0];
        total[1] += o.eta[1];
    }
    SpectrumPoint {
        lambda_nm,
        orders,
        total,
    }
}
