//! Area-weighted surface sampling, deterministic for a seed.

use super::Mesh;
use glam::Vec3;

#[derive(Clone, Debug, Default)]
pub struct SurfaceSamples {
    pub points: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// The triangle each sample lies on (for transfers back to vertices).
    pub triangles: Vec<u32>,
}

/// SplitMix64: tiny, seedable and identical on every platform, so a seed names the
/// same samples in training (which reads what the Rust crate writes) and serving.
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [0, 1): the top 24 bits fill an f32 mantissa exactly.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u32 << 24) as f32
    }

    /// Uniform on the unit sphere (Archimedes: z uniform in [-1, 1], azimuth uniform).
    pub fn unit_vec3(&mut self) -> Vec3 {
        let z = 2.0 * self.next_f32() - 1.0;
        let phi = std::f32::consts::TAU * self.next_f32();
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z).normalize()
    }
}

/// Samples `n` points uniformly over the surface, with the face normal of the triangle
/// (flat shading: interpolated normals round off sharp edges that matter for rigging).
pub fn sample_surface(mesh: &Mesh, n: usize, seed: u64) -> SurfaceSamples {
    let mut cdf = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0f64;
    for t in &mesh.triangles {
        total += super::triangle_area(mesh, t) as f64;
        cdf.push(total);
    }
    let mut out = SurfaceSamples::default();
    if total <= 0.0 || n == 0 {
        return out;
    }
    let mut rng = SplitMix64(seed);
    for _ in 0..n {
        let r = rng.next_f64() * total;
        let ti = cdf.partition_point(|&c| c <= r).min(cdf.len() - 1);
        let [a, b, c] = mesh.triangles[ti].map(|i| mesh.positions[i as usize]);
        let (mut u, mut v) = (rng.next_f64() as f32, rng.next_f64() as f32);
        if u + v > 1.0 {
            u = 1.0 - u;
            v = 1.0 - v;
        }
        out.points.push(a + (b - a) * u + (c - a) * v);
        out.normals.push((b - a).cross(c - a).normalize_or_zero());
        out.triangles.push(ti as u32);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> Mesh {
        let mut m = Mesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::Y,
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(12.0, 0.0, 0.0),
                Vec3::new(10.0, 2.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3], [4, 5, 6]],
            ..Mesh::default()
        };
        m.compute_normals();
        m
    }

    #[test]
    fn deterministic_and_area_weighted() {
        let m = quad();
        let a = sample_surface(&m, 4000, 7);
        let b = sample_surface(&m, 4000, 7);
        assert_eq!(a.points, b.points);
        assert_ne!(a.points, sample_surface(&m, 4000, 8).points);
        // The far triangle has area 2 of 3 in total.
        let far = a.points.iter().filter(|p| p.x >= 10.0).count() as f32 / 4000.0;
        assert!((far - 2.0 / 3.0).abs() < 0.03, "{far}");
        assert!(a.normals.iter().all(|n| (n.z.abs() - 1.0).abs() < 1e-5));
    }
}
