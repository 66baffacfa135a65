//! Wavefront OBJ. Vertices are welded by position index: OBJ splits a vertex wherever
//! its UV or normal changes, which would cut the surface open at every texture seam.

use super::{Limits, Mesh, MeshError};
use glam::Vec3;

pub fn load(bytes: &[u8], limits: &Limits) -> Result<Mesh, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut positions: Vec<Vec3> = Vec::new();
    let mut normals: Vec<Vec3> = Vec::new();
    // Per position: summed corner normals.
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut corner_normals: Vec<(u32, u32)> = Vec::new();
    for (lineno, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        let mut it = line.split_whitespace();
        let Some(tag) = it.next() else { continue };
        let err = |msg: &str| MeshError::Obj {
            line: lineno + 1,
            msg: msg.to_string(),
        };
        match tag {
            "v" | "vn" => {
                let mut xyz = [0f32; 3];
                for c in &mut xyz {
                    *c = it
                        .next()
                        .and_then(|s| s.parse::<f32>().ok())
                        .ok_or_else(|| err("expected three numbers"))?;
                }
                let v = Vec3::from(xyz);
                if !v.is_finite() {
                    return Err(MeshError::NonFinite);
                }
                if tag == "v" {
                    if positions.len() as u64 >= limits.max_vertices {
                        return Err(MeshError::TooManyVertices {
                            count: positions.len() as u64 + 1,
                            cap: limits.max_vertices,
                        });
                    }
                    positions.push(v);
                } else {
                    if normals.len() as u64 >= limits.max_vertices.saturating_mul(4) {
                        return Err(MeshError::TooManyVertices {
                            count: normals.len() as u64 + 1,
                            cap: limits.max_vertices,
                        });
                    }
                    normals.push(v);
                }
            }
            "f" => {
                let mut corners: Vec<(u32, Option<u32>)> = Vec::new();
                for c in it {
                    let mut parts = c.split('/');
                    let v = resolve(parts.next(), positions.len())
                        .ok_or_else(|| err("face vertex index out of range"))?;
                    let n = match parts.nth(1) {
                        Some(s) if !s.is_empty() => Some(
                            resolve(Some(s), normals.len())
                                .ok_or_else(|| err("face normal index out of range"))?,
                        ),
                        _ => None,
                    };
                    corners.push((v, n));
                    if corners.len() > 4096 {
                        return Err(err("a face with more than 4096 corners"));
                    }
                }
                if corners.len() < 3 {
                    return Err(err("a face with fewer than 3 corners"));
                }
                // Polygons become fans: OBJ faces are meant to be convex and planar.
                for i in 2..corners.len() {
                    if faces.len() as u64 >= limits.max_triangles {
                        return Err(MeshError::TooManyTriangles {
                            count: faces.len() as u64 + 1,
                            cap: limits.max_triangles,
                        });
                    }
                    faces.push([corners[0].0, corners[i - 1].0, corners[i].0]);
                }
                corner_normals.extend(corners.iter().filter_map(|&(v, n)| n.map(|n| (v, n))));
            }
            // Materials, groups, smoothing, UVs and curves do not change the surface.
            _ => {}
        }
    }
    if faces.is_empty() {
        return Err(MeshError::EmptyScene);
    }
    let (mut mesh, remap) = super::plain::from_faces(&positions, faces);
    if !corner_normals.is_empty() {
        let mut sum = vec![Vec3::ZERO; mesh.positions.len()];
        for (v, n) in corner_normals {
            sum[remap[v as usize] as usize] += normals[n as usize];
        }
        for (dst, s) in mesh.normals.iter_mut().zip(sum) {
            if s.length_squared() > 1e-12 {
                *dst = s.normalize();
            }
        }
    }
    Ok(mesh)
}

/// OBJ indices are 1-based; negative ones count back from the latest element.
fn resolve(s: Option<&str>, len: usize) -> Option<u32> {
    let i: i64 = s?.parse().ok()?;
    let idx = if i > 0 {
        i - 1
    } else if i < 0 {
        len as i64 + i
    } else {
        return None;
    };
    (idx >= 0 && (idx as usize) < len).then_some(idx as u32)
}
