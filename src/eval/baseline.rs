//! The trivial baseline a learned model must beat: for each category, the training
//! skeleton closest on average to all others of its category (a medoid: topologies
//! differ, so an arithmetic mean skeleton does not exist), stretched onto the test
//! mesh's bounding box.

use super::{load_rig, ErrorInfo, ManifestEntry, ModelReport};
use crate::mesh::Limits;
use crate::rig::metrics::{cd_j2j, score_skeleton, Frame};
use crate::rig::Skeleton;
use glam::Vec3;
use std::collections::BTreeMap;
use std::path::Path;

/// A skeleton in box coordinates: each axis of the mesh's bounding box mapped to [0, 1].
fn to_box(skel: &Skeleton, lo: Vec3, hi: Vec3) -> Skeleton {
    let size = (hi - lo).max(Vec3::splat(1e-9));
    let mut s = skel.clone();
    s.map_points(|p| (p - lo) / size);
    s
}

/// Medoid skeleton per category, in box coordinates.
pub fn category_medoids(
    dataset: &Path,
    train: &[ManifestEntry],
    limits: &Limits,
) -> BTreeMap<String, Skeleton> {
    let mut by_cat: BTreeMap<String, Vec<Skeleton>> = BTreeMap::new();
    for e in train {
        if let Ok((mesh, gt)) = load_rig(&dataset.join(&e.file), limits) {
            let (lo, hi) = mesh.bounds();
            by_cat
                .entry(e.category.clone())
                .or_default()
                .push(to_box(&gt.skeleton, lo, hi));
        }
    }
    by_cat
        .into_iter()
        .filter_map(|(cat, skels)| {
            let best = (0..skels.len()).min_by(|&a, &b| {
                let cost = |i: usize| -> f32 {
                    skels
                        .iter()
                        .filter_map(|o| cd_j2j(&skels[i], o, &Frame::UNIT))
                        .sum()
                };
                cost(a).total_cmp(&cost(b))
            })?;
            Some((cat, skels[best].clone()))
        })
        .collect()
}

/// Scores the category medoid, stretched onto each test mesh, against its rig.
pub fn score_baseline(
    dataset: &Path,
    e: &ManifestEntry,
    medoids: &BTreeMap<String, Skeleton>,
    limits: &Limits,
) -> ModelReport {
    let mut report = ModelReport::new(&e.file, &e.category);
    report.artist = e.artist_or_unknown();
    let (mesh, gt) = match load_rig(&dataset.join(&e.file), limits) {
        Ok(x) => x,
        Err(err) => {
            report.error = Some(err);
            return report;
        }
    };
    report.joints_gt = gt.skeleton.len();
    let Some(medoid) = medoids.get(&e.category) else {
        report.error = Some(ErrorInfo {
            code: "no_training_skeleton".into(),
            message: format!("no training rig of category {}", e.category),
        });
        return report;
    };
    let (lo, hi) = mesh.bounds();
    let mut pred = medoid.clone();
    pred.map_points(|p| lo + p * (hi - lo));
    report.joints_pred = pred.len();
    report.skeleton = Some(score_skeleton(
        &pred,
        &gt.skeleton,
        &Frame::from_points(&mesh.positions),
    ));
    report.valid = true;
    report
}
