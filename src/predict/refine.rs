//! A skeleton the model did not sample (a library rig moved onto the mesh) keeps its tree,
//! and the model moves its joints: the skeleton is tokenized, the decoder reads the whole
//! sequence once (teacher forcing), and each joint coordinate moves to the mean of the
//! model's distribution for that token within a few bins of where it was. The tree and the
//! artist's bone layout come from the library; where exactly each joint sits in *this*
//! mesh comes from the model, which sees the mesh and, at every joint, the rest of the rig.
//! The model's own candidates can be moved the same way (the mean of the distribution each
//! coordinate was sampled from, instead of the sample).
//!
//! Off by default (`--refine-library`, `--refine-model`): on `hold`, with a model that never
//! saw those rigs, moving library rigs was level or worse at every window, and moving the
//! model's candidates by 4 bins, better there and on the synthetic rigs, was worse on dev at
//! all five seeds (MODEL_CARD.md, "The model moves the joints").

use crate::infer::{Backend, InferError};
use crate::rig::grammar::Grammar;
use crate::rig::tokenizer::{dequantize, tokenize_with_order, COORD_BINS};
use crate::rig::Skeleton;
use glam::Vec3;
use ndarray::Array2;
use std::sync::Arc;

/// How far the model may move a coordinate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refine {
    /// Bins either side of the coordinate's own bin the mean is taken over.
    pub window: u32,
}

/// `skel` (unit frame) with every joint the model can see moved, given the encoder's output
/// for the mesh (`prefix`, [`Backend::encode`]); `category` is the class
/// token's, as the model's own candidates were prompted. Joints outside the unit cube (the
/// tokenizer clamps them) keep their coordinates on that axis. Tails follow their bone's
/// only child, or move with their head.
pub fn refine(
    backend: &Backend,
    prefix: &Arc<Array2<f32>>,
    skel: &Skeleton,
    category: Option<&str>,
    how: Refine,
) -> Result<Skeleton, InferError> {
    let mut unit = skel.clone();
    unit.category = category.map(str::to_string);
    let Ok((tokens, order)) = tokenize_with_order(&unit) else {
        return Ok(skel.clone());
    };
    let Some(at) = joint_positions(&tokens) else {
        return Ok(skel.clone());
    };
    if at.len() != order.len() {
        return Ok(skel.clone());
    }
    let logits = backend.teacher_forced(prefix, tokens.clone())?;
    let mut out = skel.clone();
    let old: Vec<Vec3> = skel.bones.iter().map(|b| b.head).collect();
    for (k, &p) in at.iter().enumerate() {
        let bone = order[k];
        let mut head = old[bone];
        for axis in 0..3 {
            let pos = p - 2 + axis;
            let v = head[axis];
            if !(-1.0..=1.0).contains(&v) {
                continue;
            }
            let bin = tokens[pos];
            let row = logits.row(pos - 1);
            let mean = window_mean(row.as_slice().expect("contiguous row"), bin, how.window);
            head[axis] = v + (mean - dequantize(bin));
        }
        out.bones[bone].head = head;
    }
    let children = out.children();
    for i in 0..out.bones.len() {
        out.bones[i].tail = match children[i].as_slice() {
            [c] => out.bones[*c].head,
            _ => skel.bones[i].tail + (out.bones[i].head - old[i]),
        };
    }
    Ok(out)
}

/// Position of each joint's last coordinate token, in the order the joints are written.
fn joint_positions(tokens: &[u32]) -> Option<Vec<usize>> {
    let mut g = Grammar::lenient(usize::MAX);
    let mut at = Vec::new();
    for (p, &t) in tokens.iter().enumerate() {
        let before = g.bones();
        g.advance(t).ok()?;
        // A template block's hand joints settle their parents at the block's end, but
        // every joint still counts once its third coordinate is in.
        if g.bones() == before + 1 {
            at.push(p);
        } else if g.bones() != before {
            return None;
        }
    }
    Some(at)
}

/// Mean coordinate of the softmax of `logits` over the bins within `window` of `bin`.
fn window_mean(logits: &[f32], bin: u32, window: u32) -> f32 {
    let lo = bin.saturating_sub(window);
    let hi = (bin + window).min(COORD_BINS - 1);
    let top = (lo..=hi)
        .map(|b| logits[b as usize])
        .fold(f32::NEG_INFINITY, f32::max);
    let (mut w, mut s) = (0.0f64, 0.0f64);
    for b in lo..=hi {
        let e = ((logits[b as usize] - top) as f64).exp();
        w += e;
        s += e * dequantize(b) as f64;
    }
    (s / w) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::tokenizer::tokenize;
    use crate::rig::Bone;

    #[test]
    fn every_joint_has_a_position() {
        let mut s = Skeleton::default();
        s.bones.push(Bone::new("a", None, Vec3::ZERO, Vec3::Y));
        s.bones
            .push(Bone::new("b", Some(0), Vec3::Y * 0.5, Vec3::Y));
        s.bones
            .push(Bone::new("c", Some(0), Vec3::X * 0.5, Vec3::X));
        s.bones
            .push(Bone::new("d", Some(1), Vec3::new(0.2, 0.7, 0.0), Vec3::X));
        let t = tokenize(&s).unwrap();
        let at = joint_positions(&t).unwrap();
        assert_eq!(at.len(), 4);
        assert!(at.iter().all(|&p| p >= 4 && p < t.len()));
    }

    #[test]
    fn window_mean_stays_in_the_window() {
        let mut l = vec![0.0f32; 273];
        l[100] = 10.0;
        assert!((window_mean(&l, 100, 3) - dequantize(100)).abs() < 1e-3);
        // A peak outside the window does not pull.
        let m = window_mean(&l, 120, 2);
        assert!(m >= dequantize(118) && m <= dequantize(122));
        assert!((m - dequantize(120)).abs() < 1e-4);
    }
}
