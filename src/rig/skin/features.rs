//! Inputs of the learned skin model (`training/skin/`), computed once here for both the
//! data set writer and inference, so the model sees at serving time exactly what it was
//! trained on.
//!
//! Everything is in the mesh's unit frame ([`Normalization`]: centred, longest half-side
//! 1). Rows are the vertices that have nearest-bone candidates ([`VertexBones::Near`]);
//! rigidly bound parts keep their bone and are not scored by the model.
//!
//! Layout (the `skin-v1` contract of `training/skin/ONNX_CONTRACT.md`):
//! - `vert`: rows × [`VERT_FEATURES`]: position, normal;
//! - `bone`: bones × [`BONE_FEATURES`]: head, tail, length, depth, root, leaf, children,
//!   bone count, three name hints, and how much of the mesh the bone is nearest to;
//! - `cand`: rows × k bone indices, nearest first, `-1` past the vertex's candidates;
//! - `pair`: rows × k × [`PAIR_FEATURES`]: distance, relative distance, the geometric
//!   blend, straight-line distance and position along the bone, rank, whether the
//!   distance is geodesic, and the offset from the bone's nearest point.

use super::{weights, Candidates, SkinConfig, VertexBones};
use crate::mesh::{Mesh, Normalization};
use crate::rig::Skeleton;
use glam::Vec3;

pub const VERT_FEATURES: usize = 6;
pub const BONE_FEATURES: usize = 17;
pub const PAIR_FEATURES: usize = 11;

/// The model's inputs for one mesh and skeleton.
#[derive(Clone, Debug, Default)]
pub struct SkinFeatures {
    /// The vertex of each row.
    pub rows: Vec<u32>,
    /// Candidates per row.
    pub k: usize,
    pub vert: Vec<f32>,
    pub bone: Vec<f32>,
    pub cand: Vec<i64>,
    pub pair: Vec<f32>,
}

impl SkinFeatures {
    pub fn bones(&self) -> usize {
        self.bone.len() / BONE_FEATURES
    }
}

/// Builds the features of every vertex with candidates, keeping at most `k` per vertex.
pub fn features(
    mesh: &Mesh,
    skeleton: &Skeleton,
    cands: &Candidates,
    cfg: &SkinConfig,
    k: usize,
) -> SkinFeatures {
    let k = k.max(1);
    let norm = Normalization::from_points(&mesh.positions);
    let scale = 1.0 / norm.half_extent;
    let normals = vertex_normals(mesh);
    let rows: Vec<u32> = cands
        .per_vertex
        .iter()
        .enumerate()
        .filter(|(_, v)| matches!(v, VertexBones::Near { bones, .. } if !bones.is_empty()))
        .map(|(i, _)| i as u32)
        .collect();
    let mut f = SkinFeatures {
        k,
        vert: Vec::with_capacity(rows.len() * VERT_FEATURES),
        cand: Vec::with_capacity(rows.len() * k),
        pair: Vec::with_capacity(rows.len() * k * PAIR_FEATURES),
        ..SkinFeatures::default()
    };
    let nb = skeleton.len();
    let (mut nearest_of, mut listed_in) = (vec![0f32; nb], vec![0f32; nb]);
    let eps = (cfg.softness * cands.cell).max(f32::MIN_POSITIVE);
    for &v in &rows {
        let VertexBones::Near { bones, geodesic } = &cands.per_vertex[v as usize] else {
            continue;
        };
        let bones = &bones[..bones.len().min(k)];
        let p = mesh.positions[v as usize];
        f.vert.extend(norm.apply(p).to_array());
        f.vert.extend(normals[v as usize].to_array());
        let d0 = bones[0].1;
        let blend: Vec<f32> = bones
            .iter()
            .map(|&(_, d)| ((d0 + eps) / (d.max(d0) + eps)).powf(cfg.falloff))
            .collect();
        let total: f32 = blend.iter().sum::<f32>().max(f32::MIN_POSITIVE);
        let kept = weights::from_distances(bones, cfg, cands.cell);
        nearest_of[bones[0].0 as usize] += 1.0;
        for (r, &(b, d)) in bones.iter().enumerate() {
            listed_in[b as usize] += 1.0;
            let bone = &skeleton.bones[b as usize];
            let (closest, t) = closest_on_segment(p, bone.head, bone.tail);
            let off = (p - closest) * scale;
            let geo = kept.iter().find(|x| x.0 == b).map_or(0.0, |x| x.1);
            f.cand.push(b as i64);
            f.pair.extend([
                d * scale,
                ((d + eps) / (d0 + eps)).ln(),
                blend[r] / total,
                geo,
                p.distance(closest) * scale,
                t.clamp(-0.5, 1.5),
                r as f32 / k as f32,
                f32::from(u8::from(*geodesic)),
                off.x,
                off.y,
                off.z,
            ]);
        }
        for _ in bones.len()..k {
            f.cand.push(-1);
            f.pair.extend([0.0; PAIR_FEATURES]);
        }
    }
    f.rows = rows;
    let n = f.rows.len().max(1) as f32;
    let children = skeleton.children();
    let mut depth = vec![0usize; nb];
    for (i, b) in skeleton.bones.iter().enumerate() {
        // Parents come first (a validated skeleton), so their depth is already known.
        depth[i] = b.parent.map_or(0, |p| depth[p] + 1);
    }
    let max_depth = depth.iter().copied().max().unwrap_or(0) as f32 + 1.0;
    f.bone.reserve(nb * BONE_FEATURES);
    for (i, b) in skeleton.bones.iter().enumerate() {
        let hints = name_hints(&b.name);
        f.bone.extend(norm.apply(b.head).to_array());
        f.bone.extend(norm.apply(b.tail).to_array());
        f.bone.extend([
            b.head.distance(b.tail) * scale,
            depth[i] as f32 / max_depth,
            f32::from(u8::from(b.parent.is_none())),
            f32::from(u8::from(children[i].is_empty())),
            children[i].len().min(4) as f32 / 4.0,
            (nb as f32).ln() / 5.0,
            hints[0],
            hints[1],
            hints[2],
            (1.0 + nb as f32 * nearest_of[i] / n).ln(),
            listed_in[i] / n,
        ]);
    }
    f
}

/// The nearest point of segment `a`–`b` to `p`, and its parameter along the (unclamped)
/// line, which says whether the vertex lies before, along or past the bone.
fn closest_on_segment(p: Vec3, a: Vec3, b: Vec3) -> (Vec3, f32) {
    let ab = b - a;
    let len2 = ab.length_squared();
    if len2 <= f32::MIN_POSITIVE {
        return (a, 0.0);
    }
    let t = (p - a).dot(ab) / len2;
    (a + ab * t.clamp(0.0, 1.0), t)
}

/// Area-weighted vertex normals from the triangles, so meshes with and without stored
/// normals (OBJ, generated) look alike to the model.
fn vertex_normals(mesh: &Mesh) -> Vec<Vec3> {
    let mut n = vec![Vec3::ZERO; mesh.positions.len()];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let face = (b - a).cross(c - a);
        for &i in t {
            n[i as usize] += face;
        }
    }
    n.iter().map(|x| x.normalize_or_zero()).collect()
}

/// What the name says about a bone artists often leave without weight: an end or tip
/// marker, a control (IK, pole, target, root, helper), a twist or roll helper.
/// Predicted skeletons carry template or generic names, for which these are all zero.
pub fn name_hints(name: &str) -> [f32; 3] {
    let lower = name.to_ascii_lowercase();
    let words: Vec<&str> = lower
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| !w.is_empty())
        .collect();
    let last = words.last().copied().unwrap_or("");
    let end = last.ends_with("end")
        || last.ends_with("nub")
        || last == "tip"
        || last == "top"
        || lower.contains("_end")
        || lower.contains("nub");
    let control = words.iter().any(|w| {
        w.strip_prefix("ik")
            .is_some_and(|r| r.chars().all(|c| c.is_ascii_digit()))
            || w.ends_with("ik")
    }) || [
        "pole", "ctrl", "control", "target", "helper", "root", "armature",
    ]
    .iter()
    .any(|h| lower.contains(h));
    let twist = lower.contains("twist") || lower.contains("roll");
    [end, control, twist].map(|x| f32::from(u8::from(x)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn name_hints_read_common_conventions() {
        assert_eq!(name_hints("mixamorig:HeadTop_End"), [1.0, 0.0, 0.0]);
        assert_eq!(name_hints("Bip01 L Finger0Nub"), [1.0, 0.0, 0.0]);
        assert_eq!(name_hints("foot_ik.L"), [0.0, 1.0, 0.0]);
        assert_eq!(name_hints("IK_Hand_R"), [0.0, 1.0, 0.0]);
        assert_eq!(name_hints("Root"), [0.0, 1.0, 0.0]);
        assert_eq!(name_hints("forearm_twist.L"), [0.0, 0.0, 1.0]);
        // Plain deforming bones, including ones whose words merely contain the hints.
        for n in [
            "Spine1",
            "mixamorig:LeftHand",
            "thigh_l",
            "Bone.001",
            "Pinky2",
            "Kick",
        ] {
            assert_eq!(name_hints(n), [0.0; 3], "{n}");
        }
    }

    #[test]
    fn closest_point_and_parameter() {
        let (a, b) = (Vec3::ZERO, Vec3::X);
        let (c, t) = closest_on_segment(Vec3::new(2.0, 1.0, 0.0), a, b);
        assert_eq!((c, t), (Vec3::X, 2.0));
        let (c, t) = closest_on_segment(Vec3::new(0.25, 1.0, 0.0), a, b);
        assert_eq!((c, t), (Vec3::new(0.25, 0.0, 0.0), 0.25));
        assert_eq!(closest_on_segment(Vec3::Y, a, a), (a, 0.0));
    }
}
