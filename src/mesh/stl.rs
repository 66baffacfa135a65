//! STL, binary and ASCII: a triangle soup, welded on exact positions so the surface is
//! connected (each STL triangle carries its own three corners).

use super::{Limits, Mesh, MeshError};
use glam::Vec3;
use std::collections::HashMap;

/// A binary STL: an 80-byte header, a triangle count, and exactly that many 50-byte
/// records. The size is the only signature (the header is free text, even "solid").
pub fn is_binary(bytes: &[u8]) -> bool {
    bytes.len() >= 84 && {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
        84 + 50 * n == bytes.len() as u64
    }
}

/// An ASCII STL: `solid` and then facets.
pub fn is_ascii(text: &str) -> bool {
    text.starts_with("solid") && text.contains("facet")
}

fn bad(msg: impl Into<String>) -> MeshError {
    MeshError::Stl(msg.into())
}

pub fn load(bytes: &[u8], limits: &Limits) -> Result<Mesh, MeshError> {
    let mut weld = Weld::default();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut push = |tri: [Vec3; 3], weld: &mut Weld| -> Result<(), MeshError> {
        if faces.len() as u64 >= limits.max_triangles {
            return Err(MeshError::TooManyTriangles {
                count: faces.len() as u64 + 1,
                cap: limits.max_triangles,
            });
        }
        let f = [
            weld.index(tri[0], limits)?,
            weld.index(tri[1], limits)?,
            weld.index(tri[2], limits)?,
        ];
        faces.push(f);
        Ok(())
    };
    if is_binary(bytes) {
        let n = (bytes.len() - 84) / 50;
        if n as u64 > limits.max_triangles {
            return Err(MeshError::TooManyTriangles {
                count: n as u64,
                cap: limits.max_triangles,
            });
        }
        for rec in bytes[84..].chunks_exact(50) {
            // 12 bytes of normal (recomputed from the faces), three corners, 2 spare.
            let f = |o: usize| f32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
            let v = |o: usize| Vec3::new(f(o), f(o + 4), f(o + 8));
            push([v(12), v(24), v(36)], &mut weld)?;
        }
    } else {
        let text = std::str::from_utf8(bytes).map_err(|_| bad("neither binary STL nor text"))?;
        let mut it = text.split_ascii_whitespace();
        let mut corners = Vec::with_capacity(3);
        while let Some(t) = it.next() {
            if t != "vertex" {
                continue;
            }
            let mut xyz = [0f32; 3];
            for c in &mut xyz {
                let s = it
                    .next()
                    .ok_or_else(|| bad("a vertex with fewer than 3 numbers"))?;
                *c = s
                    .parse()
                    .map_err(|_| bad(format!("{s:?} is not a number")))?;
            }
            corners.push(Vec3::from(xyz));
            if corners.len() == 3 {
                push([corners[0], corners[1], corners[2]], &mut weld)?;
                corners.clear();
            }
        }
        if !corners.is_empty() {
            return Err(bad("a facet with fewer than 3 vertices"));
        }
    }
    if faces.is_empty() {
        return Err(MeshError::EmptyScene);
    }
    Ok(super::plain::from_faces(&weld.positions, faces).0)
}

#[derive(Default)]
struct Weld {
    positions: Vec<Vec3>,
    index: HashMap<[u32; 3], u32>,
}

impl Weld {
    fn index(&mut self, p: Vec3, limits: &Limits) -> Result<u32, MeshError> {
        if !p.is_finite() {
            return Err(MeshError::NonFinite);
        }
        let key = super::position_key(p);
        if let Some(&i) = self.index.get(&key) {
            return Ok(i);
        }
        if self.positions.len() as u64 >= limits.max_vertices {
            return Err(MeshError::TooManyVertices {
                count: self.positions.len() as u64 + 1,
                cap: limits.max_vertices,
            });
        }
        let i = self.positions.len() as u32;
        self.positions.push(p);
        self.index.insert(key, i);
        Ok(i)
    }
}
