//! Export: writes a predicted (or ground-truth) rig into a GLB that DCC tools and game
//! engines load as a skinned mesh.
//!
//! Two guarantees shape the design:
//! - Nothing the user uploaded is lost: glTF inputs are edited in place (their JSON kept
//!   whole, their buffers copied byte for byte), so materials, textures, UVs, morph
//!   targets, extensions (VRM included) and unknown fields survive. Only the old skins
//!   and what depended on them are replaced.
//! - Vertex data is never rewritten: each skin's inverse bind matrices carry the frame the
//!   stored positions live in, so a re-exported file renders its rest pose exactly where
//!   the input did, and re-loading it gives back the same merged mesh, vertex for vertex.
//!
//! The bone tree (names, parents, heads, tails, spring flags) also travels inside the GLB,
//! as JSON in `scenes[scene].extras.rigserve` (see [`bonetree`] and
//! `proto/bone_tree.schema.json`), because glTF joints have no tails and no spring flag.

pub mod animation;
pub mod bonetree;
mod builder;
mod container;
mod fresh;
pub mod glb;
mod rewrite;
mod weights;

pub use animation::Animation;
pub use bonetree::{bone_tree, parse_bone_tree, BoneTreeError, BONE_TREE_FRAME, BONE_TREE_VERSION};
pub use glb::export_glb;

use crate::rig::skeleton::SkeletonError;

/// Knobs of [`export_glb`].
#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// Influences kept per vertex, 1 to 4 (one `JOINTS_0`/`WEIGHTS_0` set holds four,
    /// the most every glTF runtime must support). The largest are kept.
    pub max_influences: usize,
    /// Write the bone tree JSON into the default scene's `extras.rigserve`.
    pub embed_bone_tree: bool,
    /// A test motion to bake in as an animation clip (see [`animation`]).
    pub animation: Animation,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            max_influences: 4,
            embed_bone_tree: true,
            animation: Animation::None,
        }
    }
}

/// Why an export failed. Each variant has a stable [`code`](ExportError::code).
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("the skeleton is invalid: {0}")]
    Skeleton(#[from] SkeletonError),
    #[error("{weights} weight lists for {vertices} vertices")]
    WeightCount { weights: usize, vertices: usize },
    #[error("vertex {vertex} is weighted to bone {bone}, but the skeleton has {bones} bones")]
    BoneOutOfRange {
        vertex: usize,
        bone: u32,
        bones: usize,
    },
    #[error("vertex {0} has a NaN or infinite weight")]
    NonFiniteWeight(usize),
    #[error("max_influences must be 1 to 4, not {0}")]
    BadOptions(usize),
    #[error("the input document does not match its mesh: {0}")]
    Document(String),
    #[error("cannot export this input: {0}")]
    Unsupported(String),
    #[error("the GLB would be {0} bytes, over the format's 4 GiB limit")]
    TooLarge(u64),
}

impl ExportError {
    pub fn code(&self) -> &'static str {
        match self {
            ExportError::Skeleton(_) => "export_invalid_skeleton",
            ExportError::WeightCount { .. } => "export_weights_mismatch",
            ExportError::BoneOutOfRange { .. } => "export_bone_out_of_range",
            ExportError::NonFiniteWeight(_) => "export_non_finite_weight",
            ExportError::BadOptions(_) => "export_bad_options",
            ExportError::Document(_) => "export_bad_document",
            ExportError::Unsupported(_) => "export_unsupported",
            ExportError::TooLarge(_) => "export_too_large",
        }
    }
}
