//! Per-vertex influences in the form glTF stores them: four (joint, weight) slots.

use super::ExportError;
use crate::mesh::Mesh;
use crate::rig::{Skeleton, SkinWeights};
use glam::Vec3;

/// One vertex's `JOINTS_0`/`WEIGHTS_0` element. Unused slots are joint 0 with weight 0,
/// which the glTF validator accepts and every runtime ignores.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Packed {
    pub joints: [u16; 4],
    pub weights: [f32; 4],
}

/// Checks `weights` against the mesh and skeleton and packs every merged vertex.
pub(crate) fn pack_all(
    mesh: &Mesh,
    skel: &Skeleton,
    weights: &SkinWeights,
    max_influences: usize,
) -> Result<Vec<Packed>, ExportError> {
    if !(1..=4).contains(&max_influences) {
        return Err(ExportError::BadOptions(max_influences));
    }
    if weights.per_vertex.len() != mesh.positions.len() {
        return Err(ExportError::WeightCount {
            weights: weights.per_vertex.len(),
            vertices: mesh.positions.len(),
        });
    }
    let mut out = Vec::with_capacity(mesh.positions.len());
    for (v, list) in weights.per_vertex.iter().enumerate() {
        for &(b, w) in list {
            if b as usize >= skel.len() {
                return Err(ExportError::BoneOutOfRange {
                    vertex: v,
                    bone: b,
                    bones: skel.len(),
                });
            }
            if !w.is_finite() {
                return Err(ExportError::NonFiniteWeight(v));
            }
        }
        out.push(match pack_one(list, max_influences) {
            Some(p) => p,
            None => {
                // glTF has no "unskinned vertex" in a skinned primitive: all-zero weights
                // collapse it to the origin in most runtimes. The nearest bone is what an
                // artist would paint it to and keeps it on the surface.
                single(nearest_bone(skel, mesh.positions[v]))
            }
        });
    }
    Ok(out)
}

fn single(bone: usize) -> Packed {
    Packed {
        joints: [bone as u16, 0, 0, 0],
        weights: [1.0, 0.0, 0.0, 0.0],
    }
}

/// Keeps the `k` largest positive influences (ties to the lower bone, as
/// [`SkinWeights::top_k`] does) and normalises them; None when nothing positive is left.
pub(crate) fn pack_one(list: &[(u32, f32)], k: usize) -> Option<Packed> {
    // Inputs may name a bone twice (summed weights from several sources); a repeated
    // joint index with non-zero weight is invalid glTF.
    let mut merged: Vec<(u32, f64)> = Vec::with_capacity(list.len());
    for &(b, w) in list {
        if w.is_nan() || w <= 0.0 {
            continue;
        }
        match merged.iter_mut().find(|(mb, _)| *mb == b) {
            Some(e) => e.1 += w as f64,
            None => merged.push((b, w as f64)),
        }
    }
    merged.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    merged.truncate(k);
    if merged.is_empty() {
        return None;
    }
    let sum: f64 = merged.iter().map(|e| e.1).sum();
    let mut slots: Vec<(u32, f32)> = merged
        .iter()
        .map(|&(b, w)| (b, (w / sum) as f32))
        .filter(|&(_, w)| w > 0.0)
        .collect();
    // The validator (and some runtimes) check the sum of the stored f32 values; giving
    // the rounding error to the largest weight (at least 1/k) keeps the exact sum within
    // half an f32 ulp of 1.
    let rest: f64 = slots.iter().skip(1).map(|s| s.1 as f64).sum();
    slots[0].1 = (1.0 - rest) as f32;
    let mut p = Packed {
        joints: [0; 4],
        weights: [0.0; 4],
    };
    for (i, (b, w)) in slots.into_iter().enumerate() {
        p.joints[i] = b as u16;
        p.weights[i] = w;
    }
    Some(p)
}

/// The bone whose head-to-tail segment passes closest to `p` (lowest index on ties).
pub(crate) fn nearest_bone(skel: &Skeleton, p: Vec3) -> usize {
    let mut best = (0, f32::INFINITY);
    for (i, b) in skel.bones.iter().enumerate() {
        let d = segment_distance(p, b.head, b.tail);
        if d < best.1 {
            best = (i, d);
        }
    }
    best.0
}

fn segment_distance(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + ab * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_largest_and_sums_to_one() {
        let p = pack_one(&[(3, 0.1), (1, 0.3), (2, 0.3), (5, 0.2), (7, 0.1)], 4).unwrap();
        assert_eq!(p.joints, [1, 2, 5, 3]);
        let s: f64 = p.weights.iter().map(|&w| w as f64).sum();
        assert!((s - 1.0).abs() < 1e-7, "{s}");
        assert!((p.weights[0] - 0.3 / 0.9).abs() < 1e-6);
    }

    #[test]
    fn merges_repeats_and_drops_non_positive() {
        let p = pack_one(&[(2, 0.25), (2, 0.25), (4, 0.0), (1, -1.0)], 4).unwrap();
        assert_eq!(p.joints, [2, 0, 0, 0]);
        assert_eq!(p.weights, [1.0, 0.0, 0.0, 0.0]);
        assert!(pack_one(&[(1, 0.0)], 4).is_none());
        assert!(pack_one(&[], 4).is_none());
    }

    #[test]
    fn nearest_bone_uses_segments_not_heads() {
        use crate::rig::Bone;
        let bone = |name: &str, head: Vec3, tail: Vec3| Bone {
            name: name.into(),
            parent: None,
            head,
            tail,
            spring: false,
        };
        let skel = Skeleton {
            bones: vec![
                bone("long", Vec3::ZERO, Vec3::new(0.0, 10.0, 0.0)),
                bone(
                    "near_head",
                    Vec3::new(2.0, 6.0, 0.0),
                    Vec3::new(3.0, 6.0, 0.0),
                ),
            ],
            ..Default::default()
        };
        // Closer to bone 1's head (1.0) than to bone 0's head (6.0), but the segment of
        // bone 0 passes at 0.9.
        assert_eq!(nearest_bone(&skel, Vec3::new(0.9, 6.0, 0.0)), 0);
        assert_eq!(nearest_bone(&skel, Vec3::new(1.9, 6.0, 0.0)), 1);
    }
}
