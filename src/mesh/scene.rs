//! Walks a glTF scene and merges its triangle primitives into one world-space mesh.

use super::gltf::{Document, Node};
use super::{Limits, Mesh, MeshError, Part};
use glam::{Mat4, Quat, Vec3};

const TRIANGLES: u32 = 4;
const TRIANGLE_STRIP: u32 = 5;
const TRIANGLE_FAN: u32 = 6;

pub fn local_matrix(node: &Node) -> Result<Mat4, MeshError> {
    let m = if let Some(m) = node.matrix {
        Mat4::from_cols_array(&m)
    } else {
        let t = Vec3::from(node.translation.unwrap_or([0.0; 3]));
        let r = node
            .rotation
            .map(Quat::from_array)
            .unwrap_or(Quat::IDENTITY);
        let s = Vec3::from(node.scale.unwrap_or([1.0; 3]));
        // Exporters write quaternions that are only nearly unit; renormalise (a zero
        // quaternion is invalid glTF, and would otherwise collapse the subtree).
        let r = if r.length_squared() > 1e-12 {
            r.normalize()
        } else {
            Quat::IDENTITY
        };
        Mat4::from_scale_rotation_translation(s, r, t)
    };
    if !m.is_finite() {
        return Err(MeshError::NonFinite);
    }
    Ok(m)
}

/// Per node: its world matrix (None when unreachable) and its parent.
pub type NodeFrames = (Vec<Option<Mat4>>, Vec<Option<usize>>);

/// World matrices of every node reachable from the scene roots, plus the parent of each
/// node. Fails on cycles and on nodes with two parents, which glTF forbids and which
/// would otherwise make traversal loop or duplicate geometry without bound.
pub fn world_matrices(doc: &Document, limits: &Limits) -> Result<NodeFrames, MeshError> {
    let nodes = &doc.root.nodes;
    if nodes.len() > limits.max_nodes {
        return Err(MeshError::Invalid(format!(
            "{} nodes, over the cap of {}",
            nodes.len(),
            limits.max_nodes
        )));
    }
    let mut parent = vec![None; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        for &c in &n.children {
            if c >= nodes.len() {
                return Err(MeshError::IndexOutOfRange {
                    what: "node",
                    index: c as u64,
                });
            }
            if c == i || parent[c].is_some() {
                return Err(MeshError::BadHierarchy(format!(
                    "node {c} has more than one parent"
                )));
            }
            parent[c] = Some(i);
        }
    }
    let roots = scene_roots(doc)?;
    let mut world: Vec<Option<Mat4>> = vec![None; nodes.len()];
    let mut stack: Vec<(usize, Mat4)> = Vec::new();
    for &r in &roots {
        if parent[r].is_some() {
            return Err(MeshError::BadHierarchy(format!(
                "scene root {r} has a parent"
            )));
        }
        stack.push((r, Mat4::IDENTITY));
    }
    while let Some((i, parent_m)) = stack.pop() {
        if world[i].is_some() {
            return Err(MeshError::BadHierarchy(format!(
                "node {i} is reached twice"
            )));
        }
        let m = parent_m * local_matrix(&nodes[i])?;
        world[i] = Some(m);
        stack.extend(nodes[i].children.iter().map(|&c| (c, m)));
    }
    // With one parent each, the only nodes a walk down from the parentless ones never
    // enters are those on a cycle or hanging from one. (Walking up from every node
    // instead is quadratic: 15 s for a 100k-node chain.)
    if let Some(i) = euler_tour(nodes, &parent).iter().position(|s| s.0 == 0) {
        return Err(MeshError::BadHierarchy(format!(
            "node {i} is on or under a cycle"
        )));
    }
    Ok((world, parent))
}

/// Pre-order (entry, exit) clock of every node, counted from 1; 0 marks a node no walk
/// from a parentless node reaches. `a` is a proper ancestor of `b` exactly when
/// `entry(a) < entry(b) < exit(a)`, which makes ancestry questions O(1).
fn euler_tour(nodes: &[Node], parent: &[Option<usize>]) -> Vec<(usize, usize)> {
    let mut span = vec![(0, 0); nodes.len()];
    let mut clock = 0;
    let mut stack: Vec<(usize, bool)> = (0..nodes.len())
        .filter(|&i| parent[i].is_none())
        .map(|i| (i, false))
        .collect();
    while let Some((i, leaving)) = stack.pop() {
        clock += 1;
        if leaving {
            span[i].1 = clock;
        } else {
            span[i].0 = clock;
            stack.push((i, true));
            stack.extend(nodes[i].children.iter().map(|&c| (c, false)));
        }
    }
    span
}

fn scene_roots(doc: &Document) -> Result<Vec<usize>, MeshError> {
    let root = &doc.root;
    if root.scenes.is_empty() {
        // No scene: show every parentless node, as most viewers do.
        let mut has_parent = vec![false; root.nodes.len()];
        root.nodes.iter().flat_map(|n| &n.children).for_each(|&c| {
            if let Some(h) = has_parent.get_mut(c) {
                *h = true;
            }
        });
        return Ok((0..root.nodes.len()).filter(|&i| !has_parent[i]).collect());
    }
    let s = root.scene.unwrap_or(0);
    let scene = root.scenes.get(s).ok_or(MeshError::IndexOutOfRange {
        what: "scene",
        index: s as u64,
    })?;
    for &n in &scene.nodes {
        if n >= root.nodes.len() {
            return Err(MeshError::IndexOutOfRange {
                what: "node",
                index: n as u64,
            });
        }
    }
    Ok(scene.nodes.clone())
}

pub fn build(doc: &Document, limits: &Limits) -> Result<Mesh, MeshError> {
    let (world, parent) = world_matrices(doc, limits)?;
    let nodes = &doc.root.nodes;
    let mut skin_frames: Vec<Option<Mat4>> = vec![None; doc.root.skins.len()];
    let mut tour: Option<Vec<(usize, usize)>> = None;
    let mut mesh = Mesh::default();
    let mut skipped_modes = Vec::new();
    let mut any_normals_missing = false;
    // Every node may instance every primitive, so a few kilobytes of JSON can ask for
    // billions of instances even when each adds no vertex; cap them like vertices.
    let mut instances: u64 = 0;
    // A skin's inverse bind matrices cost up to MAX_JOINTS elements to read however
    // short its JSON, and many skins may share one accessor: cap their total too.
    let mut bind_matrices: u64 = 0;
    for (node_index, node) in nodes.iter().enumerate() {
        let (Some(mesh_index), Some(node_world)) = (node.mesh, world[node_index]) else {
            continue;
        };
        let def = doc
            .root
            .meshes
            .get(mesh_index)
            .ok_or(MeshError::IndexOutOfRange {
                what: "mesh",
                index: mesh_index as u64,
            })?;
        if let Some(s) = node.skin {
            if s >= doc.root.skins.len() {
                return Err(MeshError::IndexOutOfRange {
                    what: "skin",
                    index: s as u64,
                });
            }
        }
        for (pi, prim) in def.primitives.iter().enumerate() {
            instances += 1;
            if instances > limits.max_vertices {
                return Err(MeshError::Invalid(format!(
                    "more than {} primitive instances",
                    limits.max_vertices
                )));
            }
            let mode = prim.mode.unwrap_or(TRIANGLES);
            if !matches!(mode, TRIANGLES | TRIANGLE_STRIP | TRIANGLE_FAN) {
                if mode > 6 {
                    return Err(MeshError::Invalid(format!("primitive mode {mode}")));
                }
                if !skipped_modes.contains(&mode) {
                    skipped_modes.push(mode);
                }
                continue;
            }
            // Nothing to merge, and a Part per empty instance is unbounded memory.
            if let Some(&acc) = prim.attributes.get("POSITION") {
                if doc.accessor_count(acc)? == 0 {
                    continue;
                }
            }
            let skinned = node.skin.is_some() && prim.attributes.contains_key("JOINTS_0");
            let to_world = match node.skin {
                Some(si) if skinned => match skin_frames[si] {
                    Some(m) => m,
                    None => {
                        if let Some(acc) = doc.root.skins[si].inverse_bind_matrices {
                            let n = doc.accessor_count(acc)?.min(MAX_JOINTS + 1);
                            bind_matrices += n;
                            if bind_matrices > limits.max_vertices {
                                return Err(MeshError::Invalid(format!(
                                    "more than {} inverse bind matrices across skins",
                                    limits.max_vertices
                                )));
                            }
                        }
                        let t = tour.get_or_insert_with(|| euler_tour(nodes, &parent));
                        let m = skin_to_world(doc, si, &world, t)?;
                        skin_frames[si] = Some(m);
                        m
                    }
                },
                _ => node_world,
            };
            let added = add_primitive(doc, limits, &mut mesh, prim, mode, to_world)?;
            any_normals_missing |= !added.2;
            mesh.parts.push(Part {
                node: Some(node_index),
                mesh: mesh_index,
                primitive: pi,
                name: def.name.clone().or_else(|| node.name.clone()),
                first_vertex: added.0 .0,
                vertex_count: added.0 .1,
                first_triangle: added.1 .0,
                triangle_count: added.1 .1,
                to_world,
                skin: if skinned { node.skin } else { None },
            });
        }
    }
    if mesh.parts.is_empty() {
        return Err(if skipped_modes.is_empty() {
            MeshError::EmptyScene
        } else {
            MeshError::NoTriangles(skipped_modes)
        });
    }
    if any_normals_missing {
        // Recompute for all: mixing given and computed normals is harmless, but computing
        // them per primitive would need a second pass anyway.
        let given = std::mem::take(&mut mesh.normals);
        mesh.compute_normals();
        for (n, g) in mesh.normals.iter_mut().zip(given) {
            if g != Vec3::ZERO {
                *n = g;
            }
        }
    }
    Ok(mesh)
}

/// The inverse bind matrices of a skin (identity when the file omits them).
pub fn inverse_bind_matrices(doc: &Document, skin: usize) -> Result<Vec<Mat4>, MeshError> {
    let s = doc.root.skins.get(skin).ok_or(MeshError::IndexOutOfRange {
        what: "skin",
        index: skin as u64,
    })?;
    if s.joints.len() as u64 > MAX_JOINTS {
        return Err(MeshError::Invalid(format!(
            "skin {skin} has {} joints",
            s.joints.len()
        )));
    }
    let Some(acc) = s.inverse_bind_matrices else {
        return Ok(vec![Mat4::IDENTITY; s.joints.len()]);
    };
    let (v, comps) = doc.read_accessor(acc, MAX_JOINTS)?;
    if comps != 16 || v.len() / 16 < s.joints.len() {
        return Err(MeshError::Invalid(format!(
            "skin {skin}: inverseBindMatrices do not match its joints"
        )));
    }
    let m: Vec<Mat4> = v
        .chunks_exact(16)
        .map(|c| Mat4::from_cols_array(&std::array::from_fn(|i| c[i] as f32)))
        .collect();
    if m.iter().any(|m| !m.is_finite()) {
        return Err(MeshError::NonFinite);
    }
    Ok(m)
}

/// Most joints one skin may declare: far above any real rig, low enough to bound work.
pub const MAX_JOINTS: u64 = 4096;

/// Where a skin's bind space sits in the scene. glTF draws a skinned vertex at
/// `Σ w · jointWorld · inverseBind · v`; exporters differ in which frame they bind in
/// (several skins of one file can disagree), so the bind space is mapped to the scene
/// through the skin's root joint, which stays at rest even in files saved mid-pose.
fn skin_to_world(
    doc: &Document,
    skin: usize,
    world: &[Option<Mat4>],
    tour: &[(usize, usize)],
) -> Result<Mat4, MeshError> {
    let ibms = inverse_bind_matrices(doc, skin)?;
    let joints = &doc.root.skins[skin].joints;
    if let Some(&j) = joints.iter().find(|&&j| j >= world.len()) {
        return Err(MeshError::IndexOutOfRange {
            what: "joint node",
            index: j as u64,
        });
    }
    // The root joint is the first, in skin order, that no other joint of the skin
    // encloses. Sweeping joints in tour order finds them all in O(k log k); walking up
    // from each joint costs joints x depth (24 s for 4k joints under a 90k chain).
    let mut by_entry: Vec<usize> = (0..joints.len()).collect();
    by_entry.sort_by_key(|&k| tour[joints[k]].0);
    let mut is_root = vec![false; joints.len()];
    let mut reach = 0;
    let mut last: Option<(usize, bool)> = None;
    for &k in &by_entry {
        let j = joints[k];
        let root = match last {
            // A joint listed twice does not enclose itself.
            Some((n, r)) if n == j => r,
            _ => tour[j].0 > reach,
        };
        is_root[k] = root;
        reach = reach.max(tour[j].1);
        last = Some((j, root));
    }
    let root = is_root.iter().position(|&r| r);
    // Vertices are placed as points, so only the affine part counts: a bind matrix whose
    // last row is garbage can have a sizeable 4×4 determinant around a flat 3×3 part,
    // which would flatten the mesh and hand the export inverse bind matrices that no
    // reader, rigserve included, can invert.
    let m = root.and_then(|k| world[joints[k]].map(|w| affine(w * ibms[k])));
    Ok(match m {
        Some(m) if m.is_finite() && invertible(m) => m,
        _ => Mat4::IDENTITY,
    })
}

/// Whether the linear part of `m` is safely invertible: not vanishingly small (the
/// determinant's size, as before), and not flat: the determinant against the product of
/// the columns' lengths is 1 for a rotation with any scale and 0 for a projection, so
/// round-off in a flat matrix cannot pass for a small scale.
fn invertible(m: Mat4) -> bool {
    let l = glam::Mat3::from_mat4(m).as_dmat3();
    let lengths = l.x_axis.length() * l.y_axis.length() * l.z_axis.length();
    let det = l.determinant();
    det.abs() > 1e-20 && (det / lengths).abs() > 1e-6
}

/// The affine part of a matrix: stored positions are points, and a projective last row
/// (exporters leave 0.99999994 in it) makes inverse bind matrices invalid glTF
/// (ACCESSOR_INVALID_IBM).
pub fn affine(m: Mat4) -> Mat4 {
    let mut c = m.to_cols_array();
    c[3] = 0.0;
    c[7] = 0.0;
    c[11] = 0.0;
    c[15] = 1.0;
    Mat4::from_cols_array(&c)
}

type Range = (u32, u32);

/// Appends one primitive; returns its vertex range, triangle range, and whether it had normals.
fn add_primitive(
    doc: &Document,
    limits: &Limits,
    mesh: &mut Mesh,
    prim: &super::gltf::Primitive,
    mode: u32,
    to_world: Mat4,
) -> Result<(Range, Range, bool), MeshError> {
    let pos_acc = *prim
        .attributes
        .get("POSITION")
        .ok_or_else(|| MeshError::Invalid("a primitive has no POSITION".into()))?;
    let remaining_v = limits
        .max_vertices
        .saturating_sub(mesh.positions.len() as u64);
    let count = doc.accessor_count(pos_acc)?;
    if count > remaining_v {
        return Err(MeshError::TooManyVertices {
            count: mesh.positions.len() as u64 + count,
            cap: limits.max_vertices,
        });
    }
    doc.require_data(pos_acc)?;
    let (pos, comps) = doc.read_accessor(pos_acc, remaining_v)?;
    if comps != 3 {
        return Err(MeshError::Invalid("POSITION is not VEC3".into()));
    }
    let n = pos.len() / 3;
    let first = mesh.positions.len() as u32;
    for p in pos.chunks_exact(3) {
        let v = to_world.transform_point3(Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32));
        if !v.is_finite() {
            return Err(MeshError::NonFinite);
        }
        mesh.positions.push(v);
    }
    let normal_m = to_world.inverse().transpose();
    let has_normals = match prim.attributes.get("NORMAL") {
        Some(&acc) if doc.accessor_count(acc)? == n as u64 => {
            let (nrm, c) = doc.read_accessor(acc, n as u64)?;
            if c != 3 {
                return Err(MeshError::Invalid("NORMAL is not VEC3".into()));
            }
            for v in nrm.chunks_exact(3) {
                let v =
                    normal_m.transform_vector3(Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32));
                mesh.normals.push(if v.is_finite() {
                    v.normalize_or_zero()
                } else {
                    Vec3::ZERO
                });
            }
            true
        }
        _ => {
            mesh.normals.extend(std::iter::repeat_n(Vec3::ZERO, n));
            false
        }
    };
    let remaining_t = limits
        .max_triangles
        .saturating_sub(mesh.triangles.len() as u64);
    // A strip or fan makes a triangle per index, not per three: with the list cap, a
    // strip would expand to three times the triangle cap before the count is checked.
    let list = mode == TRIANGLES;
    let index_cap = if list {
        remaining_t.saturating_mul(3).saturating_add(2)
    } else {
        remaining_t.saturating_add(2)
    };
    let idx: Vec<u32> = match prim.indices {
        Some(acc) => {
            let c = doc.accessor_count(acc)?;
            if c > index_cap {
                return Err(MeshError::TooManyTriangles {
                    count: mesh.triangles.len() as u64
                        + if list { c / 3 } else { c.saturating_sub(2) },
                    cap: limits.max_triangles,
                });
            }
            doc.require_data(acc)?;
            let (v, comps) = doc.read_indices(acc, index_cap)?;
            if comps != 1 {
                return Err(MeshError::Invalid("indices are not SCALAR".into()));
            }
            v
        }
        None => (0..n as u32).collect(),
    };
    if let Some(&bad) = idx.iter().find(|&&i| i as usize >= n) {
        return Err(MeshError::IndexOutOfRange {
            what: "vertex index",
            index: bad as u64,
        });
    }
    let first_tri = mesh.triangles.len() as u32;
    let tris = assemble_triangles(&idx, mode);
    if tris.len() as u64 > remaining_t {
        return Err(MeshError::TooManyTriangles {
            count: mesh.triangles.len() as u64 + tris.len() as u64,
            cap: limits.max_triangles,
        });
    }
    mesh.triangles
        .extend(tris.into_iter().map(|t| t.map(|i| i + first)));
    let tri_count = mesh.triangles.len() as u32 - first_tri;
    Ok(((first, n as u32), (first_tri, tri_count), has_normals))
}

/// Expands strips and fans into a triangle list (winding kept consistent for strips).
fn assemble_triangles(idx: &[u32], mode: u32) -> Vec<[u32; 3]> {
    match mode {
        TRIANGLE_STRIP => (2..idx.len())
            .map(|i| {
                if i % 2 == 0 {
                    [idx[i - 2], idx[i - 1], idx[i]]
                } else {
                    [idx[i - 1], idx[i - 2], idx[i]]
                }
            })
            .collect(),
        TRIANGLE_FAN => (2..idx.len())
            .map(|i| [idx[0], idx[i - 1], idx[i]])
            .collect(),
        _ => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    }
}
