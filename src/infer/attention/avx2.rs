//! [`super::attend`] for 32-wide heads on AVX2 with FMA, for CPUs without AVX-512: a key
//! or value row is four 8-lane registers. Without it such a CPU runs the portable loop,
//! whose dot products the compiler keeps scalar (it may not reorder a float sum). F16C
//! (which every AVX2 CPU has) reads a half-precision cache.

use super::super::elem::CacheElem;
use std::arch::x86_64::*;

/// Whether this CPU can run [`attend32`].
pub(super) fn available() -> bool {
    use std::arch::is_x86_feature_detected as has;
    has!("avx2") && has!("fma") && has!("f16c")
}

/// Eight vectors to the vector of their sums (lane l = the sum of `v[l]`): two rounds of
/// pairwise adds within 128-bit lanes, then one across them.
#[target_feature(enable = "avx2,fma")]
unsafe fn sums8(v: &[__m256; 8]) -> __m256 {
    let t0 = _mm256_hadd_ps(v[0], v[1]);
    let t1 = _mm256_hadd_ps(v[2], v[3]);
    let t2 = _mm256_hadd_ps(v[4], v[5]);
    let t3 = _mm256_hadd_ps(v[6], v[7]);
    // u0's low half: the low-half sums of v[0..4]; its high half: their high-half sums.
    let u0 = _mm256_hadd_ps(t0, t1);
    let u1 = _mm256_hadd_ps(t2, t3);
    _mm256_add_ps(
        _mm256_permute2f128_ps::<0x20>(u0, u1),
        _mm256_permute2f128_ps::<0x31>(u0, u1),
    )
}

#[target_feature(enable = "avx2,fma")]
unsafe fn sum(v: __m256) -> f32 {
    let h = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let h = _mm_add_ps(h, _mm_movehl_ps(h, h));
    _mm_cvtss_f32(_mm_add_ss(h, _mm_movehdup_ps(h)))
}

#[target_feature(enable = "avx2,fma")]
unsafe fn max(v: __m256) -> f32 {
    let h = _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let h = _mm_max_ps(h, _mm_movehl_ps(h, h));
    _mm_cvtss_f32(_mm_max_ss(h, _mm_movehdup_ps(h)))
}

/// [`super::exp_neg`] on 8 lanes; 2ⁿ is built in the exponent bits.
#[target_feature(enable = "avx2,fma")]
unsafe fn exp8(x: __m256) -> __m256 {
    let x = _mm256_max_ps(x, _mm256_set1_ps(-87.0));
    let n = _mm256_floor_ps(_mm256_fmadd_ps(
        x,
        _mm256_set1_ps(std::f32::consts::LOG2_E),
        _mm256_set1_ps(0.5),
    ));
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(super::LN2_HI), x);
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(super::LN2_LO), r);
    let mut p = _mm256_set1_ps(1.0 / 720.0);
    for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
        p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(c));
    }
    let two_n = _mm256_slli_epi32::<23>(_mm256_add_epi32(
        _mm256_cvtps_epi32(n),
        _mm256_set1_epi32(127),
    ));
    _mm256_mul_ps(p, _mm256_castsi256_ps(two_n))
}

/// Exponentiates `s - max(s)` in place; returns 1 / their sum. The last `len % 8`
/// scores take the scalar path, which computes the same function.
#[target_feature(enable = "avx2,fma")]
unsafe fn softmax(s: &mut [f32]) -> f32 {
    let (n, p) = (s.len(), s.as_mut_ptr());
    let full = n / 8 * 8;
    let mut m = _mm256_set1_ps(f32::NEG_INFINITY);
    for j in (0..full).step_by(8) {
        m = _mm256_max_ps(m, _mm256_loadu_ps(p.add(j)));
    }
    let m = s[full..].iter().copied().fold(max(m), f32::max);
    let mv = _mm256_set1_ps(m);
    let mut z = _mm256_setzero_ps();
    for j in (0..full).step_by(8) {
        let e = exp8(_mm256_sub_ps(_mm256_loadu_ps(p.add(j)), mv));
        _mm256_storeu_ps(p.add(j), e);
        z = _mm256_add_ps(z, e);
    }
    let mut z = sum(z);
    for x in &mut s[full..] {
        *x = super::exp_neg(*x - m);
        z += *x;
    }
    1.0 / z
}

#[cfg(test)]
pub(super) fn sums8_of(x: &[f32; 64]) -> [f32; 8] {
    let mut out = [0.0; 8];
    // SAFETY: test-only, on a machine with the features (checked by the caller).
    unsafe {
        let v: [__m256; 8] = std::array::from_fn(|i| _mm256_loadu_ps(x.as_ptr().add(8 * i)));
        _mm256_storeu_ps(out.as_mut_ptr(), sums8(&v));
    }
    out
}

/// The caller guarantees the features and that `k`, `v` hold `len` rows of 32 floats,
/// `q` and `out` 32 and `scores` at least `len`.
#[target_feature(enable = "avx2,fma,f16c")]
pub(super) unsafe fn attend32<E: CacheElem>(
    head: super::Head<E>,
    scores: &mut [f32],
    out: &mut [f32],
) {
    let super::Head {
        q,
        k,
        v,
        len,
        scale,
        ..
    } = head;
    let sc = _mm256_set1_ps(scale);
    let qv: [__m256; 4] =
        std::array::from_fn(|i| _mm256_mul_ps(_mm256_loadu_ps(q.as_ptr().add(8 * i)), sc));
    let (kp, vp, sp) = (k.as_ptr(), v.as_ptr(), scores.as_mut_ptr());
    // Two chains of two multiply-adds, so a key's four products do not wait in one line.
    let dot = |j: usize| {
        let r = kp.add(32 * j);
        let a = _mm256_fmadd_ps(qv[1], E::load8(r.add(8)), _mm256_mul_ps(qv[0], E::load8(r)));
        let b = _mm256_fmadd_ps(
            qv[3],
            E::load8(r.add(24)),
            _mm256_mul_ps(qv[2], E::load8(r.add(16))),
        );
        _mm256_add_ps(a, b)
    };
    let full = len / 8 * 8;
    for j in (0..full).step_by(8) {
        let p: [__m256; 8] = std::array::from_fn(|l| {
            // As in the AVX-512 kernel: the values this head reads next.
            _mm_prefetch::<_MM_HINT_T0>(vp.add(32 * (j + l)).cast());
            dot(j + l)
        });
        _mm256_storeu_ps(sp.add(j), sums8(&p));
    }
    for j in full..len {
        *sp.add(j) = sum(dot(j));
    }
    let inv = softmax(&mut scores[..len]);
    // Two keys' accumulators (eight registers): one key's four would wait on their own
    // multiply-adds at every step.
    let mut o = [_mm256_setzero_ps(); 8];
    let next = head.next_keys;
    let mut j = 0;
    while j < len {
        let u = (len - j).min(2);
        for t in 0..u {
            let p = _mm256_set1_ps(*sp.add(j + t));
            let r = vp.add(32 * (j + t));
            if !next.is_null() {
                _mm_prefetch::<_MM_HINT_T0>(next.wrapping_add(32 * (j + t)).cast());
            }
            for c in 0..4 {
                o[4 * t + c] = _mm256_fmadd_ps(p, E::load8(r.add(8 * c)), o[4 * t + c]);
            }
        }
        j += u;
    }
    let inv = _mm256_set1_ps(inv);
    for c in 0..4 {
        let s = _mm256_mul_ps(_mm256_add_ps(o[c], o[4 + c]), inv);
        _mm256_storeu_ps(out.as_mut_ptr().add(8 * c), s);
    }
}
