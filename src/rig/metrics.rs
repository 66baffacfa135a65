//! Rig quality metrics, defined the way the auto-rigging literature reports them, so that
//! rigserve's evaluation numbers can sit next to the RigNet, UniRig, Puppeteer and TokenRig
//! tables.
//!
//! # Units
//!
//! Every distance is reported in the literature's unit: the mesh is mapped to [-1, 1] on the
//! longest side of its bounding box (see [`Frame`]) and the distance is then halved. UniRig's
//! code divides by the width of its [-1, 1] range (2); RigNet and Puppeteer normalise to
//! [-0.5, 0.5] instead, which is the same scale, and their tables print the value ×10⁻².
//! Distances are computed in the mesh's own frame and scaled once at the end; the map is a
//! translation plus a uniform scale, so this is the same number.
//!
//! # Skeleton metrics
//!
//! Chamfer distances follow RigNet's code, which UniRig and TokenRig reuse: the symmetric
//! chamfer distance between sets A and B is the *average* of the two directed means,
//! `(mean_{a∈A} d(a, B) + mean_{b∈B} d(b, A)) / 2`, not their sum.
//!
//! - J2J: joints (bone heads) against joints.
//! - J2B: joints of one skeleton against the bone segments of the other, both ways. RigNet
//!   and UniRig measure against points sampled along the bones; the exact point-to-segment
//!   distance is the limit of that sampling.
//! - B2B: each bone sampled at 101 evenly spaced points (every 1/100 of its length, both
//!   ends included) against the bone segments of the other skeleton, both ways. UniRig
//!   samples a fixed 100 points per bone, so every bone weighs the same however long it
//!   is (RigNet instead samples every 0.005 units, weighting long bones more); it measures
//!   samples against the other side's samples, which with 100 samples per bone differs from
//!   the segment distance by at most half a sample spacing.
//!
//! Bones are the segments head → tail of every bone, roots included; a zero-length bone
//! is a point. A skeleton without bones has no chamfer distance: the functions return
//! `None` and the score structs hold NaN.
//!
//! # Skin metrics
//!
//! Predicted bones are matched to ground-truth bones by exact name. Only vertices that carry
//! weights in the ground truth are scored; the others are counted in
//! [`SkinScores::unweighted_gt`]. Weights are used as given (callers normally pass
//! normalised ones), so a vertex's L1 lies in [0, 2].
//!
//! - L1: per vertex, Σ_bones |w_pred − w_gt| in ground-truth bone space, where weight on a
//!   predicted bone without a ground-truth match counts in full; averaged over vertices.
//!   This is UniRig's "per-vertex L1". Code that averages `|w_pred − w_gt|` over an N×J
//!   matrix (torch's `l1_loss`, as in TokenRig's table) reports this divided by J.
//! - Precision and recall of the active set: a (vertex, bone) pair is active when its weight
//!   exceeds 0.01 (TokenRig's ε = 10⁻²). Both are micro-averaged over all pairs of the mesh:
//!   precision = true positives / predicted active pairs, recall = true positives / ground
//!   truth active pairs. An active weight on an unmatched predicted bone is a false positive.
//! - Deformation: mean distance between the mesh skinned with predicted and with true
//!   weights, both driven by the ground-truth skeleton in 8 random poses (each bone rotated
//!   up to 30° about its head, see [`random_pose`]). Weight on unmatched predicted bones
//!   follows the rest pose, since the ground-truth skeleton has no bone to drive it; a
//!   wrongly named bone therefore costs deformation as well as L1.

use std::collections::HashMap;

use glam::{Mat4, Quat, Vec3};
use serde::{Deserialize, Serialize};

use super::skeleton::{Skeleton, SkinWeights};
use crate::mesh::sample::SplitMix64;

/// Samples per bone for B2B, counted as intervals: 100 intervals give 101 points.
pub const BONE_SAMPLE_INTERVALS: usize = 100;
/// A weight above this makes a (vertex, bone) pair active for precision and recall.
pub const ACTIVE_WEIGHT: f32 = 0.01;
/// Random poses the deformation error averages over.
pub const DEFORMATION_POSES: usize = 8;
/// Largest rotation of any one bone in the deformation poses, in degrees.
pub const DEFORMATION_MAX_ANGLE_DEG: f32 = 30.0;

/// Where a mesh sits and how large it is: `(p - center) / half_extent` maps it to [-1, 1]
/// along the longest side of its bounding box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    pub center: Vec3,
    pub half_extent: f32,
}

impl Frame {
    /// The frame of a mesh that is already normalised to [-1, 1].
    pub const UNIT: Frame = Frame {
        center: Vec3::ZERO,
        half_extent: 1.0,
    };

    /// Bounding-box centre and half of its longest side. Non-finite points are left out; a
    /// set with no extent (empty, or a single point) gets a half extent of 1, so distances
    /// stay finite and are simply reported in mesh units halved.
    pub fn from_points(points: &[Vec3]) -> Frame {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for p in points.iter().filter(|p| p.is_finite()) {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        if lo.x > hi.x {
            return Frame::UNIT;
        }
        Frame {
            center: (lo + hi) * 0.5,
            half_extent: sanitize_half_extent((hi - lo).max_element() * 0.5),
        }
    }

    /// Maps a mesh-frame point into the normalised [-1, 1] frame.
    pub fn normalize(&self, p: Vec3) -> Vec3 {
        (p - self.center) / sanitize_half_extent(self.half_extent)
    }

    /// Converts a distance measured in mesh units into the reported unit (normalised, then
    /// halved; see the module documentation).
    pub fn report(&self, mesh_distance: f32) -> f32 {
        mesh_distance / sanitize_half_extent(self.half_extent) * 0.5
    }
}

fn sanitize_half_extent(h: f32) -> f32 {
    // A hand-built or degenerate frame must not turn every distance into inf or NaN.
    if h.is_finite() && h > f32::MIN_POSITIVE {
        h
    } else {
        1.0
    }
}

/// A bone as the segment head → tail (a point when the two coincide).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Segment {
    pub(crate) a: Vec3,
    pub(crate) b: Vec3,
}

impl Segment {
    pub(crate) fn distance(&self, p: Vec3) -> f32 {
        let ab = self.b - self.a;
        let len2 = ab.length_squared();
        if len2 <= 0.0 {
            return p.distance(self.a);
        }
        let t = (p - self.a).dot(ab) / len2;
        // Returning the endpoints themselves (rather than a + ab·t) keeps a joint that sits
        // exactly on an endpoint at distance exactly 0.
        let closest = if t <= 0.0 {
            self.a
        } else if t >= 1.0 {
            self.b
        } else {
            self.a + ab * t
        };
        p.distance(closest)
    }

    fn same_as(&self, other: &Segment) -> bool {
        (self.a == other.a && self.b == other.b) || (self.a == other.b && self.b == other.a)
    }
}

fn joints(s: &Skeleton) -> Vec<Vec3> {
    s.bones.iter().map(|b| b.head).collect()
}

fn segments(s: &Skeleton) -> Vec<Segment> {
    s.bones
        .iter()
        .map(|b| Segment {
            a: b.head,
            b: b.tail,
        })
        .collect()
}

/// Evenly spaced points along every bone, each tagged with the bone it lies on.
fn bone_samples(segs: &[Segment]) -> Vec<(Vec3, Segment)> {
    let n = BONE_SAMPLE_INTERVALS;
    let mut out = Vec::with_capacity(segs.len() * (n + 1));
    for s in segs {
        for i in 0..=n {
            out.push((s.a.lerp(s.b, i as f32 / n as f32), *s));
        }
    }
    out
}

/// Mean over `items` of each item's distance to the other set, accumulated in f64 so that
/// tens of thousands of small distances do not lose precision.
fn directed_mean<T>(items: &[T], dist: impl Fn(&T) -> f32) -> f64 {
    let sum: f64 = items.iter().map(|x| dist(x) as f64).sum();
    sum / items.len() as f64
}

fn nearest_point(p: Vec3, set: &[Vec3]) -> f32 {
    set.iter()
        .map(|q| p.distance(*q))
        .fold(f32::INFINITY, f32::min)
}

fn nearest_segment(p: Vec3, set: &[Segment]) -> f32 {
    set.iter()
        .map(|s| s.distance(p))
        .fold(f32::INFINITY, f32::min)
}

fn symmetric(frame: &Frame, a_to_b: f64, b_to_a: f64) -> f32 {
    frame.report(((a_to_b + b_to_a) / 2.0) as f32)
}

/// Joint-to-joint chamfer distance; `None` when either skeleton has no bones.
pub fn cd_j2j(pred: &Skeleton, gt: &Skeleton, frame: &Frame) -> Option<f32> {
    if pred.is_empty() || gt.is_empty() {
        return None;
    }
    let (jp, jg) = (joints(pred), joints(gt));
    let p_to_g = directed_mean(&jp, |p| nearest_point(*p, &jg));
    let g_to_p = directed_mean(&jg, |g| nearest_point(*g, &jp));
    Some(symmetric(frame, p_to_g, g_to_p))
}

/// Joint-to-bone chamfer distance: each skeleton's joints against the other's bone
/// segments; `None` when either skeleton has no bones.
pub fn cd_j2b(pred: &Skeleton, gt: &Skeleton, frame: &Frame) -> Option<f32> {
    if pred.is_empty() || gt.is_empty() {
        return None;
    }
    let (jp, jg) = (joints(pred), joints(gt));
    let (sp, sg) = (segments(pred), segments(gt));
    let p_to_g = directed_mean(&jp, |p| nearest_segment(*p, &sg));
    let g_to_p = directed_mean(&jg, |g| nearest_segment(*g, &sp));
    Some(symmetric(frame, p_to_g, g_to_p))
}

/// Bone-to-bone chamfer distance: points sampled along each skeleton's bones against the
/// other's bone segments; `None` when either skeleton has no bones.
pub fn cd_b2b(pred: &Skeleton, gt: &Skeleton, frame: &Frame) -> Option<f32> {
    if pred.is_empty() || gt.is_empty() {
        return None;
    }
    let (sp, sg) = (segments(pred), segments(gt));
    let p_to_g = samples_to_segments(&bone_samples(&sp), &sg);
    let g_to_p = samples_to_segments(&bone_samples(&sg), &sp);
    Some(symmetric(frame, p_to_g, g_to_p))
}

fn samples_to_segments(samples: &[(Vec3, Segment)], other: &[Segment]) -> f64 {
    directed_mean(samples, |(p, own)| {
        other
            .iter()
            // A sample lies on its own bone by construction, but lerp rounding would leave
            // a residue of ~1e-8 when measured against an identical bone; counting that
            // case as 0 keeps identical rigs at exactly 0.
            .map(|s| if s.same_as(own) { 0.0 } else { s.distance(*p) })
            .fold(f32::INFINITY, f32::min)
    })
}

/// Skeleton scores in the reported unit. NaN marks a metric that is undefined (a skeleton
/// without bones); it is written to JSON as `null` and read back as NaN.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SkeletonScores {
    #[serde(with = "nan_as_null")]
    pub cd_j2j: f32,
    #[serde(with = "nan_as_null")]
    pub cd_j2b: f32,
    #[serde(with = "nan_as_null")]
    pub cd_b2b: f32,
}

pub fn score_skeleton(pred: &Skeleton, gt: &Skeleton, frame: &Frame) -> SkeletonScores {
    SkeletonScores {
        cd_j2j: cd_j2j(pred, gt, frame).unwrap_or(f32::NAN),
        cd_j2b: cd_j2b(pred, gt, frame).unwrap_or(f32::NAN),
        cd_b2b: cd_b2b(pred, gt, frame).unwrap_or(f32::NAN),
    }
}

impl SkeletonScores {
    /// Per-metric mean over meshes, skipping undefined (non-finite) values metric by metric.
    pub fn mean<'a>(items: impl IntoIterator<Item = &'a SkeletonScores>) -> SkeletonScores {
        let (mut j2j, mut j2b, mut b2b) = (Mean::default(), Mean::default(), Mean::default());
        for s in items {
            j2j.add(s.cd_j2j);
            j2b.add(s.cd_j2b);
            b2b.add(s.cd_b2b);
        }
        SkeletonScores {
            cd_j2j: j2j.value(),
            cd_j2b: j2b.value(),
            cd_b2b: b2b.value(),
        }
    }
}

/// For each predicted bone, the ground-truth bone with exactly the same name. Should the
/// ground truth repeat a name, the first bone carrying it wins.
pub fn match_bones_by_name(pred: &Skeleton, gt: &Skeleton) -> Vec<Option<usize>> {
    let mut by_name: HashMap<&str, usize> = HashMap::with_capacity(gt.len());
    for (i, b) in gt.bones.iter().enumerate() {
        by_name.entry(b.name.as_str()).or_insert(i);
    }
    pred.bones
        .iter()
        .map(|b| by_name.get(b.name.as_str()).copied())
        .collect()
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MetricsError {
    #[error("{what} covers {got} vertices but the ground-truth weights cover {expected}")]
    VertexCount {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{what} weights name bone {bone}, but that skeleton has {bones} bones")]
    BoneIndex {
        what: &'static str,
        bone: u32,
        bones: usize,
    },
}

impl MetricsError {
    pub fn code(&self) -> &'static str {
        match self {
            MetricsError::VertexCount { .. } => "metrics_vertex_count",
            MetricsError::BoneIndex { .. } => "metrics_bone_index",
        }
    }
}

/// Skin scores of one mesh. The weight and deformation metrics are NaN (JSON `null`) when
/// no vertex could be scored, and precision is NaN when nothing was predicted active.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SkinScores {
    #[serde(with = "nan_as_null")]
    pub l1: f32,
    #[serde(with = "nan_as_null")]
    pub precision: f32,
    #[serde(with = "nan_as_null")]
    pub recall: f32,
    /// Mean vertex distance between the two skinnings, in the reported unit.
    #[serde(with = "nan_as_null")]
    pub deformation: f32,
    /// Vertices scored: those with ground-truth weights.
    pub vertices: usize,
    /// Vertices left out because the ground truth does not weight them.
    pub unweighted_gt: usize,
}

impl SkinScores {
    /// Per-metric mean over meshes (each mesh counts once, as in the papers' tables),
    /// skipping undefined values; the vertex counts are summed.
    pub fn mean<'a>(items: impl IntoIterator<Item = &'a SkinScores>) -> SkinScores {
        let mut m = [Mean::default(); 4];
        let (mut vertices, mut unweighted_gt) = (0, 0);
        for s in items {
            m[0].add(s.l1);
            m[1].add(s.precision);
            m[2].add(s.recall);
            m[3].add(s.deformation);
            vertices += s.vertices;
            unweighted_gt += s.unweighted_gt;
        }
        SkinScores {
            l1: m[0].value(),
            precision: m[1].value(),
            recall: m[2].value(),
            deformation: m[3].value(),
            vertices,
            unweighted_gt,
        }
    }
}

/// Sorts a vertex's influences by bone and merges repeats, so two lists can be compared
/// with one merge walk and are summed in the same order whichever side they came from.
fn merged(list: impl IntoIterator<Item = (u32, f32)>) -> Vec<(u32, f32)> {
    let mut v: Vec<(u32, f32)> = list.into_iter().collect();
    v.sort_by_key(|&(b, _)| b);
    v.dedup_by(|later, kept| {
        if later.0 == kept.0 {
            kept.1 += later.1;
            true
        } else {
            false
        }
    });
    v
}

fn check_bones(w: &SkinWeights, bones: usize, what: &'static str) -> Result<(), MetricsError> {
    for &(bone, _) in w.per_vertex.iter().flatten() {
        if bone as usize >= bones {
            return Err(MetricsError::BoneIndex { what, bone, bones });
        }
    }
    Ok(())
}

/// Scores predicted skin weights against the ground truth on the same vertices
/// (`positions`, in the mesh frame that `frame` describes). `seed` picks the deformation
/// poses, so equal inputs and seed give equal scores.
pub fn score_skin(
    pred_skel: &Skeleton,
    pred_w: &SkinWeights,
    gt_skel: &Skeleton,
    gt_w: &SkinWeights,
    positions: &[Vec3],
    frame: &Frame,
    seed: u64,
) -> Result<SkinScores, MetricsError> {
    let n = gt_w.per_vertex.len();
    if pred_w.per_vertex.len() != n {
        return Err(MetricsError::VertexCount {
            what: "the predicted weights",
            got: pred_w.per_vertex.len(),
            expected: n,
        });
    }
    if positions.len() != n {
        return Err(MetricsError::VertexCount {
            what: "the vertex positions",
            got: positions.len(),
            expected: n,
        });
    }
    check_bones(pred_w, pred_skel.len(), "predicted")?;
    check_bones(gt_w, gt_skel.len(), "ground-truth")?;

    // Both weight sets are rewritten into one bone space: indices below the ground-truth
    // bone count are ground-truth bones, and unmatched predicted bone i becomes
    // `n_gt + i`, so each stays a distinct bone for L1 and precision and is posed with the
    // identity (rest) transform for deformation.
    let n_gt = gt_skel.len() as u32;
    let map = match_bones_by_name(pred_skel, gt_skel);
    let pred = SkinWeights {
        per_vertex: pred_w
            .per_vertex
            .iter()
            .map(|w| {
                merged(w.iter().map(|&(b, x)| match map[b as usize] {
                    Some(g) => (g as u32, x),
                    None => (n_gt + b, x),
                }))
            })
            .collect(),
    };
    let gt = SkinWeights {
        per_vertex: gt_w
            .per_vertex
            .iter()
            .map(|w| merged(w.iter().copied()))
            .collect(),
    };

    // A ground-truth list holding only zero weights leaves the vertex just as unweighted
    // as an empty one (and LBS keeps it at rest), so it is not scored either.
    let scored: Vec<usize> = (0..n)
        .filter(|&v| gt.per_vertex[v].iter().any(|&(_, x)| x > 0.0))
        .collect();
    let mut out = SkinScores {
        l1: f32::NAN,
        precision: f32::NAN,
        recall: f32::NAN,
        deformation: f32::NAN,
        vertices: scored.len(),
        unweighted_gt: n - scored.len(),
    };
    if scored.is_empty() {
        return Ok(out);
    }

    let (mut l1_sum, mut tp, mut pred_active, mut gt_active) = (0f64, 0usize, 0usize, 0usize);
    for &v in &scored {
        let (p, g) = (&pred.per_vertex[v], &gt.per_vertex[v]);
        let (mut i, mut j, mut l1) = (0, 0, 0f32);
        while i < p.len() || j < g.len() {
            let (wp, wg) = match (p.get(i), g.get(j)) {
                (Some(a), Some(b)) if a.0 == b.0 => {
                    i += 1;
                    j += 1;
                    (a.1, b.1)
                }
                (Some(a), Some(b)) if a.0 < b.0 => {
                    i += 1;
                    (a.1, 0.0)
                }
                (Some(a), None) => {
                    i += 1;
                    (a.1, 0.0)
                }
                (_, Some(b)) => {
                    j += 1;
                    (0.0, b.1)
                }
                (None, None) => unreachable!("the loop stops when both lists are done"),
            };
            l1 += (wp - wg).abs();
            let (ap, ag) = (wp > ACTIVE_WEIGHT, wg > ACTIVE_WEIGHT);
            pred_active += ap as usize;
            gt_active += ag as usize;
            tp += (ap && ag) as usize;
        }
        l1_sum += l1 as f64;
    }
    out.l1 = (l1_sum / scored.len() as f64) as f32;
    out.precision = ratio(tp, pred_active);
    out.recall = ratio(tp, gt_active);

    let mut poses = SplitMix64::new(seed);
    let mut deform_sum = 0f64;
    for _ in 0..DEFORMATION_POSES {
        let mut mats = random_pose(gt_skel, poses.next_u64(), DEFORMATION_MAX_ANGLE_DEG);
        mats.resize(gt_skel.len() + pred_skel.len(), Mat4::IDENTITY);
        let with_pred = lbs(positions, &pred, &mats);
        let with_gt = lbs(positions, &gt, &mats);
        deform_sum += scored
            .iter()
            .map(|&v| with_pred[v].distance(with_gt[v]) as f64)
            .sum::<f64>();
    }
    out.deformation = frame.report((deform_sum / (DEFORMATION_POSES * scored.len()) as f64) as f32);
    Ok(out)
}

fn ratio(num: usize, den: usize) -> f32 {
    if den == 0 {
        f32::NAN
    } else {
        num as f32 / den as f32
    }
}

/// Linear blend skinning: each vertex moves to the weighted mean of its bones' transforms
/// applied to it. As in Blender's Armature modifier, weights are divided by their sum, a
/// vertex without (positive) weights stays at rest, and influences naming a bone outside
/// `bone_world` are ignored. `bone_world` holds skinning matrices (posed world × inverse
/// rest world), such as [`random_pose`] returns.
pub fn lbs(positions: &[Vec3], weights: &SkinWeights, bone_world: &[Mat4]) -> Vec<Vec3> {
    positions
        .iter()
        .enumerate()
        .map(|(v, &p)| {
            let Some(influences) = weights.per_vertex.get(v) else {
                return p;
            };
            let (mut acc, mut total) = (Vec3::ZERO, 0.0f32);
            for &(b, w) in influences {
                match bone_world.get(b as usize) {
                    Some(m) if w > 0.0 => {
                        acc += m.transform_point3(p) * w;
                        total += w;
                    }
                    _ => {}
                }
            }
            if total > 0.0 {
                acc / total
            } else {
                p
            }
        })
        .collect()
}

/// Skinning matrices for a pose given as one rotation per bone about its own head
/// (missing entries are no rotation). Rest bone frames here are pure translations to the
/// heads, so posed world × inverse rest world reduces to
/// `skin(parent) · T(head) · R · T(−head)`.
pub fn skinning_matrices(skel: &Skeleton, local_rotations: &[Quat]) -> Vec<Mat4> {
    let mut out: Vec<Mat4> = Vec::with_capacity(skel.len());
    for (i, bone) in skel.bones.iter().enumerate() {
        let r = local_rotations.get(i).copied().unwrap_or(Quat::IDENTITY);
        let local = Mat4::from_rotation_translation(r, bone.head - r * bone.head);
        // An unvalidated parent index that does not come first is treated as a root rather
        // than a panic: metrics should score bad rigs, not crash on them.
        let parent = bone.parent.filter(|&p| p < i).map(|p| out[p]);
        out.push(parent.map_or(local, |m| m * local));
    }
    out
}

/// A random pose: every bone turns about its head by an angle drawn uniformly from
/// [0, `max_angle_deg`] about an axis drawn uniformly from the sphere. Returns skinning
/// matrices (see [`skinning_matrices`]); the same seed always gives the same pose.
pub fn random_pose(skel: &Skeleton, seed: u64, max_angle_deg: f32) -> Vec<Mat4> {
    let mut rng = SplitMix64::new(seed);
    let max = max_angle_deg.to_radians();
    let rotations: Vec<Quat> = (0..skel.len())
        .map(|_| {
            let axis = rng.unit_vec3();
            Quat::from_axis_angle(axis, rng.next_f32() * max)
        })
        .collect();
    skinning_matrices(skel, &rotations)
}

/// Skinning matrices that turn `bone` (and so its descendants) by `rotation` about its
/// head and leave everything else at rest.
///
/// # Panics
/// If `bone` is not a bone of `skel`.
pub fn pose_one_bone(skel: &Skeleton, bone: usize, rotation: Quat) -> Vec<Mat4> {
    assert!(
        bone < skel.len(),
        "bone {bone} is out of range for {} bones",
        skel.len()
    );
    let mut rotations = vec![Quat::IDENTITY; skel.len()];
    rotations[bone] = rotation;
    skinning_matrices(skel, &rotations)
}

/// Running mean that skips undefined values, for per-category and overall averages.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Mean {
    sum: f64,
    count: usize,
}

impl Mean {
    /// Adds a value; NaN and infinities (undefined metrics) are skipped.
    pub fn add(&mut self, x: f32) {
        if x.is_finite() {
            self.sum += x as f64;
            self.count += 1;
        }
    }

    /// How many values were counted.
    pub fn count(&self) -> usize {
        self.count
    }

    /// The mean, or NaN when nothing was counted.
    pub fn value(&self) -> f32 {
        if self.count == 0 {
            f32::NAN
        } else {
            (self.sum / self.count as f64) as f32
        }
    }
}

impl Extend<f32> for Mean {
    fn extend<I: IntoIterator<Item = f32>>(&mut self, iter: I) {
        iter.into_iter().for_each(|x| self.add(x));
    }
}

impl FromIterator<f32> for Mean {
    fn from_iter<I: IntoIterator<Item = f32>>(iter: I) -> Self {
        let mut m = Mean::default();
        m.extend(iter);
        m
    }
}

/// JSON has no NaN: serde_json writes it as `null` but refuses to read `null` back into an
/// f32, so undefined metrics go out as `null` and come back as NaN.
mod nan_as_null {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(x: &f32, s: S) -> Result<S::Ok, S::Error> {
        if x.is_finite() {
            s.serialize_some(x)
        } else {
            s.serialize_none()
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f32, D::Error> {
        Ok(Option::<f32>::deserialize(d)?.unwrap_or(f32::NAN))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::skeleton::Bone;

    fn bone(name: &str, parent: Option<usize>, head: [f32; 3], tail: [f32; 3]) -> Bone {
        Bone::new(name, parent, head.into(), tail.into())
    }

    fn skel(bones: Vec<Bone>) -> Skeleton {
        Skeleton {
            bones,
            ..Skeleton::default()
        }
    }

    /// A small branching rig with awkward coordinates, so rounding has a chance to show.
    fn rig() -> Skeleton {
        skel(vec![
            bone("hips", None, [0.1, 0.3, -0.2], [0.1, 0.7, -0.17]),
            bone("spine", Some(0), [0.1, 0.7, -0.17], [0.13, 1.31, -0.1]),
            bone("head", Some(1), [0.13, 1.31, -0.1], [0.13, 1.6, -0.1]),
            bone("arm.l", Some(1), [0.13, 1.2, -0.1], [0.71, 1.1, 0.03]),
            bone("arm.r", Some(1), [0.13, 1.2, -0.1], [-0.47, 1.1, 0.03]),
            bone("tip", Some(3), [0.71, 1.1, 0.03], [0.71, 1.1, 0.03]),
        ])
    }

    /// Vertices scattered along the rig, each weighted to its nearest bone and a neighbour.
    fn mesh(s: &Skeleton) -> (Vec<Vec3>, SkinWeights) {
        let segs = segments(s);
        let mut positions = Vec::new();
        let mut per_vertex = Vec::new();
        for (i, seg) in segs.iter().enumerate() {
            for k in 0..7 {
                let t = k as f32 / 6.0;
                positions.push(seg.a.lerp(seg.b, t) + Vec3::new(0.05, -0.03, 0.04));
                let other = s.bones[i].parent.unwrap_or((i + 1) % segs.len());
                per_vertex.push(vec![
                    (i as u32, 0.3 + 0.6 * t),
                    (other as u32, 0.7 - 0.6 * t),
                ]);
            }
        }
        positions.push(Vec3::new(3.0, 3.0, 3.0));
        per_vertex.push(Vec::new());
        (positions, SkinWeights { per_vertex })
    }

    fn angle_deg(m: Mat4) -> f32 {
        let (_, r, _) = m.to_scale_rotation_translation();
        r.to_axis_angle().1.to_degrees()
    }

    #[test]
    fn frame_normalises_the_longest_side() {
        let f = Frame::from_points(&[Vec3::new(-1.0, 0.0, 2.0), Vec3::new(3.0, 1.0, 2.5)]);
        assert_eq!(f.center, Vec3::new(1.0, 0.5, 2.25));
        assert_eq!(f.half_extent, 2.0);
        assert_eq!(f.normalize(Vec3::new(3.0, 0.5, 2.25)), Vec3::X);
        assert_eq!(f.report(1.0), 0.25);
        let point = Frame::from_points(&[Vec3::ONE, Vec3::ONE, Vec3::NAN]);
        assert_eq!(point.half_extent, 1.0);
        assert_eq!(Frame::from_points(&[]), Frame::UNIT);
        let broken = Frame {
            center: Vec3::ZERO,
            half_extent: 0.0,
        };
        assert_eq!(broken.report(1.0), 0.5);
    }

    #[test]
    fn identical_rigs_score_perfectly() {
        let s = rig();
        let (positions, w) = mesh(&s);
        let frame = Frame::from_points(&positions);
        let sk = score_skeleton(&s, &s, &frame);
        assert_eq!((sk.cd_j2j, sk.cd_j2b, sk.cd_b2b), (0.0, 0.0, 0.0));
        let sc = score_skin(&s, &w, &s, &w, &positions, &frame, 7).unwrap();
        assert_eq!(sc.l1, 0.0);
        assert_eq!((sc.precision, sc.recall), (1.0, 1.0));
        assert_eq!(sc.deformation, 0.0);
        assert_eq!((sc.vertices, sc.unweighted_gt), (positions.len() - 1, 1));
    }

    #[test]
    fn reordered_bones_match_by_name() {
        let gt = rig();
        let (positions, gt_w) = mesh(&gt);
        // Same rig with bones listed in another (still parents-first) order.
        let order = [0usize, 1, 4, 3, 5, 2];
        let mut pred = Skeleton::default();
        for &i in &order {
            let mut b = gt.bones[i].clone();
            b.parent = b
                .parent
                .map(|p| order.iter().position(|&o| o == p).unwrap());
            pred.bones.push(b);
        }
        let to_pred = |g: u32| order.iter().position(|&o| o == g as usize).unwrap() as u32;
        let pred_w = SkinWeights {
            per_vertex: gt_w
                .per_vertex
                .iter()
                .map(|v| v.iter().map(|&(b, x)| (to_pred(b), x)).collect())
                .collect(),
        };
        let map = match_bones_by_name(&pred, &gt);
        assert_eq!(map, order.iter().map(|&o| Some(o)).collect::<Vec<_>>());
        let frame = Frame::from_points(&positions);
        let sc = score_skin(&pred, &pred_w, &gt, &gt_w, &positions, &frame, 3).unwrap();
        assert_eq!((sc.l1, sc.precision, sc.recall), (0.0, 1.0, 1.0));
        assert_eq!(sc.deformation, 0.0);
        let sk = score_skeleton(&pred, &gt, &frame);
        assert_eq!((sk.cd_j2j, sk.cd_j2b, sk.cd_b2b), (0.0, 0.0, 0.0));
    }

    #[test]
    fn translation_scores_half_the_normalised_offset() {
        // A vertical chain; moving it sideways by d keeps every joint's nearest neighbour
        // its own counterpart, so every directed distance is exactly d.
        let gt = skel(vec![
            bone("a", None, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            bone("b", Some(0), [0.0, 1.0, 0.0], [0.0, 2.0, 0.0]),
            bone("c", Some(1), [0.0, 2.0, 0.0], [0.0, 3.0, 0.0]),
        ]);
        let d = 0.05;
        let mut pred = gt.clone();
        pred.map_points(|p| p + Vec3::new(d, 0.0, 0.0));
        // The mesh spans 4 units on its longest side: half extent 2.
        let frame = Frame::from_points(&[Vec3::new(-0.5, -0.5, -0.5), Vec3::new(0.5, 3.5, 0.5)]);
        assert_eq!(frame.half_extent, 2.0);
        let expected = d / 2.0 / 2.0;
        let sk = score_skeleton(&pred, &gt, &frame);
        for v in [sk.cd_j2j, sk.cd_j2b, sk.cd_b2b] {
            assert!((v - expected).abs() < 1e-6, "{v} vs {expected}");
        }
        // Already normalised mesh: the reported value is d / 2.
        let unit = cd_j2j(&pred, &gt, &Frame::UNIT).unwrap();
        assert!((unit - d / 2.0).abs() < 1e-6);
    }

    #[test]
    fn chamfer_averages_the_two_directions() {
        // gt has an extra joint 1 unit away: gt→pred mean = 1/2, pred→gt mean = 0.
        let pred = skel(vec![bone("a", None, [0.0; 3], [0.0; 3])]);
        let gt = skel(vec![
            bone("a", None, [0.0; 3], [0.0; 3]),
            bone("b", Some(0), [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
        ]);
        let v = cd_j2j(&pred, &gt, &Frame::UNIT).unwrap();
        assert!((v - 0.25 / 2.0).abs() < 1e-7);
        // Zero-length bones are points, so J2B and B2B agree with J2J here.
        assert!((cd_j2b(&pred, &gt, &Frame::UNIT).unwrap() - v).abs() < 1e-7);
        assert!((cd_b2b(&pred, &gt, &Frame::UNIT).unwrap() - v).abs() < 1e-7);
    }

    #[test]
    fn joint_to_bone_measures_to_the_segment() {
        // A joint beside the middle of a long bone is far from its ends but on the segment's
        // perpendicular: 0.1 away.
        let gt = skel(vec![bone("a", None, [0.0, 0.0, 0.0], [0.0, 2.0, 0.0])]);
        let pred = skel(vec![bone("a", None, [0.1, 1.0, 0.0], [0.1, 1.0, 0.0])]);
        // pred→gt: 0.1; gt→pred: gt's head to pred's point = sqrt(0.01 + 1).
        let expected = (0.1 + (1.01f32).sqrt()) / 2.0 / 2.0;
        let v = cd_j2b(&pred, &gt, &Frame::UNIT).unwrap();
        assert!((v - expected).abs() < 1e-6, "{v} vs {expected}");
    }

    #[test]
    fn empty_skeletons_have_no_distance() {
        let empty = Skeleton::default();
        let s = rig();
        assert_eq!(cd_j2j(&empty, &s, &Frame::UNIT), None);
        assert_eq!(cd_j2b(&s, &empty, &Frame::UNIT), None);
        assert_eq!(cd_b2b(&empty, &empty, &Frame::UNIT), None);
        let sk = score_skeleton(&empty, &s, &Frame::UNIT);
        assert!(sk.cd_j2j.is_nan() && sk.cd_j2b.is_nan() && sk.cd_b2b.is_nan());
    }

    fn two_bones() -> Skeleton {
        skel(vec![
            bone("upper", None, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            bone("lower", Some(0), [0.0, 1.0, 0.0], [0.0, 2.0, 0.0]),
        ])
    }

    fn column() -> Vec<Vec3> {
        (0..10)
            .map(|i| Vec3::new(0.1, 0.1 + 0.2 * i as f32, 0.0))
            .collect()
    }

    #[test]
    fn swapped_weights_cost_two_per_vertex() {
        let s = two_bones();
        let positions = column();
        let gt_of = |v: usize| if v < 5 { 0u32 } else { 1 };
        let gt_w = SkinWeights {
            per_vertex: (0..10).map(|v| vec![(gt_of(v), 1.0)]).collect(),
        };
        let swapped = SkinWeights {
            per_vertex: (0..10).map(|v| vec![(1 - gt_of(v), 1.0)]).collect(),
        };
        let frame = Frame::from_points(&positions);
        let sc = score_skin(&s, &swapped, &s, &gt_w, &positions, &frame, 1).unwrap();
        assert!((sc.l1 - 2.0).abs() < 1e-6);
        assert_eq!((sc.precision, sc.recall), (0.0, 0.0));
        assert!(sc.deformation > 1e-3, "{}", sc.deformation);

        // Swapping only the lower half: half the vertices cost 2.
        let half = SkinWeights {
            per_vertex: (0..10)
                .map(|v| vec![(if v < 5 { gt_of(v) } else { 1 - gt_of(v) }, 1.0)])
                .collect(),
        };
        let sc = score_skin(&s, &half, &s, &gt_w, &positions, &frame, 1).unwrap();
        assert!((sc.l1 - 1.0).abs() < 1e-6);
        assert_eq!((sc.precision, sc.recall), (0.5, 0.5));
    }

    #[test]
    fn unmatched_bones_count_against_the_prediction() {
        let gt = two_bones();
        let mut pred = gt.clone();
        pred.bones
            .push(bone("extra", Some(1), [0.0, 2.0, 0.0], [0.0, 2.5, 0.0]));
        assert_eq!(
            match_bones_by_name(&pred, &gt),
            vec![Some(0), Some(1), None]
        );
        let positions = vec![Vec3::new(0.1, 1.5, 0.0)];
        let gt_w = SkinWeights {
            per_vertex: vec![vec![(1, 1.0)]],
        };
        let pred_w = SkinWeights {
            per_vertex: vec![vec![(1, 0.7), (2, 0.3)]],
        };
        let frame = Frame::UNIT;
        let sc = score_skin(&pred, &pred_w, &gt, &gt_w, &positions, &frame, 5).unwrap();
        assert!((sc.l1 - 0.6).abs() < 1e-6);
        assert_eq!((sc.precision, sc.recall), (0.5, 1.0));

        // The unmatched share stays at rest: 0.3 of the way back from where "lower" puts it.
        let mut rng = SplitMix64::new(5);
        let mut expected = 0.0;
        for _ in 0..DEFORMATION_POSES {
            let m = random_pose(&gt, rng.next_u64(), DEFORMATION_MAX_ANGLE_DEG)[1];
            let moved = m.transform_point3(positions[0]);
            expected += (0.3 * (moved - positions[0])).length() / DEFORMATION_POSES as f32;
        }
        assert!((sc.deformation - frame.report(expected)).abs() < 1e-6);

        // A prediction whose names match nothing: every predicted pair is a false positive.
        let mut renamed = gt.clone();
        renamed.bones.iter_mut().for_each(|b| b.name.push('_'));
        let w = SkinWeights {
            per_vertex: vec![vec![(1, 1.0)]],
        };
        let sc = score_skin(&renamed, &w, &gt, &gt_w, &positions, &frame, 5).unwrap();
        assert!((sc.l1 - 2.0).abs() < 1e-6);
        assert_eq!((sc.precision, sc.recall), (0.0, 0.0));
    }

    #[test]
    fn skin_inputs_must_line_up() {
        let s = two_bones();
        let w = SkinWeights {
            per_vertex: vec![vec![(0, 1.0)]; 3],
        };
        let short = SkinWeights {
            per_vertex: vec![vec![(0, 1.0)]; 2],
        };
        let pos = vec![Vec3::ZERO; 3];
        let f = Frame::UNIT;
        let e = score_skin(&s, &short, &s, &w, &pos, &f, 0).unwrap_err();
        assert_eq!(e.code(), "metrics_vertex_count");
        let e = score_skin(&s, &w, &s, &w, &pos[..2], &f, 0).unwrap_err();
        assert_eq!(e.code(), "metrics_vertex_count");
        let bad = SkinWeights {
            per_vertex: vec![vec![(9, 1.0)]; 3],
        };
        let e = score_skin(&s, &bad, &s, &w, &pos, &f, 0).unwrap_err();
        assert_eq!(
            e,
            MetricsError::BoneIndex {
                what: "predicted",
                bone: 9,
                bones: 2
            }
        );
    }

    #[test]
    fn nothing_weighted_in_the_ground_truth() {
        let s = two_bones();
        let empty = SkinWeights {
            per_vertex: vec![Vec::new(); 2],
        };
        let sc = score_skin(&s, &empty, &s, &empty, &[Vec3::ZERO; 2], &Frame::UNIT, 0).unwrap();
        assert_eq!((sc.vertices, sc.unweighted_gt), (0, 2));
        assert!(sc.l1.is_nan() && sc.precision.is_nan() && sc.deformation.is_nan());
    }

    #[test]
    fn random_poses_are_seeded_and_bounded() {
        let s = rig();
        let a = random_pose(&s, 42, 30.0);
        assert_eq!(a, random_pose(&s, 42, 30.0));
        assert_ne!(a, random_pose(&s, 43, 30.0));
        let mut largest: f32 = 0.0;
        for seed in 0..200 {
            let m = random_pose(&s, seed, 30.0);
            for (i, b) in s.bones.iter().enumerate() {
                let local = match b.parent {
                    Some(p) => m[p].inverse() * m[i],
                    None => m[i],
                };
                let angle = angle_deg(local);
                assert!(angle <= 30.0 + 1e-3, "bone {i} turned {angle}°");
                largest = largest.max(angle);
                // Each bone turns about its own head.
                assert!(local.transform_point3(b.head).distance(b.head) < 1e-5);
            }
        }
        // The range is used, not just bounded.
        assert!(largest > 25.0, "{largest}");
        assert!(random_pose(&s, 9, 0.0)
            .iter()
            .all(|m| m.abs_diff_eq(Mat4::IDENTITY, 1e-6)));
    }

    #[test]
    fn one_bone_pose_moves_its_subtree_only() {
        let s = two_bones();
        let quarter = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        let m = pose_one_bone(&s, 1, quarter);
        assert_eq!(m[0], Mat4::IDENTITY);
        let w = SkinWeights {
            per_vertex: vec![vec![(0, 1.0)], vec![(1, 1.0)], vec![(0, 0.5), (1, 0.5)]],
        };
        let rest = [
            Vec3::new(0.0, 0.5, 0.0),
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::new(0.0, 2.0, 0.0),
        ];
        let out = lbs(&rest, &w, &m);
        assert_eq!(out[0], rest[0]);
        // The tip of "lower" swings a quarter turn about (0, 1, 0) towards -x.
        assert!(
            out[1].abs_diff_eq(Vec3::new(-1.0, 1.0, 0.0), 1e-6),
            "{}",
            out[1]
        );
        assert!(
            out[2].abs_diff_eq(Vec3::new(-0.5, 1.5, 0.0), 1e-6),
            "{}",
            out[2]
        );

        // Turning the parent carries the child along.
        let m = pose_one_bone(&s, 0, quarter);
        assert!(m[1].abs_diff_eq(m[0], 1e-6));
    }

    #[test]
    fn lbs_normalises_and_keeps_unweighted_vertices() {
        let shift = Mat4::from_translation(Vec3::X);
        let w = SkinWeights {
            per_vertex: vec![
                vec![(0, 2.0), (1, 2.0)],
                vec![],
                vec![(7, 1.0)],
                vec![(0, 0.0), (1, -1.0)],
            ],
        };
        let out = lbs(&[Vec3::ZERO; 5], &w, &[shift, Mat4::IDENTITY]);
        assert_eq!(out[0], Vec3::new(0.5, 0.0, 0.0));
        // Unweighted, out-of-range bone, non-positive weights, and no entry at all.
        assert!(out[1..].iter().all(|p| *p == Vec3::ZERO));
    }

    #[test]
    fn means_skip_undefined_values_and_round_trip_as_null() {
        let a = SkeletonScores {
            cd_j2j: 1.0,
            cd_j2b: f32::NAN,
            cd_b2b: 2.0,
        };
        let b = SkeletonScores {
            cd_j2j: 3.0,
            cd_j2b: f32::NAN,
            cd_b2b: 4.0,
        };
        let m = SkeletonScores::mean([&a, &b]);
        assert_eq!((m.cd_j2j, m.cd_b2b), (2.0, 3.0));
        assert!(m.cd_j2b.is_nan());

        let json = serde_json::to_string(&a).unwrap();
        assert_eq!(json, r#"{"cd_j2j":1.0,"cd_j2b":null,"cd_b2b":2.0}"#);
        let back: SkeletonScores = serde_json::from_str(&json).unwrap();
        assert_eq!((back.cd_j2j, back.cd_b2b), (1.0, 2.0));
        assert!(back.cd_j2b.is_nan());

        let s = SkinScores {
            l1: 0.5,
            precision: f32::NAN,
            recall: 1.0,
            deformation: 0.25,
            vertices: 10,
            unweighted_gt: 1,
        };
        let t = SkinScores {
            l1: 1.5,
            precision: 0.5,
            vertices: 30,
            unweighted_gt: 0,
            ..s
        };
        let m = SkinScores::mean([&s, &t]);
        assert_eq!((m.l1, m.precision, m.recall), (1.0, 0.5, 1.0));
        assert_eq!((m.vertices, m.unweighted_gt), (40, 1));
        let back: SkinScores = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert!(back.precision.is_nan());
        assert_eq!(back.vertices, 10);

        let mean: Mean = [1.0, f32::INFINITY, f32::NAN, 2.0].into_iter().collect();
        assert_eq!((mean.count(), mean.value()), (2, 1.5));
        assert!(Mean::default().value().is_nan());
    }
}
