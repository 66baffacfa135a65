//! `rigserve eval --retrieval`: the skeleton of the most similar `train` rig, moved onto
//! each mesh ([`crate::predict::library`]); a stronger baseline than the category medoid.

use super::{each_rig, entries_in, load_rig, summarize, EvalError, Report};
use crate::mesh::Limits;
use crate::predict::library::{shape_points, BoxFrame, Entry, Library};
use crate::rig::metrics::{score_skeleton, Frame};
use std::path::Path;

/// Every loadable rig of `split` as a library entry.
pub fn build_library(dataset: &Path, split: &str, limits: &Limits) -> Result<Library, EvalError> {
    build_library_filtered(dataset, split, &[], limits)
}

/// [`build_library`] without the rows whose licence contains any of `exclude_license`
/// (case-insensitive); each one left out is named.
pub fn build_library_filtered(
    dataset: &Path,
    split: &str,
    exclude_license: &[String],
    limits: &Limits,
) -> Result<Library, EvalError> {
    let mut entries = Vec::new();
    for e in entries_in(dataset, Some(split))? {
        let license = e.license.as_deref().unwrap_or("").to_lowercase();
        if let Some(x) = exclude_license
            .iter()
            .find(|x| license.contains(&x.to_lowercase()))
        {
            eprintln!("library: leaving out {}: its licence has {x:?}", e.file);
            continue;
        }
        match load_rig(&dataset.join(&e.file), limits) {
            Ok((mesh, gt)) => entries.push(Entry::new(&e.file, &e.category, &mesh, &gt.skeleton)),
            Err(err) => eprintln!(
                "library: leaving out {}: {} ({})",
                e.file, err.message, err.code
            ),
        }
    }
    Ok(Library::new(entries))
}

pub fn eval_retrieval(
    dataset: &Path,
    split: Option<&str>,
    train_split: &str,
    warp: bool,
    limits: &Limits,
) -> Result<Report, EvalError> {
    let lib = build_library(dataset, train_split, limits)?;
    let models = each_rig(dataset, split, limits, |e, mesh, gt, report| {
        // Four independent draws, as the predictor's quarters of its samples: ranked on
        // the first, fitted on all.
        let draws: Vec<Vec<glam::Vec3>> = (11..15).map(|k| shape_points(mesh, k)).collect();
        let ranked = lib.ranked(
            &draws[0],
            BoxFrame::of(mesh).proportions(),
            Some(&e.category),
        );
        // Leave-one-out when the split scored is the library's own.
        let Some(&(best, dist)) = ranked.iter().find(|(i, _)| lib.entries[*i].name != e.file)
        else {
            return;
        };
        let frame = BoxFrame::of(mesh);
        let mut pred = if warp {
            lib.entries[best].fit_mean(&draws)
        } else {
            lib.entries[best].fit(&draws[0], false)
        };
        pred.map_points(|q| frame.invert(q));
        if warp {
            // As the predictor does with a borrowed skeleton (in its unit frame).
            if let Ok(s) = crate::predict::mesh_samples(mesh, crate::predict::MODEL_POINTS, 0) {
                let norm = s.normalization;
                pred.map_points(|p| norm.apply(p));
                crate::predict::inside::pull_inside(&mut pred, &s);
                pred.map_points(|p| norm.invert(p));
            }
        }
        report.joints_pred = pred.len();
        report.valid = true;
        report.skeleton = Some(score_skeleton(
            &pred,
            &gt.skeleton,
            &Frame::from_points(&mesh.positions),
        ));
        eprintln!(
            "{:45} <- {:45} shape {:.4} CD-J2J {:.4}",
            e.file,
            lib.entries[best].name,
            dist,
            report.skeleton.as_ref().unwrap().cd_j2j
        );
    })?;
    Ok(summarize(dataset, split, "retrieval", models))
}
