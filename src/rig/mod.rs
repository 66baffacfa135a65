//! Skeletons, their tokenization, and how rigs are measured.
pub mod grammar;
pub mod groundtruth;
pub mod metrics;
pub mod nearest;
pub mod placement;
pub mod skeleton;
pub mod skin;
pub mod template;
pub mod tokenizer;

pub use skeleton::{Bone, Skeleton, SkinWeights, Template};
