//! Skin weights from the learned model: it rescores each vertex's candidate bones, and
//! the same rules as the geometric weights turn its scores into at most
//! `cfg.max_influences` influences summing to 1. Rigidly bound parts keep their bone, so
//! the per-part rules of the module docs hold whichever method runs.

use super::features::{features, SkinFeatures};
use super::prepare::Voxels;
use super::{candidates_in, ms, CandidateScorer, Candidates, SkinConfig, SkinError, SkinTimings};
use crate::mesh::Mesh;
use crate::rig::{Skeleton, SkinWeights};
use std::time::Instant;

/// [`super::skin_with`] of a checked, welded mesh and its `voxels`, also reporting where
/// the time went.
pub fn skin_learned_in(
    mesh: &Mesh,
    voxels: &Voxels,
    skeleton: &Skeleton,
    cfg: &SkinConfig,
    model: &dyn CandidateScorer,
) -> Result<(SkinWeights, SkinTimings), SkinError> {
    let (cands, mut times) = candidates_in(mesh, voxels, skeleton, cfg, super::LEARNED_CANDIDATES)?;
    let t = Instant::now();
    let f = features(mesh, skeleton, &cands, cfg, super::LEARNED_CANDIDATES);
    let scores = if f.rows.is_empty() {
        Vec::new()
    } else {
        model
            .scores(&f)
            .map_err(|(code, message)| SkinError::Model { code, message })?
    };
    times.model_ms = ms(t);
    let t = Instant::now();
    let out = from_scores(&cands, &f, &scores, cfg);
    times.weights_ms = ms(t);
    Ok((out, times))
}

/// The geometric weights, with every row the model scored replaced by its choice.
/// A row whose scores are unusable (none finite and positive) keeps its geometric
/// weights, so no vertex is left unweighted.
pub fn from_scores(
    cands: &Candidates,
    f: &SkinFeatures,
    scores: &[f32],
    cfg: &SkinConfig,
) -> SkinWeights {
    let mut out = cands.geometric(cfg);
    let k = f.k;
    for (r, &v) in f.rows.iter().enumerate() {
        let Some(row) = scores.get(r * k..(r + 1) * k) else {
            break;
        };
        let mut w: Vec<(u32, f32)> = f.cand[r * k..(r + 1) * k]
            .iter()
            .zip(row)
            .filter(|(&b, &s)| b >= 0 && s.is_finite() && s > 0.0)
            .map(|(&b, &s)| (b as u32, s))
            .collect();
        w.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        w.truncate(cfg.max_influences.max(1));
        normalize(&mut w);
        let mut first = true;
        w.retain(|&(_, x)| std::mem::replace(&mut first, false) || x >= cfg.min_weight);
        normalize(&mut w);
        if !w.is_empty() {
            out.per_vertex[v as usize] = w;
        }
    }
    out
}

fn normalize(w: &mut [(u32, f32)]) {
    let s: f32 = w.iter().map(|x| x.1).sum();
    if s > 0.0 && s.is_finite() {
        w.iter_mut().for_each(|x| x.1 /= s);
    }
}

#[cfg(test)]
mod tests {
    use super::super::VertexBones;
    use super::*;

    #[test]
    fn scores_pick_top_influences_and_bad_rows_stay_geometric() {
        let cands = Candidates {
            per_vertex: vec![
                VertexBones::Near {
                    bones: vec![(0, 0.1), (1, 0.2), (2, 0.3)],
                    geodesic: true,
                },
                VertexBones::Rigid(2),
                VertexBones::Near {
                    bones: vec![(1, 0.1), (0, 0.5)],
                    geodesic: true,
                },
            ],
            cell: 0.05,
        };
        let f = SkinFeatures {
            rows: vec![0, 2],
            k: 3,
            cand: vec![0, 1, 2, 1, 0, -1],
            ..SkinFeatures::default()
        };
        let cfg = SkinConfig {
            max_influences: 2,
            ..SkinConfig::default()
        };
        // Row 0: the model moves the weight off the nearest bone; row 1: NaN everywhere.
        let scores = [0.02, 0.6, 0.38, f32::NAN, f32::NAN, 0.0];
        let w = from_scores(&cands, &f, &scores, &cfg);
        assert_eq!(w.per_vertex[0].len(), 2);
        assert_eq!(w.per_vertex[0][0].0, 1);
        assert_eq!(w.per_vertex[0][1].0, 2);
        assert!((w.per_vertex[0][0].1 - 0.6 / 0.98).abs() < 1e-6);
        assert_eq!(w.per_vertex[1], vec![(2, 1.0)]);
        assert_eq!(w.per_vertex[2], cands.geometric(&cfg).per_vertex[2]);
        assert!(!w.per_vertex[2].is_empty());
    }
}
