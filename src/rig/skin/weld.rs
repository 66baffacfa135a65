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

/// The key of a position: its bits, with -0.0 and 0.0 the same place.
pub fn key(p: Vec3) -> [u32; 3] {
    (p + Vec3::ZERO).to_array().map(f32::to_bits)
}

/// A mesh with one vertex per distinct position, and where each original vertex went.
pub struct Welded {
    /// Positions and triangles only (the per-vertex normals of a split mesh are what
    /// welding removes).
    pub mesh: Mesh,
    /// For each original vertex, its vertex in `mesh`.
    of_vertex: Vec<u32>,
    /// For each welded vertex, the first original vertex at its position.
    first: Vec<u32>,
}

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
        }
    }

    /// The first original vertex at welded vertex `u`'s position.
    pub fn original(&self, u: u32) -> u32 {
        self.first[u as usize]
    }

    /// Weights of the welded mesh's vertices, handed to every original vertex.
    pub fn spread(&self, w: &SkinWeights) -> SkinWeights {
        SkinWeights {
            per_vertex: self
                .of_vertex
                .iter()
                .map(|&u| w.per_vertex[u as usize].clone())
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
        let out = w.spread(&welded);
        assert_eq!(out.per_vertex.len(), 7);
        assert_eq!(out.per_vertex[3], vec![(0, 1.0)]);
        assert_eq!(out.per_vertex[4], out.per_vertex[2]);
        assert_eq!(out.per_vertex[6], vec![(0, 1.0)]);
    }
}
