//! `rigserve dataset --skin`: the learned skin model's training arrays.
//!
//! Per item (a file, or one of its augmented variations): the features of
//! [`crate::rig::skin::features`] for a random subset of the vertices the artist weighted,
//! and the artist's weight on each candidate bone. Rigidly bound vertices are left out:
//! the model never scores them. As in serving, vertices at one position are one row
//! ([`Welded`]), with the weights of the first of them.
//!
//! Output, in `--out` (little-endian, rows of all items back to back):
//! - `vert.f32` rows × 6, `pair.f32` rows × k × 11, `cand.i32` rows × k (`-1` pads),
//!   `target.f32` rows × k (artist weight of each candidate; the rest of the vertex's
//!   weight is on bones outside its candidates);
//! - `bone.f32` bones × 17, all items' bones back to back;
//! - `index.jsonl`: per item, file, category, augmentation, row and bone offsets and counts.

use super::augment::{augment, AugmentConfig};
use super::{DatasetError, DatasetSummary};
use crate::eval::ManifestEntry;
use crate::mesh::sample::SplitMix64;
use crate::mesh::{self, Limits, Mesh};
use crate::rig::groundtruth;
use crate::rig::skin::features::{features, BONE_FEATURES, PAIR_FEATURES, VERT_FEATURES};
use crate::rig::skin::{candidates_timed, into_skin_frame, SkinConfig, Welded};
use serde::Serialize;
use std::io::Write;
use std::path::Path;

#[derive(Clone, Debug)]
pub struct SkinDatasetConfig {
    /// Vertices per item at most.
    pub rows: usize,
    /// Candidate bones per vertex.
    pub k: usize,
    /// Variations per file after the untouched original.
    pub augment: usize,
    pub seed: u64,
    pub max_bones: usize,
    pub skin: SkinConfig,
    /// Leaf chains are never dropped here: the artist weights name the original bones.
    pub augment_config: AugmentConfig,
}

#[derive(Serialize)]
struct Item<'a> {
    file: &'a str,
    category: &'a str,
    aug: usize,
    row_offset: usize,
    rows: usize,
    bone_offset: usize,
    bones: usize,
    k: usize,
    /// Distinct vertex positions of the item (rows are drawn from them).
    vertices: usize,
}

struct Writers {
    vert: std::io::BufWriter<std::fs::File>,
    pair: std::io::BufWriter<std::fs::File>,
    cand: std::io::BufWriter<std::fs::File>,
    target: std::io::BufWriter<std::fs::File>,
    bone: std::io::BufWriter<std::fs::File>,
    index: std::io::BufWriter<std::fs::File>,
}

fn f32s(w: &mut impl Write, v: &[f32]) -> std::io::Result<()> {
    v.iter().try_for_each(|x| w.write_all(&x.to_le_bytes()))
}

/// Writes the skin data set for the given entries of `dir`.
pub fn build_skin(
    dir: &Path,
    entries: &[ManifestEntry],
    out: &Path,
    cfg: &SkinDatasetConfig,
    limits: &Limits,
) -> Result<DatasetSummary, DatasetError> {
    std::fs::create_dir_all(out)?;
    let open = |n: &str| -> std::io::Result<_> {
        Ok(std::io::BufWriter::new(std::fs::File::create(out.join(n))?))
    };
    let mut w = Writers {
        vert: open("vert.f32")?,
        pair: open("pair.f32")?,
        cand: open("cand.i32")?,
        target: open("target.f32")?,
        bone: open("bone.f32")?,
        index: open("index.jsonl")?,
    };
    let aug_cfg = AugmentConfig {
        drop_chain: 0.0,
        ..cfg.augment_config.clone()
    };
    let (mut row_offset, mut bone_offset) = (0usize, 0usize);
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
        if gt.skeleton.len() > cfg.max_bones {
            summary.skipped.push((
                e.file.clone(),
                format!("{} bones > {}", gt.skeleton.len(), cfg.max_bones),
            ));
            continue;
        }
        let items_before = summary.items;
        for aug in 0..=cfg.augment {
            let seed = cfg.seed ^ ((fi as u64) << 20) ^ aug as u64;
            let (positions, skel) = if aug == 0 {
                (mesh.positions.clone(), gt.skeleton.clone())
            } else {
                augment(&mesh.positions, &gt.skeleton, &gt.weights, &aug_cfg, seed)
            };
            let mut posed = Welded::new(&Mesh {
                positions,
                triangles: mesh.triangles.clone(),
                ..Mesh::default()
            });
            // Into the frame skinning at serving time runs in.
            let norm = into_skin_frame(&mut posed.mesh);
            let mut skel = skel;
            skel.map_points(|p| norm.apply(p));
            let cands = match candidates_timed(&posed.mesh, &skel, &cfg.skin, cfg.k) {
                Ok((c, _)) => c,
                Err(err) => {
                    summary
                        .skipped
                        .push((e.file.clone(), err.code().to_string()));
                    break;
                }
            };
            let f = features(&posed.mesh, &skel, &cands, &cfg.skin, cfg.k);
            let artist = |r: usize| {
                gt.weights
                    .per_vertex
                    .get(posed.original(f.rows[r]) as usize)
            };
            // Rows the artist weighted, a random subset when there are more than asked.
            let mut pick: Vec<usize> = (0..f.rows.len())
                .filter(|&r| artist(r).is_some_and(|l| l.iter().any(|x| x.1 > 0.0)))
                .collect();
            let mut rng = SplitMix64::new(seed ^ 0x51_4B1D);
            for i in (1..pick.len()).rev() {
                pick.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
            }
            pick.truncate(cfg.rows);
            pick.sort_unstable();
            if pick.is_empty() {
                continue;
            }
            let k = f.k;
            for &r in &pick {
                let gtw = artist(r).expect("picked rows have artist weights");
                let total: f32 = gtw.iter().map(|x| x.1.max(0.0)).sum();
                f32s(
                    &mut w.vert,
                    &f.vert[r * VERT_FEATURES..(r + 1) * VERT_FEATURES],
                )?;
                f32s(
                    &mut w.pair,
                    &f.pair[r * k * PAIR_FEATURES..(r + 1) * k * PAIR_FEATURES],
                )?;
                for &b in &f.cand[r * k..(r + 1) * k] {
                    w.cand.write_all(&(b as i32).to_le_bytes())?;
                    let t: f32 = gtw
                        .iter()
                        .filter(|x| b >= 0 && x.0 as i64 == b)
                        .map(|x| x.1.max(0.0))
                        .sum();
                    w.target.write_all(&(t / total).to_le_bytes())?;
                }
            }
            f32s(&mut w.bone, &f.bone)?;
            let item = Item {
                file: &e.file,
                category: &e.category,
                aug,
                row_offset,
                rows: pick.len(),
                bone_offset,
                bones: f.bones(),
                k,
                vertices: posed.mesh.positions.len(),
            };
            debug_assert_eq!(f.bone.len(), f.bones() * BONE_FEATURES);
            row_offset += pick.len();
            bone_offset += f.bones();
            serde_json::to_writer(&mut w.index, &item).map_err(std::io::Error::from)?;
            w.index.write_all(b"\n")?;
            summary.items += 1;
        }
        if summary.items > items_before {
            summary.files += 1;
        }
    }
    for f in [
        &mut w.vert,
        &mut w.pair,
        &mut w.cand,
        &mut w.target,
        &mut w.bone,
        &mut w.index,
    ] {
        f.flush()?;
    }
    Ok(summary)
}
