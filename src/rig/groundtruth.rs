//! Ground truth from a rigged glTF: the skeleton in its bind pose and the skin weights.
//!
//! Joint positions come from the inverse bind matrices, not from the node transforms:
//! nodes hold whatever pose the file was saved in, while the bind matrices say where
//! each joint was when the mesh was bound, which is the frame the vertices are in.

use super::{Bone, Skeleton, SkinWeights};
use crate::mesh::scene::inverse_bind_matrices;
use crate::mesh::{Asset, MeshError};
use glam::{Mat4, Vec3};
use std::collections::HashMap;

#[derive(Clone, Debug)]
pub struct GroundTruth {
    pub skeleton: Skeleton,
    /// Per merged vertex; vertices outside skinned primitives have no weights.
    pub weights: SkinWeights,
    /// Which merged vertices belong to skinned primitives.
    pub skinned: Vec<bool>,
    /// Skinned vertices whose weights were all zero in the file.
    pub unweighted: usize,
    /// The glTF node of each bone, for exporters that reuse the source hierarchy.
    pub nodes: Vec<usize>,
}

/// Returns `Ok(None)` for files without skinned primitives.
pub fn extract(asset: &Asset) -> Result<Option<GroundTruth>, MeshError> {
    let Some(doc) = &asset.document else {
        return Ok(None);
    };
    let mesh = &asset.mesh;
    let mut used_skins: Vec<usize> = mesh.parts.iter().filter_map(|p| p.skin).collect();
    used_skins.sort_unstable();
    used_skins.dedup();
    if used_skins.is_empty() {
        return Ok(None);
    }
    let nodes = &doc.root.nodes;
    // Joint node -> bind-pose world matrix, first skin wins when skins share joints.
    let mut bind: HashMap<usize, Mat4> = HashMap::new();
    let mut order: Vec<usize> = Vec::new();
    let mut singular: Vec<(usize, usize, usize)> = Vec::new();
    for &s in &used_skins {
        let skin = &doc.root.skins[s];
        let ibms = inverse_bind_matrices(doc, s)?;
        // The same frame the skin's vertices were placed in when the mesh was built.
        let to_world = mesh
            .parts
            .iter()
            .find(|p| p.skin == Some(s))
            .map(|p| p.to_world)
            .unwrap_or(Mat4::IDENTITY);
        for (k, &j) in skin.joints.iter().enumerate() {
            if j >= nodes.len() {
                return Err(MeshError::IndexOutOfRange {
                    what: "joint node",
                    index: j as u64,
                });
            }
            if bind.contains_key(&j) {
                continue;
            }
            let ibm = ibms[k];
            if ibm.determinant().abs() < 1e-20 {
                // A skin binding a part its node flattens (a zero scale) has singular
                // matrices that say nothing of where the joints rest; another skin over
                // the same joints (rigserve writes one per frame) may say it.
                singular.push((s, k, j));
                continue;
            }
            bind.insert(j, to_world * ibm.inverse());
            order.push(j);
        }
    }
    if let Some(&(s, k, _)) = singular.iter().find(|(_, _, j)| !bind.contains_key(j)) {
        return Err(MeshError::Invalid(format!(
            "skin {s}: joint {k} has a singular inverse bind matrix"
        )));
    }
    let mut node_parent = vec![None; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        for &c in &n.children {
            if let Some(slot) = node_parent.get_mut(c) {
                *slot = Some(i);
            }
        }
    }
    // A joint's parent bone is its nearest ancestor node that is also a joint. Memoised
    // per node, so deep hierarchies cost one visit per node rather than one per
    // (joint, ancestor) pair.
    let mut nearest_joint: Vec<Option<Option<usize>>> = vec![None; nodes.len()];
    let mut joint_parent = |j: usize| -> Option<usize> {
        let mut path = Vec::new();
        let mut cur = node_parent[j];
        let found = loop {
            match cur {
                None => break None,
                Some(p) if bind.contains_key(&p) => break Some(p),
                Some(p) => {
                    if let Some(known) = nearest_joint[p] {
                        break known;
                    }
                    // The loader refused cycles; this bound only guards a hand-built asset.
                    if path.len() > nodes.len() {
                        break None;
                    }
                    path.push(p);
                    cur = node_parent[p];
                }
            }
        };
        for p in path {
            nearest_joint[p] = Some(found);
        }
        found
    };
    let parents: HashMap<usize, Option<usize>> =
        order.iter().map(|&j| (j, joint_parent(j))).collect();
    // Parents first: depth-first from the roots, siblings in skin order.
    let mut kids: HashMap<usize, Vec<usize>> = HashMap::new();
    for &j in &order {
        if let Some(p) = parents[&j] {
            kids.entry(p).or_default().push(j);
        }
    }
    let mut sorted = Vec::with_capacity(order.len());
    let mut stack: Vec<usize> = order
        .iter()
        .rev()
        .copied()
        .filter(|j| parents[j].is_none())
        .collect();
    while let Some(j) = stack.pop() {
        sorted.push(j);
        if let Some(k) = kids.get(&j) {
            stack.extend(k.iter().rev());
        }
    }
    let bone_of: HashMap<usize, usize> = sorted.iter().enumerate().map(|(b, &j)| (j, b)).collect();
    let mut seen_names: HashMap<String, usize> = HashMap::new();
    let mut skeleton = Skeleton::default();
    for &j in &sorted {
        let base = nodes[j]
            .name
            .clone()
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| format!("joint_{j}"));
        let count = seen_names.entry(base.clone()).or_insert(0);
        let name = if *count == 0 {
            base.clone()
        } else {
            format!("{base}.{count}")
        };
        *count += 1;
        let head = bind[&j].transform_point3(Vec3::ZERO);
        skeleton.bones.push(Bone {
            name,
            parent: parents[&j].map(|p| bone_of[&p]),
            head,
            tail: head,
            spring: false,
        });
    }
    skeleton.infer_tails();

    let n = mesh.positions.len();
    let mut weights = SkinWeights {
        per_vertex: vec![Vec::new(); n],
    };
    let mut skinned = vec![false; n];
    for part in mesh.parts.iter().filter(|p| p.skin.is_some()) {
        let skin = &doc.root.skins[part.skin.unwrap_or_default()];
        let prim = &doc.root.meshes[part.mesh].primitives[part.primitive];
        let count = part.vertex_count as u64;
        for set in 0.. {
            let (Some(&ja), Some(&wa)) = (
                prim.attributes.get(&format!("JOINTS_{set}")),
                prim.attributes.get(&format!("WEIGHTS_{set}")),
            ) else {
                break;
            };
            if doc.accessor_count(ja)? != count || doc.accessor_count(wa)? != count {
                return Err(MeshError::Invalid(
                    "JOINTS/WEIGHTS count differs from POSITION".into(),
                ));
            }
            let (js, jc) = doc.read_indices(ja, count)?;
            let (ws, wc) = doc.read_accessor(wa, count)?;
            if jc != 4 || wc != 4 {
                return Err(MeshError::Invalid("JOINTS/WEIGHTS are not VEC4".into()));
            }
            for v in 0..count as usize {
                let dst = &mut weights.per_vertex[part.first_vertex as usize + v];
                for c in 0..4 {
                    let w = ws[v * 4 + c] as f32;
                    if w <= 0.0 || !w.is_finite() {
                        continue;
                    }
                    let k = js[v * 4 + c] as usize;
                    let node = *skin.joints.get(k).ok_or(MeshError::IndexOutOfRange {
                        what: "joint",
                        index: k as u64,
                    })?;
                    let b = bone_of[&node] as u32;
                    match dst.iter_mut().find(|(bb, _)| *bb == b) {
                        Some(e) => e.1 += w,
                        None => dst.push((b, w)),
                    }
                }
            }
        }
        for v in 0..count as usize {
            skinned[part.first_vertex as usize + v] = true;
        }
    }
    let total_unweighted = weights.normalize();
    let unweighted = total_unweighted - skinned.iter().filter(|s| !**s).count();
    Ok(Some(GroundTruth {
        skeleton,
        weights,
        skinned,
        unweighted,
        nodes: sorted,
    }))
}
