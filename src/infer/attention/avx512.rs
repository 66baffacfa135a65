//! [`super::attend`] for 32-wide heads on AVX-512: a key or value row is two 16-lane
//! registers.

use super::super::elem::CacheElem;
use std::arch::x86_64::*;

/// Sixteen vectors to the vector of their sums (lane l = the sum of `v[l]`): pairs
/// within 128-bit lanes, then quads, then across lanes; 45 instructions where one
/// horizontal sum per vector takes 8 dependent ones.
#[target_feature(enable = "avx512f")]
unsafe fn sums16(v: &[__m512; 16]) -> __m512 {
    let mut a = [_mm512_setzero_ps(); 8];
    for (i, a) in a.iter_mut().enumerate() {
        let (x, y) = (v[2 * i], v[2 * i + 1]);
        *a = _mm512_add_ps(_mm512_unpacklo_ps(x, y), _mm512_unpackhi_ps(x, y));
    }
    let mut b = [_mm512_setzero_ps(); 4];
    for (i, b) in b.iter_mut().enumerate() {
        let (x, y) = (_mm512_castps_pd(a[2 * i]), _mm512_castps_pd(a[2 * i + 1]));
        // Moved as pairs (the casts), added as floats.
        *b = _mm512_add_ps(
            _mm512_castpd_ps(_mm512_unpacklo_pd(x, y)),
            _mm512_castpd_ps(_mm512_unpackhi_pd(x, y)),
        );
    }
    // b[i], 128-bit lane L: lane L's partial sums of v[4i..4i+4].
    let d0 = _mm512_add_ps(
        _mm512_shuffle_f32x4::<0x88>(b[0], b[1]),
        _mm512_shuffle_f32x4::<0xDD>(b[0], b[1]),
    );
    let d1 = _mm512_add_ps(
        _mm512_shuffle_f32x4::<0x88>(b[2], b[3]),
        _mm512_shuffle_f32x4::<0xDD>(b[2], b[3]),
    );
    _mm512_add_ps(
        _mm512_shuffle_f32x4::<0x88>(d0, d1),
        _mm512_shuffle_f32x4::<0xDD>(d0, d1),
    )
}

/// [`super::exp_neg`] on 16 lanes, with `vscalefps` for the 2ⁿ.
#[target_feature(enable = "avx512f")]
unsafe fn exp16(x: __m512) -> __m512 {
    let x = _mm512_max_ps(x, _mm512_set1_ps(-87.0));
    let n =
        _mm512_roundscale_ps::<0x08>(_mm512_mul_ps(x, _mm512_set1_ps(std::f32::consts::LOG2_E)));
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(super::LN2_HI), x);
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(super::LN2_LO), r);
    let mut p = _mm512_set1_ps(1.0 / 720.0);
    for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
        p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(c));
    }
    _mm512_scalef_ps(p, n)
}

/// Exponentiates `s - max(s)` in place; returns 1 / their sum.
#[target_feature(enable = "avx512f")]
unsafe fn softmax(s: &mut [f32]) -> f32 {
    let (n, p) = (s.len(), s.as_mut_ptr());
    let tail = |j: usize| -> __mmask16 { ((1u32 << (n - j).min(16)) - 1) as __mmask16 };
    let mut m = _mm512_set1_ps(f32::NEG_INFINITY);
    for j in (0..n).step_by(16) {
        m = _mm512_mask_max_ps(m, tail(j), m, _mm512_maskz_loadu_ps(tail(j), p.add(j)));
    }
    let m = _mm512_set1_ps(_mm512_reduce_max_ps(m));
    let mut z = _mm512_setzero_ps();
    for j in (0..n).step_by(16) {
        let k = tail(j);
        let e = exp16(_mm512_sub_ps(_mm512_maskz_loadu_ps(k, p.add(j)), m));
        _mm512_mask_storeu_ps(p.add(j), k, e);
        z = _mm512_mask_add_ps(z, k, z, e);
    }
    1.0 / _mm512_reduce_add_ps(z)
}

#[cfg(test)]
pub(super) fn sums16_of(x: &[f32; 256]) -> [f32; 16] {
    let mut out = [0.0; 16];
    // SAFETY: test-only, on a machine with the feature (checked by the caller).
    unsafe {
        let v: [__m512; 16] = std::array::from_fn(|i| _mm512_loadu_ps(x.as_ptr().add(16 * i)));
        _mm512_storeu_ps(out.as_mut_ptr(), sums16(&v));
    }
    out
}

/// [`super::attend`] for 32-wide heads: a key or value row is two 16-lane registers.
#[target_feature(enable = "avx512f")]
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
    let sc = _mm512_set1_ps(scale);
    let q0 = _mm512_mul_ps(_mm512_loadu_ps(q.as_ptr()), sc);
    let q1 = _mm512_mul_ps(_mm512_loadu_ps(q.as_ptr().add(16)), sc);
    let (kp, vp, sp) = (k.as_ptr(), v.as_ptr(), scores.as_mut_ptr());
    let dot = |j: usize| {
        let r = kp.add(32 * j);
        _mm512_fmadd_ps(q1, E::load16(r.add(16)), _mm512_mul_ps(q0, E::load16(r)))
    };
    let full = len / 16 * 16;
    for j in (0..full).step_by(16) {
        let mut p = [_mm512_setzero_ps(); 16];
        for (l, p) in p.iter_mut().enumerate() {
            *p = dot(j + l);
            // The values this head reads next: asked for while the keys are read, so
            // the two streams are in flight together (see `next_keys` below).
            _mm_prefetch::<_MM_HINT_T0>(vp.add(32 * (j + l)).cast());
        }
        _mm512_storeu_ps(sp.add(j), sums16(&p));
    }
    for j in full..len {
        *sp.add(j) = _mm512_reduce_add_ps(dot(j));
    }
    let inv = softmax(&mut scores[..len]);
    // Four accumulator pairs: one pair would wait on its own multiply-add every key.
    let mut o = [_mm512_setzero_ps(); 8];
    // A batch-16 step reads more cache than this CPU's caches keep from one step to the
    // next, and each head's planes are short streams (some 200 positions of 64 bytes)
    // that the hardware prefetcher picks up late. Asking for the next plane's keys while
    // this one's values are read, and for the values while the keys are read, made the
    // batch-16 step a fifth faster (README, "Another 2-core AMD EPYC Zen 5").
    let next = head.next_keys;
    let mut j = 0;
    while j < len {
        let u = (len - j).min(4);
        for t in 0..u {
            let p = _mm512_set1_ps(*sp.add(j + t));
            let r = vp.add(32 * (j + t));
            if !next.is_null() {
                _mm_prefetch::<_MM_HINT_T0>(next.wrapping_add(32 * (j + t)).cast());
            }
            o[2 * t] = _mm512_fmadd_ps(p, E::load16(r), o[2 * t]);
            o[2 * t + 1] = _mm512_fmadd_ps(p, E::load16(r.add(16)), o[2 * t + 1]);
        }
        j += u;
    }
    let inv = _mm512_set1_ps(inv);
    let lo = _mm512_add_ps(_mm512_add_ps(o[0], o[2]), _mm512_add_ps(o[4], o[6]));
    let hi = _mm512_add_ps(_mm512_add_ps(o[1], o[3]), _mm512_add_ps(o[5], o[7]));
    _mm512_storeu_ps(out.as_mut_ptr(), _mm512_mul_ps(lo, inv));
    _mm512_storeu_ps(out.as_mut_ptr().add(16), _mm512_mul_ps(hi, inv));
}
