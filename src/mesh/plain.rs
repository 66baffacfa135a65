//! What the document-less formats (OBJ, PLY, STL) share: a mesh of the faces' vertices
//! only, as one part, with normals from the faces.

use super::{Mesh, Part};
use glam::{Mat4, Vec3};

/// The mesh of `faces` over `positions`, keeping only the positions a face uses (so stray
/// points cannot stretch the bounds). Returns it and, per input position, its new index
/// (`u32::MAX` where unused), for per-vertex data to follow.
pub(crate) fn from_faces(positions: &[Vec3], mut faces: Vec<[u32; 3]>) -> (Mesh, Vec<u32>) {
    let mut remap = vec![u32::MAX; positions.len()];
    let mut mesh = Mesh::default();
    for f in &mut faces {
        for i in f.iter_mut() {
            if remap[*i as usize] == u32::MAX {
                remap[*i as usize] = mesh.positions.len() as u32;
                mesh.positions.push(positions[*i as usize]);
            }
            *i = remap[*i as usize];
        }
    }
    mesh.triangles = faces;
    mesh.compute_normals();
    mesh.parts.push(Part {
        node: None,
        mesh: 0,
        primitive: 0,
        name: None,
        first_vertex: 0,
        vertex_count: mesh.positions.len() as u32,
        first_triangle: 0,
        triangle_count: mesh.triangles.len() as u32,
        to_world: Mat4::IDENTITY,
        skin: None,
    });
    (mesh, remap)
}

/// `data` (one item per input position) in the order of the mesh [`from_faces`] made.
pub(crate) fn follow<T: Copy + Default>(data: &[T], remap: &[u32], kept: usize) -> Vec<T> {
    let mut out = vec![T::default(); kept];
    for (d, &r) in data.iter().zip(remap) {
        if r != u32::MAX {
            out[r as usize] = *d;
        }
    }
    out
}
