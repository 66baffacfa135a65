//! The unit frame the models see: bounding-box centre at the origin, longest side
//! spanning [-1, 1]. Axes are never swapped: glTF's Y-up frame is kept throughout.

use glam::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    pub center: Vec3,
    /// Half the longest side of the bounding box.
    pub half_extent: f32,
}

impl Normalization {
    pub fn from_points(points: &[Vec3]) -> Self {
        if points.is_empty() {
            return Normalization {
                center: Vec3::ZERO,
                half_extent: 1.0,
            };
        }
        let (lo, hi) = points.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let half = (hi - lo).max_element() * 0.5;
        Normalization {
            center: (lo + hi) * 0.5,
            // A single point has no extent; any positive scale keeps the maps invertible.
            half_extent: if half > 0.0 && half.is_finite() {
                half
            } else {
                1.0
            },
        }
    }

    pub fn apply(&self, p: Vec3) -> Vec3 {
        (p - self.center) / self.half_extent
    }

    pub fn invert(&self, p: Vec3) -> Vec3 {
        p * self.half_extent + self.center
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_longest_side_to_unit_and_back() {
        let pts = [Vec3::new(1.0, 2.0, 3.0), Vec3::new(5.0, 3.0, 4.0)];
        let n = Normalization::from_points(&pts);
        assert_eq!(n.apply(pts[0]).x, -1.0);
        assert_eq!(n.apply(pts[1]).x, 1.0);
        assert!(n.apply(pts[1]).y.abs() <= 1.0);
        assert!((n.invert(n.apply(pts[0])) - pts[0]).length() < 1e-6);
    }
}
