//! Inputs without a glTF document (OBJ, PLY, STL): a new glTF holding the merged mesh.
//!
//! One node, one mesh, one primitive with POSITION, NORMAL and indices exactly as
//! [`Mesh`] holds them (world space, so the skin binds with `to_world` = identity), PLY
//! vertex colours as `COLOR_0`, and a plain material (white where colours tint it, grey
//! otherwise). OBJ UVs and materials are not kept: [`Mesh`] does not carry them.

use super::builder::{Builder, ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, FLOAT, UNSIGNED_INT};
use super::weights::Packed;
use super::{animation, bonetree, Animation, ExportError, ExportOptions};
use crate::mesh::Mesh;
use crate::rig::Skeleton;
use glam::{Mat4, Vec3};
use serde_json::{json, Map, Value};

pub(crate) fn build(
    mesh: &Mesh,
    colors: &[[f32; 4]],
    skel: &Skeleton,
    packed: &[Packed],
    opts: &ExportOptions,
) -> Result<Builder, ExportError> {
    let root: Map<String, Value> = json!({
        "asset": {"version": "2.0", "generator": "rigserve"},
        "materials": [{
            "name": "default",
            "pbrMetallicRoughness": {
                // COLOR_0 multiplies the base colour, so coloured meshes get white.
                "baseColorFactor": if colors.is_empty() { [0.8, 0.8, 0.8, 1.0] } else { [1.0; 4] },
                "metallicFactor": 0.0,
                "roughnessFactor": 0.8
            }
        }],
    })
    .as_object()
    .cloned()
    .unwrap_or_default();
    let mut b = Builder::new(root, Vec::new());
    let n = mesh.positions.len();

    let (lo, hi) = mesh.bounds();
    let pos_bytes: Vec<u8> = mesh
        .positions
        .iter()
        .flat_map(|p| p.to_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    let pos = b.push_accessor(&pos_bytes, Some(ARRAY_BUFFER), FLOAT, n, "VEC3")?;
    // POSITION must declare bounds; they are the exact f32 extremes of the data.
    let acc = &mut b.array("accessors")?[pos];
    acc["min"] = json!(lo.to_array());
    acc["max"] = json!(hi.to_array());

    let mut attributes = json!({"POSITION": pos});
    if mesh.normals.len() == n {
        // The validator rejects non-unit normals; a vertex without a usable normal (one
        // on degenerate faces only) gets +Y, which shading barely notices.
        let nrm_bytes: Vec<u8> = mesh
            .normals
            .iter()
            .map(|v| {
                let u = v.normalize_or_zero();
                if u == Vec3::ZERO {
                    Vec3::Y
                } else {
                    u
                }
            })
            .flat_map(|v| v.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        attributes["NORMAL"] = b
            .push_accessor(&nrm_bytes, Some(ARRAY_BUFFER), FLOAT, n, "VEC3")?
            .into();
    }
    if colors.len() == n {
        let bytes: Vec<u8> = colors
            .iter()
            .flatten()
            .flat_map(|c| c.to_le_bytes())
            .collect();
        attributes["COLOR_0"] = b
            .push_accessor(&bytes, Some(ARRAY_BUFFER), FLOAT, n, "VEC4")?
            .into();
    }
    let (j, w) = b.push_skin_attributes(packed, skel.len())?;
    attributes["JOINTS_0"] = j.into();
    attributes["WEIGHTS_0"] = w.into();

    let idx_bytes: Vec<u8> = mesh
        .triangles
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let indices = b.push_accessor(
        &idx_bytes,
        Some(ELEMENT_ARRAY_BUFFER),
        UNSIGNED_INT,
        mesh.triangles.len() * 3,
        "SCALAR",
    )?;
    b.push(
        "meshes",
        json!({
            "name": "mesh",
            "primitives": [{"attributes": attributes, "indices": indices, "material": 0, "mode": 4}]
        }),
    )?;
    let mesh_node = b.push("nodes", json!({"name": "mesh", "mesh": 0}))?;
    let joints = b.push_joint_nodes(skel)?;
    let skin = b.push_skin(skel, &joints, &Mat4::IDENTITY)?;
    b.array("nodes")?[mesh_node]["skin"] = skin.into();
    if opts.animation == Animation::Preview {
        animation::push_preview(&mut b, skel, &joints)?;
    }

    let mut scene_nodes = vec![mesh_node];
    scene_nodes.extend(&joints.scene_roots);
    let mut scene = json!({"nodes": scene_nodes});
    if opts.embed_bone_tree {
        scene["extras"] = json!({"rigserve": bonetree::bone_tree(skel)});
    }
    b.push("scenes", scene)?;
    b.root.insert("scene".into(), 0.into());
    b.set_buffer();
    Ok(b)
}
