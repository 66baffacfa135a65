//! Connected parts of a mesh, by triangles sharing a position.
//!
//! Positions are welded exactly: glTF splits vertices along UV and normal seams, and a
//! seam must not cut a body into parts. Parts that only touch or overlap (a hat on a
//! head, a sword in a hand) stay separate, which is what lets each keep to its own bones.

use glam::Vec3;
use std::collections::HashMap;

/// The connected parts of a mesh.
#[derive(Clone, Debug)]
pub struct Components {
    /// Part of each vertex; None for a vertex no triangle uses.
    pub of_vertex: Vec<Option<u32>>,
    /// Triangles of each part.
    pub triangles: Vec<Vec<usize>>,
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let p = parent[i as usize];
        parent[i as usize] = parent[p as usize];
        i = p;
    }
    i
}

pub fn components(positions: &[Vec3], triangles: &[[u32; 3]]) -> Components {
    let mut weld: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
    let key = super::weld::key;
    let welded: Vec<u32> = positions
        .iter()
        .map(|&p| {
            let next = weld.len() as u32;
            *weld.entry(key(p)).or_insert(next)
        })
        .collect();
    let mut parent: Vec<u32> = (0..weld.len() as u32).collect();
    for t in triangles {
        let [a, b, c] = t.map(|i| find(&mut parent, welded[i as usize]));
        parent[b as usize] = a;
        let c = find(&mut parent, c);
        parent[c as usize] = a;
    }
    let mut label: HashMap<u32, u32> = HashMap::new();
    let mut parts: Vec<Vec<usize>> = Vec::new();
    for (t, tri) in triangles.iter().enumerate() {
        let root = find(&mut parent, welded[tri[0] as usize]);
        let next = label.len() as u32;
        let id = *label.entry(root).or_insert(next);
        if id as usize == parts.len() {
            parts.push(Vec::new());
        }
        parts[id as usize].push(t);
    }
    let mut of_vertex = vec![None; positions.len()];
    for (id, tris) in parts.iter().enumerate() {
        for &t in tris {
            for &v in &triangles[t] {
                of_vertex[v as usize] = Some(id as u32);
            }
        }
    }
    Components {
        of_vertex,
        triangles: parts,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seams_are_welded_and_separate_parts_stay_apart() {
        // Two triangles sharing an edge through duplicated (seam) vertices, and a third
        // triangle elsewhere, and one vertex nothing uses.
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(5.0, 0.0, 0.0),
            Vec3::new(6.0, 0.0, 0.0),
            Vec3::new(5.0, 1.0, 0.0),
            Vec3::new(9.0, 9.0, 9.0),
        ];
        let t = vec![[0, 1, 2], [3, 5, 4], [6, 7, 8]];
        let c = components(&p, &t);
        assert_eq!(c.triangles.len(), 2);
        assert_eq!(c.of_vertex[0], c.of_vertex[5]);
        assert_ne!(c.of_vertex[0], c.of_vertex[6]);
        assert_eq!(c.of_vertex[9], None);
    }
}
