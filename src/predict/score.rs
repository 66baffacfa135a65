//! Geometric checks that rank best-of-N skeleton candidates, in the spirit of TokenRig's
//! rewards: bones should reach every part of the mesh, lie inside it, and stay within its
//! bounds. Everything works in the unit frame. Coverage is measured from the surface
//! samples the model saw; inside-ness by the generalized winding number, exact for meshes
//! of moderate size and estimated from dense oriented samples beyond, so the cost per
//! candidate stays bounded whatever the mesh's size.

use crate::mesh::{sample_surface, Mesh};
use crate::rig::Skeleton;
use glam::Vec3;

/// Weight of the fraction of bone samples outside the mesh, relative to coverage.
const OUTSIDE_WEIGHT: f32 = 1.0;
/// Weight of the joints' distance outside the mesh's bounding box.
const BBOX_WEIGHT: f32 = 4.0;
/// Interior samples per parent→child edge for the inside test (plus the joints).
const EDGE_SAMPLES: usize = 1;
/// Generalized winding number above which a point counts as inside.
const INSIDE_WINDING: f32 = 0.5;

/// Lower `cost` is better.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SkeletonScore {
    /// Mean distance from the surface samples to the nearest bone, divided by their mean
    /// distance to the surface centroid: 1 is no better than a single joint at the centre.
    pub coverage: f32,
    /// Fraction of joint and bone samples outside the mesh (generalized winding number
    /// below 0.5).
    pub outside: f32,
    /// Mean distance of joints outside the mesh's bounding box (grown by 2 %), in the same
    /// unit as `coverage`.
    pub bbox_excess: f32,
    pub cost: f32,
}

/// Meshes up to this many triangles get the exact winding number: one solid angle per
/// triangle per probe, about 90 ms for a 128-bone candidate at this size.
const EXACT_MAX_TRIANGLES: usize = 8192;
/// Oriented samples standing in for the triangles of larger meshes. The model's 2048 are
/// too sparse: limbs thinner than the sample spacing read as outside.
const DENSE_SAMPLES: usize = 16_384;

/// How inside-ness is measured.
#[derive(Clone, Debug)]
enum Winding {
    /// Sum of the triangles' solid angles (Van Oosterom–Strackee).
    Exact {
        positions: Vec<Vec3>,
        triangles: Vec<[u32; 3]>,
    },
    /// Point-cloud estimate from area-weighted oriented samples.
    Points {
        points: Vec<Vec3>,
        normals: Vec<Vec3>,
        /// Surface area each sample stands for.
        sample_area: f32,
        /// Softening length², about one sample spacing: without it a probe near a sample
        /// would be dominated by that one sample.
        soft2: f32,
    },
}

/// `y.atan2(x)` within 2e-7 rad, without libm's call: the exact winding number takes one
/// per triangle per query point, and under load libm's `atan2f` was 6 % of the server's
/// CPU. The ratio of the smaller to the larger magnitude goes through an odd degree-15
/// polynomial fitted to atan on [0, 1], then to its octant and quadrant.
fn atan2(y: f32, x: f32) -> f32 {
    const C: [f32; 8] = [
        0.999_999_34,
        -0.333_298_6,
        0.199_465_7,
        -0.139_086_5,
        0.096_422_55,
        -0.055_913_14,
        0.021_863_535,
        -0.004_054_730_3,
    ];
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = (ax.min(ay), ax.max(ay));
    if hi == 0.0 || hi.is_nan() || lo.is_nan() {
        return y.atan2(x);
    }
    let a = lo / hi;
    let s = a * a;
    let p = C.iter().rev().fold(0.0f32, |acc, &c| acc * s + c);
    let mut r = a * p;
    if ay > ax {
        r = std::f32::consts::FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = std::f32::consts::PI - r;
    }
    r.copysign(y)
}

/// The mesh as the scorer sees it, in the unit frame.
#[derive(Clone, Debug)]
pub struct SurfaceModel {
    /// Surface samples coverage is measured from.
    points: Vec<Vec3>,
    winding: Winding,
    centroid_spread: f32,
    lo: Vec3,
    hi: Vec3,
}

impl SurfaceModel {
    /// `samples` are `x y z nx ny nz` rows on `unit` (the mesh in the unit frame), as fed
    /// to the model; `seed` draws the denser samples large meshes are tested against.
    pub fn new(samples: &[[f32; 6]], unit: &Mesh, seed: u64) -> SurfaceModel {
        let points: Vec<Vec3> = samples
            .iter()
            .map(|s| Vec3::new(s[0], s[1], s[2]))
            .collect();
        let n = points.len().max(1) as f32;
        let centroid = points.iter().copied().sum::<Vec3>() / n;
        let spread = points.iter().map(|p| p.distance(centroid)).sum::<f32>() / n;
        let winding = if unit.triangles.len() <= EXACT_MAX_TRIANGLES {
            Winding::Exact {
                positions: unit.positions.clone(),
                triangles: unit.triangles.clone(),
            }
        } else {
            let area: f32 = unit
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| unit.positions[i as usize]);
                    (b - a).cross(c - a).length() * 0.5
                })
                .sum();
            let dense = sample_surface(unit, DENSE_SAMPLES, seed ^ 0x5eed_5eed);
            let sample_area = area / dense.points.len().max(1) as f32;
            Winding::Points {
                points: dense.points,
                normals: dense.normals,
                sample_area,
                soft2: sample_area.max(1e-12),
            }
        };
        let (lo, hi) = unit.bounds();
        let margin = (hi - lo).max_element() * 0.02;
        SurfaceModel {
            points,
            winding,
            centroid_spread: spread.max(1e-6),
            lo: lo - Vec3::splat(margin),
            hi: hi + Vec3::splat(margin),
        }
    }

    /// Generalized winding number at `q`: about 1 inside a closed surface, 0 outside, and it
    /// degrades gracefully on meshes with holes, where ray parity breaks. The sign follows
    /// the triangle winding, so callers test the magnitude.
    pub fn winding(&self, q: Vec3) -> f32 {
        match &self.winding {
            Winding::Exact {
                positions,
                triangles,
            } => {
                let mut w = 0.0f64;
                for t in triangles {
                    let [a, b, c] = t.map(|i| positions[i as usize] - q);
                    let (la, lb, lc) = (a.length(), b.length(), c.length());
                    let num = a.dot(b.cross(c));
                    let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
                    w += atan2(num, den) as f64;
                }
                (w / (2.0 * std::f64::consts::PI)) as f32
            }
            Winding::Points {
                points,
                normals,
                sample_area,
                soft2,
            } => {
                let mut w = 0.0f32;
                for (p, n) in points.iter().zip(normals) {
                    let d = *p - q;
                    let r2 = d.length_squared() + soft2;
                    w += d.dot(*n) / (r2 * r2.sqrt());
                }
                w * sample_area / (4.0 * std::f32::consts::PI)
            }
        }
    }

    pub fn is_inside(&self, q: Vec3) -> bool {
        self.winding(q).abs() >= INSIDE_WINDING
    }

    /// Scores a skeleton given in the unit frame.
    pub fn score(&self, skel: &Skeleton) -> SkeletonScore {
        let mut segs: Vec<(Vec3, Vec3)> = Vec::with_capacity(skel.len() * 2);
        for b in &skel.bones {
            if let Some(p) = b.parent {
                segs.push((skel.bones[p].head, b.head));
            }
            segs.push((b.head, b.tail));
        }
        let coverage = if segs.is_empty() {
            f32::INFINITY
        } else {
            let total: f32 = self
                .points
                .iter()
                .map(|&q| {
                    segs.iter()
                        .map(|&(a, b)| segment_distance2(q, a, b))
                        .fold(f32::INFINITY, f32::min)
                        .sqrt()
                })
                .sum();
            total / self.points.len().max(1) as f32 / self.centroid_spread
        };
        let mut probes: Vec<Vec3> = skel.bones.iter().map(|b| b.head).collect();
        for b in &skel.bones {
            if let Some(p) = b.parent {
                let a = skel.bones[p].head;
                for k in 1..=EDGE_SAMPLES {
                    probes.push(a.lerp(b.head, k as f32 / (EDGE_SAMPLES + 1) as f32));
                }
            }
        }
        let outside = if probes.is_empty() {
            1.0
        } else {
            probes.iter().filter(|&&q| !self.is_inside(q)).count() as f32 / probes.len() as f32
        };
        let bbox_excess = if skel.is_empty() {
            0.0
        } else {
            skel.bones
                .iter()
                .map(|b| {
                    (self.lo - b.head)
                        .max(b.head - self.hi)
                        .max(Vec3::ZERO)
                        .length()
                })
                .sum::<f32>()
                / skel.len() as f32
                / self.centroid_spread
        };
        SkeletonScore {
            coverage,
            outside,
            bbox_excess,
            cost: coverage + OUTSIDE_WEIGHT * outside + BBOX_WEIGHT * bbox_excess,
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

#[cfg(test)]
mod tests {
    #[test]
    fn fast_atan2_agrees_with_libm_in_every_quadrant() {
        let mut worst = 0.0f32;
        for i in -200..=200 {
            for j in -200..=200 {
                let (y, x) = (i as f32 * 0.37, j as f32 * 0.53);
                let (got, want) = (super::atan2(y, x), y.atan2(x));
                worst = worst.max((got - want).abs());
            }
        }
        assert!(worst < 5e-7, "worst {worst}");
        assert_eq!(super::atan2(0.0, 0.0), 0.0);
        assert!(super::atan2(1e-30, -1.0) > std::f32::consts::PI - 1e-6);
        assert!(super::atan2(-1.0, 1e-30) < -std::f32::consts::FRAC_PI_2 + 1e-6);
    }

    use super::*;
    use crate::rig::Bone;

    fn cube() -> Mesh {
        crate::mesh::box_mesh(Vec3::splat(-1.0), Vec3::ONE)
    }

    fn surface_of(m: &Mesh) -> SurfaceModel {
        let s = sample_surface(m, 2048, 3);
        let rows: Vec<[f32; 6]> = s
            .points
            .iter()
            .zip(&s.normals)
            .map(|(p, n)| [p.x, p.y, p.z, n.x, n.y, n.z])
            .collect();
        SurfaceModel::new(&rows, m, 3)
    }

    fn surface() -> SurfaceModel {
        surface_of(&cube())
    }

    /// The cube with every face split into many triangles, past the exact-winding limit.
    fn fine_cube() -> Mesh {
        let c = cube();
        let mut m = Mesh::default();
        let k = 30;
        for t in &c.triangles {
            let [a, b, cc] = t.map(|i| c.positions[i as usize]);
            // Barycentric grid subdivision of the triangle into k² pieces.
            let base = m.positions.len() as u32;
            let idx = |i: u32, j: u32| base + i * (k + 1) + j;
            for i in 0..=k {
                for j in 0..=k {
                    let (u, v) = (i as f32 / k as f32, j as f32 / k as f32);
                    let (u, v) = if u + v > 1.0 { (u, 1.0 - u) } else { (u, v) };
                    m.positions.push(a + (b - a) * u + (cc - a) * v);
                }
            }
            for i in 0..k {
                for j in 0..k - i {
                    m.triangles.push([idx(i, j), idx(i + 1, j), idx(i, j + 1)]);
                    if i + j + 1 < k {
                        m.triangles
                            .push([idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)]);
                    }
                }
            }
        }
        m
    }

    fn chain(points: &[Vec3]) -> Skeleton {
        let mut s = Skeleton {
            bones: points
                .iter()
                .enumerate()
                .map(|(i, &p)| Bone {
                    name: format!("b{i}"),
                    parent: i.checked_sub(1),
                    head: p,
                    tail: p,
                    spring: false,
                })
                .collect(),
            ..Skeleton::default()
        };
        s.infer_tails();
        s
    }

    #[test]
    fn winding_separates_inside_from_outside() {
        let fine = fine_cube();
        assert!(fine.triangles.len() > EXACT_MAX_TRIANGLES);
        for s in [surface(), surface_of(&fine)] {
            assert!(
                (s.winding(Vec3::ZERO) - 1.0).abs() < 0.05,
                "{}",
                s.winding(Vec3::ZERO)
            );
            assert!(s.is_inside(Vec3::new(0.7, -0.6, 0.5)));
            assert!(!s.is_inside(Vec3::new(1.6, 0.0, 0.0)));
            assert!(s.winding(Vec3::new(3.0, 3.0, -2.0)).abs() < 0.05);
        }
    }

    #[test]
    fn inside_spread_skeleton_beats_outside_or_collapsed_one() {
        let s = surface();
        let good = chain(&[
            Vec3::new(0.0, -0.7, 0.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 0.7, 0.0),
        ]);
        let tiny = chain(&[Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.05, 0.0)]);
        let outside = chain(&[
            Vec3::new(1.5, -0.7, 0.0),
            Vec3::new(1.5, 0.0, 0.0),
            Vec3::new(1.5, 0.7, 0.0),
        ]);
        let (g, t, o) = (s.score(&good), s.score(&tiny), s.score(&outside));
        assert!(g.cost < t.cost, "{g:?} vs {t:?}");
        assert!(g.cost < o.cost, "{g:?} vs {o:?}");
        assert_eq!(g.outside, 0.0);
        assert!(o.outside > 0.9 && o.bbox_excess > 0.0);
    }
}
