//! The noise sweep of docs/validation.md ("The paper's finding"): the demo's protocol (paper
//! scene framed as `demo` frames it, H at SPP spp seed 1, captures H′f + o′ with an
//! independent H′ of seed 2, sensor noise of the scene with the exposure fraction varied
//! (env FRACS, default 0.8,0.2,0.05,0.0125) and bit depth (env BITS, default 8), a noisy dark
//! frame subtracted) and, per exposure, CGM at 30 iterations, CGM stopped by the discrepancy
//! principle, ADMM-TV at τ_rel 1e-3 and ADMM-TV with τ by the discrepancy principle, with H and
//! with the Hadamard-calibrated H_est. Usage: `cargo run --release --example paper_noise_sweep
//! -- SPP SIZE` (64 64: about 2 min per exposure on 2 shared cores).
use stscam::demo::{DEMO_TARGETS, noisy_capture_of};
use stscam::hadamard::{CalibrationSettings, FrameSource, calibrate};
use stscam::matrix::compute_matrix_stack;
use stscam::noise::SensorNoise;
use stscam::recon::Problem;
use stscam::recon::admm::{AdmmSettings, admm_tv};
use stscam::recon::cg::{CgSettings, cg_normal};
use stscam::recon::discrepancy::{NoiseLevel, admm_tv_discrepancy, cg_discrepancy};
use stscam::recon::metrics::psnr;
use stscam::render::RenderSettings;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let spp: u32 = args.get(1).map_or(16, |s| s.parse().unwrap());
    let size: usize = args.get(2).map_or(64, |s| s.parse().unwrap());
    let mut set = vec![format!("display.image=letter:F@{size}")];
    let ls = stscam::scene::load_scene(None, &set).unwrap();
    let sys = stscam::system::System::build(&ls).unwrap();
    if let Some(off) = stscam::analysis::framing_offset_px(&sys) {
        set.push(format!("sensor.crop_offset_px=[{},{}]", off[0], off[1]));
    }
    let ls = stscam::scene::load_scene(None, &set).unwrap();
    let sys = stscam::system::System::build(&ls).unwrap();
    let d0 = -sys.display.z_mm;
    let t = std::time::Instant::now();
    let m =
        compute_matrix_stack(&sys, &RenderSettings::lattice(spp, 1, false), &[d0]).swap_remove(0);
    let m2 =
        compute_matrix_stack(&sys, &RenderSettings::lattice(spp, 2, false), &[d0]).swap_remove(0);
    eprintln!(
        "H {:?} crop {:?} in {:.1}s",
        m.h.nnz(),
        m.crop,
        t.elapsed().as_secs_f64()
    );
    let gamma = sys.scene.display.gamma;
    let truths: Vec<Vec<f64>> = DEMO_TARGETS
        .iter()
        .map(|(_, _, s)| {
            let (_, _, v) = {
                let (w, h, c, vals) =
                    stscam::targets::builtin_image(&format!("{s}@{size}")).unwrap();
                (
                    w,
                    h,
                    stscam::display::Display::planes_of(&vals, c, false, gamma, 1),
                )
            };
            v
        })
        .collect();
    let p_true = Problem::new(&m.h, size, size);
    let white_peak = stscam::demo::white_peak_of(&m);
    let fracs: Vec<f64> = std::env::var("FRACS").map_or(vec![0.8, 0.2, 0.05, 0.0125], |s| {
        s.split(',').map(|x| x.parse().unwrap()).collect()
    });
    let bits: u32 = std::env::var("BITS").map_or(8, |s| s.parse().unwrap());
    for &frac in &fracs {
        let mut desc = sys.scene.noise.clone();
        desc.exposure_fraction = frac;
        desc.bit_depth = bits;
        if bits > 8 {
            desc.dark_offset_dn *= (1u32 << (bits - 8)) as f64;
        }
        let noise = SensorNoise::new(&desc, white_peak);
        let dark = stscam::demo::dark_frame(&m, &noise, 1);
        let mut hs: Vec<(&str, Problem)> = vec![];
        for (name, dark_frame, thr) in [("cal-demo", true, 5.0)] {
            let cal = calibrate(
                &m.h,
                &m.offset,
                FrameSource::Matrix,
                &CalibrationSettings {
                    noise: Some(noise.clone()),
                    seed: 1,
                    dark_frame,
                    threshold_sigma: thr,
                    progress: false,
                },
            )
            .unwrap();
            hs.push((name, Problem::new(&cal.h_est, size, size)));
        }
        println!(
            "## exposure_fraction {frac} bits {bits}: white peak {:.0} e-",
            frac * desc.full_well_e
        );
        for (hname, p) in std::iter::once(("true", &p_true)).chain(hs.iter().map(|(n, p)| (*n, p)))
        {
            let mut sums = [0.0; 4];
            let mut line = String::new();
            for (ti, truth) in truths.iter().enumerate() {
                let frame = noisy_capture_of(&m2, truth, &noise, 1, ti as u64);
                let g: Vec<f64> = frame.iter().zip(&dark).map(|(a, d)| a - d).collect();
                let level = NoiseLevel::of_capture(
                    p,
                    &g,
                    &stscam::demo::black_level_of(&dark, &noise),
                    true,
                    &noise,
                );
                let htg = p.back_project(&g);
                let rt = stscam::recon::discrepancy::residual_norm2(p, &htg, level.g_norm2, truth);
                let dark_rows = (0..m.h.rows)
                    .filter(|&r| m.h.row_range(r).is_empty())
                    .count();
                if hname == "true" {
                    eprintln!(
                        "frac {frac} {}: residual(f_true)/budget = {:.3}  ({} of {} rows empty)",
                        DEMO_TARGETS[ti].0,
                        rt / level.budget,
                        dark_rows,
                        m.h.rows
                    );
                }
                let cg30 = cg_normal(
                    p,
                    &htg,
                    &CgSettings {
                        iters: 30,
                        tol: 0.0,
                    },
                )
                .f;
                let cgd = cg_discrepancy(p, &htg, &level, 300);
                let ad = admm_tv(p, &htg, &AdmmSettings::default()).f;
                let tc = admm_tv_discrepancy(p, &htg, &level, &AdmmSettings::default());
                let q = [
                    psnr(&cg30, truth),
                    psnr(&cgd.f, truth),
                    psnr(&ad, truth),
                    psnr(&tc.result.f, truth),
                ];
                for k in 0..4 {
                    sums[k] += q[k] / 4.0;
                }
                line += &format!(
                    "  {}: cg30 {:.1} cgD {:.1} ({} it) admm1e-3 {:.1} admmD {:.1} (tau {:.2e}{})\n",
                    DEMO_TARGETS[ti].0,
                    q[0],
                    q[1],
                    cgd.iterations,
                    q[2],
                    q[3],
                    tc.tau_rel,
                    if tc.reached { "" } else { " !" }
                );
            }
            println!(
                "H {hname}: mean cg30 {:.2} cgD {:.2} admm1e-3 {:.2} admmD {:.2}\n{line}",
                sums[0], sums[1], sums[2], sums[3]
            );
        }
    }
}
