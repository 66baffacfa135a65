//! Eight probe points at a time: loops over a mesh's triangles or samples that test
//! several points run them as the lanes of one vector, so each triangle or sample is read
//! once per eight points. The lane functions are plain Rust over `[f32; LANES]` arrays,
//! compiled a second time with AVX2 enabled for CPUs that have it. Each has its own
//! `#[target_feature]` wrapper: one generic wrapper taking a closure left the closure
//! compiled without AVX2 (not inlined into it), and the scorer 50 % slower.

use glam::Vec3;

/// Points that share a pass.
pub const LANES: usize = 8;

#[cfg(target_arch = "x86_64")]
pub fn avx2() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Runs `lanes` over `points` eight at a time, transposed to one array per coordinate,
/// and returns its values in the order of `points`.
pub fn by_lanes<T: Copy>(
    points: &[Vec3],
    lanes: impl Fn(&[[f32; LANES]; 3]) -> [T; LANES],
) -> Vec<T> {
    let mut out = Vec::with_capacity(points.len());
    for chunk in points.chunks(LANES) {
        // Short chunks repeat their last point; the extra lanes are dropped.
        let mut q = [[0.0f32; LANES]; 3];
        for l in 0..LANES {
            let p = chunk[l.min(chunk.len() - 1)];
            (q[0][l], q[1][l], q[2][l]) = (p.x, p.y, p.z);
        }
        out.extend_from_slice(&lanes(&q)[..chunk.len()]);
    }
    out
}

/// `run_lanes!(points, f(a: A, b: B) -> T)`: [`by_lanes`] over `points` with the lane
/// function `f(a, b, q) -> [T; LANES]`, through a copy of `f` compiled with AVX2 and FMA
/// where the CPU has them. Every use expands its own `#[target_feature]` wrapper, as the
/// module's first paragraph requires; `f` should be `#[inline(always)]`.
macro_rules! run_lanes {
    ($points:expr, $lanes:ident($($arg:ident: $ty:ty),*) -> $out:ty) => {{
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn with_avx2(
            $($arg: $ty,)*
            q: &[[f32; $crate::predict::lanes::LANES]; 3],
        ) -> [$out; $crate::predict::lanes::LANES] {
            $lanes($($arg,)* q)
        }
        $crate::predict::lanes::by_lanes($points, |q| {
            #[cfg(target_arch = "x86_64")]
            if $crate::predict::lanes::avx2() {
                // SAFETY: the features were detected.
                return unsafe { with_avx2($($arg,)* q) };
            }
            $lanes($($arg,)* q)
        })
    }};
}
pub(crate) use run_lanes;

/// Each point's nearest member of `set` (the first of equals): the same distances, compared
/// in the same order, as [`nearest2`]. `None` when `set` is empty.
pub fn nearest_index(points: &[Vec3], set: &[Vec3]) -> Vec<Option<usize>> {
    run_lanes!(points, nearest_index_lanes(set: &[Vec3]) -> Option<usize>)
}

#[inline(always)]
fn nearest_index_lanes(set: &[Vec3], q: &[[f32; LANES]; 3]) -> [Option<usize>; LANES] {
    let mut best = [f32::INFINITY; LANES];
    // u32 lanes vectorize where usize ones would not; a set has far fewer members.
    let mut at = [u32::MAX; LANES];
    for (i, s) in set.iter().enumerate() {
        for l in 0..LANES {
            let (x, y, z) = (q[0][l] - s.x, q[1][l] - s.y, q[2][l] - s.z);
            let d = x * x + y * y + z * z;
            let closer = d < best[l];
            best[l] = if closer { d } else { best[l] };
            at[l] = if closer { i as u32 } else { at[l] };
        }
    }
    at.map(|i| (i != u32::MAX).then_some(i as usize))
}

/// Gaussian-weighted mean of `values` around each of `points`: the pair `k` weighs
/// exp(−|point − keys[k]|² · `inv`), pairs further out than an exponent of 30 (1e-13 of a
/// pair at the point itself) not at all; zero where nothing weighs. The exponential is
/// [`exp_neg`], within 2e-7 of the exact one, so that the pairs of eight points are
/// weighed at once.
pub fn gaussian_mean(points: &[Vec3], keys: &[Vec3], values: &[Vec3], inv: f32) -> Vec<Vec3> {
    assert_eq!(keys.len(), values.len(), "one value per key");
    run_lanes!(points, gaussian_mean_lanes(keys: &[Vec3], values: &[Vec3], inv: f32) -> Vec3)
}

#[inline(always)]
fn gaussian_mean_lanes(
    keys: &[Vec3],
    values: &[Vec3],
    inv: f32,
    q: &[[f32; LANES]; 3],
) -> [Vec3; LANES] {
    let mut sum = [[0.0f32; LANES]; 3];
    let mut w = [0.0f32; LANES];
    for (k, v) in keys.iter().zip(values) {
        for l in 0..LANES {
            let (x, y, z) = (q[0][l] - k.x, q[1][l] - k.y, q[2][l] - k.z);
            let e = (x * x + y * y + z * z) * inv;
            let g = if e < 30.0 { exp_neg(e) } else { 0.0 };
            sum[0][l] += v.x * g;
            sum[1][l] += v.y * g;
            sum[2][l] += v.z * g;
            w[l] += g;
        }
    }
    std::array::from_fn(|l| {
        if w[l] > 1e-12 {
            Vec3::new(sum[0][l], sum[1][l], sum[2][l]) / w[l]
        } else {
            Vec3::ZERO
        }
    })
}

/// exp(−e) for e ≥ 0, in straight-line arithmetic the compiler vectorizes (a library
/// `expf` is one call per lane): Cephes' `expf`, a power of two times a degree-6
/// polynomial on |r| ≤ ln 2 / 2. Past e = 87 it returns exp(−87).
#[inline(always)]
fn exp_neg(e: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // ln 2 in two parts, so that n · C1 is exact.
    const C1: f32 = 0.693_359_4;
    const C2: f32 = -2.121_944_4e-4;
    let x = -(if e < 87.0 { e } else { 87.0 });
    let n = (x * LOG2E + 0.5).floor();
    let r = x - n * C1 - n * C2;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        // Cephes writes 5.0000001201e-1, which is 0.5 in f32.
        + 0.5;
    let y = p * r * r + r + 1.0;
    y * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// Each point's squared distance to the nearest of `set` (infinite when `set` is empty).
pub fn nearest2(points: &[Vec3], set: &[Vec3]) -> Vec<f32> {
    run_lanes!(points, nearest2_lanes(set: &[Vec3]) -> f32)
}

#[inline(always)]
fn nearest2_lanes(set: &[Vec3], q: &[[f32; LANES]; 3]) -> [f32; LANES] {
    let mut best = [f32::INFINITY; LANES];
    for s in set {
        for l in 0..LANES {
            let (x, y, z) = (q[0][l] - s.x, q[1][l] - s.y, q[2][l] - s.z);
            let d = x * x + y * y + z * z;
            best[l] = if d < best[l] { d } else { best[l] };
        }
    }
    best
}

/// Each point's squared distance to the nearest of the segments `(a, b)`.
pub fn nearest_segment2(points: &[Vec3], segs: &[(Vec3, Vec3)]) -> Vec<f32> {
    run_lanes!(points, nearest_segment2_lanes(segs: &[(Vec3, Vec3)]) -> f32)
}

/// The same arithmetic, in the same order, as the one-point formula in the tests.
#[inline(always)]
fn nearest_segment2_lanes(segs: &[(Vec3, Vec3)], q: &[[f32; LANES]; 3]) -> [f32; LANES] {
    let mut best = [f32::INFINITY; LANES];
    for &(a, b) in segs {
        let ab = b - a;
        let len2 = ab.length_squared();
        for l in 0..LANES {
            let (x, y, z) = (q[0][l] - a.x, q[1][l] - a.y, q[2][l] - a.z);
            let mut t = if len2 > 0.0 {
                (x * ab.x + y * ab.y + z * ab.z) / len2
            } else {
                0.0
            };
            t = if t < 0.0 { 0.0 } else { t };
            t = if t > 1.0 { 1.0 } else { t };
            let (x, y, z) = (
                a.x + ab.x * t - q[0][l],
                a.y + ab.y * t - q[1][l],
                a.z + ab.z * t - q[2][l],
            );
            let d = x * x + y * y + z * z;
            best[l] = if d < best[l] { d } else { best[l] };
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` points along a wavy curve: (sin(a·i), cos(b·i), c·i + d).
    fn curve(n: usize, [a, b, c, d]: [f32; 4]) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let t = i as f32;
                Vec3::new((t * a).sin(), (t * b).cos(), t * c + d)
            })
            .collect()
    }

    #[test]
    fn nearest_matches_the_brute_force_for_every_chunk_length() {
        let set = curve(37, [0.7, 1.3, 0.05, -1.0]);
        for n in [1, 7, 8, 9, 20] {
            let points: Vec<Vec3> = (0..n)
                .map(|i| Vec3::new(i as f32 * 0.1 - 0.5, 0.2, (i as f32).cos()))
                .collect();
            let got = nearest2(&points, &set);
            assert_eq!(got.len(), n);
            for (p, d) in points.iter().zip(&got) {
                let want = set
                    .iter()
                    .map(|q| p.distance_squared(*q))
                    .fold(f32::INFINITY, f32::min);
                assert_eq!(*d, want, "{p:?}");
            }
        }
        assert_eq!(nearest2(&[Vec3::ZERO], &[]), vec![f32::INFINITY]);
    }

    #[test]
    fn nearest_index_finds_the_first_nearest_for_every_chunk_length() {
        let mut set = curve(29, [0.9, 0.4, 0.07, -1.0]);
        // A duplicate: the first of two equals wins.
        set.push(set[5]);
        for n in [1, 7, 8, 9, 20] {
            let mut points: Vec<Vec3> = (0..n)
                .map(|i| Vec3::new(i as f32 * 0.1 - 0.5, 0.2, (i as f32).cos()))
                .collect();
            points[0] = set[5] + Vec3::splat(1e-3);
            let got = nearest_index(&points, &set);
            for (p, i) in points.iter().zip(&got) {
                let d: Vec<f32> = set.iter().map(|q| p.distance_squared(*q)).collect();
                let want = (0..d.len()).fold(0, |b, k| if d[k] < d[b] { k } else { b });
                assert_eq!(*i, Some(want), "{p:?}");
            }
            assert_eq!(got[0], Some(5));
        }
        assert_eq!(nearest_index(&[Vec3::ZERO], &[]), vec![None]);
    }

    #[test]
    fn exp_neg_is_within_two_parts_in_ten_million_of_the_exact_one() {
        for k in 0..=20_000 {
            let e = k as f32 * 0.0045; // 0 to 90
            let (got, want) = (exp_neg(e) as f64, (-(e.min(87.0)) as f64).exp());
            assert!(
                ((got - want) / want).abs() < 2e-7,
                "exp(-{e}): {got} vs {want}"
            );
        }
        assert_eq!(exp_neg(0.0), 1.0);
    }

    #[test]
    fn gaussian_mean_matches_the_one_point_sum() {
        let keys = curve(53, [0.3, 0.8, 0.02, -0.5]);
        let values: Vec<Vec3> = keys
            .iter()
            .map(|k| Vec3::new(k.z, -k.x, 0.5 * k.y))
            .collect();
        let points: Vec<Vec3> = (0..11)
            .map(|i| Vec3::new(i as f32 * 0.2 - 1.0, 0.1, (i as f32 * 0.5).sin()))
            // Far from every key nothing weighs: no displacement.
            .chain([Vec3::splat(50.0)])
            .collect();
        for sigma in [0.05f32, 0.2, 0.6] {
            let inv = 1.0 / (2.0 * sigma * sigma);
            let got = gaussian_mean(&points, &keys, &values, inv);
            for (p, g) in points.iter().zip(&got) {
                let (mut sum, mut w) = (glam::DVec3::ZERO, 0.0f64);
                for (k, v) in keys.iter().zip(&values) {
                    let e = ((*p - *k).length_squared() * inv) as f64;
                    if e < 30.0 {
                        sum += v.as_dvec3() * (-e).exp();
                        w += (-e).exp();
                    }
                }
                let want = if w > 1e-12 {
                    sum / w
                } else {
                    glam::DVec3::ZERO
                };
                assert!(
                    (g.as_dvec3() - want).length() < 1e-5,
                    "σ {sigma}, {p:?}: {g:?} vs {want:?}"
                );
            }
        }
    }

    fn segment_distance2(q: Vec3, a: Vec3, b: Vec3) -> f32 {
        let ab = b - a;
        let len2 = ab.length_squared();
        let t = if len2 > 0.0 {
            ((q - a).dot(ab) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (a + ab * t).distance_squared(q)
    }

    #[test]
    fn nearest_segment_matches_the_one_point_formula() {
        let segs: Vec<(Vec3, Vec3)> = (0..13)
            .map(|i| {
                let t = i as f32;
                let a = Vec3::new(t.sin(), t * 0.1, t.cos());
                // Every third segment is a point.
                let b = if i % 3 == 0 {
                    a
                } else {
                    a + Vec3::new(0.3, -0.2, t * 0.01)
                };
                (a, b)
            })
            .collect();
        let points: Vec<Vec3> = (0..19)
            .map(|i| Vec3::new(i as f32 * 0.13 - 1.0, 0.5, (i as f32 * 0.7).sin()))
            .collect();
        let got = nearest_segment2(&points, &segs);
        for (p, d) in points.iter().zip(&got) {
            let want = segs
                .iter()
                .map(|&(a, b)| segment_distance2(*p, a, b))
                .fold(f32::INFINITY, f32::min);
            assert_eq!(*d, want, "{p:?}");
        }
    }
}
