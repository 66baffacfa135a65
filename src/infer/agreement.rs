//! The start-up check that `decoder_step.onnx` and `decoder.onnx` are the same model.
//!
//! Their inputs and outputs can match (same dimensions, same contract) while their weights
//! come from different training runs: a step file left beside a newly exported decoder, say.
//! Served together, the prefill would come from one model and every decode step from the
//! other, and skeletons would quietly be nonsense. So loading runs one prefill and one step
//! through both paths and compares the logits.

use super::model::SkeletonModel;
use super::InferError;
use crate::rig::tokenizer::{BOS, CLS_NONE};
use ndarray::Array3;

/// How far the two paths' logits may differ, as a fraction of the logits' range: an int8
/// or fp16 decoder beside the fp32 step drifts by a few percent of it (up to 0.5 on a
/// range of ~20), a different model by about the whole range.
const TOLERANCE: f32 = 0.1;

/// Surface-like points on a sphere (position and outward normal), so the check needs no
/// mesh and gives the same numbers on every start.
fn probe_points(n: usize) -> Array3<f32> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    Array3::from_shape_fn((1, n, 6), |(_, i, c)| {
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let r = (1.0 - y * y).sqrt();
        let a = golden * i as f32;
        [r * a.cos(), y, r * a.sin()][c % 3]
    })
}

impl SkeletonModel {
    /// Errors with [`InferError::Contract`] naming the step file when its logits for the
    /// first decode step disagree with `decoder.onnx`'s, and with
    /// [`InferError::ModelLoad`] naming the file that failed to run.
    pub(super) fn check_step_agrees(&mut self) -> Result<(), InferError> {
        let failed = |path: &std::path::Path| {
            let path = path.to_path_buf();
            move |e: InferError| InferError::ModelLoad {
                path,
                message: format!("a first run at start-up failed: {e}"),
            }
        };
        let files = self.files().clone();
        let (decoder, step) = (&files.decoder, &files.step);
        let prefix = self
            .encode(&probe_points(64))
            .map_err(failed(&files.encoder))?;
        let (logits, mut dense) = self
            .prefill(&prefix, &[&[BOS, CLS_NONE]])
            .map_err(failed(decoder))?;
        let token = (0..logits.ncols())
            .max_by(|&a, &b| logits[[0, a]].total_cmp(&logits[[0, b]]))
            .unwrap_or(0) as u32;
        let mut ragged = self.empty_ragged();
        ragged.append_rows(&dense, &[0]).map_err(failed(step))?;
        let want = self
            .decode_step(&[token], &mut dense)
            .map_err(failed(decoder))?;
        let got = self
            .decode_step_ragged(&[token], &mut ragged)
            .map_err(failed(step))?;
        let (lo, hi) = want
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &x| {
                (l.min(x), h.max(x))
            });
        let diff = want
            .iter()
            .zip(got.iter())
            .map(|(a, b)| (a - b).abs())
            .fold(
                0.0f32,
                |m, d| if d.is_nan() { f32::INFINITY } else { m.max(d) },
            );
        if diff > TOLERANCE * (hi - lo).max(1e-3) {
            return Err(InferError::Contract {
                path: step.clone(),
                problem: format!(
                    "its logits disagree with the decoder's (max difference {diff:.3} on a \
                     range of {:.3}): the two files are not the same model",
                    hi - lo
                ),
            });
        }
        Ok(())
    }
}
