//! Nearest-point queries over a uniform grid: enough for matching vertices between two
//! files of the same mesh and for transferring values between point sets.

use glam::Vec3;
use std::collections::HashMap;

pub struct PointGrid<'a> {
    points: &'a [Vec3],
    cell: f32,
    origin: Vec3,
    cells: HashMap<(i32, i32, i32), Vec<u32>>,
}

impl<'a> PointGrid<'a> {
    pub fn new(points: &'a [Vec3]) -> Self {
        let (lo, hi) = points.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let extent = if points.is_empty() {
            1.0
        } else {
            (hi - lo).max_element().max(1e-9)
        };
        // About two points per occupied cell for surface-like sets.
        let per_axis = ((points.len() as f32).sqrt()).clamp(1.0, 1024.0);
        let cell = extent / per_axis;
        let origin = if points.is_empty() { Vec3::ZERO } else { lo };
        let mut cells: HashMap<(i32, i32, i32), Vec<u32>> = HashMap::new();
        for (i, &p) in points.iter().enumerate() {
            cells
                .entry(key(p, origin, cell))
                .or_default()
                .push(i as u32);
        }
        PointGrid {
            points,
            cell,
            origin,
            cells,
        }
    }

    /// Index of the nearest point and its distance; None for an empty set.
    pub fn nearest(&self, q: Vec3) -> Option<(usize, f32)> {
        if self.points.is_empty() {
            return None;
        }
        let c = key(q, self.origin, self.cell);
        let mut best: Option<(usize, f32)> = None;
        // Grow the searched shell until no unsearched cell can hold anything closer.
        for r in 0i32.. {
            for dx in -r..=r {
                for dy in -r..=r {
                    for dz in -r..=r {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                            continue;
                        }
                        if let Some(ids) = self.cells.get(&(c.0 + dx, c.1 + dy, c.2 + dz)) {
                            for &i in ids {
                                let d = self.points[i as usize].distance(q);
                                if best.is_none_or(|(_, bd)| d < bd) {
                                    best = Some((i as usize, d));
                                }
                            }
                        }
                    }
                }
            }
            if let Some((_, d)) = best {
                if d <= r as f32 * self.cell {
                    return best;
                }
            }
            // Far from every point: fall back to a scan instead of growing shells.
            if r > 8 {
                return self
                    .points
                    .iter()
                    .enumerate()
                    .map(|(i, p)| (i, p.distance(q)))
                    .min_by(|a, b| a.1.total_cmp(&b.1));
            }
        }
        best
    }
}

fn key(p: Vec3, origin: Vec3, cell: f32) -> (i32, i32, i32) {
    let k = ((p - origin) / cell).floor();
    let clamp = |v: f32| v.clamp(-1e6, 1e6) as i32;
    (clamp(k.x), clamp(k.y), clamp(k.z))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::sample::SplitMix64;

    #[test]
    fn matches_brute_force() {
        let mut rng = SplitMix64(3);
        let mut r = || rng.next_f64() as f32 * 2.0 - 1.0;
        let pts: Vec<Vec3> = (0..2000).map(|_| Vec3::new(r(), r() * 0.1, r())).collect();
        let grid = PointGrid::new(&pts);
        for _ in 0..500 {
            let q = Vec3::new(r() * 1.5, r(), r() * 1.5);
            let brute = pts.iter().map(|p| p.distance(q)).fold(f32::MAX, f32::min);
            let (_, d) = grid.nearest(q).unwrap();
            assert!((d - brute).abs() < 1e-6);
        }
    }
}
