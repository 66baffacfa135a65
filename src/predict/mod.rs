//! Mesh → skeleton with the skeleton model: normalize and sample the mesh exactly as
//! `rigserve dataset` does, decode best-of-N candidates in one batch, keep the one the
//! geometric checks ([`score`]) like best, and map it back to the mesh's frame.
//!
//! A partial skeleton (bones to keep) becomes the prompt: it is normalized, tokenized, and
//! decoding continues after it, so the kept bones come first in the result, unchanged.

pub mod inside;
mod lanes;
pub mod library;
pub mod orient;
pub mod refine;
pub mod score;
mod winding;

use crate::infer::{Backend, InferError, SamplingParams, SkeletonRequest};
use crate::mesh::{sample_surface, Mesh, Normalization};
use crate::rig::placement;
use crate::rig::template::match_mixamo;
use crate::rig::tokenizer::{
    class_token, detokenize, tokenize_with_order, TokenizeError, BOS, EOS, MIXAMO_BODY,
};
use crate::rig::Skeleton;
use glam::Vec3;
use library::{draws_of_samples, BoxFrame, Library};
use orient::{Turn, Up};
use score::{SkeletonScore, SurfaceModel};
use std::collections::HashSet;
use std::sync::Arc;

/// Surface samples the model is fed (validation in training uses this many).
pub const MODEL_POINTS: usize = 2048;

/// See [`PredictConfig::library_candidates`].
pub const DEFAULT_LIBRARY_CANDIDATES: usize = 1;
/// See [`PredictConfig::library_trust`]. Surfaces 0.2 apart in box coordinates are
/// different shapes (a dragon and a bat, a mech and another mech's armour). Between 0.15
/// and 0.2 they are too often a different kind with a like silhouette (a sunfish and a
/// penguin, a sheep and a treasure chest): there the borrowed rig competes with the
/// model's candidates instead of replacing them. Chosen on `train` leave-one-out and 300
/// held-out synthetic rigs (MODEL_CARD.md, "Library trust").
pub const DEFAULT_LIBRARY_TRUST: f32 = 0.15;

/// `template` of a job: whether the Mixamo body template is left to the model, forced
/// (the prompt opens the block), or refused by the grammar.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TemplateMode {
    #[default]
    Auto,
    Force,
    Forbid,
}

#[derive(Clone)]
pub struct PredictConfig {
    pub points: usize,
    /// Candidates decoded (best-of-N); 1 when sampling is greedy, since all would agree.
    pub samples: usize,
    /// Seeds the surface samples and the candidates (candidate `k` uses `seed + k`).
    pub seed: u64,
    /// Temperature / top-k / top-p; its seed is ignored (see `seed`).
    pub sampling: SamplingParams,
    pub max_bones: usize,
    /// Longest sequence, prompt included; 0 is the model's limit.
    pub max_tokens: usize,
    /// Whether the skeleton may, must or must not follow the Mixamo body template.
    pub template: TemplateMode,
    /// Asked between waits; when it returns true, decoding stops with `canceled`.
    pub canceled: Option<Arc<dyn Fn() -> bool + Send + Sync>>,
    /// Category hint for the class token (`humanoid`, `quadruped`, …); unknown or `None`
    /// gives `<cls:none>`.
    pub category: Option<String>,
    /// Rigged meshes whose skeletons, moved onto this mesh, join the candidates.
    pub library: Option<Arc<Library>>,
    /// How many of the library's most similar entries join (0: none).
    pub library_candidates: usize,
    /// Shape distance (box coordinates) under which the nearest library entry is taken
    /// over the model's candidates: the mesh is then a close relative of a rigged one.
    pub library_trust: f32,
    /// Library rigs' joints moved by the model ([`refine`]); `None` leaves them as fitted.
    pub refine_library: Option<refine::Refine>,
    /// The model's own candidates' joints moved the same way, before they are scored.
    pub refine_model: Option<refine::Refine>,
    /// The mesh's up axis (Y by default), or `Auto` to find it ([`orient`]).
    pub up: Up,
}

/// Sampling temperature of the candidates. Chosen per model on data the dev split never
/// enters, by a rule written before the figures (the grid 0.35 / 0.5 / 0.65 on the `train`
/// leave-one-out and 300 held-out synthetic rigs; a temperature wins only if it lowers both
/// means on both sets). Flat logits want a cooler sampler and sharp ones a warmer: v3's
/// two-bin Gaussian targets took 0.35, v4's one-bin targets take 0.5 again (MODEL_CARD.md,
/// "Skeleton model v4"); v5, trained with targets narrowing from two bins to one, and v6 to
/// v9, each the one before trained longer on one-bin targets, kept 0.5 without a grid
/// (MODEL_CARD.md, "Skeleton model v5" to "v9").
pub const DEFAULT_TEMPERATURE: f32 = 0.5;

impl Default for PredictConfig {
    fn default() -> Self {
        PredictConfig {
            points: MODEL_POINTS,
            samples: 4,
            seed: 0,
            sampling: SamplingParams {
                temperature: DEFAULT_TEMPERATURE,
                top_k: 0,
                top_p: 0.95,
                seed: 0,
            },
            max_bones: 128,
            max_tokens: 0,
            template: TemplateMode::Auto,
            canceled: None,
            category: None,
            library: None,
            library_candidates: DEFAULT_LIBRARY_CANDIDATES,
            library_trust: DEFAULT_LIBRARY_TRUST,
            refine_library: None,
            refine_model: None,
            up: Up::default(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PredictError {
    #[error(transparent)]
    Infer(#[from] InferError),
    #[error("the mesh has no surface to sample")]
    EmptySurface,
    #[error("bones to keep: {0}")]
    KeepTokenize(#[from] TokenizeError),
    #[error("{0} bones to keep, more than the cap of {1}")]
    KeepTooMany(usize, usize),
    #[error("bones to keep: {0}")]
    KeepOutside(#[from] crate::rig::placement::Misplaced),
    #[error("no candidate gave a skeleton: {0}")]
    NoCandidate(String),
}

impl PredictError {
    pub fn code(&self) -> &'static str {
        match self {
            PredictError::Infer(e) => e.code(),
            PredictError::EmptySurface => "mesh_no_surface",
            PredictError::KeepTokenize(_) => "keep_bones_invalid",
            PredictError::KeepTooMany(..) => "keep_bones_too_many",
            PredictError::KeepOutside(_) => "keep_bones_outside_mesh",
            PredictError::NoCandidate(_) => "no_candidate",
        }
    }
}

/// The mesh in the model's frame, with the samples fed to the encoder.
#[derive(Clone, Debug)]
pub struct MeshSamples {
    pub normalization: Normalization,
    /// `x y z nx ny nz` in the unit frame, shared by every candidate's request.
    pub points: Arc<[[f32; 6]]>,
    pub surface: SurfaceModel,
    /// Bounding box of the mesh in the unit frame.
    pub bounds: (Vec3, Vec3),
    /// Applied to the mesh before `normalization`: the unit frame is Y-up.
    pub turn: Turn,
}

impl MeshSamples {
    /// A point of the unit frame in the mesh's own frame.
    pub fn to_mesh(&self, p: Vec3) -> Vec3 {
        self.turn.invert(self.normalization.invert(p))
    }
}

/// Normalizes `mesh` and samples `n` surface points with `seed`: the same steps, in the
/// same order, as `dataset::build`, so the model sees what it was trained on.
pub fn mesh_samples(mesh: &Mesh, n: usize, seed: u64) -> Result<MeshSamples, PredictError> {
    mesh_samples_turned(mesh, n, seed, Turn::IDENTITY)
}

/// The samples `cfg` asks for: with an axis given, the mesh turned so that axis is up;
/// with `Auto` and a library, turned the way that brings it nearest a library rig
/// ([`orient::find_up`]); with `Auto` and no library, as given.
pub fn samples_for(mesh: &Mesh, cfg: &PredictConfig) -> Result<MeshSamples, PredictError> {
    match (cfg.up, &cfg.library) {
        (Up::Axis(a), _) => mesh_samples_turned(mesh, cfg.points, cfg.seed, Turn::bringing_up(a)),
        (Up::Auto, Some(lib)) => {
            let given = mesh_samples(mesh, cfg.points, cfg.seed)?;
            let found = orient::find_up(lib, &given.points, given.bounds, cfg.category.as_deref());
            if found.turn.is_identity() {
                return Ok(given);
            }
            // The turned mesh is sampled afresh, as a mesh arriving that way would be.
            drop(given);
            mesh_samples_turned(mesh, cfg.points, cfg.seed, found.turn)
        }
        (Up::Auto, None) => mesh_samples(mesh, cfg.points, cfg.seed),
    }
}

/// [`mesh_samples`] of the mesh turned by `turn` first.
pub fn mesh_samples_turned(
    mesh: &Mesh,
    n: usize,
    seed: u64,
    turn: Turn,
) -> Result<MeshSamples, PredictError> {
    let turned: Vec<Vec3>;
    let positions = if turn.is_identity() {
        &mesh.positions
    } else {
        turned = mesh.positions.iter().map(|&p| turn.apply(p)).collect();
        &turned
    };
    let norm = Normalization::from_points(positions);
    let unit = Mesh {
        positions: positions.iter().map(|&p| norm.apply(p)).collect(),
        triangles: mesh.triangles.clone(),
        ..Mesh::default()
    };
    let s = sample_surface(&unit, n, seed);
    if s.points.is_empty() {
        return Err(PredictError::EmptySurface);
    }
    let rows: Vec<[f32; 6]> = s
        .points
        .iter()
        .zip(&s.normals)
        .map(|(p, n)| [p.x, p.y, p.z, n.x, n.y, n.z])
        .collect();
    let surface = SurfaceModel::new(&rows, &unit, seed);
    Ok(MeshSamples {
        normalization: norm,
        points: rows.into(),
        surface,
        bounds: unit.bounds(),
        turn,
    })
}

/// Bones to keep, turned into a prompt.
#[derive(Clone, Debug)]
pub struct KeepPrompt {
    /// `<bos> <cls:…>` and the kept bones' tokens, without `<eos>`.
    pub tokens: Vec<u32>,
    /// The kept skeleton in the mesh frame, in the order decoding returns its bones
    /// (Mixamo rigs reordered into the template, as the data set does).
    pub bones: Skeleton,
}

/// Prompt for continuing `keep` (mesh frame) on the mesh whose unit-frame bounding box is
/// `bounds`. `category` overrides the keep file's own.
pub fn keep_prompt(
    keep: &Skeleton,
    norm: &Normalization,
    bounds: (Vec3, Vec3),
    category: Option<&str>,
    max_bones: usize,
) -> Result<KeepPrompt, PredictError> {
    if keep.len() > max_bones {
        return Err(PredictError::KeepTooMany(keep.len(), max_bones));
    }
    // Bones the tokenizer would clamp onto the unit cube's faces, and put back afterwards
    // where they were: checked in the mesh's frame, where a far joint's distance is finite.
    let (lo, hi) = (norm.invert(bounds.0), norm.invert(bounds.1));
    placement::check(keep, lo, hi, placement::OUTSIDE_MARGIN)?;
    let mut matched = match_mixamo(keep).unwrap_or_else(|| keep.clone());
    if let Some(c) = category {
        matched.category = Some(c.to_string());
    }
    let mut unit = matched.clone();
    unit.map_points(|p| norm.apply(p));
    let (mut tokens, order) = tokenize_with_order(&unit)?;
    if tokens.last() == Some(&EOS) {
        tokens.pop();
    }
    let bones = Skeleton {
        bones: order.iter().map(|&i| matched.bones[i].clone()).collect(),
        template: matched.template,
        category: matched.category.clone(),
    };
    Ok(KeepPrompt { tokens, bones })
}

/// Where a candidate came from.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Origin {
    /// Sampled from the skeleton model with this seed.
    Model { seed: u64 },
    /// A library entry's skeleton moved onto the mesh; `shape` is the surfaces' distance.
    Library { name: String, shape: f32 },
}

/// One candidate skeleton.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Candidate {
    pub origin: Origin,
    pub tokens: Vec<u32>,
    pub bones: usize,
    pub score: Option<SkeletonScore>,
    /// Why the candidate has no skeleton, when it has none.
    pub error: Option<String>,
}

#[derive(Clone, Debug)]
pub struct Prediction {
    /// In the mesh's frame.
    pub skeleton: Skeleton,
    /// Index of the chosen candidate.
    pub chosen: usize,
    pub candidates: Vec<Candidate>,
    /// Each candidate's skeleton in the unit frame (None where it has none).
    pub unit_skeletons: Vec<Option<Skeleton>>,
    pub normalization: Normalization,
    /// How the mesh was turned to be rigged ([`MeshSamples::turn`]).
    pub turn: Turn,
}

impl Prediction {
    /// A point of the unit frame in the mesh's own frame.
    pub fn to_mesh(&self, p: Vec3) -> Vec3 {
        self.turn.invert(self.normalization.invert(p))
    }
}

/// Predicts a skeleton for `mesh`, continuing `keep` when given, in the frame `cfg.up`
/// asks for ([`samples_for`]); the skeleton is in the mesh's own frame.
pub fn predict_skeleton(
    backend: &Backend,
    mesh: &Mesh,
    cfg: &PredictConfig,
    keep: Option<&Skeleton>,
) -> Result<Prediction, PredictError> {
    let samples = samples_for(mesh, cfg)?;
    predict_from_samples(backend, &samples, cfg, keep)
}

/// [`predict_skeleton`] from samples already taken (to time or reuse them).
pub fn predict_from_samples(
    backend: &Backend,
    samples: &MeshSamples,
    cfg: &PredictConfig,
    keep: Option<&Skeleton>,
) -> Result<Prediction, PredictError> {
    let norm = samples.normalization;
    // Bones to keep are given in the mesh's frame; the prompt is made in the turned one.
    let keep = keep.map(|k| {
        let mut k = k.clone();
        k.map_points(|p| samples.turn.apply(p));
        k
    });
    let kept = keep
        .as_ref()
        .map(|k| {
            keep_prompt(
                k,
                &norm,
                samples.bounds,
                cfg.category.as_deref(),
                cfg.max_bones,
            )
        })
        .transpose()?;
    let prompt = match &kept {
        Some(k) => k.tokens.clone(),
        None if cfg.template == TemplateMode::Force => {
            vec![BOS, class_token(cfg.category.as_deref()), MIXAMO_BODY]
        }
        None => vec![BOS, class_token(cfg.category.as_deref())],
    };
    // The library goes first: when its nearest entry is trusted, nothing the model could
    // decode would be chosen over it, so the model is not run at all.
    let borrowed = match &cfg.library {
        Some(lib) if kept.is_none() && cfg.template == TemplateMode::Auto => library_candidates(
            lib,
            samples,
            cfg.category.as_deref(),
            cfg.library_candidates,
            cfg.max_bones,
        ),
        _ => Vec::new(),
    };
    let trusted = borrowed
        .first()
        .is_some_and(|(_, shape, _)| *shape <= cfg.library_trust);
    // Refinement reads the encoder's output for this mesh: encoded once, and only when a
    // skeleton will be refined (a library rig, or model candidates that will be decoded).
    let refining = (cfg.refine_library.is_some() && !borrowed.is_empty())
        || (cfg.refine_model.is_some() && !trusted);
    let prefix = refining
        .then(|| backend.encode(&samples.points))
        .transpose()?;
    let mut candidates = Vec::new();
    let mut skeletons = Vec::new();
    if !trusted {
        decode_candidates(
            backend,
            samples,
            cfg,
            prompt,
            prefix.as_ref(),
            &mut candidates,
            &mut skeletons,
        )?;
    }
    for (name, shape, mut skel) in borrowed {
        if let (Some(how), Some(p)) = (cfg.refine_library, &prefix) {
            skel = refine::refine(backend, p, &skel, cfg.category.as_deref(), how)?;
            inside::pull_inside(&mut skel, samples);
        }
        candidates.push(Candidate {
            origin: Origin::Library { name, shape },
            tokens: Vec::new(),
            bones: skel.len(),
            score: Some(samples.surface.score(&skel)),
            error: None,
        });
        skeletons.push(Some(skel));
    }
    // A trusted library rig is the only candidate there is.
    let chosen = if trusted {
        Some(0)
    } else {
        (0..candidates.len())
            .filter(|&k| candidates[k].score.is_some())
            .min_by(|&a, &b| {
                let cost = |k: usize| candidates[k].score.unwrap().cost;
                cost(a).total_cmp(&cost(b)).then(a.cmp(&b))
            })
    };
    let chosen = chosen.ok_or_else(|| {
        PredictError::NoCandidate(
            candidates
                .iter()
                .filter_map(|c| c.error.clone())
                .next()
                .unwrap_or_default(),
        )
    })?;
    let mut skeleton = skeletons[chosen].clone().expect("chosen has a skeleton");
    // A chosen model skeleton's joints left outside the mesh are pulled into it, as a
    // library rig's are (held-out synthetic rigs, model alone: CD-J2J 0.0649 -> 0.0593,
    // MODEL_CARD). After the choice, which stays the one validated, and for the chosen
    // skeleton only: the rays cost about a millisecond per candidate.
    if matches!(candidates[chosen].origin, Origin::Model { .. }) {
        inside::pull_inside(&mut skeleton, samples);
    }
    skeleton.map_points(|p| norm.invert(p));
    if let Some(k) = &kept {
        restore_kept(&mut skeleton, &k.bones);
    }
    // Exact: a turn only permutes and negates coordinates, so kept bones come back as given.
    if !samples.turn.is_identity() {
        skeleton.map_points(|p| samples.turn.invert(p));
    }
    if skeleton.category.is_none() {
        skeleton.category = cfg.category.clone();
    }
    Ok(Prediction {
        skeleton,
        chosen,
        candidates,
        unit_skeletons: skeletons,
        normalization: norm,
        turn: samples.turn,
    })
}

/// Decodes the model's best-of-N candidates for `prompt`, in seed order.
fn decode_candidates(
    backend: &Backend,
    samples: &MeshSamples,
    cfg: &PredictConfig,
    prompt: Vec<u32>,
    refine_prefix: Option<&Arc<ndarray::Array2<f32>>>,
    candidates: &mut Vec<Candidate>,
    skeletons: &mut Vec<Option<Skeleton>>,
) -> Result<(), PredictError> {
    let n = if cfg.sampling.is_greedy() {
        1
    } else {
        cfg.samples.max(1)
    };
    let seeds: Vec<u64> = (0..n as u64).map(|k| cfg.seed.wrapping_add(k)).collect();
    let reqs = seeds
        .iter()
        .map(|&seed| SkeletonRequest {
            points: samples.points.clone(),
            prompt: prompt.clone(),
            sampling: SamplingParams {
                seed,
                ..cfg.sampling
            },
            max_bones: cfg.max_bones,
            max_tokens: cfg.max_tokens,
            no_templates: cfg.template == TemplateMode::Forbid,
            ignore_eos: false,
        })
        .collect();
    let pending = backend.submit_many(reqs)?;
    for (p, &seed) in pending.into_iter().zip(&seeds) {
        let waited = match &cfg.canceled {
            Some(c) => p.wait_unless(&**c),
            None => p.wait(),
        };
        if let Err(InferError::Canceled) = waited {
            return Err(InferError::Canceled.into());
        }
        let (tokens, mut skel, error) = match waited {
            Ok(g) => match detokenize(&g.tokens) {
                Ok(s) => (g.tokens, Some(s), None),
                Err(e) => (g.tokens, None, Some(e.to_string())),
            },
            Err(e) => (Vec::new(), None, Some(e.to_string())),
        };
        if let (Some(how), Some(p), Some(s)) = (cfg.refine_model, refine_prefix, skel.as_mut()) {
            let cat = s.category.clone();
            *s = refine::refine(backend, p, s, cat.as_deref(), how)?;
        }
        let score = skel.as_ref().map(|s| samples.surface.score(s));
        candidates.push(Candidate {
            origin: Origin::Model { seed },
            bones: skel.as_ref().map_or(0, Skeleton::len),
            tokens,
            score,
            error,
        });
        skeletons.push(skel);
    }
    Ok(())
}

/// The `k` library entries most like the mesh (of its category when hinted), their
/// skeletons moved onto it, in the unit frame; entries over the bone cap are skipped.
fn library_candidates(
    lib: &Library,
    samples: &MeshSamples,
    category: Option<&str>,
    k: usize,
    max_bones: usize,
) -> Vec<(String, f32, Skeleton)> {
    if k == 0 {
        return Vec::new();
    }
    let frame = BoxFrame::from_bounds(samples.bounds.0, samples.bounds.1);
    // Ranked on the first draw; fitted on every draw of the model's samples.
    let draws = draws_of_samples(&samples.points, &frame);
    lib.ranked(&draws[0], frame.proportions(), category)
        .into_iter()
        .filter(|&(i, _)| lib.entries[i].bones() <= max_bones)
        .take(k)
        .map(|(i, d)| {
            let e = &lib.entries[i];
            let mut s = e.fit_mean(&draws);
            s.map_points(|q| frame.invert(q));
            inside::pull_inside(&mut s, samples);
            (e.name.clone(), d, s)
        })
        .collect()
}

/// Puts the kept bones back exactly as given (the decoded ones went through quantization)
/// and renames decoded bones whose generated names collide with kept ones.
fn restore_kept(skel: &mut Skeleton, kept: &Skeleton) {
    let n = kept.len().min(skel.len());
    for (b, k) in skel.bones.iter_mut().zip(&kept.bones).take(n) {
        b.name = k.name.clone();
        b.head = k.head;
        b.spring = k.spring;
    }
    // New bones may hang off moved kept joints: re-infer every tail, then give kept
    // bones their own tails back.
    skel.infer_tails();
    for (b, k) in skel.bones.iter_mut().zip(&kept.bones).take(n) {
        b.tail = k.tail;
    }
    let mut used: HashSet<String> = skel.bones[..n].iter().map(|b| b.name.clone()).collect();
    for b in &mut skel.bones[n..] {
        if used.contains(&b.name) {
            let base = b.name.clone();
            b.name = (1..)
                .map(|k| format!("{base}_{k}"))
                .find(|c| !used.contains(c))
                .expect("unbounded");
        }
        used.insert(b.name.clone());
    }
    if skel.template.is_none() {
        skel.template = kept.template;
    }
}
