//! What a decode-step cache keeps per number: `f32`, or IEEE half precision ([`F16`]).
//!
//! A decode step reads every live row's whole cache (a batch-16 step over 200 positions
//! reads 20 MB in `f32`), and on a CPU whose last-level cache is about that size the
//! attention op is bound by those reads: half precision halves them (and the cache's
//! memory). Keys and values are rounded once, when they are written; the op computes in
//! `f32` (ONNX_CONTRACT.md, "Decode step").

use ort::value::TensorElementType;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// An IEEE 754 half-precision number, as its bits (ONNX's `float16`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(transparent)]
pub struct F16(pub u16);

impl F16 {
    /// Rounded to nearest, ties to even; out of range gives ±infinity.
    pub fn from_f32(x: f32) -> F16 {
        F16(half::f16::from_f32(x).to_bits())
    }

    pub fn to_f32(self) -> f32 {
        half::f16::from_bits(self.0).to_f32()
    }
}

/// A number type a cache tensor may hold.
pub trait CacheElem: Copy + Default + Send + Sync + 'static {
    const TYPE: TensorElementType;

    fn to_f32(self) -> f32;

    /// `dst[i] = src[i]` rounded to this type (equal lengths).
    fn write(dst: &mut [Self], src: &[f32]);

    /// Sixteen numbers from `p` as `f32` lanes.
    ///
    /// # Safety
    /// AVX-512F is available and `p` points at sixteen readable numbers.
    #[cfg(target_arch = "x86_64")]
    unsafe fn load16(p: *const Self) -> __m512;

    /// Eight numbers from `p` as `f32` lanes.
    ///
    /// # Safety
    /// AVX and F16C are available and `p` points at eight readable numbers.
    #[cfg(target_arch = "x86_64")]
    unsafe fn load8(p: *const Self) -> __m256;
}

impl CacheElem for f32 {
    const TYPE: TensorElementType = TensorElementType::Float32;

    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }

    fn write(dst: &mut [f32], src: &[f32]) {
        dst.copy_from_slice(src);
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn load16(p: *const f32) -> __m512 {
        _mm512_loadu_ps(p)
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn load8(p: *const f32) -> __m256 {
        _mm256_loadu_ps(p)
    }
}

impl CacheElem for F16 {
    const TYPE: TensorElementType = TensorElementType::Float16;

    #[inline(always)]
    fn to_f32(self) -> f32 {
        F16::to_f32(self)
    }

    fn write(dst: &mut [F16], src: &[f32]) {
        assert_eq!(dst.len(), src.len());
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("f16c") {
            // SAFETY: F16C was detected; the lengths are equal.
            done = unsafe { round8(dst, src) };
        }
        for (d, &s) in dst[done..].iter_mut().zip(&src[done..]) {
            *d = F16::from_f32(s);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn load16(p: *const F16) -> __m512 {
        _mm512_cvtph_ps(_mm256_loadu_si256(p.cast()))
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn load8(p: *const F16) -> __m256 {
        _mm256_cvtph_ps(_mm_loadu_si128(p.cast()))
    }
}

/// Rounds the leading multiple of eight of `src` into `dst` (nearest, ties to even, as
/// [`F16::from_f32`]); returns how many it wrote. The scalar conversion costs more than
/// the attention of a short row: a step writes 1,536 numbers per row.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,f16c")]
unsafe fn round8(dst: &mut [F16], src: &[f32]) -> usize {
    let n = src.len().min(dst.len()) / 8 * 8;
    for i in (0..n).step_by(8) {
        let h = _mm256_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(_mm256_loadu_ps(src.as_ptr().add(i)));
        _mm_storeu_si128(dst.as_mut_ptr().add(i).cast(), h);
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_rounds_to_nearest_even_and_saturates_to_infinity() {
        assert_eq!(F16::from_f32(1.0), F16(0x3c00));
        assert_eq!(F16::from_f32(-2.0), F16(0xc000));
        assert_eq!(F16::from_f32(65504.0), F16(0x7bff));
        assert_eq!(F16::from_f32(1e6), F16(0x7c00));
        // 1 + 2^-11 lies halfway between 1 and the next half, 1 + 2^-10: ties to even.
        assert_eq!(F16::from_f32(1.0 + 1.0 / 2048.0), F16(0x3c00));
        assert_eq!(F16::from_f32(1.0 + 3.0 / 2048.0), F16(0x3c02));
        assert_eq!(F16(0x3555).to_f32(), 0.333_251_95);
    }

    #[test]
    fn vector_rounding_equals_scalar_rounding() {
        let src: Vec<f32> = (0..1003)
            .map(|i| ((i as f32) * 0.7311).sin() * 10f32.powi(i % 9 - 4))
            .collect();
        let mut dst = vec![F16::default(); src.len()];
        F16::write(&mut dst, &src);
        for (i, (d, &s)) in dst.iter().zip(&src).enumerate() {
            assert_eq!(*d, F16::from_f32(s), "element {i}: {s}");
        }
    }
}
