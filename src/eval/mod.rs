//! Scores rigged files against a data set's artist rigs: the figures every model change
//! is judged by, computed by the same code whichever tool produced the rig.

pub mod baseline;
pub mod retrieval;
pub mod skin;

use crate::mesh::{self, Limits};
use crate::rig::groundtruth::{self, GroundTruth};
use crate::rig::metrics::{score_skeleton, score_skin, Frame, SkeletonScores, SkinScores};
use crate::rig::nearest::PointGrid;
use crate::rig::{Skeleton, SkinWeights};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Seed for the deformation poses, fixed so reports are comparable run to run.
const POSE_SEED: u64 = 0x5EED;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("cannot read {0}: {1}")]
    Io(PathBuf, std::io::Error),
    #[error("manifest {0}: {1}")]
    Manifest(PathBuf, String),
}

#[derive(Clone, Debug)]
pub struct ManifestEntry {
    pub file: String,
    pub category: String,
    pub split: Option<String>,
    /// Who made the rig: `ARTISTS.tsv` beside the manifest where the set has one, else
    /// the manifest's `artist` column, else its `source_repo`.
    pub artist: Option<String>,
    /// The manifest's `license` (or `licence`) column.
    pub license: Option<String>,
}

impl ManifestEntry {
    pub fn artist_or_unknown(&self) -> String {
        self.artist
            .clone()
            .unwrap_or_else(|| UNKNOWN_ARTIST.to_string())
    }
}

/// Reads `manifest.tsv`: tab-separated with a header naming `file` and `category`
/// (`split`, `artist`, `source_repo` and `license` optional), and `ARTISTS.tsv` (`file`,
/// `artist`) beside it when there is one.
pub fn read_manifest(dataset: &Path) -> Result<Vec<ManifestEntry>, EvalError> {
    let path = dataset.join("manifest.tsv");
    let text = std::fs::read_to_string(&path).map_err(|e| EvalError::Io(path.clone(), e))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split('\t').collect();
    let col = |name: &str| header.iter().position(|h| h.trim() == name);
    let (Some(f), Some(c)) = (col("file"), col("category")) else {
        return Err(EvalError::Manifest(
            path,
            "needs `file` and `category` columns".into(),
        ));
    };
    let s = col("split");
    let artist_col = col("artist").or_else(|| col("source_repo"));
    let license_col = col("license").or_else(|| col("licence"));
    let artists = read_artists(&dataset.join("ARTISTS.tsv"));
    Ok(lines
        .filter(|l| !l.trim().is_empty())
        .filter_map(|l| {
            let v: Vec<&str> = l.split('\t').collect();
            let cell = |i: Option<usize>| {
                i.and_then(|i| v.get(i))
                    .map(|x| x.trim().to_string())
                    .filter(|x| !x.is_empty())
            };
            let file = v.get(f)?.trim().to_string();
            Some(ManifestEntry {
                artist: artists.get(&file).cloned().or_else(|| cell(artist_col)),
                license: cell(license_col),
                category: v.get(c)?.trim().to_string(),
                split: cell(s),
                file,
            })
        })
        .collect())
}

/// `file -> artist` from an `ARTISTS.tsv` (header `file`, tab, `artist`); empty when absent.
fn read_artists(path: &Path) -> BTreeMap<String, String> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return BTreeMap::new();
    };
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let (f, a) = l.split_once('\t')?;
            Some((f.trim().to_string(), a.trim().to_string()))
        })
        .collect()
}

/// The manifest rows of one split (all rows when `split` is None).
pub fn entries_in(dataset: &Path, split: Option<&str>) -> Result<Vec<ManifestEntry>, EvalError> {
    let mut entries = read_manifest(dataset)?;
    entries.retain(|e| split.is_none() || e.split.as_deref() == split);
    Ok(entries)
}

#[derive(Clone, Debug, Serialize)]
pub struct ErrorInfo {
    pub code: String,
    pub message: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct ModelReport {
    pub file: String,
    pub category: String,
    pub artist: String,
    pub valid: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorInfo>,
    pub joints_gt: usize,
    pub joints_pred: usize,
    pub skeleton: Option<SkeletonScores>,
    pub skin: Option<SkinScores>,
    /// `--skeleton-only`: each decoded candidate's CD-J2J against the artist's skeleton
    /// (null for a candidate without a skeleton), in decoding order, and which one the
    /// predictor chose: how much a better choice among them could gain.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub candidates: Vec<CandidateReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub chosen: Option<usize>,
    /// How much the model's candidates disagree ([`crate::predict::score::spread`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spread: Option<f32>,
}

/// A candidate as the predictor saw it, and how it scores against the artist's skeleton.
#[derive(Clone, Debug, Serialize)]
pub struct CandidateReport {
    #[serde(flatten)]
    pub candidate: crate::predict::Candidate,
    pub cd_j2j: Option<f32>,
    /// CD-B2B the same way (before a model skeleton's joints are pulled inside).
    pub cd_b2b: Option<f32>,
}

impl ModelReport {
    /// A report with nothing scored yet (invalid until a scorer says otherwise).
    pub fn new(file: &str, category: &str) -> Self {
        ModelReport {
            file: file.to_string(),
            category: category.to_string(),
            artist: UNKNOWN_ARTIST.to_string(),
            valid: false,
            error: None,
            joints_gt: 0,
            joints_pred: 0,
            skeleton: None,
            skin: None,
            candidates: Vec::new(),
            chosen: None,
            spread: None,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct GroupReport {
    pub count: usize,
    pub valid: usize,
    pub valid_fraction: f32,
    pub skeleton: SkeletonScores,
    pub skin: SkinScores,
}

/// The group of files whose manifest names no artist or source.
pub const UNKNOWN_ARTIST: &str = "unknown";

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub dataset: String,
    pub split: Option<String>,
    pub mode: String,
    /// The model and library files the figures came from, with content hashes, so a
    /// figure can be traced to exactly what produced it (filled in by the caller).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub used: Option<Used>,
    pub overall: GroupReport,
    pub per_category: BTreeMap<String, GroupReport>,
    pub per_artist: BTreeMap<String, GroupReport>,
    pub models: Vec<ModelReport>,
}

/// What produced a report's rigs.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Used {
    pub models: Vec<FileHash>,
    /// `None`: the model alone.
    pub library: Option<FileHash>,
    pub category_hint: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct FileHash {
    pub path: String,
    /// SHA-256 of the file's bytes, hex.
    pub sha256: String,
}

impl FileHash {
    pub fn of(path: &Path) -> std::io::Result<FileHash> {
        use sha2::{Digest, Sha256};
        let bytes = std::fs::read(path)?;
        Ok(FileHash {
            path: path.display().to_string(),
            sha256: hex::encode(Sha256::digest(&bytes)),
        })
    }
}

fn err(code: &str, message: impl ToString) -> ErrorInfo {
    ErrorInfo {
        code: code.into(),
        message: message.to_string(),
    }
}

/// Loads a rigged file and its ground truth.
pub fn load_rig(path: &Path, limits: &Limits) -> Result<(mesh::Mesh, GroundTruth), ErrorInfo> {
    let bytes =
        std::fs::read(path).map_err(|e| err("missing", format!("{}: {e}", path.display())))?;
    let asset = mesh::load(&bytes, limits).map_err(|e| err(e.code(), e))?;
    let gt = groundtruth::extract(&asset)
        .map_err(|e| err(e.code(), e))?
        .ok_or_else(|| err("no_skin", "the file has no skinned mesh"))?;
    Ok((asset.mesh, gt))
}

/// Carries predicted weights onto the ground truth's vertices. Rigs exported by
/// rigserve keep vertex order; other tools may weld or split, so then each vertex takes
/// the weights of the nearest predicted vertex.
fn transfer_weights(
    gt_pos: &[glam::Vec3],
    pred_pos: &[glam::Vec3],
    pred: &SkinWeights,
    frame: &Frame,
) -> SkinWeights {
    let same = gt_pos.len() == pred_pos.len()
        && gt_pos
            .iter()
            .zip(pred_pos)
            .all(|(a, b)| frame.report(a.distance(*b)) < 1e-5);
    if same {
        return pred.clone();
    }
    let grid = PointGrid::new(pred_pos);
    SkinWeights {
        per_vertex: gt_pos
            .iter()
            .map(|&p| {
                grid.nearest(p)
                    .map(|(i, _)| pred.per_vertex[i].clone())
                    .unwrap_or_default()
            })
            .collect(),
    }
}

/// Scores one predicted rig file against one ground-truth file.
pub fn score_pair(
    gt_path: &Path,
    pred_path: &Path,
    limits: &Limits,
) -> Result<ModelReport, ErrorInfo> {
    let (gt_mesh, gt) = load_rig(gt_path, limits).map_err(|e| {
        err(
            "ground_truth_unreadable",
            format!("{}: {}", e.code, e.message),
        )
    })?;
    let mut report = ModelReport::new("", "");
    report.joints_gt = gt.skeleton.len();
    let (pred_mesh, pred) = match load_rig(pred_path, limits) {
        Ok(x) => x,
        Err(e) => {
            report.error = Some(e);
            return Ok(report);
        }
    };
    let frame = Frame::from_points(&gt_mesh.positions);
    report.joints_pred = pred.skeleton.len();
    report.skeleton = Some(score_skeleton(&pred.skeleton, &gt.skeleton, &frame));
    let weights = transfer_weights(
        &gt_mesh.positions,
        &pred_mesh.positions,
        &pred.weights,
        &frame,
    );
    match score_skin(
        &pred.skeleton,
        &weights,
        &gt.skeleton,
        &gt.weights,
        &gt_mesh.positions,
        &frame,
        POSE_SEED,
    ) {
        Ok(s) => report.skin = Some(s),
        Err(e) => report.error = Some(err(e.code(), e)),
    }
    report.valid = report.error.is_none() && pred.skeleton.validate(usize::MAX).is_ok();
    Ok(report)
}

fn group(models: &[&ModelReport]) -> GroupReport {
    let valid = models.iter().filter(|m| m.valid).count();
    GroupReport {
        count: models.len(),
        valid,
        valid_fraction: if models.is_empty() {
            f32::NAN
        } else {
            valid as f32 / models.len() as f32
        },
        skeleton: SkeletonScores::mean(models.iter().filter_map(|m| m.skeleton.as_ref())),
        skin: SkinScores::mean(models.iter().filter_map(|m| m.skin.as_ref())),
    }
}

/// Builds the report from per-model results (shared by every eval mode).
pub fn summarize(
    dataset: &Path,
    split: Option<&str>,
    mode: &str,
    models: Vec<ModelReport>,
) -> Report {
    let by = |key: fn(&ModelReport) -> &str| {
        let mut groups: BTreeMap<String, Vec<&ModelReport>> = BTreeMap::new();
        for m in &models {
            groups.entry(key(m).to_string()).or_default().push(m);
        }
        groups
            .into_iter()
            .map(|(k, v)| (k, group(&v)))
            .collect::<BTreeMap<_, _>>()
    };
    let per_category = by(|m| &m.category);
    let per_artist = by(|m| &m.artist);
    Report {
        dataset: dataset.display().to_string(),
        split: split.map(str::to_string),
        mode: mode.to_string(),
        used: None,
        overall: group(&models.iter().collect::<Vec<_>>()),
        per_category,
        per_artist,
        models,
    }
}

/// `rigserve eval --pred DIR`: scores the rigged files in `pred` (same file names as the
/// data set) against the data set's own rigs.
pub fn eval_pred(
    dataset: &Path,
    split: Option<&str>,
    pred: &Path,
    limits: &Limits,
) -> Result<Report, EvalError> {
    let mut models = Vec::new();
    for e in entries_in(dataset, split)? {
        let mut m = match score_pair(&dataset.join(&e.file), &pred.join(&e.file), limits) {
            Ok(m) => m,
            Err(info) => ModelReport {
                error: Some(info),
                ..ModelReport::new("", "")
            },
        };
        m.file = e.file.clone();
        m.category = e.category.clone();
        m.artist = e.artist_or_unknown();
        models.push(m);
    }
    Ok(summarize(dataset, split, "pred", models))
}

/// `rigserve eval --baseline`: the category-medoid skeleton of the `train_split` rigs,
/// stretched onto each mesh of `split` (skeleton metrics only).
pub fn eval_baseline(
    dataset: &Path,
    split: Option<&str>,
    train_split: &str,
    limits: &Limits,
) -> Result<Report, EvalError> {
    let train = entries_in(dataset, Some(train_split))?;
    let medoids = baseline::category_medoids(dataset, &train, limits);
    let models = entries_in(dataset, split)?
        .iter()
        .map(|e| baseline::score_baseline(dataset, e, &medoids, limits))
        .collect();
    Ok(summarize(
        dataset,
        split,
        "baseline_category_medoid",
        models,
    ))
}

/// Loads every rig of the split and lets `score` fill its report (the ground truth's
/// joint count is already in it); a file that does not load is reported with its error.
pub(crate) fn each_rig(
    dataset: &Path,
    split: Option<&str>,
    limits: &Limits,
    mut score: impl FnMut(&ManifestEntry, &mesh::Mesh, &GroundTruth, &mut ModelReport),
) -> Result<Vec<ModelReport>, EvalError> {
    let mut models = Vec::new();
    for e in entries_in(dataset, split)? {
        let mut report = ModelReport::new(&e.file, &e.category);
        report.artist = e.artist_or_unknown();
        match load_rig(&dataset.join(&e.file), limits) {
            Err(info) => report.error = Some(info),
            Ok((mesh, gt)) => {
                report.joints_gt = gt.skeleton.len();
                score(&e, &mesh, &gt, &mut report);
            }
        }
        models.push(report);
    }
    Ok(models)
}

/// `rigserve eval --skeleton-only`: runs the skeleton model on every mesh of the split
/// (the model sees only geometry, so the file's own rig is ignored) and scores the
/// predicted skeleton against the artist's. With `category_hint`, the manifest's
/// category is given to the model as its class token.
pub fn eval_model_skeleton(
    dataset: &Path,
    split: Option<&str>,
    backend: &crate::infer::Backend,
    cfg: &crate::predict::PredictConfig,
    category_hint: bool,
    rotate: Option<crate::predict::orient::Turn>,
    limits: &Limits,
) -> Result<Report, EvalError> {
    let models = each_rig(dataset, split, limits, |e, mesh, gt, report| {
        // The data set turned as a whole (mesh and artist's rig alike), as if exported so.
        let turned;
        let (mesh, gt_skeleton) = match rotate {
            Some(t) => {
                let mut m = mesh.clone();
                m.positions.iter_mut().for_each(|p| *p = t.apply(*p));
                let mut g = gt.skeleton.clone();
                g.map_points(|p| t.apply(p));
                turned = (m, g);
                (&turned.0, &turned.1)
            }
            None => (mesh, &gt.skeleton),
        };
        // Never the scored file's own entry: leave-one-out when the library holds the split.
        let library = cfg.library.as_ref().map(|l| {
            if l.entries.iter().any(|x| x.name == e.file) {
                std::sync::Arc::new(l.without(&[e.file.clone()].into()))
            } else {
                l.clone()
            }
        });
        let cfg = crate::predict::PredictConfig {
            category: category_hint.then(|| e.category.clone()),
            library,
            ..cfg.clone()
        };
        match crate::predict::predict_skeleton(backend, mesh, &cfg, None) {
            Ok(pred) => {
                let frame = Frame::from_points(&mesh.positions);
                report.joints_pred = pred.skeleton.len();
                report.valid = pred.skeleton.validate(cfg.max_bones).is_ok();
                report.skeleton = Some(score_skeleton(&pred.skeleton, gt_skeleton, &frame));
                report.chosen = Some(pred.chosen);
                // Only the report needs it, so the service never computes it.
                let model_skeletons: Vec<&Skeleton> = pred
                    .candidates
                    .iter()
                    .zip(&pred.unit_skeletons)
                    .filter(|(c, _)| matches!(c.origin, crate::predict::Origin::Model { .. }))
                    .filter_map(|(_, s)| s.as_ref())
                    .collect();
                report.spread = crate::predict::score::spread(&model_skeletons);
                report.candidates = pred
                    .candidates
                    .iter()
                    .zip(&pred.unit_skeletons)
                    .map(|(c, s)| {
                        let s = s.as_ref().map(|s| {
                            let mut s = s.clone();
                            s.map_points(|p| pred.to_mesh(p));
                            s
                        });
                        let metric = |f: fn(&Skeleton, &Skeleton, &Frame) -> Option<f32>| {
                            s.as_ref().and_then(|s| f(s, gt_skeleton, &frame))
                        };
                        CandidateReport {
                            candidate: c.clone(),
                            cd_j2j: metric(crate::rig::metrics::cd_j2j),
                            cd_b2b: metric(crate::rig::metrics::cd_b2b),
                        }
                    })
                    .collect();
            }
            Err(e) => report.error = Some(err(e.code(), e)),
        }
    })?;
    let mode = if category_hint {
        "model_skeleton_with_category_hint"
    } else {
        "model_skeleton"
    };
    Ok(summarize(dataset, split, mode, models))
}
