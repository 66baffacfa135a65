//! `rigserve rig`: mesh in, rigged GLB out (or, with `--skeleton-only`, the bone tree).

use super::LimitArgs;
use anyhow::Context;
use rigserve::export::{export_glb, Animation, BoneTreeError, ExportOptions};
use rigserve::infer::{
    Backend, BackendConfig, ModelFiles, Runtime, SamplingParams, SessionConfig, SkeletonModel,
    SkinModel, Variant,
};
use rigserve::mesh;
use rigserve::predict::library::Library;
use rigserve::predict::refine::Refine;
use rigserve::predict::{predict_skeleton, Origin, PredictConfig};
use rigserve::rig::groundtruth::extract;
use rigserve::rig::skin::{skin_with_timed, CandidateScorer, SkinConfig};
use rigserve::rig::Skeleton;
use std::path::{Path, PathBuf};
use std::sync::Arc;

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
    /// Decode with `decoder.onnx` over a cache of one shared length even when the model
    /// has the ragged `decoder_step.onnx` (the slower layout; for comparison).
    #[arg(long, env = "RIGSERVE_DENSE_DECODE")]
    pub dense_decode: bool,
    /// Skeleton library (`rigserve library` writes one) whose most similar entry, moved
    /// onto the mesh, joins the candidates [default: library.bin in --models when there].
    #[arg(long, env = "RIGSERVE_LIBRARY", conflicts_with = "no_library")]
    pub library: Option<PathBuf>,
    /// Decode with the model alone, even when the models folder has a library.
    #[arg(long)]
    pub no_library: bool,
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

    /// The library file to use, if any: `--library`, else the models folder's own.
    pub fn library_path(&self) -> Option<PathBuf> {
        if self.no_library {
            return None;
        }
        self.library.clone().or_else(|| {
            let p = rigserve::predict::library::default_path(&self.models);
            p.is_file().then_some(p)
        })
    }

    pub fn load_library(&self) -> anyhow::Result<Option<Arc<Library>>> {
        self.library_path()
            .map(|p| {
                let lib = Library::load(&p).map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
                eprintln!(
                    "skeleton library: {} ({} rigs)",
                    p.display(),
                    lib.entries.len()
                );
                Ok(Arc::new(lib))
            })
            .transpose()
    }

    /// The files a run with these arguments reads, hashed (`library`: whether the
    /// library comes from these arguments at all).
    pub fn used(&self, library: bool, category_hint: bool) -> anyhow::Result<rigserve::eval::Used> {
        let files = ModelFiles::in_dir(&self.models, self.variant);
        let hash = |p: &Path| {
            rigserve::eval::FileHash::of(p).with_context(|| format!("reading {}", p.display()))
        };
        let mut models = vec![hash(&files.encoder)?, hash(&files.decoder)?];
        if files.step.is_file() {
            models.push(hash(&files.step)?);
        }
        let library = match self.library_path() {
            Some(p) if library => Some(hash(&p)?),
            _ => None,
        };
        Ok(rigserve::eval::Used {
            models,
            library,
            category_hint,
        })
    }

    pub fn backend(&self, mut config: BackendConfig) -> anyhow::Result<Backend> {
        config.ragged &= !self.dense_decode;
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
    #[arg(long, default_value_t = rigserve::predict::DEFAULT_TEMPERATURE)]
    pub temperature: f32,
    /// Keep only the k most likely tokens at each step (0: all).
    #[arg(long, default_value_t = 0)]
    pub top_k: usize,
    /// Nucleus sampling threshold (1: off).
    #[arg(long, default_value_t = 0.95)]
    pub top_p: f32,
    /// Library entries that join the candidates.
    #[arg(long, default_value_t = rigserve::predict::DEFAULT_LIBRARY_CANDIDATES)]
    pub library_candidates: usize,
    /// Shape distance under which the nearest library entry is taken over the model.
    #[arg(long, default_value_t = rigserve::predict::DEFAULT_LIBRARY_TRUST)]
    pub library_trust: f32,
    /// Let the model move library rigs' joints by up to this many bins (0: off; measured
    /// and left off, MODEL_CARD.md "The model moves the joints").
    #[arg(long, default_value_t = 0)]
    pub refine_library: u32,
    /// Let the model move its own candidates' joints by up to this many bins (0: off).
    #[arg(long, default_value_t = 0)]
    pub refine_model: u32,
    /// The mesh's up axis: y (glTF's convention), -y, x, -x, z, -z, or auto (found by
    /// turning the mesh to its nearest library rig). The rig is written in the mesh's own
    /// frame either way.
    #[arg(long, default_value = "y")]
    pub up: rigserve::predict::orient::Up,
    /// auto: the model decides (and a close library rig is borrowed); mixamo: decode the
    /// Mixamo body template; none: decode freely, without the template or the library.
    /// The API's `template`.
    #[arg(long, default_value = "auto")]
    pub template: rigserve::jobs::TemplateChoice,
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
            library_candidates: self.library_candidates,
            library_trust: self.library_trust,
            refine_library: (self.refine_library > 0).then_some(Refine {
                window: self.refine_library,
            }),
            refine_model: (self.refine_model > 0).then_some(Refine {
                window: self.refine_model,
            }),
            up: self.up,
            template: self.template.into(),
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
    /// Meshes with more distinct positions skin on a coarser copy of this many, every
    /// vertex taking its cluster's weights (0: always full resolution).
    #[arg(long, default_value_t = SkinConfig::default().max_vertices)]
    pub skin_max_vertices: usize,
    /// auto: the learned skin model when `--skin-model` holds one, else geometric weights;
    /// learned: the model or an error; geometric: never the model.
    #[arg(long, value_enum, default_value_t = SkinMethod::Auto)]
    pub skin_method: SkinMethod,
    /// The learned skin model: an ONNX file, its folder, or a models root holding `skin/`.
    #[arg(long, env = "RIGSERVE_SKIN_MODEL", default_value = "models")]
    pub skin_model: PathBuf,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SkinMethod {
    Auto,
    Learned,
    Geometric,
}

impl SkinArgs {
    /// The learned model `--skin-method` asks for, loaded on ONNX Runtime (`ort_lib`, as
    /// `--ort-lib`); None means geometric weights.
    pub fn load_model(&self, ort_lib: Option<&Path>) -> anyhow::Result<Option<SkinModel>> {
        let found = match self.skin_method {
            SkinMethod::Geometric => return Ok(None),
            SkinMethod::Auto => SkinModel::find(&self.skin_model),
            SkinMethod::Learned => Some(SkinModel::find(&self.skin_model).ok_or_else(|| {
                anyhow::anyhow!(
                    "no skin model (skin.onnx or skin.fp16.onnx) under {} [model_not_found]",
                    self.skin_model.display()
                )
            })?),
        };
        let Some(file) = found else {
            return Ok(None);
        };
        let rt = Runtime::init(ort_lib).map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
        SkinModel::load(&rt, &file, &SessionConfig::default())
            .map(Some)
            .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))
    }

    pub fn config(&self) -> SkinConfig {
        SkinConfig {
            resolution: self.voxels,
            falloff: self.falloff,
            softness: self.softness,
            min_weight: self.min_weight,
            max_vertices: self.skin_max_vertices,
            ..SkinConfig::default()
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct RigArgs {
    /// The mesh (GLB, glTF, VRM or OBJ).
    pub input: PathBuf,
    /// Where to write the rigged GLB (skeleton and skin weights).
    #[arg(short = 'o', long = "out")]
    pub out: Option<PathBuf>,
    /// Predict the skeleton only and write its bone tree (no skinning, no GLB).
    #[arg(long, conflicts_with_all = ["skeleton", "skeleton_from_input", "out"])]
    pub skeleton_only: bool,
    /// Skin this skeleton (a bone tree JSON in the mesh's frame) instead of predicting one.
    #[arg(long, conflicts_with = "skeleton_from_input")]
    pub skeleton: Option<PathBuf>,
    /// Re-skin the skeleton the input file already has.
    #[arg(long)]
    pub skeleton_from_input: bool,
    /// A test motion baked into the GLB as an animation clip: none or preview.
    #[arg(long, default_value = "none", value_parser = parse_animation, conflicts_with = "skeleton_only")]
    pub animation: Animation,
    /// Where to write the bone tree JSON; with --skeleton-only, standard output when absent.
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
    pub skin: SkinArgs,
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub limits: LimitArgs,
}

/// Reads a bone tree JSON. A tree that parses but breaks the skeleton's invariants is
/// reported with the skeleton's own code (`skeleton_empty`, `skeleton_not_a_tree`, …).
fn read_skeleton(path: &Path) -> anyhow::Result<Skeleton> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: not JSON: {e} [bone_tree_malformed]", path.display()))?;
    rigserve::export::parse_bone_tree(&value).map_err(|e| match e {
        BoneTreeError::Skeleton(inner) => {
            anyhow::anyhow!("{}: {inner} [{}]", path.display(), inner.code())
        }
        e => anyhow::anyhow!("{}: {e} [{}]", path.display(), e.code()),
    })
}

fn predict(a: &RigArgs, mesh: &mesh::Mesh) -> anyhow::Result<Skeleton> {
    let keep = a.keep.as_deref().map(read_skeleton).transpose()?;
    let backend = a.model.backend(BackendConfig {
        max_batch: a.decode.samples.max(1),
        kv_cache: true,
        ragged: true,
        ..BackendConfig::default()
    })?;
    let mut cfg = a.decode.predict_config(a.category.clone());
    cfg.library = a.model.load_library()?;
    let pred = predict_skeleton(&backend, mesh, &cfg, keep.as_ref())
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let c = &pred.candidates[pred.chosen];
    let s = c.score.expect("the chosen candidate is scored");
    eprintln!(
        "{}: {} bones (candidate {} of {}, {}, cost {:.3}: coverage {:.3}, outside {:.3}, bbox {:.3})",
        a.input.display(),
        pred.skeleton.len(),
        pred.chosen,
        pred.candidates.len(),
        match &c.origin {
            Origin::Model { seed } => format!("model seed {seed}"),
            Origin::Library { name, shape } => format!("library {name}, shape distance {shape:.3}"),
        },
        s.cost,
        s.coverage,
        s.outside,
        s.bbox_excess
    );
    Ok(pred.skeleton)
}

fn parse_animation(s: &str) -> Result<Animation, String> {
    Animation::parse(s).ok_or_else(|| format!("{s:?} is not an animation: none or preview"))
}

pub fn run(a: RigArgs) -> anyhow::Result<()> {
    if !a.skeleton_only && a.out.is_none() {
        anyhow::bail!("rig: say where the rigged GLB goes with -o OUT.glb, or pass --skeleton-only to predict the skeleton alone");
    }
    let bytes =
        std::fs::read(&a.input).with_context(|| format!("reading {}", a.input.display()))?;
    let asset = mesh::load(&bytes, &a.limits.limits())
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let skeleton = if let Some(path) = &a.skeleton {
        read_skeleton(path)?
    } else if a.skeleton_from_input {
        extract(&asset)
            .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "{} has no skinned mesh to take a skeleton from [no_skin]",
                    a.input.display()
                )
            })?
            .skeleton
    } else {
        predict(&a, &asset.mesh)?
    };
    let tree = serde_json::to_string_pretty(&rigserve::export::bone_tree(&skeleton))?;
    match (&a.bones, a.skeleton_only) {
        (Some(out), _) => std::fs::write(out, tree + "\n")
            .with_context(|| format!("writing {}", out.display()))?,
        (None, true) => println!("{tree}"),
        (None, false) => {}
    }
    let Some(out) = &a.out else {
        return Ok(());
    };
    let model = a.skin.load_model(a.model.ort_lib.as_deref())?;
    let (weights, t) = skin_with_timed(
        &asset.mesh,
        &skeleton,
        &a.skin.config(),
        model.as_ref().map(|m| m as &dyn CandidateScorer),
    )
    .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let export = ExportOptions {
        animation: a.animation,
        ..ExportOptions::default()
    };
    let glb = export_glb(&asset, &skeleton, &weights, &export)
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    std::fs::write(out, glb).with_context(|| format!("writing {}", out.display()))?;
    eprintln!(
        "{}: skinned {} vertices to {} bones ({}) in {:.0} ms (voxels {:.0}, geodesic {:.0}, model {:.0}, weights {:.0}) -> {}",
        a.input.display(),
        weights.per_vertex.len(),
        skeleton.len(),
        if model.is_some() { "learned" } else { "geometric" },
        t.voxelize_ms + t.geodesic_ms + t.model_ms + t.weights_ms,
        t.voxelize_ms,
        t.geodesic_ms,
        t.model_ms,
        t.weights_ms,
        out.display()
    );
    Ok(())
}
