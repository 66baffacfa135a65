//! One query attending over one head's cached keys and values: the inner loop of the
//! ragged decode step (`ai.rigserve.RaggedAttention`, see [`super::attention_op`]).
//!
//! ONNX Runtime's `GroupQueryAttention` runs this per row and head as two general matrix
//! products of one row each (q·Kᵀ, then p·V), and each product first packs its right-hand
//! side into a scratch panel: at batch 16 that op took 64 % of a decode step on this
//! 2-core CPU. A single query needs neither: one pass of dot products over the keys, a
//! softmax, and one pass of multiply-adds over the values, reading each cached column
//! once where it lies.

use super::elem::CacheElem;

/// ln 2 split so that `n · LN2_HI` is exact for the n of any f32 exponent (Cody and Waite):
/// the reduced argument then carries no rounding error of its own.
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;

/// `exp(x)` for the softmax (x ≤ 0 after the max is subtracted), written so that the
/// loop over a row vectorizes: range reduction to 2ⁿ·e^r with |r| ≤ ln2/2 and a degree-6
/// Taylor polynomial, relative error below 3e-7. Inputs below -87
/// (whose true value is under 1.7e-38) return 1.7e-38 rather than a denormal.
#[inline(always)]
fn exp_neg(x: f32) -> f32 {
    let x = x.max(-87.0);
    let n = (x * std::f32::consts::LOG2_E + 0.5).floor();
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    f32::from_bits(((n as i32 + 127) << 23) as u32) * p
}

/// One head's query over its cache: `k` and `v` hold at least `len` rows of `q.len()`
/// numbers each (row-major), in `f32` or half precision ([`CacheElem`]).
pub struct Head<'a, E> {
    pub q: &'a [f32],
    pub k: &'a [E],
    pub v: &'a [E],
    pub len: usize,
    pub scale: f32,
    /// Where the next call will read keys, if known (null if not): the vectorized kernel
    /// asks for them while it reads this call's values. Never dereferenced.
    pub next_keys: *const E,
}

// Derived, these would ask `E: Copy` of the slices' elements for no reason.
impl<E> Clone for Head<'_, E> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<E> Copy for Head<'_, E> {}

/// `out = softmax(scale · q·Kᵀ) · V` over the first `len` rows of `k` and `v`, with
/// `scores` as scratch of at least `len`.
pub fn attend<E: CacheElem>(head: Head<E>, scores: &mut [f32], out: &mut [f32]) {
    let Head { q, k, v, len, .. } = head;
    let dh = q.len();
    assert!(
        len >= 1 && k.len() >= len * dh && v.len() >= len * dh && scores.len() >= len,
        "attend: a head needs at least one position"
    );
    assert_eq!(out.len(), dh);
    #[cfg(target_arch = "x86_64")]
    if dh == 32 {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the feature was detected, and the asserts above bound every access.
            unsafe { avx512::attend32(head, scores, out) };
            return;
        }
        if avx2::available() {
            // SAFETY: as above.
            unsafe { avx2::attend32(head, scores, out) };
            return;
        }
    }
    portable(head, scores, out);
}

fn portable<E: CacheElem>(head: Head<E>, scores: &mut [f32], out: &mut [f32]) {
    let Head {
        q,
        k,
        v,
        len,
        scale,
        ..
    } = head;
    let dh = q.len();
    let scores = &mut scores[..len];
    for (s, kj) in scores.iter_mut().zip(k.chunks_exact(dh)) {
        *s = q.iter().zip(kj).map(|(a, b)| a * b.to_f32()).sum::<f32>() * scale;
    }
    let inv = softmax_in_place(scores);
    out.fill(0.0);
    for (&p, vj) in scores.iter().zip(v.chunks_exact(dh)) {
        for (o, &x) in out.iter_mut().zip(vj) {
            *o += p * x.to_f32();
        }
    }
    for o in out.iter_mut() {
        *o *= inv;
    }
}

/// Exponentiates `s - max(s)` in place and returns 1 / their sum (the caller scales the
/// weighted sum once instead of every weight).
#[inline(always)]
fn softmax_in_place(scores: &mut [f32]) -> f32 {
    let m = scores.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut z = 0.0;
    for s in scores.iter_mut() {
        let e = exp_neg(*s - m);
        *s = e;
        z += e;
    }
    1.0 / z
}

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;

#[cfg(test)]
mod tests {
    use super::super::elem::F16;
    use super::*;

    /// Softmax attention in f64, the textbook way.
    fn reference(q: &[f32], k: &[f32], v: &[f32], len: usize, scale: f32) -> Vec<f64> {
        let dh = q.len();
        let s: Vec<f64> = (0..len)
            .map(|j| {
                (0..dh)
                    .map(|d| q[d] as f64 * k[j * dh + d] as f64)
                    .sum::<f64>()
                    * scale as f64
            })
            .collect();
        let m = s.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let e: Vec<f64> = s.iter().map(|x| (x - m).exp()).collect();
        let z: f64 = e.iter().sum();
        (0..dh)
            .map(|d| (0..len).map(|j| e[j] * v[j * dh + d] as f64).sum::<f64>() / z)
            .collect()
    }

    fn filled(n: usize, seed: u64) -> Vec<f32> {
        let mut x = seed;
        (0..n)
            .map(|_| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((x >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 4.0
            })
            .collect()
    }

    type Kernel<E> = fn(Head<E>, &mut [f32], &mut [f32]);

    /// The 32-wide kernels this CPU can run, called directly (`attend` picks only one).
    fn simd_kernels<E: CacheElem>() -> Vec<(&'static str, Kernel<E>)> {
        #[allow(unused_mut)]
        let mut found: Vec<(&'static str, Kernel<E>)> = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: detected just above.
                found.push(("avx512", |h, s, o| unsafe { avx512::attend32(h, s, o) }));
            }
            if avx2::available() {
                // SAFETY: detected just above.
                found.push(("avx2", |h, s, o| unsafe { avx2::attend32(h, s, o) }));
            }
        }
        found
    }

    #[test]
    fn exp_is_accurate_over_the_softmax_range() {
        for i in 0..=8700 {
            let x = -(i as f32) / 100.0;
            let (got, want) = (exp_neg(x) as f64, (x as f64).exp());
            assert!(
                (got - want).abs() <= 3e-7 * want,
                "exp({x}) = {got}, want {want}"
            );
        }
        assert!(exp_neg(-1e4) > 0.0 && exp_neg(-1e4) < 2e-38);
    }

    #[test]
    fn matches_the_textbook_formula_for_every_width_and_length() {
        formula_holds::<f32>(|x| x);
        formula_holds::<F16>(F16::from_f32);
    }

    /// Every kernel over a cache of `E` (the keys and values rounded by `round`) against
    /// the formula in f64 over the same rounded numbers.
    fn formula_holds<E: CacheElem>(round: fn(f32) -> E) {
        for dh in [32, 8, 5] {
            for len in [1, 2, 8, 16, 17, 300] {
                let q = filled(dh, 1);
                let k: Vec<E> = filled(len * dh, 2).into_iter().map(round).collect();
                let v: Vec<E> = filled(len * dh, 3).into_iter().map(round).collect();
                let wide = |x: &[E]| x.iter().map(|e| e.to_f32()).collect::<Vec<f32>>();
                let mut scores = vec![0.0; len];
                let mut out = vec![0.0; dh];
                let scale = 1.0 / (dh as f32).sqrt();
                let head = Head {
                    q: &q,
                    k: &k,
                    v: &v,
                    len,
                    scale,
                    // Any address will do for a hint; the keys' own exercise the path.
                    next_keys: k.as_ptr(),
                };
                let want = reference(&q, &wide(&k), &wide(&v), len, scale);
                let mut kernels: Vec<(&str, Kernel<E>)> =
                    vec![("attend", attend), ("portable", portable)];
                if dh == 32 {
                    kernels.extend(simd_kernels());
                }
                for (name, kernel) in kernels {
                    out.fill(f32::NAN);
                    kernel(head, &mut scores, &mut out);
                    for d in 0..dh {
                        assert!(
                            (out[d] as f64 - want[d]).abs() < 2e-5,
                            "{name} over {:?}, dh {dh} len {len}: {} vs {}",
                            E::TYPE,
                            out[d],
                            want[d]
                        );
                    }
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sixteen_sums_at_once() {
        if !std::arch::is_x86_feature_detected!("avx512f") {
            return;
        }
        let x: [f32; 256] = std::array::from_fn(|i| (i * i % 97) as f32);
        let got = avx512::sums16_of(&x);
        for l in 0..16 {
            assert_eq!(
                got[l],
                x[16 * l..16 * l + 16].iter().sum::<f32>(),
                "lane {l}: {got:?}"
            );
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn eight_sums_at_once() {
        if !(std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma"))
        {
            return;
        }
        let x: [f32; 64] = std::array::from_fn(|i| (i * i % 97) as f32);
        let got = avx2::sums8_of(&x);
        for l in 0..8 {
            assert_eq!(
                got[l],
                x[8 * l..8 * l + 8].iter().sum::<f32>(),
                "lane {l}: {got:?}"
            );
        }
    }

    #[test]
    fn one_position_returns_its_value() {
        let (q, k, v) = (filled(32, 4), filled(32, 5), filled(32, 6));
        let mut out = vec![0.0; 32];
        let head = Head {
            q: &q,
            k: &k,
            v: &v,
            len: 1,
            scale: 0.2,
            next_keys: std::ptr::null(),
        };
        attend(head, &mut [0.0], &mut out);
        for d in 0..32 {
            assert!((out[d] - v[d]).abs() < 1e-6);
        }
    }
}
