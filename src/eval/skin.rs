//! `rigserve eval --skin-on-gt`: rigserve's skinning (learned model or geometric) given the artist's skeleton, scored
//! against the artist's weights. The skeleton is the ground truth, so the skeleton
//! figures are zero and the skin figures measure the weights alone.

use super::{each_rig, err, summarize, EvalError, Report, POSE_SEED};
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
    let models = each_rig(dataset, split, limits, |_, mesh, gt, report| {
        report.joints_pred = gt.skeleton.len();
        let frame = Frame::from_points(&mesh.positions);
        report.skeleton = Some(score_skeleton(&gt.skeleton, &gt.skeleton, &frame));
        let scored = skin_with(
            mesh,
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
    })?;
    Ok(summarize(dataset, split, "skin_on_gt", models))
}
