//! Geometric checks that rank best-of-N skeleton candidates, in the spirit of TokenRig's
//! rewards: bones should reach every part of the mesh, lie inside it, and stay within its
//! bounds. Everything works in the unit frame. Coverage is measured from the surface
//! samples the model saw; inside-ness by the generalized winding number, exact for meshes
//! of moderate size and estimated from dense oriented samples beyond, so the cost per
//! candidate stays bounded whatever the mesh's size.

use super::winding::{Dipoles, Triangles};
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
    /// Sum of the triangles' solid angles.
    Exact(Triangles),
    /// Point-cloud estimate from area-weighted oriented samples.
    Points(Dipoles),
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
            Winding::Exact(Triangles::new(&unit.positions, &unit.triangles))
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
            Winding::Points(Dipoles::new(&dense.points, &dense.normals, sample_area))
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

    /// Generalized winding number at each of `probes` (several share a pass): about 1
    /// inside a closed surface, 0 outside, and it degrades gracefully on meshes with holes,
    /// where ray parity breaks. The sign follows the triangle winding, so callers test the
    /// magnitude ([`Self::inside`]).
    pub fn windings(&self, probes: &[Vec3]) -> Vec<f32> {
        match &self.winding {
            Winding::Exact(triangles) => triangles.winding(probes),
            Winding::Points(dipoles) => dipoles.winding(probes),
        }
    }

    /// Whether a winding number from [`Self::windings`] counts as inside.
    pub fn inside(winding: f32) -> bool {
        winding.abs() >= INSIDE_WINDING
    }

    /// One probe's winding number; the scorer always asks for several.
    #[cfg(test)]
    pub fn winding(&self, q: Vec3) -> f32 {
        self.windings(&[q])[0]
    }

    #[cfg(test)]
    pub fn is_inside(&self, q: Vec3) -> bool {
        Self::inside(self.winding(q))
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
            let total: f32 = super::lanes::nearest_segment2(&self.points, &segs)
                .into_iter()
                .map(f32::sqrt)
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
            let w = self.windings(&probes);
            w.iter().filter(|&&w| !Self::inside(w)).count() as f32 / probes.len() as f32
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

/// How much candidates disagree with one another: the mean symmetric joint chamfer
/// distance (unit frame) over their pairs; `None` with fewer than two. Not part of the
/// cost: a choice rule that took the library rig whenever the model's four candidates
/// disagreed was measured and not shipped (MODEL_CARD.md, "The model's own disagreement").
pub fn spread(skeletons: &[&Skeleton]) -> Option<f32> {
    let mut sum = 0.0f64;
    let mut pairs = 0usize;
    for (i, a) in skeletons.iter().enumerate() {
        for b in &skeletons[i + 1..] {
            if let Some(d) = crate::rig::metrics::cd_j2j(a, b, &crate::rig::metrics::Frame::UNIT) {
                sum += d as f64;
                pairs += 1;
            }
        }
    }
    (pairs > 0).then(|| (sum / pairs as f64) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::Bone;

    #[test]
    fn spread_is_the_mean_pairwise_joint_distance() {
        let chain = |dx: f32| Skeleton {
            bones: vec![
                Bone::new("a", None, Vec3::new(dx, 0.0, 0.0), Vec3::Y),
                Bone::new("b", Some(0), Vec3::new(dx, 1.0, 0.0), Vec3::Y * 2.0),
            ],
            ..Skeleton::default()
        };
        let (a, b, c) = (chain(0.0), chain(0.2), chain(0.4));
        assert_eq!(
            spread(&[&a]),
            None,
            "one candidate has nothing to disagree with"
        );
        assert_eq!(spread(&[&a, &a]), Some(0.0));
        let ab = crate::rig::metrics::cd_j2j(&a, &b, &crate::rig::metrics::Frame::UNIT).unwrap();
        assert!(ab > 0.0);
        // Pairs a-b and b-c are one shift apart, a-c two: the mean is 4/3 of one shift.
        let d = spread(&[&a, &b, &c]).unwrap();
        assert!((d - ab * 4.0 / 3.0).abs() < 1e-5, "{d} vs {ab}");
    }

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
