//! The cache of the ragged decode step (`decoder_step.onnx`, ONNX_CONTRACT.md "Decode
//! step"): every row keeps its own length, so a step reads each row's real positions only
//! and never the padding a shared length puts in front of the rows that joined later.
//!
//! Each of the `2 × n_layers` tensors is one ONNX Runtime tensor of shape (slots, H, cols,
//! dh), bound as both the past input and the present output of the step, so the
//! attention op writes each row's new key and value into column `len[row]` in place and
//! nothing is copied per step. Row `r`'s positions are columns `0..len[r]` (right
//! padding). Slots `rows..slots` are spare: a row that left, or room for rows to come.
//! With rigserve's attention op ([`RaggedKv::spare_slots`]) the step runs the live rows
//! only and leaves the rest of the cache alone, so rows join into spare slots and leave
//! without a relayout. `GroupQueryAttention` needs the cache and the batch to have the
//! same rows: there the spare slots are dead rows that still run (one position each, their
//! logits dropped) until the slack is worth a relayout, which is cheaper than resizing the
//! tensors every time a row finishes.
//!
//! The tensors hold `f32` or half-precision numbers, as the step graph declares
//! ([`super::elem`]); a prefill's `f32` rows are rounded when they join.

use super::elem::{CacheElem, F16};
use super::kv::{fill_moves, KvCache, GROW};
use super::InferError;
use ort::memory::Allocator;
use ort::value::{DynTensor, TensorElementType};

fn bad(m: impl std::fmt::Display) -> InferError {
    InferError::run("ragged kv cache", m)
}

/// Bytes per cached number.
fn elem_size(elem: TensorElementType) -> usize {
    match elem {
        TensorElementType::Float16 => 2,
        _ => 4,
    }
}

/// The tensor's numbers as bytes.
fn bytes_mut(t: &mut DynTensor) -> &mut [u8] {
    let n = t.size().expect("a numeric tensor has a byte size");
    // SAFETY: a CPU tensor of `n` bytes, borrowed mutably for the slice's lifetime.
    unsafe { std::slice::from_raw_parts_mut(t.data_ptr_mut().cast::<u8>(), n) }
}

/// The tensor's numbers, which must be `E`s.
fn typed_mut<E: CacheElem>(t: &mut DynTensor) -> &mut [E] {
    assert_eq!(*t.data_type(), E::TYPE, "cache tensor of another type");
    let n = t.shape().num_elements();
    // SAFETY: a CPU tensor of `n` numbers of type E (checked above), borrowed mutably.
    unsafe { std::slice::from_raw_parts_mut(t.data_ptr_mut().cast::<E>(), n) }
}

/// Copies `dh` numbers from `src[from..]` to `dst[to..]` for each span, rounded to `E`.
fn place<E: CacheElem>(dst: &mut [E], src: &[f32], spans: &[(usize, usize)], dh: usize) {
    for &(to, from) in spans {
        E::write(&mut dst[to..to + dh], &src[from..from + dh]);
    }
}

fn round_up(n: usize) -> usize {
    n.div_ceil(GROW).max(1) * GROW
}

/// Columns to allocate for rows that need `need`: half as many again (at least [`GROW`])
/// for the steps to come. A relayout allocates and copies the whole cache (30 MB at 16
/// rows and 300 columns): growing by a fixed 32 columns, its page faults, zeroing and
/// copies were about 5 % of a batch-16 bench; growing by half makes them geometric.
fn with_headroom(need: usize) -> usize {
    round_up(need + (need / 2).max(GROW))
}

pub struct RaggedKv {
    heads: usize,
    head_dim: usize,
    n_tensors: usize,
    /// Float32 or Float16.
    elem: TensorElementType,
    /// Empty while there are no slots.
    tensors: Vec<DynTensor>,
    slots: usize,
    cols: usize,
    /// Per live row: written positions, and the position id of its next token.
    len: Vec<usize>,
    next_pos: Vec<i64>,
    /// The step runs the live rows only (spare slots cost nothing per step).
    spare: bool,
}

impl std::fmt::Debug for RaggedKv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RaggedKv")
            .field("rows", &self.len.len())
            .field("slots", &self.slots)
            .field("cols", &self.cols)
            .finish()
    }
}

impl RaggedKv {
    pub fn empty(n_tensors: usize, heads: usize, head_dim: usize) -> RaggedKv {
        RaggedKv {
            heads,
            head_dim,
            n_tensors,
            elem: TensorElementType::Float32,
            tensors: Vec::new(),
            slots: 0,
            cols: 0,
            len: Vec::new(),
            next_pos: Vec::new(),
            spare: false,
        }
    }

    /// For a step whose attention op takes a cache of more rows than the batch
    /// (`ai.rigserve.RaggedAttention`): rows then join into spare slots without a
    /// relayout, and only live rows run.
    pub fn spare_slots(mut self, spare: bool) -> RaggedKv {
        self.spare = spare;
        self
    }

    /// Half-precision tensors (for a step graph whose cache is `float16`) instead of `f32`.
    pub fn half(mut self, half: bool) -> RaggedKv {
        self.elem = if half {
            TensorElementType::Float16
        } else {
            TensorElementType::Float32
        };
        self
    }

    pub fn is_half(&self) -> bool {
        self.elem == TensorElementType::Float16
    }

    /// Rows a step runs: the live rows, and with `GroupQueryAttention` the dead slots
    /// after them.
    pub fn step_rows(&self) -> usize {
        if self.spare {
            self.batch()
        } else {
            self.slots
        }
    }

    /// Slots for `rows` live rows: room for half as many again when spare slots are free.
    fn slots_for(&self, rows: usize) -> usize {
        if self.spare {
            rows + (rows / 2).max(4)
        } else {
            rows
        }
    }

    /// Live rows.
    pub fn batch(&self) -> usize {
        self.len.len()
    }

    /// Allocated rows: the live rows and the spare slots after them.
    pub fn slots(&self) -> usize {
        self.slots
    }

    pub fn capacity(&self) -> usize {
        self.cols
    }

    pub fn lens(&self) -> &[usize] {
        &self.len
    }

    pub fn real_positions(&self) -> usize {
        self.len.iter().sum()
    }

    pub fn next_positions(&self) -> &[i64] {
        &self.next_pos
    }

    fn plane(&self) -> usize {
        self.cols * self.head_dim
    }

    fn row_len(&self) -> usize {
        self.heads * self.plane()
    }

    /// The tensors, to bind as the step's past inputs and present outputs.
    pub(crate) fn tensors_mut(&mut self) -> &mut [DynTensor] {
        &mut self.tensors
    }

    /// Fresh tensors of `slots × cols`, holding the live rows' written columns.
    fn relayout(&mut self, slots: usize, cols: usize) -> Result<(), InferError> {
        let (h, dh, es) = (self.heads, self.head_dim, elem_size(self.elem));
        let old_plane = self.plane() * es;
        let new_plane = cols * dh * es;
        let mut out = Vec::with_capacity(self.n_tensors);
        for i in 0..self.n_tensors {
            let mut t = DynTensor::new(
                &Allocator::default(),
                self.elem,
                [slots.max(1), h, cols, dh],
            )
            .map_err(bad)?;
            let dst = bytes_mut(&mut t);
            // Only written columns are copied: the step reads a row's columns 0..=len only
            // after writing column len, so nothing unwritten is ever read.
            let old = self.tensors.get_mut(i).map(bytes_mut);
            if let Some(src) = old {
                for (p, plane) in dst.chunks_exact_mut(new_plane).enumerate() {
                    let (r, hh) = (p / h, p % h);
                    if let Some(&n) = self.len.get(r) {
                        let (s, n) = ((r * h + hh) * old_plane, n * dh * es);
                        plane[..n].copy_from_slice(&src[s..s + n]);
                    }
                }
            }
            out.push(t);
        }
        self.tensors = out;
        self.slots = slots;
        self.cols = cols;
        Ok(())
    }

    /// Appends rows of a prefill's cache (in that order; one may be taken several times),
    /// each row's real columns (mask 1) packed to the front.
    pub fn append_rows(&mut self, src: &KvCache, rows: &[usize]) -> Result<(), InferError> {
        if rows.is_empty() {
            return Ok(());
        }
        if let Some(&r) = rows.iter().find(|&&r| r >= src.batch()) {
            return Err(bad(format!("row {r} of {}", src.batch())));
        }
        let t0 = src.tensor(0);
        let (_, h, _, dh) = t0.dim();
        if (h, dh) != (self.heads, self.head_dim) {
            return Err(bad("head shapes differ"));
        }
        let mask = src.mask();
        let real: Vec<Vec<usize>> = rows
            .iter()
            .map(|&s| (0..mask.ncols()).filter(|&c| mask[[s, c]] != 0).collect())
            .collect();
        let live = self.batch();
        let need_rows = live + rows.len();
        let longest = real
            .iter()
            .map(Vec::len)
            .chain(self.len.iter().copied())
            .max()
            .unwrap_or(0);
        if need_rows > self.slots || longest + 1 > self.cols {
            let cols = if longest + 1 > self.cols {
                with_headroom(longest + 1)
            } else {
                self.cols
            };
            let slots = if need_rows > self.slots {
                self.slots_for(need_rows)
            } else {
                self.slots
            };
            self.relayout(slots, cols)?;
        }
        let (plane, src_plane) = (self.plane(), src.capacity() * dh);
        // Where each joining row's real columns go: (destination, source) offsets, the
        // same in every tensor.
        let mut spans = Vec::new();
        for (k, (&row, cols)) in rows.iter().zip(&real).enumerate() {
            for hh in 0..h {
                let (to, from) = (((live + k) * h + hh) * plane, (row * h + hh) * src_plane);
                spans.extend(
                    cols.iter()
                        .enumerate()
                        .map(|(j, &c)| (to + j * dh, from + c * dh)),
                );
            }
        }
        let half = self.is_half();
        for (i, tensor) in self.tensors.iter_mut().enumerate() {
            let view = src.tensor(i);
            let s = view.as_slice().expect("a cache tensor is contiguous");
            if half {
                place(typed_mut::<F16>(tensor), s, &spans, dh);
            } else {
                place(typed_mut::<f32>(tensor), s, &spans, dh);
            }
        }
        for (&row, cols) in rows.iter().zip(&real) {
            self.len.push(cols.len());
            self.next_pos.push(src.next_positions()[row]);
        }
        Ok(())
    }

    /// Room for one more column in every live row (called before a step).
    pub(crate) fn reserve_step(&mut self) -> Result<(), InferError> {
        let longest = self.len.iter().copied().max().unwrap_or(0);
        if longest + 1 > self.cols {
            self.relayout(self.slots, with_headroom(longest + 1))?;
        }
        Ok(())
    }

    /// After a step wrote column `len[r]` of every live row.
    pub(crate) fn advance(&mut self) {
        for (n, p) in self.len.iter_mut().zip(&mut self.next_pos) {
            *n += 1;
            *p += 1;
        }
    }

    /// Keeps the live rows `keep` (ascending, distinct) and returns, for each row now in
    /// the cache, the index it had before; vacated slots below the new row count take rows
    /// from the end, as [`KvCache::retain`] does.
    pub fn retain(&mut self, keep: &[usize]) -> Result<Vec<usize>, InferError> {
        let (moves, order) = fill_moves(keep, self.batch())?;
        let n = keep.len();
        let rl = self.row_len() * elem_size(self.elem);
        for (hole, from) in moves {
            for t in &mut self.tensors {
                bytes_mut(t).copy_within(from * rl..(from + 1) * rl, hole * rl);
            }
            self.len[hole] = self.len[from];
            self.next_pos[hole] = self.next_pos[from];
        }
        self.len.truncate(n);
        self.next_pos.truncate(n);
        if n == 0 {
            *self = RaggedKv::empty(self.n_tensors, self.heads, self.head_dim)
                .spare_slots(self.spare)
                .half(self.is_half());
            return Ok(order);
        }
        // Dead slots that run each step, or spare slots and columns that only take memory:
        // compact once the slack is large enough to be worth one copy of the live rows.
        let dead = self.slots - n;
        let need = self.len.iter().copied().max().unwrap_or(0) + 1;
        let too_many = if self.spare {
            self.slots > 2 * n + 8
        } else {
            dead >= 2.max(self.slots / 4)
        };
        if too_many || self.cols >= 2 * need + 2 * GROW {
            self.relayout(self.slots_for(n), with_headroom(need))?;
        }
        Ok(order)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Array4};

    /// A prefill-like source: value = row * 1000 + column, mask from `masks`.
    fn source(masks: &[&[i64]]) -> KvCache {
        let (b, s) = (masks.len(), masks[0].len());
        let a = Array4::from_shape_fn((b, 2, s, 3), |(r, _, c, _)| (r * 1000 + c) as f32);
        let mask = Array2::from_shape_fn((b, s), |(r, c)| masks[r][c]);
        KvCache::from_new(&[a.view(), a.view()], mask, vec![s as i64; b]).unwrap()
    }

    fn value(c: &RaggedKv, t: usize, r: usize, col: usize) -> f32 {
        let i = ((r * 2 + 1) * c.cols + col) * 3 + 2;
        let p = c.tensors[t].data_ptr();
        assert!(i < c.tensors[t].shape().num_elements());
        // SAFETY: within the tensor (asserted), of the type `elem` says.
        unsafe {
            match c.elem {
                TensorElementType::Float16 => (*p.cast::<F16>().add(i)).to_f32(),
                _ => *p.cast::<f32>().add(i),
            }
        }
    }

    fn first(c: &RaggedKv) -> *const std::ffi::c_void {
        c.tensors[0].data_ptr().cast()
    }

    fn ort_available() -> bool {
        // Tensors are allocated by ONNX Runtime; without the library these tests cannot run.
        crate::infer::Runtime::init(None).is_ok()
    }

    #[test]
    fn rows_are_packed_to_the_front_and_keep_their_own_lengths() {
        if !ort_available() {
            eprintln!("skipped: ONNX Runtime not found");
            return;
        }
        // The test's values are integers below 2048, which half precision holds exactly.
        for half in [false, true] {
            packed_rows(RaggedKv::empty(2, 2, 3).half(half));
        }
    }

    fn packed_rows(mut c: RaggedKv) {
        c.append_rows(&source(&[&[1, 1, 0, 1], &[1, 1, 1, 1]]), &[0, 1, 0])
            .unwrap();
        assert_eq!(c.lens(), &[3, 4, 3]);
        assert_eq!(c.batch(), 3);
        assert!(c.capacity() >= 5);
        // Row 0's third real column is source column 3.
        assert_eq!(value(&c, 1, 0, 2), 3.0);
        assert_eq!(value(&c, 1, 1, 3), 1003.0);
        c.advance();
        assert_eq!(c.lens(), &[4, 5, 4]);
        assert_eq!(c.next_positions(), &[5, 5, 5]);
        // Row 1 leaves: the last row fills its slot.
        let order = c.retain(&[0, 2]).unwrap();
        assert_eq!(order, vec![0, 2]);
        assert_eq!(c.lens(), &[4, 4]);
        assert_eq!(value(&c, 0, 1, 2), 3.0);
        assert!(c.slots() >= c.batch());
        assert!(c.retain(&[1, 0]).is_err());
        assert!(c.retain(&[]).unwrap().is_empty());
        assert_eq!((c.batch(), c.slots()), (0, 0));
    }

    #[test]
    fn slack_is_compacted_and_columns_grow_before_a_step() {
        if !ort_available() {
            eprintln!("skipped: ONNX Runtime not found");
            return;
        }
        for half in [false, true] {
            slack_and_growth(RaggedKv::empty(2, 2, 3).half(half));
        }
    }

    fn slack_and_growth(mut c: RaggedKv) {
        let src = source(&[&[1; 5]]);
        c.append_rows(&src, &[0; 8]).unwrap();
        assert_eq!(c.slots(), 8);
        c.retain(&[0, 1, 2, 3, 4, 5, 6]).unwrap();
        assert_eq!(c.slots(), 8, "one dead slot is not worth a copy");
        c.retain(&[0, 1, 2, 3]).unwrap();
        assert_eq!(c.slots(), 4, "half the slots dead: compacted");
        for _ in 0..(2 * GROW) {
            c.reserve_step().unwrap();
            assert!(c.lens().iter().all(|&n| n < c.capacity()));
            c.advance();
        }
        assert_eq!(c.lens(), &[5 + 2 * GROW; 4]);
        assert_eq!(value(&c, 0, 3, 4), 4.0);
    }

    #[test]
    fn spare_slots_take_joining_rows_and_do_not_run() {
        if !ort_available() {
            eprintln!("skipped: ONNX Runtime not found");
            return;
        }
        for half in [false, true] {
            spare_slots(RaggedKv::empty(2, 2, 3).spare_slots(true).half(half));
        }
    }

    fn spare_slots(mut c: RaggedKv) {
        let src = source(&[&[1, 1, 1, 0], &[1, 1, 1, 1]]);
        c.append_rows(&src, &[0, 1]).unwrap();
        let (slots, cols) = (c.slots(), c.capacity());
        assert!(slots > 2, "room for rows to come");
        assert_eq!(c.step_rows(), 2, "only live rows run");
        c.advance();
        // A row joins into a spare slot: same tensors, no relayout.
        let before = first(&c);
        c.append_rows(&src, &[1]).unwrap();
        assert_eq!((c.slots(), c.capacity()), (slots, cols));
        assert_eq!(first(&c), before);
        assert_eq!(c.lens(), &[4, 5, 4]);
        assert_eq!(value(&c, 1, 2, 3), 1003.0);
        // Leaving moves the last row into the hole, still in place.
        c.retain(&[1, 2]).unwrap();
        assert_eq!((c.batch(), c.step_rows(), c.slots()), (2, 2, slots));
        assert_eq!(c.lens(), &[4, 5]);
        assert_eq!(
            value(&c, 1, 0, 3),
            1003.0,
            "the joined row moved into slot 0"
        );
        assert_eq!(first(&c), before);
    }
}
