//! Skeleton model inference on ONNX Runtime: the `skeleton-v2` contract of
//! `training/skeleton/ONNX_CONTRACT.md`, seen from the serving side.
//!
//! - [`Runtime`] loads the ONNX Runtime library once per process;
//! - [`SkeletonModel`] opens and validates the encoder/decoder pair and runs the encoder,
//!   a prefill, and cached decode steps over a [`KvCache`];
//! - [`sampling`] picks tokens under the token grammar;
//! - [`Backend`] owns a model on its own thread and decodes many requests at once with
//!   continuous batching.
//!
//! ```no_run
//! use rigserve::infer::*;
//! use std::path::Path;
//! let rt = Runtime::init(None)?;
//! let files = ModelFiles::in_dir(Path::new("models"), Variant::Fp32);
//! let model = SkeletonModel::load(&rt, &files, &SessionConfig::default())?;
//! let backend = Backend::new(model, BackendConfig::default())?;
//! # Ok::<(), InferError>(())
//! ```

mod agreement;
mod attention;
mod attention_op;
mod backend;
mod cache;
mod elem;
mod error;
mod kv;
mod model;
mod prefill;
mod priority;
mod ragged;
mod runtime;
pub mod sampling;
mod skin_model;

pub use backend::{
    Backend, BackendConfig, FinishReason, Generation, Metrics, MetricsSnapshot, Pending,
    SkeletonRequest,
};
pub use error::InferError;
pub use kv::KvCache;
pub use model::{ModelFiles, ModelInfo, SessionConfig, SkeletonModel, Variant, CONTRACT};
pub use ragged::RaggedKv;
pub use runtime::{resolve_library, Runtime, ORT_LIB_DEFAULT, ORT_LIB_ENV, ORT_LIB_NAME};
pub use sampling::{Sampler, SamplingParams};
pub use skin_model::{SkinModel, ROWS_PER_CALL, SKIN_CONTRACT};
