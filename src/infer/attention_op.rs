//! `ai.rigserve.RaggedAttention`: the decode step's attention as an ONNX Runtime custom
//! operator, registered on the step session (ONNX_CONTRACT.md, "Decode step").
//!
//! Same inputs, outputs and semantics as the `GroupQueryAttention` node it replaces
//! (packed q|k|v of one token per row, each row attending over its own `seqlens_k`
//! written columns plus its new one, the new key and value written at column
//! `seqlens_k`), with the per-head loop of [`super::attention::attend`]. When the present
//! output is bound to the past input's buffer (the server binds them so), the new column
//! is written in place and nothing else is touched; otherwise the past is copied first.
//!
//! One difference: the cache may hold more rows (slots) than the batch. Rows past the
//! batch are left as they are, so a cache can keep spare slots for rows that join later
//! without running them every step (`GroupQueryAttention` needs the two equal).
//!
//! The cache tensors are `float` or `float16` (the graph says which; q, k, v and the
//! output stay `float`): the op is registered once per cache type, and ONNX Runtime picks
//! the kernel by the graph's types. A half-precision cache rounds each new key and value
//! when it writes them and halves what a step reads ([`super::elem`]).

use super::attention::{attend, Head};
use super::elem::{CacheElem, F16};
use ort::operator::{
    ComputeContext, Kernel, KernelContext, Operator, OperatorDomain, OperatorInput, OperatorOutput,
};
use ort::value::{DynTensorValueType, TensorElementType};
use std::marker::PhantomData;

pub const DOMAIN: &str = "ai.rigserve";
pub const OP: &str = "RaggedAttention";

/// The domain holding [`RaggedAttention`] for both cache types, for
/// `SessionBuilder::with_operators`.
pub fn operators() -> ort::Result<OperatorDomain> {
    OperatorDomain::new(DOMAIN)?
        .add(RaggedAttention::<f32>(PhantomData))?
        .add(RaggedAttention::<F16>(PhantomData))
}

/// The op for caches of `E`.
pub struct RaggedAttention<E>(PhantomData<E>);

impl<E: CacheElem> Operator for RaggedAttention<E> {
    type Kernel<'attr> = RaggedAttentionKernel<E>;

    fn name(&self) -> &str {
        OP
    }

    fn inputs(&self) -> impl IntoIterator<Item = OperatorInput> {
        use TensorElementType::{Float32, Int32};
        [
            OperatorInput::required(Float32), // qkv (B, 1, 3·H·dh)
            OperatorInput::required(E::TYPE), // past key (B, H, C, dh)
            OperatorInput::required(E::TYPE), // past value
            OperatorInput::required(Int32),   // seqlens_k (B)
            OperatorInput::optional(Int32),   // total_sequence_length (scalar), checked
        ]
    }

    fn outputs(&self) -> impl IntoIterator<Item = OperatorOutput> {
        [
            OperatorOutput::required(TensorElementType::Float32), // attention (B, 1, H·dh)
            OperatorOutput::required(E::TYPE),                    // present key (B, H, C, dh)
            OperatorOutput::required(E::TYPE),                    // present value
        ]
    }

    fn create_kernel<'attr>(&self, k: &KernelContext<'attr>) -> ort::Result<Self::Kernel<'attr>> {
        let heads = k
            .get::<i64>("num_heads")
            .filter(|&h| h > 0)
            .ok_or_else(|| ort::Error::new("RaggedAttention needs num_heads > 0"))?;
        Ok(RaggedAttentionKernel {
            heads: heads as usize,
            scale: k.get::<f32>("scale").filter(|s| *s != 0.0),
            cache: PhantomData,
        })
    }
}

pub struct RaggedAttentionKernel<E> {
    heads: usize,
    /// None: 1/√dh.
    scale: Option<f32>,
    cache: PhantomData<E>,
}

fn fail(m: impl std::fmt::Display) -> ort::Error {
    ort::Error::new(format!("RaggedAttention: {m}"))
}

/// A buffer shared by the row closures of one call; each row writes only its own slice.
struct Shared<T>(*mut T);
// SAFETY: the closures write disjoint rows (see `compute`), and the buffer outlives them.
unsafe impl<T> Send for Shared<T> {}
unsafe impl<T> Sync for Shared<T> {}
impl<T> Clone for Shared<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Shared<T> {}

impl<T> Shared<T> {
    /// A method, not the field: a closure using `.0` would capture the bare pointer,
    /// which is not `Sync`.
    fn at(self, offset: usize) -> *mut T {
        // SAFETY (of callers): offsets stay within the buffer's checked shape.
        self.0.wrapping_add(offset)
    }
}

/// A cache tensor's shape and data, checked to hold `E`.
fn cache_in<E: CacheElem>(v: ort::value::ValueRef<'_>) -> ort::Result<(Vec<i64>, *const E)> {
    if *v.data_type() != E::TYPE {
        return Err(fail(format!(
            "a cache of {:?}, want {:?}",
            v.data_type(),
            E::TYPE
        )));
    }
    let shape = v.shape().to_vec();
    let t = v.downcast::<DynTensorValueType>()?;
    Ok((shape, t.data_ptr().cast()))
}

impl<E: CacheElem> Kernel for RaggedAttentionKernel<E> {
    fn compute(&mut self, ctx: &ComputeContext) -> ort::Result<()> {
        let input = |i: usize| {
            ctx.input(i)?
                .ok_or_else(|| fail(format!("input {i} missing")))
        };
        let (qkv_in, lens_in) = (input(0)?, input(3)?);
        let (qs, qkv) = qkv_in.try_extract_tensor::<f32>()?;
        let (ps, past_k) = cache_in::<E>(input(1)?)?;
        let (vs, past_v) = cache_in::<E>(input(2)?)?;
        let (_, lens) = lens_in.try_extract_tensor::<i32>()?;
        let (h, dims) = (self.heads, ps.clone());
        let [slots, hh, cols, dh] = dims[..] else {
            return Err(fail(format!(
                "past key of shape {ps:?}, want (slots, H, C, dh)"
            )));
        };
        let (slots, cols, dh) = (slots as usize, cols as usize, dh as usize);
        if hh as usize != h || vs.to_vec() != dims || dh == 0 {
            return Err(fail(format!(
                "past key {ps:?} and value {vs:?} for {h} heads"
            )));
        }
        // The batch is the rows of qkv; the cache may hold more (spare slots), untouched.
        let b = qs.first().copied().unwrap_or(0) as usize;
        if qs.to_vec() != [b as i64, 1, (3 * h * dh) as i64] || b > slots {
            return Err(fail(format!(
                "qkv of shape {qs:?}, want (B ≤ {slots}, 1, {})",
                3 * h * dh
            )));
        }
        if lens.len() != b {
            return Err(fail(format!("{} seqlens_k for {b} rows", lens.len())));
        }
        if let Some(&bad) = lens.iter().find(|&&n| n < 0 || n as usize >= cols) {
            return Err(fail(format!(
                "seqlens_k {bad} outside a cache of {cols} columns"
            )));
        }
        if let Some(total) = ctx.input(4)? {
            let (_, t) = total.try_extract_tensor::<i32>()?;
            let need = lens.iter().copied().max().unwrap_or(0) + 1;
            if t.first().is_some_and(|&t| t < need || t as usize > cols) {
                return Err(fail(format!(
                    "total_sequence_length {t:?}, rows need {need}"
                )));
            }
        }
        let lens: Vec<usize> = lens.iter().map(|&n| n as usize).collect();
        let n = slots * h * cols * dh;
        let (pk, pv) = (past_k, past_v);
        let shape = [slots, h, cols, dh];
        let present = |i: usize| -> ort::Result<Shared<E>> {
            let v = ctx
                .output(i, shape)?
                .ok_or_else(|| fail(format!("output {i} missing")))?;
            if *v.data_type() != E::TYPE {
                return Err(fail(format!("output {i} of {:?}", v.data_type())));
            }
            // The output's own buffer (ONNX Runtime's GetTensorMutableData either way).
            let t = v.downcast::<DynTensorValueType>()?;
            Ok(Shared(t.data_ptr().cast_mut().cast()))
        };
        let (ok, ov) = (present(1)?, present(2)?);
        for (dst, src) in [(ok, pk), (ov, pv)] {
            if !std::ptr::eq(dst.0, src) {
                // SAFETY: both buffers hold `n` numbers (shapes checked above) and are
                // distinct allocations, as the pointers differ.
                unsafe { std::ptr::copy_nonoverlapping(src, dst.0, n) };
            }
        }
        let mut att = ctx
            .output(0, [b, 1, h * dh])?
            .ok_or_else(|| fail("output 0 missing"))?;
        let att = Shared(att.try_extract_tensor_mut::<f32>()?.1.as_mut_ptr());
        let qkv = Shared(qkv.as_ptr().cast_mut());
        let scale = self.scale.unwrap_or(1.0 / (dh as f32).sqrt());
        let row = |r: usize| {
            let mut scores = vec![0.0f32; lens[r] + 1];
            // SAFETY: row r reads its qkv row and writes its own planes of the present
            // buffers and its own attention row; no two calls share a row, and every
            // offset is within the shapes checked above.
            unsafe {
                let q = std::slice::from_raw_parts(qkv.at(r * 3 * h * dh), 3 * h * dh);
                let out = std::slice::from_raw_parts_mut(att.at(r * h * dh), h * dh);
                for i in 0..h {
                    let plane = (r * h + i) * cols * dh;
                    let k = std::slice::from_raw_parts_mut(ok.at(plane), cols * dh);
                    let v = std::slice::from_raw_parts_mut(ov.at(plane), cols * dh);
                    let col = lens[r] * dh;
                    let new_k = &q[(h + i) * dh..(h + i + 1) * dh];
                    let new_v = &q[(2 * h + i) * dh..(2 * h + i + 1) * dh];
                    E::write(&mut k[col..col + dh], new_k);
                    E::write(&mut v[col..col + dh], new_v);
                    let head = Head {
                        q: &q[i * dh..(i + 1) * dh],
                        k,
                        v,
                        len: lens[r] + 1,
                        scale,
                        // The next head's plane, or after the last head the next row's
                        // first: the cache's next plane either way.
                        next_keys: if r + 1 < b || i + 1 < h {
                            ok.at(plane + cols * dh).cast_const()
                        } else {
                            std::ptr::null()
                        },
                    };
                    attend(head, &mut scores, &mut out[i * dh..(i + 1) * dh]);
                }
            }
        };
        ctx.par_for(b, 0, row)
    }
}
