//! One job's rigging, start to end: load and validate the upload, predict (or take) the
//! skeleton, skin it, export the GLB and the bone tree. Blocking: workers run it on the
//! blocking pool, while the skeleton decode itself runs on the shared inference thread,
//! batched with the other jobs' candidates.

use super::model::{JobOptions, Stage};
use super::slots::CpuSlots;
use crate::export::{bone_tree, export_glb, parse_bone_tree, ExportOptions};
use crate::infer::Backend;
use crate::infer::SkinModel;
use crate::mesh::{self, Limits};
use crate::predict::library::Library;
use crate::predict::{predict_from_samples, samples_for, PredictConfig};
use crate::rig::groundtruth;
use crate::rig::skin::{prepare, CandidateScorer, SkinConfig};
use crate::rig::Skeleton;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// What the workers share: the skeleton model's backend and the settings of each stage.
pub struct Engine {
    /// `None` when no skeleton model is loaded: only `skin_only` jobs can run.
    pub skeleton: Option<Backend>,
    pub limits: Limits,
    pub skin: SkinConfig,
    /// The learned skin model; `None`: geometric weights.
    pub skin_model: Option<SkinModel>,
    /// Rigged meshes whose skeletons join the model's candidates.
    pub library: Option<Arc<Library>>,
    /// Candidates per job at most (`samples` is clamped to it).
    pub max_samples: usize,
    /// Bones per skeleton at most (`max_bones` is clamped to it).
    pub max_bones: usize,
    /// Jobs skinning and exporting at once (see [`CpuSlots`]).
    pub cpu_slots: CpuSlots,
}

/// A failed job's code and message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StageError {
    pub code: String,
    pub message: String,
}

impl StageError {
    fn new(code: &str, message: impl std::fmt::Display) -> StageError {
        StageError {
            code: code.to_string(),
            message: message.to_string(),
        }
    }
}

pub struct Rigged {
    pub glb: Vec<u8>,
    pub bone_tree: serde_json::Value,
    pub bones: usize,
}

/// Progress callbacks and the cancel check of a running job.
pub trait Progress {
    fn stage(&self, stage: Stage);
    /// True once the job was canceled (or its lease lost): stop at the next check.
    fn canceled(&self) -> bool;
}

fn check(p: &dyn Progress) -> Result<(), StageError> {
    if p.canceled() {
        Err(StageError::new("canceled", "the job was canceled"))
    } else {
        Ok(())
    }
}

/// The bone tree in `options.skeleton`, parsed.
pub fn options_skeleton(options: &JobOptions) -> Result<Option<Skeleton>, StageError> {
    options
        .skeleton
        .as_ref()
        .map(|v| parse_bone_tree(v).map_err(|e| StageError::new(e.code(), e)))
        .transpose()
}

pub fn run(
    engine: &Engine,
    input: &[u8],
    options: &JobOptions,
    progress: Arc<dyn Progress + Send + Sync>,
) -> Result<Rigged, StageError> {
    let p = &*progress;
    p.stage(Stage::Validating);
    let asset = mesh::load(input, &engine.limits).map_err(|e| StageError::new(e.code(), e))?;
    let given = options_skeleton(options)?;
    check(p)?;

    // The mesh's side of skinning (welding, voxels, volume) needs no skeleton, so it can
    // be built while this thread waits for the skeleton, mostly on the shared inference
    // thread. Only on a spare CPU slot, though (one no job is waiting for): with every
    // slot busy (a loaded server) another thread voxelizing beside them took jobs/min and
    // poll latency (README, "The Zen 4 again"). If none is spare before the skeleton is
    // done, it is built below, in the job's own slot, as before.
    let skeleton_done = AtomicBool::new(false);
    let (skeleton, early) = std::thread::scope(|s| {
        let early = s.spawn(|| {
            let _slot = engine
                .cpu_slots
                .acquire_spare(|| skeleton_done.load(Ordering::Relaxed) || p.canceled())?;
            Some(prepare(&asset.mesh, &engine.skin))
        });
        let skeleton = {
            // Dropped however this ends, a panic included: the scope joins the other
            // thread before it unwinds, so that thread must stop waiting then too.
            let _done = Done(&skeleton_done, &engine.cpu_slots);
            skeleton_for(engine, &asset, options, given, &progress)
        };
        let early = early
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        (skeleton, early)
    });
    let skeleton = skeleton?;
    check(p)?;

    p.stage(Stage::Skinning);
    let _slot = engine
        .cpu_slots
        .acquire(|| p.canceled())
        .ok_or_else(|| StageError::new("canceled", "the job was canceled"))?;
    let scorer = engine
        .skin_model
        .as_ref()
        .map(|m| m as &dyn CandidateScorer);
    let prepared = early.unwrap_or_else(|| prepare(&asset.mesh, &engine.skin));
    let weights = prepared
        .and_then(|m| m.skin(&skeleton, &engine.skin, scorer))
        .map_err(|e| StageError::new(e.code(), e))?;
    check(p)?;

    p.stage(Stage::Exporting);
    let export = ExportOptions {
        animation: options.animation,
        ..ExportOptions::default()
    };
    let glb = export_glb(&asset, &skeleton, &weights, &export)
        .map_err(|e| StageError::new(e.code(), e))?;
    Ok(Rigged {
        glb,
        bone_tree: bone_tree(&skeleton),
        bones: skeleton.len(),
    })
}

/// Marks a job's skeleton done and wakes its early preparation if that still waits for a
/// slot (see `run`).
struct Done<'a>(&'a AtomicBool, &'a CpuSlots);

impl Drop for Done<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
        self.1.wake_waiters();
    }
}

/// The job's skeleton: the one given or uploaded for `skin_only`, else the model's.
fn skeleton_for(
    engine: &Engine,
    asset: &mesh::Asset,
    options: &JobOptions,
    given: Option<Skeleton>,
    progress: &Arc<dyn Progress + Send + Sync>,
) -> Result<Skeleton, StageError> {
    let p = &**progress;
    let skeleton = if options.skin_only {
        match given {
            Some(s) => s,
            None => groundtruth::extract(asset)
                .map_err(|e| StageError::new(e.code(), e))?
                .map(|gt| gt.skeleton)
                .ok_or_else(|| {
                    StageError::new(
                        "no_skeleton",
                        "skin_only needs a skeleton: pass one in `skeleton` or upload a rigged file",
                    )
                })?,
        }
    } else {
        let backend = engine.skeleton.as_ref().ok_or_else(|| {
            StageError::new(
                "model_unavailable",
                "no skeleton model is loaded on this server; only skin_only jobs can run",
            )
        })?;
        p.stage(Stage::Encoding);
        let cfg = predict_config(engine, options, progress.clone());
        let samples = samples_for(&asset.mesh, &cfg).map_err(|e| StageError::new(e.code(), e))?;
        check(p)?;
        p.stage(Stage::Skeleton);
        predict_from_samples(backend, &samples, &cfg, given.as_ref())
            .map_err(|e| StageError::new(e.code(), e))?
            .skeleton
    };
    Ok(skeleton)
}

fn predict_config(
    engine: &Engine,
    options: &JobOptions,
    progress: Arc<dyn Progress + Send + Sync>,
) -> PredictConfig {
    let mut cfg = PredictConfig {
        samples: options.samples.clamp(1, engine.max_samples.max(1)),
        seed: options.seed,
        max_bones: options.max_bones.clamp(1, engine.max_bones.max(1)),
        category: options.category.clone(),
        template: options.template.into(),
        canceled: Some(Arc::new(move || progress.canceled())),
        library: engine.library.clone(),
        up: options.up,
        ..PredictConfig::default()
    };
    cfg.sampling.seed = options.seed;
    cfg
}
