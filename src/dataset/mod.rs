//! `rigserve dataset`: turns rigged meshes into the arrays and token sequences training
//! reads. Training never parses a mesh itself, so what it learns from is exactly what
//! the server feeds the model.
//!
//! Output, in `--out`:
//! - `points.f32`: little-endian f32, `items × points × 6` (normalized position, normal);
//! - `index.jsonl`: one JSON object per item, in the same order (file, category,
//!   augmentation, token sequence, bone count, normalization).

pub mod augment;
pub mod skin;

use crate::eval::ManifestEntry;
use crate::mesh::{self, sample_surface, Limits, Mesh, Normalization};
use crate::rig::groundtruth;
use crate::rig::template::match_mixamo;
use crate::rig::tokenizer::tokenize;
use augment::{augment, AugmentConfig};
use serde::Serialize;
use std::io::Write;
use std::path::Path;

#[derive(Clone, Debug)]
pub struct DatasetConfig {
    pub points: usize,
    /// Variations per file after the untouched original.
    pub augment: usize,
    pub seed: u64,
    pub max_bones: usize,
    pub augment_config: AugmentConfig,
}

#[derive(Serialize)]
struct Item<'a> {
    file: &'a str,
    category: &'a str,
    aug: usize,
    bones: usize,
    template: Option<crate::rig::Template>,
    tokens: Vec<u32>,
    normalization: Normalization,
}

#[derive(Debug, Default, Serialize)]
pub struct DatasetSummary {
    pub files: usize,
    pub items: usize,
    pub skipped: Vec<(String, String)>,
}

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// Writes the data set for the given entries of `dir`.
pub fn build(
    dir: &Path,
    entries: &[ManifestEntry],
    out: &Path,
    cfg: &DatasetConfig,
    limits: &Limits,
) -> Result<DatasetSummary, DatasetError> {
    std::fs::create_dir_all(out)?;
    let mut points = std::io::BufWriter::new(std::fs::File::create(out.join("points.f32"))?);
    let mut index = std::io::BufWriter::new(std::fs::File::create(out.join("index.jsonl"))?);
    let mut summary = DatasetSummary::default();
    for (fi, e) in entries.iter().enumerate() {
        let loaded = std::fs::read(dir.join(&e.file))
            .map_err(|err| err.to_string())
            .and_then(|b| mesh::load(&b, limits).map_err(|err| err.code().to_string()))
            .and_then(|a| match groundtruth::extract(&a) {
                Ok(Some(gt)) => Ok((a.mesh, gt)),
                Ok(None) => Err("no_skin".to_string()),
                Err(err) => Err(err.code().to_string()),
            });
        let (mesh, gt) = match loaded {
            Ok(x) => x,
            Err(why) => {
                summary.skipped.push((e.file.clone(), why));
                continue;
            }
        };
        let items_before = summary.items;
        let base = match_mixamo(&gt.skeleton).unwrap_or_else(|| gt.skeleton.clone());
        for aug in 0..=cfg.augment {
            let seed = cfg.seed ^ ((fi as u64) << 20) ^ aug as u64;
            let (positions, mut skel) = if aug == 0 {
                (mesh.positions.clone(), base.clone())
            } else {
                augment(
                    &mesh.positions,
                    &base,
                    &gt.weights,
                    &cfg.augment_config,
                    seed,
                )
            };
            let norm = Normalization::from_points(&positions);
            skel.map_points(|p| norm.apply(p));
            skel.category = Some(e.category.clone());
            if skel.len() > cfg.max_bones {
                summary.skipped.push((
                    e.file.clone(),
                    format!("{} bones > {}", skel.len(), cfg.max_bones),
                ));
                break;
            }
            let tokens = match tokenize(&skel) {
                Ok(t) => t,
                Err(err) => {
                    summary.skipped.push((e.file.clone(), err.to_string()));
                    continue;
                }
            };
            let unit = Mesh {
                positions: positions.iter().map(|&p| norm.apply(p)).collect(),
                triangles: mesh.triangles.clone(),
                ..Mesh::default()
            };
            let s = sample_surface(&unit, cfg.points, seed);
            for (p, n) in s.points.iter().zip(&s.normals) {
                for v in [p.x, p.y, p.z, n.x, n.y, n.z] {
                    points.write_all(&v.to_le_bytes())?;
                }
            }
            let item = Item {
                file: &e.file,
                category: &e.category,
                aug,
                bones: skel.len(),
                template: skel.template,
                tokens,
                normalization: norm,
            };
            serde_json::to_writer(&mut index, &item).map_err(std::io::Error::from)?;
            index.write_all(b"\n")?;
            summary.items += 1;
        }
        // A file counts once it gave at least one item (it may be skipped for its size).
        if summary.items > items_before {
            summary.files += 1;
        }
    }
    points.flush()?;
    index.flush()?;
    Ok(summary)
}
