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
pub fn by_lanes(points: &[Vec3], lanes: impl Fn(&[[f32; LANES]; 3]) -> [f32; LANES]) -> Vec<f32> {
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

/// Each point's squared distance to the nearest of `set` (infinite when `set` is empty).
pub fn nearest2(points: &[Vec3], set: &[Vec3]) -> Vec<f32> {
    by_lanes(points, |q| {
        #[cfg(target_arch = "x86_64")]
        if avx2() {
            // SAFETY: the features were detected.
            return unsafe { nearest2_avx2(set, q) };
        }
        nearest2_lanes(set, q)
    })
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn nearest2_avx2(set: &[Vec3], q: &[[f32; LANES]; 3]) -> [f32; LANES] {
    nearest2_lanes(set, q)
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
    by_lanes(points, |q| {
        #[cfg(target_arch = "x86_64")]
        if avx2() {
            // SAFETY: the features were detected.
            return unsafe { nearest_segment2_avx2(segs, q) };
        }
        nearest_segment2_lanes(segs, q)
    })
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn nearest_segment2_avx2(segs: &[(Vec3, Vec3)], q: &[[f32; LANES]; 3]) -> [f32; LANES] {
    nearest_segment2_lanes(segs, q)
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

    #[test]
    fn nearest_matches_the_brute_force_for_every_chunk_length() {
        let set: Vec<Vec3> = (0..37)
            .map(|i| {
                let t = i as f32;
                Vec3::new((t * 0.7).sin(), (t * 1.3).cos(), t * 0.05 - 1.0)
            })
            .collect();
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
