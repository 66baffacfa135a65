//! `rigserve eval --skin-on-gt`: rigserve's skinning (learned model or geometric) given the artist's skeleton, scored
//! against the artist's weights. The skeleton is the ground truth, so the skeleton
//! figures are zero and the skin figures measure the weights alone.

use super::{entries_in, err, load_rig, summarize, EvalError, ModelReport, Report, POSE_SEED};
use crate::infer::SkinModel;
use crate::mesh::Limits;
use crate::rig::metrics::{score_skeleton, score_skin, Frame};
use crate::rig::skin::{skin_with, CandidateScorer, SkinConfig};
use std::path::Path;

pub fn eval_skin_on_gt(
    dataset: &Path,
    split: Option<&str>,
    cfg: &SkinConfig,
    model: Option<&SkinModel>,
    limits: &Limits,
) -> Result<Report, EvalError> {
    let mut models = Vec::new();
    for e in entries_in(dataset, split)? {
        let mut report = ModelReport::new(&e.file, &e.category);
        match load_rig(&dataset.join(&e.file), limits) {
            Err(info) => report.error = Some(info),
            Ok((mesh, gt)) => {
                report.joints_gt = gt.skeleton.len();
                report.joints_pred = gt.skeleton.len();
                let frame = Frame::from_points(&mesh.positions);
                report.skeleton = Some(score_skeleton(&gt.skeleton, &gt.skeleton, &frame));
                let scored = skin_with(
                    &mesh,
                    &gt.skeleton,
                    cfg,
                    model.map(|m| m as &dyn CandidateScorer),
                )
                .map_err(|e| err(e.code(), e))
                .and_then(|w| {
                    score_skin(
                        &gt.skeleton,
                        &w,
                        &gt.skeleton,
                        &gt.weights,
                        &mesh.positions,
                        &frame,
                        POSE_SEED,
                    )
                    .map_err(|e| err(e.code(), e))
                });
                match scored {
                    Ok(s) => {
                        report.skin = Some(s);
                        report.valid = true;
                    }
                    Err(info) => report.error = Some(info),
                }
            }
        }
        models.push(report);
    }
    Ok(summarize(dataset, split, "skin_on_gt", models))
}
