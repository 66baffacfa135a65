//! Weights from per-bone distances.
//!
//! Each candidate bone weighs `((d₀ + ε) / (d + ε))^p`, where `d₀` is the vertex's
//! distance to its nearest bone. Relative distances make the blend scale with the limb:
//! a vertex on a thick thigh blends over a wider band than one on a finger, as an artist
//! paints it. `ε` (a fraction of a cell) keeps vertices lying on a bone from becoming
//! all-or-nothing, and small weights are dropped, because an influence of a few percent
//! is invisible when posing but costs a bone slot and precision.

use super::SkinConfig;

/// Weights for one vertex from its candidates `(bone, distance)`, nearest first.
/// Returns at most `cfg.max_influences` pairs summing to 1; empty only when `cands` is.
pub fn from_distances(cands: &[(u32, f32)], cfg: &SkinConfig, cell: f32) -> Vec<(u32, f32)> {
    let Some(&(_, d0)) = cands.first() else {
        return Vec::new();
    };
    let eps = (cfg.softness * cell).max(f32::MIN_POSITIVE);
    let mut w: Vec<(u32, f32)> = cands
        .iter()
        .take(cfg.max_influences.max(1))
        .map(|&(b, d)| (b, ((d0 + eps) / (d.max(d0) + eps)).powf(cfg.falloff)))
        .collect();
    normalize(&mut w);
    // The nearest bone always stays, so no vertex is left unweighted.
    let keep = cfg.min_weight;
    let mut first = true;
    w.retain(|&(_, x)| std::mem::replace(&mut first, false) || x >= keep);
    normalize(&mut w);
    w
}

fn normalize(w: &mut [(u32, f32)]) {
    let s: f32 = w.iter().map(|x| x.1).sum();
    if s > 0.0 && s.is_finite() {
        w.iter_mut().for_each(|x| x.1 /= s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_dominates_and_weights_sum_to_one() {
        let cfg = SkinConfig::default();
        let w = from_distances(
            &[(3, 0.1), (1, 0.12), (2, 0.5), (0, 0.6), (5, 0.9)],
            &cfg,
            0.02,
        );
        assert!(w.len() <= 4);
        assert_eq!(w[0].0, 3);
        assert!(w[0].1 > w[1].1);
        assert!((w.iter().map(|x| x.1).sum::<f32>() - 1.0).abs() < 1e-6);
        assert!(w.iter().all(|x| x.1 >= cfg.min_weight));
        // Equidistant bones share evenly.
        let w = from_distances(&[(0, 0.2), (1, 0.2)], &cfg, 0.02);
        assert!((w[0].1 - 0.5).abs() < 1e-6);
        assert!(from_distances(&[], &cfg, 0.02).is_empty());
    }
}
