//! The decoder's KV cache for a batch, with the per-row state that has to move with it
//! (attention mask, next position).
//!
//! Between membership changes the cache is the decoder's own `present` tensors, fed back
//! unchanged: no copy per step. Only when rows leave or join is it copied, through
//! `ndarray`: [`KvCache::select`] gathers rows, [`KvCache::concat`] stacks two batches
//! left-padded to a common length (padding has mask 0, so no row sees it).

use super::InferError;
use ndarray::{s, Array2, Array4, ArrayView2, ArrayView4, Axis, Ix4};
use ort::value::{DynValue, Tensor};

pub struct KvCache {
    /// `2 × n_layers` tensors (B, H, T, dh): layer 0 key, layer 0 value, layer 1 key, …
    tensors: Vec<DynValue>,
    /// (B, T): 1 where a row has a real position, 0 for padding.
    mask: Array2<i64>,
    /// Per row, the position id of the next token.
    next_pos: Vec<i64>,
}

impl std::fmt::Debug for KvCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KvCache")
            .field("batch", &self.batch())
            .field("len", &self.len())
            .field("tensors", &self.tensors.len())
            .finish()
    }
}

fn view4(v: &DynValue) -> Result<ArrayView4<'_, f32>, InferError> {
    v.try_extract_array::<f32>()
        .map_err(|e| InferError::run("kv cache", e))?
        .into_dimensionality::<Ix4>()
        .map_err(|e| InferError::run("kv cache", e))
}

fn to_value(a: Array4<f32>) -> Result<DynValue, InferError> {
    Tensor::from_array(a)
        .map(|t| t.into_dyn())
        .map_err(|e| InferError::run("kv cache", e))
}

impl KvCache {
    pub(crate) fn new(
        tensors: Vec<DynValue>,
        mask: Array2<i64>,
        next_pos: Vec<i64>,
    ) -> Result<Self, InferError> {
        let c = KvCache {
            tensors,
            mask,
            next_pos,
        };
        c.check()?;
        Ok(c)
    }

    fn check(&self) -> Result<(), InferError> {
        let (b, t) = self.mask.dim();
        if self.next_pos.len() != b {
            return Err(InferError::run("kv cache", "row count mismatch"));
        }
        for v in &self.tensors {
            let a = view4(v)?;
            if a.dim().0 != b || a.dim().2 != t {
                return Err(InferError::run(
                    "kv cache",
                    format!("tensor {:?} does not match mask ({b}, {t})", a.shape()),
                ));
            }
        }
        Ok(())
    }

    pub fn batch(&self) -> usize {
        self.mask.dim().0
    }

    /// Cached positions per row, padding included.
    pub fn len(&self) -> usize {
        self.mask.dim().1
    }

    pub fn is_empty(&self) -> bool {
        self.batch() == 0
    }

    pub fn mask(&self) -> ArrayView2<'_, i64> {
        self.mask.view()
    }

    pub fn next_positions(&self) -> &[i64] {
        &self.next_pos
    }

    pub(crate) fn tensors(&self) -> &[DynValue] {
        &self.tensors
    }

    /// Tensor `i` (layer `i / 2`, key when even) as an array, for inspection and tests.
    pub fn tensor(&self, i: usize) -> Result<ArrayView4<'_, f32>, InferError> {
        view4(&self.tensors[i])
    }

    /// After a decode step: the decoder's `present` and the mask it was given.
    pub(crate) fn advance(
        &mut self,
        present: Vec<DynValue>,
        mask: Array2<i64>,
    ) -> Result<(), InferError> {
        let next = KvCache {
            tensors: present,
            mask,
            next_pos: self.next_pos.iter().map(|p| p + 1).collect(),
        };
        next.check()?;
        *self = next;
        Ok(())
    }

    /// The given rows, in that order. Leading columns that are padding in every kept row
    /// are dropped, so a cache does not stay as long as the longest item that ever ran.
    pub fn select(&self, rows: &[usize]) -> Result<KvCache, InferError> {
        if let Some(&r) = rows.iter().find(|&&r| r >= self.batch()) {
            return Err(InferError::run(
                "kv cache",
                format!("row {r} of {}", self.batch()),
            ));
        }
        let mask = self.mask.select(Axis(0), rows);
        let trim = (0..mask.dim().1)
            .take_while(|&c| mask.column(c).iter().all(|&m| m == 0))
            .count();
        let mask = mask.slice(s![.., trim..]).to_owned();
        let tensors = self
            .tensors
            .iter()
            .map(|v| {
                let a = view4(v)?;
                let picked = a.select(Axis(0), rows);
                to_value(
                    picked
                        .slice(s![.., .., trim.., ..])
                        .as_standard_layout()
                        .into_owned(),
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(KvCache {
            tensors,
            mask,
            next_pos: rows.iter().map(|&r| self.next_pos[r]).collect(),
        })
    }

    /// `a`'s rows then `b`'s, the shorter left-padded (mask 0) to the longer's length.
    pub fn concat(a: KvCache, b: KvCache) -> Result<KvCache, InferError> {
        if a.is_empty() {
            return Ok(b);
        }
        if b.is_empty() {
            return Ok(a);
        }
        if a.tensors.len() != b.tensors.len() {
            return Err(InferError::run("kv cache", "caches of different models"));
        }
        let (ba, ta) = a.mask.dim();
        let (bb, tb) = b.mask.dim();
        let t = ta.max(tb);
        let mut mask = Array2::<i64>::zeros((ba + bb, t));
        mask.slice_mut(s![..ba, t - ta..]).assign(&a.mask);
        mask.slice_mut(s![ba.., t - tb..]).assign(&b.mask);
        let tensors = a
            .tensors
            .iter()
            .zip(&b.tensors)
            .map(|(x, y)| {
                let (x, y) = (view4(x)?, view4(y)?);
                let (_, h, _, dh) = x.dim();
                if (y.dim().1, y.dim().3) != (h, dh) {
                    return Err(InferError::run("kv cache", "head shapes differ"));
                }
                let mut out = Array4::<f32>::zeros((ba + bb, h, t, dh));
                out.slice_mut(s![..ba, .., t - ta.., ..]).assign(&x);
                out.slice_mut(s![ba.., .., t - tb.., ..]).assign(&y);
                to_value(out)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut next_pos = a.next_pos;
        next_pos.extend(b.next_pos);
        Ok(KvCache {
            tensors,
            mask,
            next_pos,
        })
    }
}
