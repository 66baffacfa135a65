//! The running batch's cache, in whichever layout the model's decode step reads: the
//! shared-length [`KvCache`] of `decoder.onnx`, or the per-row [`RaggedKv`] of
//! `decoder_step.onnx`. The backend sees one type; the model picks the step.

use super::kv::KvCache;
use super::ragged::RaggedKv;
use super::{InferError, SkeletonModel};
use ndarray::Array2;

pub(crate) enum DecodeCache {
    Dense(KvCache),
    Ragged(RaggedKv),
}

impl DecodeCache {
    /// Ragged when the model has a decode-step graph and `ragged` asks for it.
    pub(crate) fn for_model(model: &SkeletonModel, ragged: bool) -> DecodeCache {
        let info = model.info();
        if ragged && model.has_step() {
            DecodeCache::Ragged(model.empty_ragged())
        } else {
            DecodeCache::Dense(KvCache::empty(
                2 * info.n_layers,
                info.n_heads,
                info.head_dim,
            ))
        }
    }

    pub(crate) fn append_rows(&mut self, src: &KvCache, rows: &[usize]) -> Result<(), InferError> {
        match self {
            DecodeCache::Dense(c) => c.append_rows(src, rows),
            DecodeCache::Ragged(c) => c.append_rows(src, rows),
        }
    }

    pub(crate) fn retain(&mut self, keep: &[usize]) -> Result<Vec<usize>, InferError> {
        match self {
            DecodeCache::Dense(c) => c.retain(keep),
            DecodeCache::Ragged(c) => c.retain(keep),
        }
    }

    /// Cache positions the next step reads: every row × column of a dense cache, each
    /// row's own length (and one per dead slot that runs) of a ragged one.
    pub(crate) fn read_positions(&self) -> usize {
        match self {
            DecodeCache::Dense(c) => c.batch() * c.capacity(),
            DecodeCache::Ragged(c) => c.real_positions() + (c.step_rows() - c.batch()),
        }
    }

    pub(crate) fn real_positions(&self) -> usize {
        match self {
            DecodeCache::Dense(c) => c.real_positions(),
            DecodeCache::Ragged(c) => c.real_positions(),
        }
    }

    pub(crate) fn step(
        &mut self,
        model: &mut SkeletonModel,
        tokens: &[u32],
    ) -> Result<Array2<f32>, InferError> {
        match self {
            DecodeCache::Dense(c) => model.decode_step(tokens, c),
            DecodeCache::Ragged(c) => model.decode_step_ragged(tokens, c),
        }
    }
}
