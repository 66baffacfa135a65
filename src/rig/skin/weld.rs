//! Co-located vertices skin as one.
//!
//! glTF splits a vertex wherever its normal or UV changes (every edge of a flat-shaded
//! mesh), so the copies share a position. They must share their weights too, or the
//! surface opens along the seam as soon as it moves. Distances alone give copies equal
//! weights, but the learned model also reads each vertex's normal, and a copy's normal is
//! its own faces' (the Dragon of ../shared came back with different weights on 663 of its
//! 774 seams, up to an L1 difference of 1.2 between copies). So skinning runs on the
//! welded positions and every copy takes its position's weights; on such meshes that is
//! also a fraction of the per-vertex work (../shared's rigs hold 3.1 vertices a position).

use crate::mesh::Mesh;
use crate::rig::SkinWeights;
use glam::Vec3;
use std::collections::HashMap;

pub use crate::mesh::position_key as key;

/// A mesh with one vertex per distinct position, and where each original vertex went.
pub struct Welded {
    /// Positions and triangles only (the per-vertex normals of a split mesh are what
    /// welding removes).
    pub mesh: Mesh,
    /// For each original vertex, its vertex in `mesh` (before coarsening: its distinct
    /// position, which `blend` then maps onto `mesh`).
    of_vertex: Vec<u32>,
    /// For each vertex of `mesh`, the first original vertex at (or in) it.
    first: Vec<u32>,
    /// After [`Welded::coarsened`]: per distinct position, the clusters it takes weights
    /// from and how much of each (empty: every position is a vertex of `mesh`).
    blend: Vec<[(u32, f32); BLEND]>,
}

/// Clusters a position blends: its own and those of up to three neighbours.
const BLEND: usize = 4;

impl Welded {
    pub fn new(mesh: &Mesh) -> Welded {
        let mut index: HashMap<[u32; 3], u32> = HashMap::with_capacity(mesh.positions.len());
        let (mut positions, mut first) = (Vec::new(), Vec::new());
        let of_vertex: Vec<u32> = mesh
            .positions
            .iter()
            .enumerate()
            .map(|(v, &p)| {
                *index.entry(key(p)).or_insert_with(|| {
                    positions.push(p);
                    first.push(v as u32);
                    positions.len() as u32 - 1
                })
            })
            .collect();
        let triangles = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| of_vertex[i as usize]))
            .collect();
        Welded {
            mesh: Mesh {
                positions,
                triangles,
                ..Mesh::default()
            },
            of_vertex,
            first,
            blend: Vec::new(),
        }
    }

    /// At most `target` vertices: positions clustered on a grid (the cell size searched
    /// for), each cluster at its members' mean, triangles that collapse dropped. Each
    /// position then blends the weights of its cluster and its neighbours' clusters by
    /// inverse squared distance to their centres, so weights do not step at cluster
    /// borders. Unchanged when the grid cannot keep a triangle.
    pub fn coarsened(self, target: usize) -> Welded {
        if self.mesh.positions.len() <= target {
            return self;
        }
        let m = &self.mesh;
        let (lo, hi) = m.bounds();
        let area: f32 = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                (b - a).cross(c - a).length() / 2.0
            })
            .sum();
        let extent = (hi - lo).max_element().max(f32::MIN_POSITIVE);
        // A surface of area A holds about A / c² cells of side c.
        let mut cell = (area / target as f32).sqrt().clamp(extent * 1e-5, extent);
        let cell_of = |p: Vec3, c: f32| ((p - lo) / c).floor().as_ivec3().to_array();
        let mut clusters: HashMap<[i32; 3], u32> = HashMap::new();
        for _ in 0..8 {
            clusters.clear();
            for &p in &m.positions {
                let n = clusters.len() as u32;
                clusters.entry(cell_of(p, cell)).or_insert(n);
            }
            if clusters.len() <= target {
                break;
            }
            cell *= (clusters.len() as f32 / target as f32).sqrt() * 1.05;
        }
        if clusters.len() > target {
            return self;
        }
        let mut sum = vec![(Vec3::ZERO, 0u32); clusters.len()];
        let mut first = vec![u32::MAX; clusters.len()];
        let to_cluster: Vec<u32> = m
            .positions
            .iter()
            .enumerate()
            .map(|(u, &p)| {
                let c = clusters[&cell_of(p, cell)];
                sum[c as usize].0 += p;
                sum[c as usize].1 += 1;
                if first[c as usize] == u32::MAX {
                    first[c as usize] = self.first[u];
                }
                c
            })
            .collect();
        let triangles: Vec<[u32; 3]> = m
            .triangles
            .iter()
            .map(|t| t.map(|i| to_cluster[i as usize]))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        if triangles.is_empty() {
            return self;
        }
        let centres: Vec<Vec3> = sum.iter().map(|&(s, n)| s / n as f32).collect();
        // Each position's own cluster first, then its neighbours' (along the fine
        // triangles), as long as there is room.
        let mut near = vec![[u32::MAX; BLEND]; m.positions.len()];
        for (u, c) in to_cluster.iter().enumerate() {
            near[u][0] = *c;
        }
        for t in &m.triangles {
            for k in 0..3 {
                let u = t[k] as usize;
                for &v in &[t[(k + 1) % 3], t[(k + 2) % 3]] {
                    let c = to_cluster[v as usize];
                    if let Some(slot) = near[u].iter().position(|&x| x == u32::MAX || x == c) {
                        near[u][slot] = c;
                    }
                }
            }
        }
        let eps = (cell * 0.25).powi(2);
        let blend = near
            .iter()
            .zip(&m.positions)
            .map(|(cs, &p)| {
                let mut out = [(u32::MAX, 0f32); BLEND];
                let mut total = 0.0;
                for (o, &c) in out.iter_mut().zip(cs).filter(|(_, &c)| c != u32::MAX) {
                    let a = 1.0 / (p.distance_squared(centres[c as usize]) + eps);
                    *o = (c, a);
                    total += a;
                }
                out.iter_mut().for_each(|o| o.1 /= total);
                out
            })
            .collect();
        Welded {
            mesh: Mesh {
                positions: centres,
                triangles,
                ..Mesh::default()
            },
            of_vertex: self.of_vertex,
            first,
            blend,
        }
    }

    /// The first original vertex at welded vertex `u`'s position.
    pub fn original(&self, u: u32) -> u32 {
        self.first[u as usize]
    }

    /// Weights of the welded mesh's vertices, handed to every original vertex (blended,
    /// after [`Welded::coarsened`], and then cut to the `max_influences` largest).
    pub fn spread(&self, w: &SkinWeights, max_influences: usize) -> SkinWeights {
        if self.blend.is_empty() {
            return SkinWeights {
                per_vertex: self
                    .of_vertex
                    .iter()
                    .map(|&u| w.per_vertex[u as usize].clone())
                    .collect(),
            };
        }
        // Per distinct position once; its copies share the result.
        let mixed: Vec<Vec<(u32, f32)>> = self
            .blend
            .iter()
            .map(|b| {
                let mut acc: Vec<(u32, f32)> = Vec::with_capacity(8);
                for &(c, a) in b.iter().filter(|&&(c, a)| c != u32::MAX && a > 0.0) {
                    for &(j, x) in &w.per_vertex[c as usize] {
                        match acc.iter_mut().find(|e| e.0 == j) {
                            Some(e) => e.1 += a * x,
                            None => acc.push((j, a * x)),
                        }
                    }
                }
                acc.sort_by(|p, q| q.1.total_cmp(&p.1).then(p.0.cmp(&q.0)));
                acc.truncate(max_influences);
                let total: f32 = acc.iter().map(|e| e.1).sum();
                if total > 0.0 {
                    acc.iter_mut().for_each(|e| e.1 /= total);
                }
                acc
            })
            .collect();
        SkinWeights {
            per_vertex: self
                .of_vertex
                .iter()
                .map(|&u| mixed[u as usize].clone())
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_share_a_vertex_and_its_weights() {
        let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
        // Two triangles of a quad, split along their shared edge as glTF does, and a
        // copy of the origin at -0.0.
        let mesh = Mesh {
            positions: vec![
                p(0.0, 0.0),
                p(1.0, 0.0),
                p(1.0, 1.0),
                p(0.0, 0.0),
                p(1.0, 1.0),
                p(0.0, 1.0),
                Vec3::new(-0.0, 0.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [3, 4, 5]],
            ..Mesh::default()
        };
        let w = Welded::new(&mesh);
        assert_eq!(w.mesh.positions.len(), 4);
        assert_eq!(w.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!((w.original(0), w.original(3)), (0, 5));
        let welded = SkinWeights {
            per_vertex: vec![
                vec![(0, 1.0)],
                vec![(1, 1.0)],
                vec![(1, 0.5), (2, 0.5)],
                vec![],
            ],
        };
        let out = w.spread(&welded, 4);
        assert_eq!(out.per_vertex.len(), 7);
        assert_eq!(out.per_vertex[3], vec![(0, 1.0)]);
        assert_eq!(out.per_vertex[4], out.per_vertex[2]);
        assert_eq!(out.per_vertex[6], vec![(0, 1.0)]);
    }

    #[test]
    fn a_dense_grid_coarsens_to_at_most_the_target_and_keeps_its_extent() {
        // A 200 x 200 vertex sheet: 40,000 positions, 79,202 triangles.
        let n = 200u32;
        let positions = (0..n * n)
            .map(|i| {
                Vec3::new(
                    (i % n) as f32 / (n - 1) as f32,
                    (i / n) as f32 / (n - 1) as f32,
                    0.0,
                )
            })
            .collect();
        let mut triangles = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let i = y * n + x;
                triangles.extend([[i, i + 1, i + n], [i + 1, i + n + 1, i + n]]);
            }
        }
        let mesh = Mesh {
            positions,
            triangles,
            ..Mesh::default()
        };
        let c = Welded::new(&mesh).coarsened(5_000);
        let k = c.mesh.positions.len();
        assert!((2_000..=5_000).contains(&k), "{k} clusters");
        assert!(c
            .mesh
            .triangles
            .iter()
            .all(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]));
        let (lo, hi) = c.mesh.bounds();
        assert!(
            lo.x < 0.02 && lo.y < 0.02 && hi.x > 0.98 && hi.y > 0.98,
            "{lo} {hi}"
        );
        // Every vertex blends its own cluster (the largest share) and its neighbours'.
        let w = SkinWeights {
            per_vertex: (0..k as u32).map(|u| vec![(u, 1.0)]).collect(),
        };
        let out = c.spread(&w, 4);
        assert_eq!(out.per_vertex.len(), mesh.positions.len());
        for (v, ws) in out.per_vertex.iter().enumerate() {
            assert!((1..=4).contains(&ws.len()), "vertex {v}: {ws:?}");
            let total: f32 = ws.iter().map(|e| e.1).sum();
            assert!((total - 1.0).abs() < 1e-5, "vertex {v}: {ws:?}");
        }
        for u in 0..k as u32 {
            let ws = &out.per_vertex[c.original(u) as usize];
            assert!(ws.iter().any(|e| e.0 == u), "cluster {u}: {ws:?}");
        }
        // Under the target, nothing changes.
        let same = Welded::new(&mesh).coarsened(50_000);
        assert_eq!(same.mesh.positions.len(), mesh.positions.len());
    }
}
