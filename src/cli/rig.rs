//! `rigserve rig`: mesh in, skeleton (bone tree JSON) out.

use super::LimitArgs;
use anyhow::Context;
use rigserve::infer::{
    Backend, BackendConfig, ModelFiles, Runtime, SamplingParams, SessionConfig, SkeletonModel,
    Variant,
};
use rigserve::mesh;
use rigserve::predict::{predict_skeleton, PredictConfig};
use rigserve::rig::skin::SkinConfig;
use std::path::{Path, PathBuf};

/// Where the model and ONNX Runtime come from (shared by `rig` and `bench`).
#[derive(clap::Args, Debug, Clone)]
pub struct ModelArgs {
    /// Folder with `encoder.onnx` and `decoder.onnx` (from `training/skeleton/export.py`),
    /// or a models root holding them in `skeleton/`.
    #[arg(long, env = "RIGSERVE_MODELS", default_value = "models")]
    pub models: PathBuf,
    /// Which exported weights: fp32, fp16 or int8.
    #[arg(long, default_value = "fp32")]
    pub variant: Variant,
    /// The ONNX Runtime shared library [default: .onnxruntime/libonnxruntime.so.1.31.1 in
    /// the current directory, then beside the executable].
    #[arg(long, env = "RIGSERVE_ORT_LIB")]
    pub ort_lib: Option<PathBuf>,
    /// ONNX Runtime intra-op threads per session.
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
}

impl ModelArgs {
    pub fn load(&self) -> anyhow::Result<SkeletonModel> {
        let rt = Runtime::init(self.ort_lib.as_deref())
            .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
        let files = ModelFiles::in_dir(&self.models, self.variant);
        SkeletonModel::load(
            &rt,
            &files,
            &SessionConfig {
                intra_threads: self.threads,
            },
        )
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))
    }

    pub fn backend(&self, config: BackendConfig) -> anyhow::Result<Backend> {
        let model = self.load()?;
        Backend::new(model, config).map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))
    }
}

/// How candidates are decoded (shared by `rig` and `eval --skeleton-only`).
#[derive(clap::Args, Debug, Clone)]
pub struct DecodeArgs {
    /// Seeds surface sampling and the candidates (candidate k uses seed + k).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Candidates to decode; the best by geometric checks is kept.
    #[arg(long, default_value_t = 4)]
    pub samples: usize,
    #[arg(long, default_value_t = 128)]
    pub max_bones: usize,
    /// Sampling temperature; 0 decodes greedily (one candidate).
    #[arg(long, default_value_t = 0.8)]
    pub temperature: f32,
    /// Keep only the k most likely tokens at each step (0: all).
    #[arg(long, default_value_t = 0)]
    pub top_k: usize,
    /// Nucleus sampling threshold (1: off).
    #[arg(long, default_value_t = 0.95)]
    pub top_p: f32,
}

impl DecodeArgs {
    pub fn predict_config(&self, category: Option<String>) -> PredictConfig {
        PredictConfig {
            samples: self.samples,
            seed: self.seed,
            sampling: SamplingParams {
                temperature: self.temperature,
                top_k: self.top_k,
                top_p: self.top_p,
                seed: self.seed,
            },
            max_bones: self.max_bones,
            category,
            ..PredictConfig::default()
        }
    }
}

/// Knobs of the geometric skinning (shared by `rig`, `eval --skin-on-gt` and `bench skin`).
#[derive(clap::Args, Debug, Clone)]
pub struct SkinArgs {
    /// Voxels along the mesh's longest side for the geodesic distances (8 to 192).
    #[arg(long, default_value_t = SkinConfig::default().resolution)]
    pub voxels: usize,
    /// Inverse-distance falloff exponent (larger: crisper boundaries between bones).
    #[arg(long, default_value_t = SkinConfig::default().falloff)]
    pub falloff: f32,
    /// Added to every distance, in voxels (larger: softer blends near the bones).
    #[arg(long, default_value_t = SkinConfig::default().softness)]
    pub softness: f32,
    /// Influences below this weight are dropped.
    #[arg(long, default_value_t = SkinConfig::default().min_weight)]
    pub min_weight: f32,
}

impl SkinArgs {
    pub fn config(&self) -> SkinConfig {
        SkinConfig {
            resolution: self.voxels,
            falloff: self.falloff,
            softness: self.softness,
            min_weight: self.min_weight,
            ..SkinConfig::default()
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct RigArgs {
    /// The mesh (GLB, glTF, VRM or OBJ).
    pub input: PathBuf,
    /// Predict the skeleton only (skinning is not part of this command yet, so this is
    /// required).
    #[arg(long)]
    pub skeleton_only: bool,
    /// Where to write the bone tree JSON; standard output when absent.
    #[arg(long)]
    pub bones: Option<PathBuf>,
    #[command(flatten)]
    pub decode: DecodeArgs,
    /// Category hint (humanoid, quadruped, bird_flyer, …).
    #[arg(long)]
    pub category: Option<String>,
    /// Bone tree JSON of bones to keep; prediction continues from them.
    #[arg(long)]
    pub keep: Option<PathBuf>,
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub limits: LimitArgs,
}

fn read_keep(path: &Path) -> anyhow::Result<rigserve::rig::Skeleton> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    rigserve::export::parse_bone_tree(&value)
        .map_err(|e| anyhow::anyhow!("{}: {e} [{}]", path.display(), e.code()))
}

pub fn run(a: RigArgs) -> anyhow::Result<()> {
    if !a.skeleton_only {
        anyhow::bail!("rig: skinning is not available in this command yet; pass --skeleton-only to predict the skeleton");
    }
    let bytes =
        std::fs::read(&a.input).with_context(|| format!("reading {}", a.input.display()))?;
    let asset = mesh::load(&bytes, &a.limits.limits())
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let keep = a.keep.as_deref().map(read_keep).transpose()?;
    let backend = a.model.backend(BackendConfig {
        max_batch: a.decode.samples.max(1),
        kv_cache: true,
    })?;
    let cfg = a.decode.predict_config(a.category.clone());
    let pred = predict_skeleton(&backend, &asset.mesh, &cfg, keep.as_ref())
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let tree = serde_json::to_string_pretty(&rigserve::export::bone_tree(&pred.skeleton))?;
    match &a.bones {
        Some(out) => std::fs::write(out, tree + "\n")
            .with_context(|| format!("writing {}", out.display()))?,
        None => println!("{tree}"),
    }
    let c = &pred.candidates[pred.chosen];
    let s = c.score.expect("the chosen candidate is scored");
    eprintln!(
        "{}: {} bones (candidate {} of {}, seed {}, cost {:.3}: coverage {:.3}, outside {:.3}, bbox {:.3})",
        a.input.display(),
        pred.skeleton.len(),
        pred.chosen,
        pred.candidates.len(),
        c.seed,
        s.cost,
        s.coverage,
        s.outside,
        s.bbox_excess
    );
    Ok(())
}
