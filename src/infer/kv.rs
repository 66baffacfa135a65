//! The decoder's KV cache for a batch, kept in place, with the per-row state that has to
//! move with it (attention mask, next position).
//!
//! Each of the `2 × n_layers` tensors lives in one buffer laid out (rows, H, cols, dh):
//! `cols` is a capacity along the sequence axis, of which the first `len` columns are
//! written. The decoder (`skeleton-v2`) is given the whole buffer as its past, the
//! unwritten columns masked 0, and returns only the new position's keys and values,
//! which [`KvCache::push`] writes into column `len`. So a decode step copies one column,
//! not the cache (`skeleton-v1` returned `concat(past, new)`, a copy of every row's whole
//! history at every step).
//!
//! The buffer is reallocated only when it is full (every [`GROW`] columns), when rows
//! join beyond the row capacity, or when leading columns that no row uses any more are
//! worth dropping. Rows that leave are filled by rows from the end ([`KvCache::retain`]
//! says where each row went), so a finished sequence costs one row's copy, not a shift of
//! every row after it. All rows share the column index `len`: a row that joins later is
//! left-padded (mask 0) to it, as the contract's protocol describes.

use super::InferError;
use ndarray::{Array2, ArrayView2, ArrayView4, ArrayViewMut2};

/// Columns added when the buffer is full; also how many dead leading columns make a
/// trim worth a copy of the cache.
pub const GROW: usize = 32;

#[derive(Clone)]
pub struct KvCache {
    heads: usize,
    head_dim: usize,
    /// Per tensor: `row_cap × heads × cols × head_dim` floats (layer 0 key, layer 0
    /// value, layer 1 key, …). Slots of rows and columns not in use hold finite values
    /// (zeros or an earlier row's), never NaN: masked attention weights are exactly 0,
    /// and 0 × a finite value is 0.
    bufs: Vec<Vec<f32>>,
    row_cap: usize,
    rows: usize,
    cols: usize,
    len: usize,
    /// `row_cap × cols`: 1 where a row has a real, written position.
    mask: Vec<i64>,
    /// Per row, the position id of the next token.
    next_pos: Vec<i64>,
    /// Per row, its real written positions (the ones of its mask row), kept as rows
    /// change so the per-step metrics need not scan the mask.
    real: Vec<usize>,
}

impl std::fmt::Debug for KvCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KvCache")
            .field("batch", &self.rows)
            .field("len", &self.len)
            .field("capacity", &self.cols)
            .field("tensors", &self.bufs.len())
            .finish()
    }
}

fn bad(m: impl std::fmt::Display) -> InferError {
    InferError::run("kv cache", m)
}

/// A vacated slot and the row that moves into it.
pub(super) type Move = (usize, usize);

/// For keeping rows `keep` (ascending, distinct, < `rows`) of a batch: each vacated slot
/// below the new row count takes a kept row from the end. Returns those moves (slot,
/// row) and, for each slot after them, the row it held before.
pub(super) fn fill_moves(
    keep: &[usize],
    rows: usize,
) -> Result<(Vec<Move>, Vec<usize>), InferError> {
    if keep.windows(2).any(|w| w[0] >= w[1]) {
        return Err(bad("rows to keep must be ascending and distinct"));
    }
    if let Some(&r) = keep.iter().find(|&&r| r >= rows) {
        return Err(bad(format!("row {r} of {rows}")));
    }
    let n = keep.len();
    let holes = (0..n).filter(|r| keep.binary_search(r).is_err());
    let movers = keep.iter().copied().filter(|&r| r >= n);
    let moves: Vec<Move> = holes.zip(movers).collect();
    let mut order: Vec<usize> = (0..n).collect();
    for &(hole, from) in &moves {
        order[hole] = from;
    }
    Ok((moves, order))
}

fn round_up(n: usize) -> usize {
    n.div_ceil(GROW).max(1) * GROW
}

impl KvCache {
    /// A cache of no rows for a model with `n_tensors` cache tensors of `heads × head_dim`.
    pub fn empty(n_tensors: usize, heads: usize, head_dim: usize) -> KvCache {
        KvCache {
            heads,
            head_dim,
            bufs: vec![Vec::new(); n_tensors],
            row_cap: 0,
            rows: 0,
            cols: 0,
            len: 0,
            mask: Vec::new(),
            next_pos: Vec::new(),
            real: Vec::new(),
        }
    }

    /// A cache holding a prefill's output: `new[i]` (B, H, S, dh) for every tensor, the
    /// prefill's mask (B, S) and each row's next position. Sized to the rows given, with
    /// no room to grow: it is a source of rows for [`KvCache::append_rows`] or is grown
    /// on its first [`KvCache::push`].
    pub(crate) fn from_new(
        new: &[ArrayView4<f32>],
        mask: Array2<i64>,
        next_pos: Vec<i64>,
    ) -> Result<KvCache, InferError> {
        let (b, s) = mask.dim();
        let first = new.first().ok_or_else(|| bad("no tensors"))?;
        let (_, heads, _, head_dim) = first.dim();
        if next_pos.len() != b {
            return Err(bad("row count mismatch"));
        }
        let mut bufs = Vec::with_capacity(new.len());
        for a in new {
            if a.dim() != (b, heads, s, head_dim) {
                return Err(bad(format!(
                    "tensor {:?} does not match mask ({b}, {s})",
                    a.shape()
                )));
            }
            bufs.push(a.iter().copied().collect());
        }
        Ok(KvCache {
            heads,
            head_dim,
            bufs,
            row_cap: b,
            rows: b,
            cols: s,
            len: s,
            real: mask
                .rows()
                .into_iter()
                .map(|r| r.iter().filter(|&&m| m != 0).count())
                .collect(),
            mask: mask.iter().copied().collect(),
            next_pos,
        })
    }

    pub fn batch(&self) -> usize {
        self.rows
    }

    /// Written positions per row, left padding included.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Columns the buffer holds: the past length the decoder is given.
    pub fn capacity(&self) -> usize {
        self.cols
    }

    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// (batch, capacity): 1 for a row's written, real positions.
    pub fn mask(&self) -> ArrayView2<'_, i64> {
        ArrayView2::from_shape((self.rows, self.cols), &self.mask[..self.rows * self.cols])
            .expect("mask is rows × cols")
    }

    /// Written, real positions over all rows (what attention needs; the rest of
    /// `batch × capacity` is padding).
    pub fn real_positions(&self) -> usize {
        self.real.iter().sum()
    }

    pub fn next_positions(&self) -> &[i64] {
        &self.next_pos
    }

    /// Tensor `i` (layer `i / 2`, key when even) as the decoder's past input,
    /// (batch, H, capacity, dh), borrowed.
    pub fn tensor(&self, i: usize) -> ArrayView4<'_, f32> {
        let n = self.rows * self.row_len();
        ArrayView4::from_shape(
            (self.rows, self.heads, self.cols, self.head_dim),
            &self.bufs[i][..n],
        )
        .expect("buffer is rows × H × cols × dh")
    }

    fn row_len(&self) -> usize {
        self.heads * self.cols * self.head_dim
    }

    /// Copies the used part into fresh buffers of `row_cap` rows and `cols` columns,
    /// dropping the first `drop` written columns and putting `pad` masked columns in
    /// front: written column `c` moves to `c - drop + pad`.
    fn relayout(&mut self, row_cap: usize, drop: usize, pad: usize, cols: usize) {
        let len = self.len - drop + pad;
        debug_assert!(len <= cols && row_cap >= self.rows);
        let (h, dh, old_cols) = (self.heads, self.head_dim, self.cols);
        let kept = (self.len - drop) * dh;
        for buf in &mut self.bufs {
            let mut out = vec![0f32; row_cap * h * cols * dh];
            for plane in 0..self.rows * h {
                let src = (plane * old_cols + drop) * dh;
                let dst = (plane * cols + pad) * dh;
                out[dst..dst + kept].copy_from_slice(&buf[src..src + kept]);
            }
            *buf = out;
        }
        let mut mask = vec![0i64; row_cap * cols];
        for r in 0..self.rows {
            let src = r * old_cols + drop;
            let dst = r * cols + pad;
            mask[dst..dst + self.len - drop]
                .copy_from_slice(&self.mask[src..src + self.len - drop]);
        }
        self.mask = mask;
        self.row_cap = row_cap;
        self.cols = cols;
        self.len = len;
    }

    /// Appends rows of `src` (in that order; one may be taken several times), left-padded
    /// to this cache's length, or this cache left-padded to theirs when they are longer.
    pub fn append_rows(&mut self, src: &KvCache, rows: &[usize]) -> Result<(), InferError> {
        if rows.is_empty() {
            return Ok(());
        }
        if let Some(&r) = rows.iter().find(|&&r| r >= src.rows) {
            return Err(bad(format!("row {r} of {}", src.rows)));
        }
        if self.bufs.len() != src.bufs.len() {
            return Err(bad("caches of different models"));
        }
        if self.rows == 0 {
            // Nothing to keep: take the source's head shape and start over.
            self.heads = src.heads;
            self.head_dim = src.head_dim;
            self.len = 0;
        } else if (self.heads, self.head_dim) != (src.heads, src.head_dim) {
            return Err(bad("head shapes differ"));
        }
        let pad = src.len.saturating_sub(self.len);
        let need_rows = self.rows + rows.len();
        if pad > 0 || need_rows > self.row_cap || self.len + pad >= self.cols {
            // Rows grow by doubling, and only when they must: a relayout for columns
            // alone keeps the row capacity (doubling it every time would explode).
            let row_cap = if need_rows > self.row_cap {
                need_rows.max(self.row_cap * 2).max(4)
            } else {
                self.row_cap
            };
            let cols = round_up(self.len + pad + 1).max(self.cols);
            self.relayout(row_cap, 0, pad, cols);
        }
        let (h, dh) = (self.heads, self.head_dim);
        let off = self.len - src.len;
        let n = src.len * dh;
        for (buf, sbuf) in self.bufs.iter_mut().zip(&src.bufs) {
            for (i, &s) in rows.iter().enumerate() {
                for hh in 0..h {
                    let from = ((s * h + hh) * src.cols) * dh;
                    let to = (((self.rows + i) * h + hh) * self.cols + off) * dh;
                    buf[to..to + n].copy_from_slice(&sbuf[from..from + n]);
                }
            }
        }
        for (i, &s) in rows.iter().enumerate() {
            let row = (self.rows + i) * self.cols;
            self.mask[row..row + off].fill(0);
            self.mask[row + off..row + self.len]
                .copy_from_slice(&src.mask[s * src.cols..s * src.cols + src.len]);
            self.mask[row + self.len..row + self.cols].fill(0);
            self.next_pos.push(src.next_pos[s]);
            self.real.push(src.real[s]);
        }
        self.rows = need_rows;
        Ok(())
    }

    /// After a decode step: writes each row's new key and value (`new[i]` of shape
    /// (batch, H, 1, dh)) into column `len`.
    pub(crate) fn push(&mut self, new: &[ArrayView4<f32>]) -> Result<(), InferError> {
        if new.len() != self.bufs.len() {
            return Err(bad("tensor count mismatch"));
        }
        let want = (self.rows, self.heads, 1, self.head_dim);
        if let Some(a) = new.iter().find(|a| a.dim() != want) {
            return Err(bad(format!("new keys {:?}, expected {want:?}", a.shape())));
        }
        if self.len == self.cols {
            let cols = self.cols + GROW;
            self.relayout(self.row_cap.max(self.rows), 0, 0, cols);
        }
        let (dh, cols, len) = (self.head_dim, self.cols, self.len);
        for (buf, a) in self.bufs.iter_mut().zip(new) {
            let a = a.as_standard_layout();
            let src = a.as_slice().expect("standard layout");
            // (rows, H, 1, dh): plane p's new key is src[p * dh..], its column in the buffer
            // is `len` of plane p.
            for (p, chunk) in src.chunks_exact(dh).enumerate() {
                let to = (p * cols + len) * dh;
                buf[to..to + dh].copy_from_slice(chunk);
            }
        }
        for r in 0..self.rows {
            self.mask[r * cols + len] = 1;
            self.next_pos[r] += 1;
            self.real[r] += 1;
        }
        self.len += 1;
        Ok(())
    }

    /// Keeps the rows `keep` (ascending, distinct) and returns, for each row now in the
    /// cache, the index it had before. Rows are not kept in order: each vacated slot below
    /// the new row count takes a kept row from the end.
    pub fn retain(&mut self, keep: &[usize]) -> Result<Vec<usize>, InferError> {
        let (moves, order) = fill_moves(keep, self.rows)?;
        let n = keep.len();
        let rl = self.row_len();
        for (hole, from) in moves {
            for buf in &mut self.bufs {
                buf.copy_within(from * rl..(from + 1) * rl, hole * rl);
            }
            let c = self.cols;
            self.mask.copy_within(from * c..(from + 1) * c, hole * c);
            self.next_pos[hole] = self.next_pos[from];
            self.real[hole] = self.real[from];
        }
        self.rows = n;
        self.next_pos.truncate(n);
        self.real.truncate(n);
        if n == 0 {
            *self = KvCache::empty(self.bufs.len(), self.heads, self.head_dim);
        } else {
            self.trim();
        }
        Ok(order)
    }

    /// Drops leading columns no row uses any more, once there are enough of them to pay
    /// for the copy, so a cache does not stay as long as the longest item that ever ran.
    fn trim(&mut self) {
        let dead = (0..self.len)
            .take_while(|&c| (0..self.rows).all(|r| self.mask[r * self.cols + c] == 0))
            .count();
        if dead >= GROW {
            let cols = round_up(self.len - dead + 1);
            self.relayout(self.row_cap, dead, 0, cols);
        }
    }

    /// The decoder's `attention_mask` for one step: the mask, then 1 for the new token.
    pub(crate) fn step_mask(&self) -> Array2<i64> {
        let mut m = Array2::<i64>::ones((self.rows, self.cols + 1));
        let mut past: ArrayViewMut2<i64> = m.slice_mut(ndarray::s![.., ..self.cols]);
        past.assign(&self.mask());
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array4;

    /// A prefill-like cache: value = row * 1000 + column, mask all ones.
    fn filled(rows: usize, len: usize) -> KvCache {
        let a = Array4::from_shape_fn((rows, 2, len, 3), |(r, _, c, _)| (r * 1000 + c) as f32);
        let mask = Array2::ones((rows, len));
        KvCache::from_new(&[a.view(), a.view()], mask, vec![len as i64; rows]).unwrap()
    }

    fn value(c: &KvCache, r: usize, col: usize) -> f32 {
        c.tensor(1)[[r, 1, col, 2]]
    }

    #[test]
    fn appended_rows_are_left_padded_and_pushes_write_one_column() {
        let mut c = KvCache::empty(2, 2, 3);
        c.append_rows(&filled(2, 5), &[1, 0]).unwrap();
        c.append_rows(&filled(1, 3), &[0, 0]).unwrap();
        assert_eq!((c.batch(), c.len()), (4, 5));
        assert!(c.capacity() > 5);
        assert_eq!(value(&c, 0, 4), 1004.0);
        assert_eq!(value(&c, 1, 0), 0.0);
        assert_eq!(value(&c, 2, 2), 0.0); // source column 0, shifted by 2
        assert_eq!(c.mask().row(2).to_vec()[..5], [0, 0, 1, 1, 1]);
        let new = Array4::from_elem((4, 2, 1, 3), 7.0f32);
        c.push(&[new.view(), new.view()]).unwrap();
        assert_eq!(value(&c, 3, 5), 7.0);
        assert_eq!(c.mask()[[3, 5]], 1);
        assert_eq!(c.next_positions(), &[6, 6, 4, 4]);
        assert_eq!(c.step_mask().dim(), (4, c.capacity() + 1));
    }

    #[test]
    fn longer_rows_pad_the_cache_and_pushes_grow_it() {
        let mut c = KvCache::empty(2, 2, 3);
        c.append_rows(&filled(1, 2), &[0]).unwrap();
        c.append_rows(&filled(1, 4), &[0]).unwrap();
        assert_eq!(c.len(), 4);
        assert_eq!(c.mask().row(0).to_vec()[..4], [0, 0, 1, 1]);
        assert_eq!(value(&c, 0, 3), 1.0);
        let new = Array4::from_elem((2, 2, 1, 3), 1.5f32);
        for _ in 0..(GROW * 2) {
            c.push(&[new.view(), new.view()]).unwrap();
        }
        assert_eq!(c.len(), 4 + 2 * GROW);
        assert!(c.capacity() >= c.len());
        assert_eq!(value(&c, 1, 2), 2.0);
        assert_eq!(value(&c, 1, c.len() - 1), 1.5);
    }

    #[test]
    fn capacity_stays_bounded_when_rows_come_and_go() {
        let mut c = KvCache::empty(2, 2, 3);
        for i in 0..200 {
            // A row joins (a relayout when it is longer), then the oldest (the row whose
            // first real column is leftmost) leaves: rows of every age stay for a while.
            c.append_rows(&filled(1, 5 + i % 7), &[0]).unwrap();
            if c.batch() > 3 {
                let m = c.mask();
                let start = |r: usize| m.row(r).iter().position(|&v| v != 0).unwrap();
                let oldest = (0..c.batch()).min_by_key(|&r| start(r)).unwrap();
                let keep: Vec<usize> = (0..c.batch()).filter(|&r| r != oldest).collect();
                c.retain(&keep).unwrap();
            }
            let step = Array4::from_elem((c.batch(), 2, 1, 3), 1.0f32);
            c.push(&[step.view(), step.view()]).unwrap();
            let ones = c.mask().iter().filter(|&&m| m != 0).count();
            assert_eq!(c.real_positions(), ones);
        }
        assert!(c.row_cap <= 8, "row capacity {}", c.row_cap);
        assert!(c.capacity() <= 3 * GROW, "column capacity {}", c.capacity());
    }

    #[test]
    fn retain_fills_holes_from_the_end_and_trims_dead_columns() {
        let mut c = KvCache::empty(2, 2, 3);
        c.append_rows(&filled(1, GROW + 4), &[0]).unwrap();
        c.append_rows(&filled(3, 3), &[0, 1, 2]).unwrap();
        // rows: 0 long, 1..=3 short (source rows 0, 1, 2)
        let order = c.retain(&[1, 3]).unwrap();
        assert_eq!(order, vec![3, 1]);
        assert_eq!(c.batch(), 2);
        // The long row left: its columns are dead in every row and were dropped.
        assert_eq!(c.len(), 3);
        assert_eq!(value(&c, 0, 0), 2000.0);
        assert_eq!(value(&c, 1, 2), 2.0);
        assert_eq!(c.mask().row(0).to_vec()[..3], [1, 1, 1]);
        assert!(c.retain(&[1, 0]).is_err());
        assert!(c.retain(&[5]).is_err());
        assert_eq!(c.retain(&[]).unwrap(), Vec::<usize>::new());
        assert!(c.is_empty());
    }
}
