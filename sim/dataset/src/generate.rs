//! Generation of a dataset (or one shard of it): the scenes with their H, the exposure, the
//! samples (object, capture and, for 3-D samples, the ground truth), then the metadata and
//! the card.

use std::borrow::Cow;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::card::{CardContext, ShardCard, finish, metadata_line};
use crate::error::{DatasetError, out_err, recipe_err, write_err};
use crate::folder::{RUN_MARKER, prepare_out, put};
use crate::matrix::{SystemMatrix, compute_matrix};
use crate::noise::{NoiseRng, SensorNoise};
use crate::plan::{Plan, SampleSpec, WHITE_TAG, source_key};
use crate::recipe::{self, CaptureMode, DEPTH_KEY, NoiseModel, SPLITS, TracePaths};
use crate::render::{RenderSettings, render};
use crate::shard::Shard;
use crate::sparse::CsrMatrix;
use crate::system::System;
use crate::{depth, meshes};

/// Options of a run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Output folder.
    pub out: PathBuf,
    /// Part to make (None: all).
    pub shard: Option<Shard>,
    /// Continue a run in `out`.
    pub resume: bool,
    /// Progress bar on a terminal.
    pub progress: bool,
}

/// What a run did.
#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    /// Samples of this run (shard).
    pub samples: usize,
    /// Samples generated now (the rest were already finished).
    pub generated: usize,
    /// Seconds spent on H and the exposure.
    pub scenes_s: f64,
    /// Seconds spent generating samples.
    pub samples_s: f64,
    /// Generated samples per second.
    pub samples_per_s: f64,
    /// Seconds to finish (checksums, metadata, card).
    pub finish_s: f64,
}

/// H of one scene, in memory.
struct SceneMatrix {
    h: CsrMatrix,
    offset: Vec<f32>,
}

fn npy(rel: &str, shape: &[usize], v: &[f32]) -> Result<Vec<u8>, DatasetError> {
    Ok(crate::io::npz::encode_npy_f32(Path::new(rel), shape, v)?)
}

/// The exposure of the dataset.
struct Exposure {
    white_peak: f64,
    full_scale: f64,
    noise: Option<SensorNoise>,
}

impl Exposure {
    /// The stored capture of a clean one: measured by the sensor model (pixel i with
    /// `NoiseRng([seed, NOISE_TAG, i])`) minus the mean dark offset, or as it is.
    fn measure(&self, clean: &[f64], seed: u64) -> Vec<f32> {
        match &self.noise {
            Some(n) => crate::noise::measure_capture(n, clean, seed),
            None => clean.iter().map(|&v| v as f32).collect(),
        }
    }
}

/// H of the incomplete depth scenes among `used`, one [`depth::depth_matrices`] call per
/// discrete scene (its depths share the seed); empty without `[depth]`.
fn depth_stack(
    plan: &Plan,
    root: &Path,
    used: &BTreeSet<usize>,
    progress: bool,
) -> BTreeMap<usize, SystemMatrix> {
    let n = plan.depths_mm.len();
    let mut out = BTreeMap::new();
    if n == 0 || !plan.has_matrix {
        return out;
    }
    let todo: Vec<usize> = used
        .iter()
        .copied()
        .filter(|&k| !plan.scene_files(k).iter().all(|f| root.join(f).is_file()))
        .collect();
    let groups: BTreeSet<usize> = todo.iter().map(|k| k / n).collect();
    for g in groups {
        let ks: Vec<usize> = todo.iter().copied().filter(|k| k / n == g).collect();
        let depths: Vec<f64> = ks.iter().map(|k| plan.depths_mm[k % n]).collect();
        let settings = RenderSettings::lattice(plan.recipe.spp, plan.scene_seed(ks[0]), progress);
        let ms = depth::depth_matrices(&plan.scenes[ks[0]].system, &depths, &settings);
        out.extend(ks.into_iter().zip(ms));
    }
    out
}

/// The folder of a recipe's `[camera_table] dir` (relative to the recipe's folder).
fn table_dir(plan: &Plan, dir: impl AsRef<Path>) -> std::path::PathBuf {
    plan.recipe_path
        .parent()
        .unwrap_or(Path::new("."))
        .join(dir)
}

/// Generates a dataset (or one shard of it) into `opts.out`: the scenes (H, scene.json), the
/// exposure, the samples, then the metadata and card ([`Generation`]'s steps).
pub fn generate(plan: &Plan, opts: &RunOptions) -> Result<RunSummary, DatasetError> {
    let recipe = &plan.recipe;
    let ids = opts
        .shard
        .map_or(0..recipe.samples, |s| s.range(recipe.samples));
    // A camera-table folder that cannot hold a table is refused before anything is written
    // (it was found only after the run marker and scene_000/scene.json were).
    if let Some(d) = recipe.camera_table.as_ref().and_then(|t| t.dir.as_ref()) {
        crate::render::table_file::writable_dir(&table_dir(plan, d))
            .map_err(|e| recipe_err(&plan.recipe_path, "camera_table.dir", e.to_string()))?;
    }
    // Held until the run ends (dropped on return, also on an error).
    let _lock = prepare_out(plan, opts)?;
    let run = Generation {
        plan,
        opts,
        root: &opts.out,
        cancel: crate::cancel::current(),
        tables: Default::default(),
        keys: Default::default(),
    };
    let t0 = Instant::now();
    let specs: Vec<SampleSpec> = ids.clone().map(|i| plan.sample(i)).collect();
    let done = |s: &SampleSpec| {
        plan.sample_files(s)
            .iter()
            .all(|f| run.root.join(f).is_file())
    };
    let todo: Vec<&SampleSpec> = specs.iter().filter(|s| !done(s)).collect();
    // Scenes: the reference scene 0 and every scene a sample of this run uses.
    let used: BTreeSet<usize> = std::iter::once(0)
        .chain(specs.iter().map(|s| s.scene))
        .collect();
    let need_h: BTreeSet<usize> = std::iter::once(0)
        .chain(
            todo.iter()
                .filter(|_| recipe.mode == CaptureMode::Matrix)
                .map(|s| s.scene),
        )
        .collect();
    let scenes = run.scenes(&used, &need_h)?;
    let exposure = run.exposure(&scenes.matrices)?;
    let scenes_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let generated = run.samples(&todo, &scenes, &exposure)?;
    let samples_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    run.finish(ids, &specs, used, scenes, &exposure)?;
    let finish_s = t2.elapsed().as_secs_f64();
    Ok(RunSummary {
        samples: specs.len(),
        generated,
        scenes_s,
        samples_s,
        samples_per_s: if samples_s > 0.0 {
            generated as f64 / samples_s
        } else {
            0.0
        },
        finish_s,
    })
}

/// What the steps of [`generate`] share: the plan, the run's options and output folder, and
/// the cancel token of the calling thread (checked between steps and samples).
struct Generation<'a> {
    plan: &'a Plan,
    opts: &'a RunOptions,
    root: &'a Path,
    cancel: crate::cancel::Token,
    /// Camera-side tables drawn so far, by design key (`[camera_table]`).
    tables: std::sync::Mutex<
        BTreeMap<[u64; 2], std::sync::Arc<crate::render::camera_table::CameraTable>>,
    >,
    /// Design keys of the planned scenes, by scene index (computed once: a key prints the
    /// whole camera side, milliseconds a sample otherwise).
    keys: std::sync::Mutex<BTreeMap<usize, [u64; 2]>>,
}

/// The scenes of a run: H and offset of each scene a matrix-mode sample needs, and the
/// sensor's crop and channel names (the same in every scene).
struct SceneSetup {
    matrices: BTreeMap<usize, SceneMatrix>,
    crop: (usize, usize),
    channel_names: Vec<String>,
}

impl Generation<'_> {
    /// `Err(Cancelled)` once the run was cancelled.
    fn check_cancel(&self) -> Result<(), DatasetError> {
        if self.cancel.is_cancelled() {
            Err(DatasetError::Cancelled)
        } else {
            Ok(())
        }
    }

    /// The object size of the recipe, pixels.
    fn object(&self) -> (usize, usize) {
        let n = self.plan.recipe.objects.size_px;
        (n, n)
    }

    /// Step 1: every scene of `used` written (scene.json, and H with its sidecar where the
    /// recipe has H) unless complete; H loaded or kept for the scenes of `need_h`.
    fn scenes(
        &self,
        used: &BTreeSet<usize>,
        need_h: &BTreeSet<usize>,
    ) -> Result<SceneSetup, DatasetError> {
        let (plan, root, object) = (self.plan, self.root, self.object());
        let mut matrices: BTreeMap<usize, SceneMatrix> = BTreeMap::new();
        let mut crop = (0, 0);
        let mut channel_names: Vec<String> = Vec::new();
        let mut stack = depth_stack(plan, root, used, self.opts.progress);
        for &k in used {
            let ps = &plan.scenes[k];
            let sys = &ps.system;
            crop = (sys.camera.width_px, sys.camera.height_px);
            channel_names = sys.response.names.iter().map(|s| s.to_string()).collect();
            let dir = root.join(&ps.id);
            let files = plan.scene_files(k);
            let complete = files.iter().all(|f| root.join(f).is_file());
            if plan.has_matrix && complete && need_h.contains(&k) {
                let m = crate::matrix::load_matrix(&dir.join("H.npz"), Some(object), None)?;
                let offset = m.offset.ok_or_else(|| {
                    out_err(
                        &dir.join("offset.npy"),
                        "missing; delete the scene folder and --resume",
                    )
                })?;
                matrices.insert(k, SceneMatrix { h: m.h, offset });
            } else if !complete && let Some(m) = self.write_scene(k, stack.remove(&k))? {
                matrices.insert(k, m);
            }
        }
        Ok(SceneSetup {
            matrices,
            crop,
            channel_names,
        })
    }

    /// Writes scene `k`'s folder: scene.json, and where the recipe has H, H (from the depth
    /// stack's `stacked`, else computed here) with its sidecar, which it returns.
    fn write_scene(
        &self,
        k: usize,
        stacked: Option<SystemMatrix>,
    ) -> Result<Option<SceneMatrix>, DatasetError> {
        let (plan, recipe, object) = (self.plan, &self.plan.recipe, self.object());
        let ps = &plan.scenes[k];
        let dir = self.root.join(&ps.id);
        let scene_json = serde_json::to_vec_pretty(&ps.loaded.scene)
            .map_err(|e| out_err(&dir, e.to_string()))?;
        if !plan.has_matrix {
            std::fs::create_dir_all(&dir).map_err(|e| write_err(&dir, e))?;
            crate::io::write_atomic(&dir.join("scene.json"), &scene_json)
                .map_err(DatasetError::Write)?;
            return Ok(None);
        }
        let m: SystemMatrix = stacked.unwrap_or_else(|| {
            compute_matrix(
                &ps.system,
                &RenderSettings::lattice(recipe.spp, plan.scene_seed(k), self.opts.progress),
            )
        });
        self.check_cancel()?;
        let sidecar = serde_json::json!({
            "object_px": [object.0, object.1],
            "crop_px": [m.crop.0, m.crop.1],
            "shape": [m.h.rows, m.h.cols],
            "nnz": m.h.nnz(),
            "channels": m.channels,
            "spp": recipe.spp,
            "seed": plan.scene_seed(k),
            "overrides": ps.overrides,
            "depth_mm": ps.params.get(DEPTH_KEY),
            "units": crate::matrix::MATRIX_UNITS,
            "stscam_version": crate::VERSION,
        });
        crate::output::write_matrix(&dir, &m, &sidecar).map_err(DatasetError::Write)?;
        crate::io::write_atomic(&dir.join("scene.json"), &scene_json)
            .map_err(DatasetError::Write)?;
        Ok(Some(SceneMatrix {
            h: m.h,
            offset: m.offset,
        }))
    }

    /// Step 2: the exposure, from the reference scene's all-white capture (H's where it has
    /// one, else rendered).
    fn exposure(&self, matrices: &BTreeMap<usize, SceneMatrix>) -> Result<Exposure, DatasetError> {
        let (recipe, object) = (&self.plan.recipe, self.object());
        let ref_sys = &self.plan.scenes[0].system;
        let white_peak = if let Some(m) = matrices.get(&0) {
            let g = m.h.mul_vec(&vec![1.0; m.h.cols]);
            g.iter()
                .zip(&m.offset)
                .map(|(a, &b)| a + f64::from(b))
                .fold(0.0, f64::max)
        } else {
            let white = vec![1.0; object.0 * object.1];
            let seed = NoiseRng::new(&[recipe.seed, WHITE_TAG]).next_u64() >> 11;
            // 3-D datasets: display white on the scene's display plane, without the scene's
            // objects.
            let mut flat = ref_sys.clone();
            if recipe.is_meshes() {
                flat.world = None;
            }
            render_object(&flat, &white, recipe.spp, seed, recipe.paths)
                .into_iter()
                .fold(0.0f64, f64::max)
        };
        self.check_cancel()?;
        let noise_desc = &ref_sys.scene.noise;
        Ok(Exposure {
            white_peak,
            full_scale: white_peak / noise_desc.exposure_fraction,
            noise: (recipe.noise == NoiseModel::Sensor)
                .then(|| SensorNoise::new(noise_desc, white_peak)),
        })
    }

    /// Step 3: the samples of `todo` (in parallel with H, one by one when rendered); returns
    /// how many were made.
    fn samples(
        &self,
        todo: &[&SampleSpec],
        scenes: &SceneSetup,
        exposure: &Exposure,
    ) -> Result<usize, DatasetError> {
        let (plan, recipe) = (self.plan, &self.plan.recipe);
        let bar = progress_bar(self.opts.progress, todo.len());
        let counter = AtomicUsize::new(0);
        let made = || {
            counter.fetch_add(1, Ordering::Relaxed);
            bar.inc(1);
        };
        match recipe.mode {
            CaptureMode::Matrix => {
                todo.par_iter().try_for_each(|s| {
                    self.flat_sample(s, &plan.scenes[s.scene].system, scenes, exposure)
                        .map(|()| made())
                })?;
            }
            CaptureMode::Render if recipe.is_meshes() => {
                // A few samples at a time: one sample's serial steps (its world and BVH, the
                // frontal view, the files) overlap another's render, and memory stays bounded
                // (at most `chunk` worlds alive). Each sample's bytes depend on its seed only.
                self.draw_scene_tables(todo)?;
                let chunk = 2 * rayon::current_num_threads();
                for group in todo.chunks(chunk) {
                    group.par_iter().try_for_each(|s| {
                        self.check_cancel()?;
                        if self.mesh_sample(s, scenes.crop, exposure)? {
                            made();
                        }
                        Ok::<(), DatasetError>(())
                    })?;
                }
            }
            CaptureMode::Render => {
                for s in todo {
                    let (_, sys) = plan.sample_scene(s)?;
                    self.flat_sample(s, &sys, scenes, exposure)?;
                    made();
                }
            }
        }
        bar.finish_and_clear();
        self.check_cancel()?;
        Ok(counter.load(Ordering::Relaxed))
    }

    /// A sample of a flat object on the display: its object, its capture (with H or rendered
    /// in `sys`), measured and written.
    fn flat_sample(
        &self,
        s: &SampleSpec,
        sys: &System,
        scenes: &SceneSetup,
        exposure: &Exposure,
    ) -> Result<(), DatasetError> {
        let plan = self.plan;
        let gamma = sys.scene.display.gamma;
        let f = plan.object_of(s, gamma)?;
        let clean: Vec<f64> = match plan.recipe.mode {
            CaptureMode::Matrix => {
                let m = &scenes.matrices[&s.scene];
                let g = m.h.mul_vec(&f);
                g.iter()
                    .zip(&m.offset)
                    .map(|(a, &b)| a + f64::from(b))
                    .collect()
            }
            CaptureMode::Render => {
                render_object(sys, &f, plan.recipe.spp, s.seed, plan.recipe.paths)
            }
        };
        self.check_cancel()?;
        let capture = exposure.measure(&clean, s.seed);
        write_sample(
            plan,
            self.root,
            s,
            &f,
            &capture,
            scenes.crop,
            scenes.channel_names.len(),
            gamma,
            exposure.full_scale,
        )
    }

    /// The camera-side table of `sys`'s design, whose key is `key` (drawn on first use, then
    /// shared by every sample of the run with that design; seeded by the recipe, so every shard
    /// draws the same).
    fn camera_table(
        &self,
        sys: &System,
        key: [u64; 2],
        t: &recipe::TableRecipe,
    ) -> Result<std::sync::Arc<crate::render::camera_table::CameraTable>, DatasetError> {
        let known = {
            let tables = self.tables.lock().unwrap_or_else(|e| e.into_inner());
            tables.get(&key).cloned()
        };
        if let Some(t) = known {
            return Ok(t);
        }
        // Drawn without the lock: the draw's own rayon work may run a sibling sample on this
        // thread, which must not wait for a lock its own thread holds. (`samples` draws each
        // planned scene's table before the parallel loop, so a table is drawn once.)
        let ts = crate::render::camera_table::TableSettings {
            spp: t.spp,
            reps: t.reps,
            seed: self.plan.recipe.seed,
        };
        let err = |k: &str, e: crate::render::camera_table::TableError| {
            recipe_err(&self.plan.recipe_path, k, e.to_string())
        };
        let table = match &t.dir {
            None => crate::render::camera_table::build(sys, &ts, false)
                .map_err(|e| err("camera_table", e))?,
            Some(d) => {
                crate::render::table_file::cached(sys, &ts, &table_dir(self.plan, d), false)
                    .map_err(|e| err("camera_table.dir", e))?
                    .table
            }
        };
        let mut tables = self.tables.lock().unwrap_or_else(|e| e.into_inner());
        Ok(tables
            .entry(key)
            .or_insert_with(|| std::sync::Arc::new(table))
            .clone())
    }

    /// The design key of sample `s`, whose scene's system is `sys`. A mesh draw adds objects
    /// and lights, which the key leaves out: a planned scene's key serves all its samples
    /// (computed once); a design drawn per sample (`vary`) has its own.
    fn sample_design_key(&self, s: &SampleSpec, sys: &Cow<'_, System>) -> [u64; 2] {
        match sys {
            Cow::Borrowed(base) => *self
                .keys
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .entry(s.scene)
                .or_insert_with(|| crate::render::camera_table::design_key(base)),
            Cow::Owned(own) => crate::render::camera_table::design_key(own),
        }
    }

    /// Draws (or reads) the camera-side table of every planned scene that a mesh sample of
    /// `todo` renders, one scene at a time, before the samples run in parallel (designs drawn
    /// per sample get theirs with the sample).
    fn draw_scene_tables(&self, todo: &[&SampleSpec]) -> Result<(), DatasetError> {
        let Some(t) = self.plan.recipe.camera_table.as_ref() else {
            return Ok(());
        };
        if !self.plan.designs_planned() {
            return Ok(());
        }
        let mut done = BTreeSet::new();
        for s in todo {
            if self.plan.mesh_source(s).is_none() || !done.insert(s.scene) {
                continue;
            }
            let sys = Cow::Borrowed(&self.plan.scenes[s.scene].system);
            let key = self.sample_design_key(s, &sys);
            self.camera_table(&sys, key, t)?;
        }
        Ok(())
    }

    /// A sample of a 3-D scene: its meshes drawn, rendered with the frontal view, measured and
    /// written; `false` where the sample has no mesh source.
    fn mesh_sample(
        &self,
        s: &SampleSpec,
        crop: (usize, usize),
        exposure: &Exposure,
    ) -> Result<bool, DatasetError> {
        let (plan, recipe) = (self.plan, &self.plan.recipe);
        let (ls, sys) = plan.sample_scene(s)?;
        let Some((src, files)) = plan.mesh_source(s) else {
            return Ok(false);
        };
        let key = recipe
            .camera_table
            .as_ref()
            .map(|_| self.sample_design_key(s, &sys));
        let (d, _) = plan.mesh_draw(s, src, files, &ls)?;
        let sys = meshes::sample_system(&ls, &sys, &d, src.units.as_deref())
            .map_err(|e| recipe_err(&plan.recipe_path, source_key(s), e.to_string()))?;
        let space = recipe.objects.frontal_space();
        let band = &sys.scene.sampling;
        if space != crate::world::colour::FrontalSpace::Sensor
            && crate::world::colour::ColourWeights::new(
                space,
                band.lambda_min_nm,
                band.lambda_max_nm,
            )
            .is_none()
        {
            return Err(recipe_err(
                &plan.recipe_path,
                "objects.frontal_space",
                format!(
                    "{}: the CIE luminance function is 0 over the sampling band",
                    space.name()
                ),
            ));
        }
        let table = recipe
            .camera_table
            .as_ref()
            .zip(key)
            .map(|(t, key)| self.camera_table(&sys, key, t).map(|t| (t, key)))
            .transpose()?;
        let (clean, frontal) = meshes::render_sample(
            &sys,
            recipe.objects.size_px,
            [recipe.spp, recipe.objects.frontal_spp(recipe.spp)],
            s.seed,
            space,
            table.as_ref().map(|(t, key)| (&**t, *key)),
        )
        .map_err(|e| recipe_err(&plan.recipe_path, "camera_table", e.to_string()))?;
        let capture = exposure.measure(&clean, s.seed);
        write_mesh_sample(
            plan,
            self.root,
            s,
            &capture,
            &frontal,
            crop,
            exposure.full_scale,
        )?;
        Ok(true)
    }

    /// Step 4: metadata, checksums and the card (`dataset.json`, or a shard's `shard.json`
    /// for ids `ids`); then the run marker is removed.
    fn finish(
        &self,
        ids: std::ops::Range<usize>,
        specs: &[SampleSpec],
        used: BTreeSet<usize>,
        scenes: SceneSetup,
        exposure: &Exposure,
    ) -> Result<(), DatasetError> {
        let (plan, root) = (self.plan, self.root);
        let (crop, channel_names) = (scenes.crop, scenes.channel_names);
        let capture_shape = if channel_names.len() == 1 {
            vec![crop.1, crop.0]
        } else {
            vec![channel_names.len(), crop.1, crop.0]
        };
        let ctx = CardContext {
            plan,
            capture_shape,
            channels: channel_names,
            exposure: serde_json::json!({
                "rule": "fixed once for the whole dataset from the reference scene's all-white capture (scene_000)",
                "white_peak": exposure.white_peak,
                "capture_full_scale": exposure.full_scale,
                "noise_model": plan.recipe.noise,
                "sensor": plan.scenes[0].system.scene.noise,
                "electrons_per_unit": exposure.noise.as_ref().map(|n| n.electrons_per_unit),
            }),
        };
        let metadata: Vec<(usize, String)> = specs
            .par_iter()
            .map(|s| Ok((s.split, metadata_line(plan, s)?)))
            .collect::<Result<_, DatasetError>>()?;
        let scene_ids: Vec<usize> = used.into_iter().collect();
        let card = finish(root, &ctx, &metadata, &scene_ids, specs)?;
        let (name, bytes) = match self.opts.shard {
            Some(shard) => {
                let sc = ShardCard {
                    shard,
                    ids: [ids.start, ids.end],
                    card,
                };
                ("shard.json", serde_json::to_vec_pretty(&sc))
            }
            None => ("dataset.json", serde_json::to_vec_pretty(&card)),
        };
        let bytes = bytes.map_err(|e| out_err(root, e.to_string()))?;
        crate::io::write_atomic(&root.join(name), &bytes).map_err(DatasetError::Write)?;
        std::fs::remove_file(root.join(RUN_MARKER))
            .map_err(|e| write_err(&root.join(RUN_MARKER), e))
    }
}

/// The capture of object `f` (linear intensities) rendered by the tracer, channel-major: the
/// designed path (`render`), or every path (`stscam_stray`'s all-paths image, the same
/// samples).
fn render_object(sys: &System, f: &[f64], spp: u32, seed: u64, paths: TracePaths) -> Vec<f64> {
    let mut s = sys.clone();
    s.display.set_intensity(f);
    let channels = match paths {
        TracePaths::Designed => render(&s, &RenderSettings::lattice(spp, seed, false)).channels,
        TracePaths::All => {
            let set = stscam_stray::image::StraySettings {
                spp,
                seed,
                paths: Default::default(),
                progress: false,
            };
            stscam_stray::image::stray_images(&s, &set).all_paths
        }
    };
    channels.iter().flatten().map(|&v| f64::from(v)).collect()
}

fn progress_bar(show: bool, len: usize) -> crate::progress::Progress {
    crate::progress::Progress::new(show, len as u64, "samples")
}

#[allow(clippy::too_many_arguments)]
fn write_sample(
    plan: &Plan,
    root: &Path,
    s: &SampleSpec,
    f: &[f64],
    capture: &[f32],
    crop: (usize, usize),
    channels: usize,
    gamma: f64,
    full_scale: f64,
) -> Result<(), DatasetError> {
    let n = plan.recipe.objects.size_px;
    let files = plan.sample_files(s);
    let (on, op, cn, cp) = (&files[0], &files[1], &files[2], &files[3]);
    split_dir(root, s)?;
    let f32s: Vec<f32> = f.iter().map(|&v| v as f32).collect();
    put(root, on, &npy(on, &[n, n], &f32s)?)?;
    let png =
        crate::output::encode_object_png(f, n, n, gamma).map_err(|m| out_err(&root.join(op), m))?;
    put(root, op, &png)?;
    put_image(root, [cn, cp], capture, crop, channels, full_scale)
}

/// Creates the split folder of a sample.
fn split_dir(root: &Path, s: &SampleSpec) -> Result<(), DatasetError> {
    let dir = root.join(SPLITS[s.split]);
    if !dir.is_dir() {
        std::fs::create_dir_all(&dir).map_err(|e| write_err(&dir, e))?;
    }
    Ok(())
}

/// Writes an image `v` (channel-major, `size` = (w, h)) as float32 `.npy` ([h, w], or
/// [c, h, w] for several channels) and 16-bit linear PNG, round(65535·clamp(v / full_scale)).
fn put_image(
    root: &Path,
    [rel_npy, rel_png]: [&str; 2],
    v: &[f32],
    size: (usize, usize),
    channels: usize,
    full_scale: f64,
) -> Result<(), DatasetError> {
    let shape: Vec<usize> = if channels == 1 {
        vec![size.1, size.0]
    } else {
        vec![channels, size.1, size.0]
    };
    put(root, rel_npy, &npy(rel_npy, &shape, v)?)?;
    // PNG: pixel-major, channels interleaved.
    let p = size.0 * size.1;
    let q = |x: f32| ((f64::from(x) / full_scale).clamp(0.0, 1.0) * 65535.0).round() as u16;
    let samples: Vec<u16> = if channels == 1 {
        v.iter().map(|&x| q(x)).collect()
    } else {
        (0..p)
            .flat_map(|i| (0..channels).map(move |c| q(v[c * p + i])))
            .collect()
    };
    let png = crate::io::encode_png16(
        size.0,
        size.1,
        channels.min(3),
        &samples,
        crate::io::PngTransfer::Linear,
    )
    .map_err(|m| out_err(&root.join(rel_png), m))?;
    put(root, rel_png, &png)
}

/// Writes the six files of a 3-D sample: capture (`.npy`, `.png` as for 2-D samples), frontal
/// (`.npy` in capture units, `.png` with full scale [`meshes::FRONTAL_PNG_FULL_SCALE`]),
/// depth (`.npy`, mm, +inf where nothing is hit) and mask (16-bit `.png`).
fn write_mesh_sample(
    plan: &Plan,
    root: &Path,
    s: &SampleSpec,
    capture: &[f32],
    frontal: &stscam_tracer::frontal::Frontal,
    crop: (usize, usize),
    full_scale: f64,
) -> Result<(), DatasetError> {
    let files = plan.sample_files(s);
    split_dir(root, s)?;
    let nch = frontal.channels.len();
    let size = (frontal.width, frontal.height);
    // The capture has the sensor's channels; the frontal image those of its colour space.
    let capture_channels = capture.len() / (crop.0 * crop.1).max(1);
    put_image(
        root,
        [&files[0], &files[1]],
        capture,
        crop,
        capture_channels,
        full_scale,
    )?;
    let fv: Vec<f32> = frontal.channels.concat();
    put_image(
        root,
        [&files[2], &files[3]],
        &fv,
        size,
        nch,
        meshes::FRONTAL_PNG_FULL_SCALE,
    )?;
    put(
        root,
        &files[4],
        &npy(&files[4], &[size.1, size.0], &frontal.depth_mm)?,
    )?;
    let png = crate::io::encode_png16(
        size.0,
        size.1,
        1,
        &frontal.mask,
        crate::io::PngTransfer::Labels,
    )
    .map_err(|m| out_err(&root.join(&files[5]), m))?;
    put(root, &files[5], &png)
}
