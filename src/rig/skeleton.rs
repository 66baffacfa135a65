//! The skeleton as rigserve sees it: a forest of bones stored parents-first.
//!
//! Every bone is a joint (`head`) plus a direction (`tail`), in the frame of the mesh it
//! belongs to (glTF's Y-up). Keeping parents before children lets every pass over the
//! tree be a single forward loop, and makes "is this a tree?" a local check.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// A rig template: bone order and parents come from the template, not from the tokens.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Template {
    /// The 22-bone Mixamo-compatible humanoid body.
    MixamoBody,
    /// A Mixamo-compatible hand (15 finger bones), one per side.
    MixamoHand,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bone {
    pub name: String,
    /// Index of the parent bone; always smaller than this bone's own index.
    pub parent: Option<usize>,
    pub head: Vec3,
    pub tail: Vec3,
    /// Part of a spring chain (hair, cloth, tails driven by physics).
    #[serde(default)]
    pub spring: bool,
}

impl Bone {
    /// A non-spring bone.
    pub fn new(name: impl Into<String>, parent: Option<usize>, head: Vec3, tail: Vec3) -> Self {
        Bone {
            name: name.into(),
            parent,
            head,
            tail,
            spring: false,
        }
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    pub bones: Vec<Bone>,
    /// Set when the whole body follows a template (its first bones are the template's).
    #[serde(default)]
    pub template: Option<Template>,
    /// Category hint such as `humanoid` or `quadruped`.
    #[serde(default)]
    pub category: Option<String>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SkeletonError {
    #[error("the skeleton has no bones")]
    Empty,
    #[error("bone {0} has a parent index {1} that does not come before it")]
    BadParent(usize, usize),
    #[error("bone {0} has a non-finite coordinate")]
    NonFinite(usize),
    #[error("the skeleton has {0} bones, more than the cap of {1}")]
    TooManyBones(usize, usize),
    #[error("bone name {0:?} is used twice")]
    DuplicateName(String),
}

impl SkeletonError {
    pub fn code(&self) -> &'static str {
        match self {
            SkeletonError::Empty => "skeleton_empty",
            SkeletonError::BadParent(..) => "skeleton_not_a_tree",
            SkeletonError::NonFinite(..) => "skeleton_non_finite",
            SkeletonError::TooManyBones(..) => "skeleton_too_many_bones",
            SkeletonError::DuplicateName(..) => "skeleton_duplicate_name",
        }
    }
}

impl Skeleton {
    pub fn len(&self) -> usize {
        self.bones.len()
    }

    pub fn is_empty(&self) -> bool {
        self.bones.is_empty()
    }

    /// Checks the invariants every consumer relies on: parents first (hence acyclic),
    /// finite coordinates, unique names, at most `max_bones` bones.
    pub fn validate(&self, max_bones: usize) -> Result<(), SkeletonError> {
        if self.bones.is_empty() {
            return Err(SkeletonError::Empty);
        }
        if self.bones.len() > max_bones {
            return Err(SkeletonError::TooManyBones(self.bones.len(), max_bones));
        }
        let mut names = std::collections::HashSet::new();
        for (i, b) in self.bones.iter().enumerate() {
            if let Some(p) = b.parent {
                if p >= i {
                    return Err(SkeletonError::BadParent(i, p));
                }
            }
            if !b.head.is_finite() || !b.tail.is_finite() {
                return Err(SkeletonError::NonFinite(i));
            }
            if !names.insert(b.name.as_str()) {
                return Err(SkeletonError::DuplicateName(b.name.clone()));
            }
        }
        Ok(())
    }

    pub fn children(&self) -> Vec<Vec<usize>> {
        let mut out = vec![Vec::new(); self.bones.len()];
        for (i, b) in self.bones.iter().enumerate() {
            if let Some(p) = b.parent {
                out[p].push(i);
            }
        }
        out
    }

    pub fn roots(&self) -> impl Iterator<Item = usize> + '_ {
        self.bones
            .iter()
            .enumerate()
            .filter(|(_, b)| b.parent.is_none())
            .map(|(i, _)| i)
    }

    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.bones.iter().position(|b| b.name == name)
    }

    /// Fills tails the way UniRig does: a joint with exactly one child points at it;
    /// leaves and branching joints extend by half their parent-to-joint offset.
    pub fn infer_tails(&mut self) {
        let children = self.children();
        for (i, kids) in children.iter().enumerate() {
            let head = self.bones[i].head;
            let tail = if kids.len() == 1 {
                self.bones[kids[0]].head
            } else if let Some(p) = self.bones[i].parent {
                head + (head - self.bones[p].head) * 0.5
            } else {
                head
            };
            // A zero-length bone has no direction; give it a small upward one so
            // exporters and viewers can still draw and orient it.
            self.bones[i].tail = if (tail - head).length() < 1e-6 {
                head + Vec3::Y * 0.05 * self.scale().max(1e-3)
            } else {
                tail
            };
        }
    }

    /// Length of the joints' bounding box diagonal (a size to scale defaults by).
    pub fn scale(&self) -> f32 {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for b in &self.bones {
            lo = lo.min(b.head);
            hi = hi.max(b.head);
        }
        if self.bones.is_empty() {
            0.0
        } else {
            (hi - lo).length()
        }
    }

    /// Applies an affine map to every joint (normalisation and its inverse).
    pub fn map_points(&mut self, f: impl Fn(Vec3) -> Vec3) {
        for b in &mut self.bones {
            b.head = f(b.head);
            b.tail = f(b.tail);
        }
    }
}

/// Per-vertex skin weights: for each vertex, (bone index, weight) pairs.
/// An empty list means the vertex is unweighted.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinWeights {
    pub per_vertex: Vec<Vec<(u32, f32)>>,
}

impl SkinWeights {
    /// Makes each vertex's weights sum to 1, dropping non-positive entries; vertices
    /// whose weights sum to zero become unweighted. Returns how many are unweighted.
    pub fn normalize(&mut self) -> usize {
        let mut unweighted = 0;
        for w in &mut self.per_vertex {
            w.retain(|&(_, x)| x > 0.0 && x.is_finite());
            let s: f32 = w.iter().map(|&(_, x)| x).sum();
            if s > 0.0 {
                w.iter_mut().for_each(|(_, x)| *x /= s);
            } else {
                w.clear();
                unweighted += 1;
            }
        }
        unweighted
    }

    /// Keeps the `k` largest influences per vertex and renormalises.
    pub fn top_k(&mut self, k: usize) {
        for w in &mut self.per_vertex {
            w.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            w.truncate(k);
        }
        self.normalize();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bone(name: &str, parent: Option<usize>, head: [f32; 3]) -> Bone {
        Bone::new(name, parent, head.into(), head.into())
    }

    #[test]
    fn validate_rejects_cycles_nan_and_empty() {
        let mut s = Skeleton::default();
        assert_eq!(s.validate(10), Err(SkeletonError::Empty));
        s.bones.push(bone("a", None, [0.0; 3]));
        s.bones.push(bone("b", Some(1), [0.0; 3]));
        assert_eq!(s.validate(10).unwrap_err().code(), "skeleton_not_a_tree");
        s.bones[1].parent = Some(0);
        s.bones[1].head.x = f32::NAN;
        assert_eq!(s.validate(10).unwrap_err().code(), "skeleton_non_finite");
        s.bones[1].head.x = 0.0;
        assert!(s.validate(10).is_ok());
        assert_eq!(s.validate(1).unwrap_err().code(), "skeleton_too_many_bones");
    }

    #[test]
    fn tails_follow_single_children() {
        let mut s = Skeleton::default();
        s.bones.push(bone("a", None, [0.0, 0.0, 0.0]));
        s.bones.push(bone("b", Some(0), [0.0, 1.0, 0.0]));
        s.infer_tails();
        assert_eq!(s.bones[0].tail, Vec3::new(0.0, 1.0, 0.0));
        assert_eq!(s.bones[1].tail, Vec3::new(0.0, 1.5, 0.0));
    }

    #[test]
    fn weights_normalize_and_truncate() {
        let mut w = SkinWeights {
            per_vertex: vec![vec![(0, 2.0), (1, 1.0), (2, 1.0)], vec![(0, 0.0)]],
        };
        w.top_k(2);
        assert_eq!(w.per_vertex[0].len(), 2);
        assert!((w.per_vertex[0][0].1 - 2.0 / 3.0).abs() < 1e-6);
        assert!(w.per_vertex[1].is_empty());
    }
}
