//! glTF inputs: the uploaded document, edited in place to carry the new skin.
//!
//! What changes, and why:
//! - All buffers become the GLB BIN chunk, each copied whole at a 16-byte aligned offset
//!   (bufferViews are re-pointed; buffer `uri`s, names and extras are dropped), so data
//!   URIs and multi-buffer files come out as one self-contained GLB.
//! - Old skins go: every node's `skin`, the `skins` array, and `JOINTS_n`/`WEIGHTS_n` of
//!   every primitive (with no skin left they mean nothing, and stale joint indices into
//!   the new skin would be wrong). Animations with a channel on a joint of an old skin
//!   are removed, since they animated a skeleton that no longer deforms anything; other
//!   animations (props, morph weights) stay. Accessors left unused by these removals
//!   lose their data (see `empty_accessors`); their bytes stay in the BIN chunk, as every
//!   bufferView does. The old joint nodes themselves stay, as
//!   plain nodes, because rigid children and extensions such as VRM's humanoid map
//!   point at them by index.
//! - The new joints are appended as nodes and listed as roots of every scene that shows
//!   a re-skinned mesh (the default scene always).
//! - Each node that instances a triangle primitive gets a skin whose bind matrices fit
//!   the frame its stored positions are in; nodes sharing a frame share a skin. A mesh
//!   used by more than one node is duplicated, because `JOINTS_0`/`WEIGHTS_0` live on
//!   the primitive while weights are per instance.
//! - Points and lines primitives (not part of the merged mesh) are left as they were.
//! - With `animation=preview`, the preview clip is appended to `animations` (see
//!   [`super::animation`]); the input's remaining animations stay beside it.
//! - The bone tree goes into the default scene's `extras.rigserve` (an `extras` that is
//!   not an object is kept under `extras.original`); `asset.generator` becomes
//!   "rigserve". Everything else, unknown fields included, is copied untouched.

use super::builder::{affine, Builder};
use super::weights::Packed;
use super::{animation, bonetree, Animation, ExportError, ExportOptions};
use crate::mesh::gltf::Document;
use crate::mesh::{Mesh, Part};
use crate::rig::Skeleton;
use serde_json::{json, Map, Value};
use std::collections::{BTreeMap, HashMap, HashSet};

fn doc_err(msg: impl Into<String>) -> ExportError {
    ExportError::Document(msg.into())
}

fn objects_mut<'a>(
    root: &'a mut Map<String, Value>,
    key: &str,
) -> Result<Vec<&'a mut Map<String, Value>>, ExportError> {
    match root.get_mut(key) {
        None => Ok(Vec::new()),
        Some(Value::Array(a)) => a
            .iter_mut()
            .enumerate()
            .map(|(i, v)| {
                v.as_object_mut()
                    .ok_or_else(|| doc_err(format!("{key}[{i}] is not an object")))
            })
            .collect(),
        Some(_) => Err(doc_err(format!("{key:?} is not an array"))),
    }
}

/// `root[key][i]` as an object.
fn object_at<'a>(
    root: &'a mut Map<String, Value>,
    key: &str,
    i: usize,
) -> Result<&'a mut Map<String, Value>, ExportError> {
    root.get_mut(key)
        .and_then(Value::as_array_mut)
        .and_then(|a| a.get_mut(i))
        .and_then(Value::as_object_mut)
        .ok_or_else(|| doc_err(format!("{key}[{i}] is missing or not an object")))
}

fn index(v: Option<&Value>) -> Option<usize> {
    v.and_then(Value::as_u64).map(|i| i as usize)
}

pub(crate) fn rewrite(
    doc: &Document,
    mesh: &Mesh,
    skel: &Skeleton,
    packed: &[Packed],
    opts: &ExportOptions,
) -> Result<Builder, ExportError> {
    let mut root = doc
        .json
        .as_object()
        .cloned()
        .ok_or_else(|| doc_err("the top level is not an object"))?;
    let bin = merge_buffers(doc, &mut root)?;
    remove_old_skins(doc, &mut root)?;

    let by_node = parts_by_node(mesh, &root)?;
    let node_mesh = give_instances_own_meshes(&mut root, &by_node)?;
    let original_nodes = objects_mut(&mut root, "nodes")?.len();

    let mut b = Builder::new(root, bin);
    let joints = b.push_joint_nodes(skel)?;
    // Keyed by the matrix's bits: parts of one frame carry bit-identical matrices.
    let mut frames: HashMap<[u32; 16], usize> = HashMap::new();
    for (&node, parts) in &by_node {
        let frame = affine(parts[0].to_world);
        let key = frame.to_cols_array().map(f32::to_bits);
        let skin = match frames.get(&key) {
            Some(&s) => s,
            None => {
                let s = b.push_skin(skel, &joints, &frame)?;
                frames.insert(key, s);
                s
            }
        };
        object_at(&mut b.root, "nodes", node)?.insert("skin".into(), skin.into());
        let m = node_mesh[&node];
        for part in parts {
            let first = part.first_vertex as usize;
            let range = first..first + part.vertex_count as usize;
            let slice = packed
                .get(range)
                .ok_or_else(|| doc_err("a part's vertex range lies outside the mesh"))?;
            let (j, w) = b.push_skin_attributes(slice, skel.len())?;
            let attrs = object_at(&mut b.root, "meshes", m)?
                .get_mut("primitives")
                .and_then(Value::as_array_mut)
                .and_then(|p| p.get_mut(part.primitive))
                .and_then(|p| p.get_mut("attributes"))
                .and_then(Value::as_object_mut)
                .ok_or_else(|| {
                    doc_err(format!(
                        "mesh {m} has no primitive {} with attributes",
                        part.primitive
                    ))
                })?;
            attrs.insert("JOINTS_0".into(), j.into());
            attrs.insert("WEIGHTS_0".into(), w.into());
        }
    }

    if opts.animation == Animation::Preview {
        animation::push_preview(&mut b, skel, &joints)?;
    }

    let reskinned: HashSet<usize> = by_node.keys().copied().collect();
    let scene =
        place_joints_in_scenes(&mut b.root, original_nodes, &joints.scene_roots, &reskinned)?;
    if opts.embed_bone_tree {
        let s = object_at(&mut b.root, "scenes", scene)?;
        let extras = s.entry("extras").or_insert_with(|| json!({}));
        if !extras.is_object() {
            *extras = json!({"original": extras.take()});
        }
        extras["rigserve"] = bonetree::bone_tree(skel);
    }
    let asset = b
        .root
        .entry("asset")
        .or_insert_with(|| json!({"version": "2.0"}));
    if let Some(a) = asset.as_object_mut() {
        a.insert("generator".into(), "rigserve".into());
    }
    b.set_buffer();
    Ok(b)
}

/// Concatenates every buffer into the BIN chunk and re-points the bufferViews at it.
fn merge_buffers(doc: &Document, root: &mut Map<String, Value>) -> Result<Vec<u8>, ExportError> {
    let mut bin = Vec::with_capacity(doc.buffers.iter().map(|b| b.len() + 15).sum());
    let mut offsets = Vec::with_capacity(doc.buffers.len());
    for buf in &doc.buffers {
        // 16 keeps every original offset's alignment (at most a MAT4 column needs 16).
        bin.resize(bin.len().next_multiple_of(16), 0);
        offsets.push(bin.len() as u64);
        bin.extend_from_slice(buf);
    }
    for (i, view) in objects_mut(root, "bufferViews")?.into_iter().enumerate() {
        let buffer = index(view.get("buffer"))
            .ok_or_else(|| doc_err(format!("bufferView {i} has no buffer")))?;
        let base = *offsets
            .get(buffer)
            .ok_or_else(|| doc_err(format!("bufferView {i} names a missing buffer {buffer}")))?;
        let offset = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0);
        view.insert("buffer".into(), 0.into());
        view.insert("byteOffset".into(), (base + offset).into());
    }
    root.remove("buffers");
    Ok(bin)
}

fn remove_old_skins(doc: &Document, root: &mut Map<String, Value>) -> Result<(), ExportError> {
    let old_joints: HashSet<usize> = doc
        .root
        .skins
        .iter()
        .flat_map(|s| s.joints.iter().copied())
        .collect();
    // Accessors that held only what is removed here; see `empty_accessors`.
    let mut dropped: HashSet<usize> = doc
        .root
        .skins
        .iter()
        .filter_map(|s| s.inverse_bind_matrices)
        .collect();
    root.remove("skins");
    for node in objects_mut(root, "nodes")? {
        node.remove("skin");
    }
    for m in objects_mut(root, "meshes")? {
        let Some(prims) = m.get_mut("primitives").and_then(Value::as_array_mut) else {
            continue;
        };
        for attrs in prims
            .iter_mut()
            .filter_map(|p| p.get_mut("attributes").and_then(Value::as_object_mut))
        {
            attrs.retain(|k, v| {
                let skinning = k.starts_with("JOINTS_") || k.starts_with("WEIGHTS_");
                if skinning {
                    dropped.extend(index(Some(v)));
                }
                !skinning
            });
        }
    }
    if let Some(Value::Array(anims)) = root.get_mut("animations") {
        anims.retain(|a| {
            let channels = a.get("channels").and_then(Value::as_array);
            let on_old_joint = channels.into_iter().flatten().any(|c| {
                index(c.get("target").and_then(|t| t.get("node")))
                    .is_some_and(|n| old_joints.contains(&n))
            });
            if on_old_joint {
                let samplers = a.get("samplers").and_then(Value::as_array);
                for s in samplers.into_iter().flatten() {
                    dropped.extend(index(s.get("input")));
                    dropped.extend(index(s.get("output")));
                }
            }
            !on_old_joint
        });
        if anims.is_empty() {
            root.remove("animations");
        }
    }
    let live = referenced_accessors(root);
    empty_accessors(root, dropped.difference(&live).copied())
}

/// Accessors the document still refers to, through every core property that names one
/// and EXT_mesh_gpu_instancing (the one common extension that does).
fn referenced_accessors(root: &Map<String, Value>) -> HashSet<usize> {
    let mut out = HashSet::new();
    let list = |key: &str| {
        root.get(key)
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
    };
    let values = |v: Option<&Value>| {
        v.and_then(Value::as_object)
            .into_iter()
            .flat_map(|o| o.values())
            .filter_map(|x| index(Some(x)))
            .collect::<Vec<_>>()
    };
    for m in list("meshes") {
        for p in m
            .get("primitives")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            out.extend(values(p.get("attributes")));
            out.extend(index(p.get("indices")));
            for t in p
                .get("targets")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
            {
                out.extend(values(Some(t)));
            }
        }
    }
    for s in list("skins") {
        out.extend(index(s.get("inverseBindMatrices")));
    }
    for a in list("animations") {
        for s in a
            .get("samplers")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            out.extend(index(s.get("input")));
            out.extend(index(s.get("output")));
        }
    }
    for n in list("nodes") {
        let inst = n
            .get("extensions")
            .and_then(|e| e.get("EXT_mesh_gpu_instancing"))
            .and_then(|e| e.get("attributes"));
        out.extend(values(inst));
    }
    out
}

/// Turns accessors nothing uses any more into data-less ones (glTF reads them as zeros).
/// Deleting them would renumber every later accessor and break references we cannot
/// see (unknown extensions); leaving them would keep validating data the export no
/// longer uses, such as the NaN weights some exporters write.
fn empty_accessors(
    root: &mut Map<String, Value>,
    unused: impl Iterator<Item = usize>,
) -> Result<(), ExportError> {
    let mut accessors = objects_mut(root, "accessors")?;
    for a in unused {
        if let Some(acc) = accessors.get_mut(a) {
            for key in ["bufferView", "byteOffset", "sparse", "min", "max"] {
                acc.remove(key);
            }
        }
    }
    Ok(())
}

/// Parts grouped by the node that instances them, checked against the document.
fn parts_by_node<'m>(
    mesh: &'m Mesh,
    root: &Map<String, Value>,
) -> Result<BTreeMap<usize, Vec<&'m Part>>, ExportError> {
    let nodes = root.get("nodes").and_then(Value::as_array);
    let mut by_node: BTreeMap<usize, Vec<&Part>> = BTreeMap::new();
    for part in &mesh.parts {
        let node = part
            .node
            .ok_or_else(|| doc_err("a glTF part has no node"))?;
        let node_mesh = nodes
            .and_then(|n| n.get(node))
            .and_then(|n| index(n.get("mesh")));
        if node_mesh != Some(part.mesh) {
            return Err(doc_err(format!(
                "node {node} does not instance mesh {}",
                part.mesh
            )));
        }
        by_node.entry(node).or_default().push(part);
    }
    for (node, parts) in &by_node {
        let frame = affine(parts[0].to_world);
        if parts.iter().any(|p| affine(p.to_world) != frame) {
            // Only a node with a skin whose mesh mixes skinned and unskinned triangle
            // primitives gets here: one skin cannot bind both frames without rewriting
            // positions, and glTF leaves such a mix undefined anyway.
            return Err(ExportError::Unsupported(format!(
                "node {node} mixes skinned and unskinned primitives"
            )));
        }
    }
    Ok(by_node)
}

/// The mesh each re-skinned node will use. A mesh keeps its index for its first
/// re-skinned user only when every node that uses it is re-skinned; every other
/// re-skinned user gets a copy, so no two instances (or an unskinned one) share the
/// per-primitive `JOINTS_0`/`WEIGHTS_0`.
fn give_instances_own_meshes(
    root: &mut Map<String, Value>,
    by_node: &BTreeMap<usize, Vec<&Part>>,
) -> Result<HashMap<usize, usize>, ExportError> {
    let mut users: HashMap<usize, Vec<usize>> = HashMap::new();
    for (i, n) in objects_mut(root, "nodes")?.into_iter().enumerate() {
        if let Some(m) = index(n.get("mesh")) {
            users.entry(m).or_default().push(i);
        }
    }
    let mut node_mesh = HashMap::new();
    let mut kept: HashSet<usize> = HashSet::new();
    for (&node, parts) in by_node {
        let m = parts[0].mesh;
        let all_reskinned = users
            .get(&m)
            .is_some_and(|u| u.iter().all(|n| by_node.contains_key(n)));
        let target = if all_reskinned && kept.insert(m) {
            m
        } else {
            let meshes = root
                .get_mut("meshes")
                .and_then(Value::as_array_mut)
                .ok_or_else(|| doc_err("\"meshes\" is not an array"))?;
            let copy = meshes
                .get(m)
                .cloned()
                .ok_or_else(|| doc_err(format!("mesh {m} does not exist")))?;
            meshes.push(copy);
            let new = meshes.len() - 1;
            object_at(root, "nodes", node)?.insert("mesh".into(), new.into());
            new
        };
        node_mesh.insert(node, target);
    }
    Ok(node_mesh)
}

/// Lists the joint roots in the default scene and in every scene showing a re-skinned
/// node (the validator's NODE_SKIN_NO_SCENE); returns the default scene's index.
fn place_joints_in_scenes(
    root: &mut Map<String, Value>,
    original_nodes: usize,
    joint_roots: &[usize],
    reskinned: &HashSet<usize>,
) -> Result<usize, ExportError> {
    let children: Vec<Vec<usize>> = objects_mut(root, "nodes")?
        .iter()
        .map(|n| {
            n.get("children")
                .and_then(Value::as_array)
                .map(|c| c.iter().filter_map(|v| index(Some(v))).collect())
                .unwrap_or_default()
        })
        .collect();
    let mut has_parent = vec![false; children.len()];
    for &c in children.iter().flatten() {
        if let Some(h) = has_parent.get_mut(c) {
            *h = true;
        }
    }
    let no_scenes = root
        .get("scenes")
        .and_then(Value::as_array)
        .is_none_or(|s| s.is_empty());
    if no_scenes {
        // The loader (and most viewers) show every parentless node of a scene-less file;
        // an explicit scene with the same roots keeps that.
        let roots: Vec<usize> = (0..original_nodes).filter(|&i| !has_parent[i]).collect();
        root.insert("scenes".into(), json!([{ "nodes": roots }]));
    }
    let shows = subtree_contains(&children, &has_parent, reskinned);
    let default = index(root.get("scene")).unwrap_or(0);
    root.insert("scene".into(), default.into());
    for (si, scene) in objects_mut(root, "scenes")?.into_iter().enumerate() {
        let nodes = scene
            .entry("nodes")
            .or_insert_with(|| json!([]))
            .as_array_mut()
            .ok_or_else(|| doc_err(format!("scene {si}: nodes is not an array")))?;
        let shows_reskinned = nodes
            .iter()
            .any(|n| index(Some(n)).is_some_and(|n| shows.get(n).copied().unwrap_or(false)));
        if si == default || shows_reskinned {
            nodes.extend(joint_roots.iter().map(|&r| Value::from(r)));
        }
    }
    Ok(default)
}

/// Per node, whether it or a descendant is in `marked`. The loader has already refused
/// cycles and nodes with two parents, so the nodes form a forest and one post-order
/// pass from the parentless ones covers them all (however many scenes list them).
fn subtree_contains(
    children: &[Vec<usize>],
    has_parent: &[bool],
    marked: &HashSet<usize>,
) -> Vec<bool> {
    let n = children.len();
    let mut out = vec![false; n];
    let mut stack: Vec<(usize, bool)> = (0..n)
        .filter(|&i| !has_parent[i])
        .map(|i| (i, false))
        .collect();
    while let Some((i, done)) = stack.pop() {
        if done {
            out[i] = marked.contains(&i)
                || children[i]
                    .iter()
                    .any(|&c| out.get(c).copied().unwrap_or(false));
        } else {
            stack.push((i, true));
            stack.extend(children[i].iter().filter(|&&c| c < n).map(|&c| (c, false)));
        }
    }
    out
}
