//! GLB export, checked from the outside: rigserve's own loader must read back the rig it
//! wrote, the Khronos glTF validator must find no error, and Blender must deform the
//! mesh the way rigserve's linear blend skinning says.
mod common;

use base64::Engine;
use glam::{Mat4, Quat, Vec3};
use rigserve::export::{export_glb, parse_bone_tree, ExportOptions};
use rigserve::mesh::scene::world_matrices;
use rigserve::mesh::{load, Asset, Limits};
use rigserve::rig::groundtruth::extract;
use rigserve::rig::metrics::{lbs, pose_one_bone};
use rigserve::rig::{Bone, Skeleton, SkinWeights};
use serde_json::{json, Value};
use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::process::Command;

use common::{errors_of, tools_dir, validate};

// ---------------------------------------------------------------------------------------
// Round-trip checks shared by the synthetic and the data-set tests.

/// Largest errors seen in one round trip, for the printed summaries.
#[derive(Default, Debug, Clone, Copy)]
struct RoundTrip {
    head: f32,
    weight: f32,
    weight_sum: f64,
    rest: f32,
    fallback: usize,
}

/// Distance from `p` to the segment a–b.
fn segment_distance(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 {
        ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + ab * t)
}

fn mesh_size(asset: &Asset) -> f32 {
    let (lo, hi) = asset.mesh.bounds();
    (hi - lo).length().max(1.0)
}

fn bone_tree_of(doc_json: &Value) -> &Value {
    let scene = doc_json["scene"].as_u64().unwrap_or(0) as usize;
    &doc_json["scenes"][scene]["extras"]["rigserve"]
}

/// Where glTF's skinning rules put every merged vertex of `asset` at rest:
/// `Σ w · jointWorld · inverseBind · v` per joint, read straight from the file, so every
/// bind matrix is checked (rigserve's loader only uses the root joint's). Also checks
/// the stored influences themselves: unused slots are joint 0, no joint repeats, and
/// returns the largest |Σ weights − 1| over the stored f32 values.
fn rest_by_gltf_rules(asset: &Asset) -> (Vec<Vec3>, f64) {
    let doc = asset.document.as_ref().expect("a glTF document");
    let (world, _) = world_matrices(doc, &Limits::default()).unwrap();
    let mut out = vec![Vec3::NAN; asset.mesh.positions.len()];
    let mut sum_error = 0f64;
    for part in &asset.mesh.parts {
        let node = &doc.root.nodes[part.node.unwrap()];
        let skin = &doc.root.skins[node.skin.expect("every mesh node is skinned")];
        let prim = &doc.root.meshes[part.mesh].primitives[part.primitive];
        let n = part.vertex_count as u64;
        let (pos, _) = doc.read_accessor(prim.attributes["POSITION"], n).unwrap();
        let (js, _) = doc.read_indices(prim.attributes["JOINTS_0"], n).unwrap();
        let (ws, _) = doc.read_accessor(prim.attributes["WEIGHTS_0"], n).unwrap();
        let (ibm, _) = doc
            .read_accessor(skin.inverse_bind_matrices.unwrap(), 10_000)
            .unwrap();
        let joint_m: Vec<Mat4> = skin
            .joints
            .iter()
            .enumerate()
            .map(|(k, &j)| {
                let m = Mat4::from_cols_array(&std::array::from_fn(|i| ibm[k * 16 + i] as f32));
                world[j].unwrap() * m
            })
            .collect();
        for v in 0..n as usize {
            let p = Vec3::new(
                pos[v * 3] as f32,
                pos[v * 3 + 1] as f32,
                pos[v * 3 + 2] as f32,
            );
            let mut acc = Vec3::ZERO;
            let mut seen = Vec::new();
            for c in 0..4 {
                let (w, j) = (ws[v * 4 + c] as f32, js[v * 4 + c]);
                if w != 0.0 {
                    assert!(!seen.contains(&j), "vertex {v}: joint {j} twice");
                    seen.push(j);
                    acc += joint_m[j as usize].transform_point3(p) * w;
                } else {
                    assert_eq!(j, 0, "vertex {v}: an unused slot names joint {j}");
                }
            }
            let sum: f64 = ws[v * 4..v * 4 + 4].iter().sum();
            sum_error = sum_error.max((sum - 1.0).abs());
            out[part.first_vertex as usize + v] = acc;
        }
    }
    (out, sum_error)
}

/// Re-loads `glb` and checks it against what was exported: the same merged mesh, the same
/// skeleton (heads within 1e-5 of the mesh size, names, parents), the same weights (within
/// 1e-6; vertices exported without weights carry weight 1 on a nearest bone segment), the
/// bone tree in the scene's extras, and a rest pose where the input had it.
fn check_round_trip(
    label: &str,
    input: &Asset,
    skel: &Skeleton,
    weights: &SkinWeights,
    glb: &[u8],
) -> (Asset, RoundTrip) {
    let out = load(glb, &Limits::default()).unwrap_or_else(|e| panic!("{label}: reload: {e}"));
    let size = mesh_size(input);
    let mut rt = RoundTrip::default();

    assert_eq!(
        out.mesh.positions.len(),
        input.mesh.positions.len(),
        "{label}"
    );
    assert_eq!(out.mesh.triangles, input.mesh.triangles, "{label}");
    let (by_rules, sum_error) = rest_by_gltf_rules(&out);
    for (i, (a, b)) in input
        .mesh
        .positions
        .iter()
        .zip(&out.mesh.positions)
        .enumerate()
    {
        rt.rest = rt.rest.max(a.distance(*b)).max(a.distance(by_rules[i]));
    }
    assert!(
        rt.rest <= 1e-5 * size,
        "{label}: rest pose moved by {}",
        rt.rest
    );
    // The exporter gives the f32 rounding to the largest weight, so the exact sum of the
    // stored values is 1 within half an f32 ulp below 1 (2⁻²⁵); rounding every weight on
    // its own lands up to about twice that away.
    rt.weight_sum = sum_error;
    let half_ulp = 0.5f64.powi(25) + 1e-12;
    assert!(
        sum_error <= half_ulp,
        "{label}: stored weights sum to 1 ± {sum_error}"
    );

    let gt = extract(&out)
        .unwrap_or_else(|e| panic!("{label}: extract: {e}"))
        .unwrap_or_else(|| panic!("{label}: the export has no skin"));
    assert_eq!(gt.skeleton.len(), skel.len(), "{label}");
    for (a, b) in skel.bones.iter().zip(&gt.skeleton.bones) {
        assert_eq!(a.name, b.name, "{label}");
        assert_eq!(a.parent, b.parent, "{label}: parent of {}", a.name);
        rt.head = rt.head.max(a.head.distance(b.head));
    }
    assert!(
        rt.head <= 1e-5 * size,
        "{label}: heads moved by {}",
        rt.head
    );

    for (v, (want, got)) in weights
        .per_vertex
        .iter()
        .zip(&gt.weights.per_vertex)
        .enumerate()
    {
        if want.is_empty() {
            rt.fallback += 1;
            let p = input.mesh.positions[v];
            let best = skel
                .bones
                .iter()
                .map(|b| segment_distance(p, b.head, b.tail))
                .fold(f32::INFINITY, f32::min);
            assert_eq!(got.len(), 1, "{label}: vertex {v}: {got:?}");
            let b = &skel.bones[got[0].0 as usize];
            assert!(
                segment_distance(p, b.head, b.tail) <= best + 1e-6 * size,
                "{label}: vertex {v} bound to {} which is not the nearest bone",
                b.name
            );
            rt.weight = rt.weight.max((got[0].1 - 1.0).abs());
            continue;
        }
        let mut a = want.clone();
        let mut b = got.clone();
        a.sort_by_key(|e| e.0);
        b.sort_by_key(|e| e.0);
        let bones = |l: &[(u32, f32)]| l.iter().map(|e| e.0).collect::<Vec<_>>();
        assert_eq!(bones(&a), bones(&b), "{label}: vertex {v}");
        for (x, y) in a.iter().zip(&b) {
            rt.weight = rt.weight.max((x.1 - y.1).abs());
        }
    }
    assert!(
        rt.weight <= 1e-6,
        "{label}: weights differ by {}",
        rt.weight
    );

    let tree = bone_tree_of(&out.document.as_ref().unwrap().json);
    let parsed = parse_bone_tree(tree).unwrap_or_else(|e| panic!("{label}: bone tree: {e}"));
    assert_eq!(
        &parsed, skel,
        "{label}: the bone tree is not the exported skeleton"
    );
    (out, rt)
}

// ---------------------------------------------------------------------------------------
// External tools.

fn blender_available() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import bpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!("SKIPPED: Blender as a Python module (`import bpy`) is not available");
    }
    ok
}

// ---------------------------------------------------------------------------------------
// Synthetic inputs.

/// A capped-free cylinder along +Y as OBJ text: `rings` rings of `segments` vertices.
fn cylinder_obj(rings: usize, segments: usize, height: f32) -> String {
    let mut s = String::from("# test cylinder\no tube\n");
    for r in 0..rings {
        let y = height * r as f32 / (rings - 1) as f32;
        for k in 0..segments {
            let a = std::f32::consts::TAU * k as f32 / segments as f32;
            s += &format!("v {} {} {}\n", 0.3 * a.cos(), y, 0.3 * a.sin());
        }
    }
    for r in 0..rings - 1 {
        for k in 0..segments {
            let a = r * segments + k + 1;
            let b = r * segments + (k + 1) % segments + 1;
            let (c, d) = (a + segments, b + segments);
            s += &format!("f {a} {b} {d} {c}\n");
        }
    }
    s
}

fn bone(name: &str, parent: Option<usize>, head: [f32; 3], tail: [f32; 3]) -> Bone {
    Bone::new(name, parent, head.into(), tail.into())
}

/// Smooth weights by distance to each bone's segment, negligible ones dropped and the
/// four largest kept, as inference produces them; a vertex far from every bone goes
/// fully to the nearest.
fn distance_weights(skel: &Skeleton, positions: &[Vec3], scale: f32) -> SkinWeights {
    let mut w = SkinWeights {
        per_vertex: positions
            .iter()
            .map(|&p| {
                let d: Vec<f32> = skel
                    .bones
                    .iter()
                    .map(|b| segment_distance(p, b.head, b.tail) / scale)
                    .collect();
                let mut list: Vec<(u32, f32)> = d
                    .iter()
                    .enumerate()
                    .map(|(i, d)| (i as u32, (-d * d * 8.0).exp()))
                    .filter(|e| e.1 > 1e-3)
                    .collect();
                if list.is_empty() {
                    let nearest = (0..d.len()).min_by(|&a, &b| d[a].total_cmp(&d[b])).unwrap();
                    list.push((nearest as u32, 1.0));
                }
                list
            })
            .collect(),
    };
    w.top_k(4);
    w
}

/// A tube with a two-root skeleton (the exporter must give the joints a common root for
/// the validator) and two unweighted vertices: one near the antenna, away from the
/// chain's bones, and one at the bottom.
fn obj_case() -> (Asset, Skeleton, SkinWeights, usize) {
    let input = load(cylinder_obj(9, 12, 2.0).as_bytes(), &Limits::default()).unwrap();
    assert!(input.document.is_none());
    let mut skel = Skeleton {
        bones: vec![
            bone("root", None, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            bone("mid", Some(0), [0.0, 1.0, 0.0], [0.0, 1.8, 0.0]),
            bone("tip", Some(1), [0.0, 1.8, 0.0], [0.0, 2.2, 0.0]),
            bone("antenna", None, [0.5, 1.5, 0.0], [0.9, 1.9, 0.0]),
        ],
        template: None,
        category: Some("robot_prop".into()),
    };
    skel.bones[3].spring = true;
    let mut weights = distance_weights(&skel, &input.mesh.positions, 1.0);
    let near_antenna = input
        .mesh
        .positions
        .iter()
        .enumerate()
        .min_by(|a, b| {
            let d = |p: &Vec3| p.distance(Vec3::new(0.5, 1.5, 0.0));
            d(a.1).total_cmp(&d(b.1))
        })
        .unwrap()
        .0;
    weights.per_vertex[near_antenna].clear();
    weights.per_vertex[0].clear();
    (input, skel, weights, near_antenna)
}

#[test]
fn obj_exports_as_a_fresh_skinned_gltf() {
    let (input, skel, weights, near_antenna) = obj_case();
    let glb = export_glb(&input, &skel, &weights, &ExportOptions::default()).unwrap();
    let (out, rt) = check_round_trip("obj", &input, &skel, &weights, &glb);
    assert_eq!(rt.fallback, 2);
    let json = &out.document.as_ref().unwrap().json;
    assert_eq!(json["asset"]["generator"], "rigserve");
    assert_eq!(json["skins"].as_array().unwrap().len(), 1);
    assert_eq!(json["materials"].as_array().unwrap().len(), 1);
    let prim = &json["meshes"][0]["primitives"][0];
    assert_eq!(prim["material"], 0);
    assert!(prim["attributes"]["NORMAL"].is_u64());
    let gt = extract(&out).unwrap().unwrap();
    assert_eq!(gt.weights.per_vertex[near_antenna], vec![(3, 1.0)]);

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tube.glb");
    std::fs::write(&path, &glb).unwrap();
    if let Some(reports) = validate(&[path]) {
        assert!(errors_of(&reports).is_empty(), "{reports:#?}");
    }
}

/// A small GLB exercising what export must keep or replace: two buffers (one a data URI),
/// a textured mesh instanced by two nodes, a mesh skinned to an old skeleton whose frame
/// is not the identity, a points primitive, animations on an old joint and on a prop,
/// extras, an unknown extension and an unknown top-level field.
struct SyntheticGlb {
    bytes: Vec<u8>,
    png: Vec<u8>,
}

const PNG_1X1: &str =
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg==";

fn synthetic_glb() -> SyntheticGlb {
    let png = base64::engine::general_purpose::STANDARD
        .decode(PNG_1X1)
        .unwrap();
    let mut bin: Vec<u8> = Vec::new();
    let mut views: Vec<Value> = Vec::new();
    let mut accessors: Vec<Value> = Vec::new();
    let mut view = |views: &mut Vec<Value>, bytes: &[u8], target: Option<u32>| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = t.into();
        }
        bin.extend_from_slice(bytes);
        views.push(v);
        views.len() - 1
    };
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let acc = |accessors: &mut Vec<Value>, a: Value| {
        accessors.push(a);
        accessors.len() - 1
    };

    // Mesh 0: a 4×4 grid in the XZ plane with normals, UVs and indices.
    let (mut pos, mut nrm, mut uv) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..4 {
        for j in 0..4 {
            pos.extend([i as f32 * 0.2, 0.0, j as f32 * 0.2]);
            nrm.extend([0.0, 1.0, 0.0]);
            uv.extend([i as f32 / 3.0, j as f32 / 3.0]);
        }
    }
    let mut idx: Vec<u16> = Vec::new();
    for i in 0..3u16 {
        for j in 0..3u16 {
            let a = i * 4 + j;
            idx.extend([a, a + 1, a + 4, a + 1, a + 5, a + 4]);
        }
    }
    let v = view(&mut views, &f32s(&pos), Some(34962));
    let grid_pos = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 16, "type": "VEC3",
               "min": [0.0, 0.0, 0.0], "max": [0.6000000238418579, 0.0, 0.6000000238418579]}),
    );
    let v = view(&mut views, &f32s(&nrm), Some(34962));
    let grid_nrm = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 16, "type": "VEC3"}),
    );
    let idx_bytes: Vec<u8> = idx.iter().flat_map(|x| x.to_le_bytes()).collect();
    let v = view(&mut views, &idx_bytes, Some(34963));
    let grid_idx = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5123, "count": idx.len(), "type": "SCALAR"}),
    );
    // The UVs live in a second buffer, a data URI, so export must merge buffers.
    let uv_bytes = f32s(&uv);
    views
        .push(json!({"buffer": 1, "byteOffset": 0, "byteLength": uv_bytes.len(), "target": 34962}));
    let grid_uv = acc(
        &mut accessors,
        json!({"bufferView": views.len() - 1, "componentType": 5126, "count": 16, "type": "VEC2"}),
    );

    // Mesh 1: a vertical strip skinned to two old joints, stored in the bind frame.
    let strip: Vec<f32> = (0..6)
        .flat_map(|k| [(k % 2) as f32 * 0.3, (k / 2) as f32 * 0.4, 0.0])
        .collect();
    let v = view(&mut views, &f32s(&strip), Some(34962));
    let strip_pos = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 6, "type": "VEC3",
               "min": [0.0, 0.0, 0.0], "max": [0.30000001192092896, 0.800000011920929, 0.0]}),
    );
    let joints: Vec<u8> = (0..6).flat_map(|k| [(k / 3) as u8, 0, 0, 0]).collect();
    let v = view(&mut views, &joints, Some(34962));
    let strip_j = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5121, "count": 6, "type": "VEC4"}),
    );
    let wts: Vec<f32> = (0..6).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect();
    let v = view(&mut views, &f32s(&wts), Some(34962));
    let strip_w = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 6, "type": "VEC4"}),
    );
    let strip_idx: Vec<u8> = [0u16, 1, 2, 1, 3, 2, 2, 3, 4, 3, 5, 4]
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let v = view(&mut views, &strip_idx, Some(34963));
    let strip_i = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5123, "count": 12, "type": "SCALAR"}),
    );
    // Inverse bind matrices for joints bound at (0, 0.5, 0) and (0, 1, 0) while the nodes
    // sit 1 higher: the strip's stored positions are in a frame offset from the scene.
    let ibm: Vec<f32> = [0.5f32, 1.0]
        .iter()
        .flat_map(|y| Mat4::from_translation(Vec3::new(0.0, -y, 0.0)).to_cols_array())
        .collect();
    let v = view(&mut views, &f32s(&ibm), None);
    let ibm_acc = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 2, "type": "MAT4"}),
    );

    // Mesh 2: points, which export leaves alone.
    let v = view(
        &mut views,
        &f32s(&[0.0, 2.0, 0.0, 0.1, 2.0, 0.0]),
        Some(34962),
    );
    let pts = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 2, "type": "VEC3",
               "min": [0.0, 2.0, 0.0], "max": [0.10000000149011612, 2.0, 0.0]}),
    );

    // Animations: one on an old joint (goes), one on a prop node (stays).
    let v = view(&mut views, &f32s(&[0.0, 1.0]), None);
    let times = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 2, "type": "SCALAR",
               "min": [0.0], "max": [1.0]}),
    );
    let v = view(
        &mut views,
        &f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.38268343, 0.9238795]),
        None,
    );
    let rots = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 2, "type": "VEC4"}),
    );
    let v = view(&mut views, &f32s(&[0.0, 3.0, 0.0, 0.0, 3.5, 0.0]), None);
    let moves = acc(
        &mut accessors,
        json!({"bufferView": v, "componentType": 5126, "count": 2, "type": "VEC3"}),
    );
    let image_view = view(&mut views, &png, None);
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }

    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&uv_bytes)
    );
    let doc = json!({
        "asset": {"version": "2.0", "generator": "test", "copyright": "CC0"},
        "x_custom": {"kept": [1, 2, 3]},
        "extras": {"root_extra": true},
        "extensionsUsed": ["EXT_rigserve_test_unknown"],
        "scene": 0,
        "scenes": [{"name": "main", "nodes": [0, 1, 2, 3, 5, 6], "extras": {"keep": 1}}],
        "nodes": [
            {"name": "grid_a", "mesh": 0, "translation": [1.0, 0.0, 0.0],
             "rotation": [0.0, 0.70710677, 0.0, 0.70710677], "scale": [2.0, 2.0, 2.0]},
            {"name": "grid_b", "mesh": 0, "translation": [-1.0, 0.0, 0.0]},
            {"name": "strip", "mesh": 1, "skin": 0},
            {"name": "old_root", "translation": [0.0, 1.5, 0.0], "children": [4]},
            {"name": "old_child", "translation": [0.0, 0.5, 0.0]},
            {"name": "dots", "mesh": 2},
            {"name": "prop", "translation": [0.0, 3.0, 0.0]}
        ],
        "meshes": [
            {"name": "grid", "primitives": [{"attributes": {"POSITION": grid_pos, "NORMAL": grid_nrm,
                "TEXCOORD_0": grid_uv}, "indices": grid_idx, "material": 0}]},
            {"name": "strip", "primitives": [{"attributes": {"POSITION": strip_pos, "JOINTS_0": strip_j,
                "WEIGHTS_0": strip_w}, "indices": strip_i}]},
            {"name": "dots", "primitives": [{"attributes": {"POSITION": pts}, "mode": 0}]}
        ],
        "skins": [{"joints": [3, 4], "inverseBindMatrices": ibm_acc, "skeleton": 3}],
        "animations": [
            {"name": "old_wave", "samplers": [{"input": times, "output": rots}],
             "channels": [{"sampler": 0, "target": {"node": 4, "path": "rotation"}}]},
            {"name": "prop_bob", "samplers": [{"input": times, "output": moves}],
             "channels": [{"sampler": 0, "target": {"node": 6, "path": "translation"}}]}
        ],
        "materials": [{"name": "painted", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
                       "extras": {"tag": "m"}, "extensions": {"EXT_rigserve_test_unknown": {"v": 1}}}],
        "textures": [{"sampler": 0, "source": 0}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987}],
        "images": [{"bufferView": image_view, "mimeType": "image/png", "name": "pixel"}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}, {"byteLength": uv_bytes.len(), "uri": uri}]
    });
    SyntheticGlb {
        bytes: write_glb(&doc, &bin),
        png,
    }
}

/// A GLB container written independently of rigserve's writer.
fn write_glb(json: &Value, bin: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_vec(json).unwrap();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((text.len() as u32).to_le_bytes());
    out.extend(0x4E4F_534Au32.to_le_bytes());
    out.extend(text);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(0x004E_4942u32.to_le_bytes());
    out.extend_from_slice(bin);
    out
}

fn view_bytes(asset: &Asset, view: usize) -> &[u8] {
    let doc = asset.document.as_ref().unwrap();
    let v = &doc.root.buffer_views[view];
    &doc.buffers[v.buffer][v.byte_offset as usize..(v.byte_offset + v.byte_length) as usize]
}

/// The synthetic GLB with a skeleton spanning its three mesh frames.
fn glb_case() -> (SyntheticGlb, Asset, Skeleton, SkinWeights) {
    let syn = synthetic_glb();
    let input = load(&syn.bytes, &Limits::default()).unwrap();
    // grid_a, grid_b (the same mesh) and the strip; the points primitive is not merged.
    assert_eq!(input.mesh.parts.len(), 3);
    let skel = Skeleton {
        bones: vec![
            bone("hips", None, [0.0, 0.5, 0.0], [0.0, 1.0, 0.0]),
            bone("left", Some(0), [1.0, 0.2, 0.0], [1.8, 0.2, 0.0]),
            bone("right", Some(0), [-1.0, 0.2, 0.0], [-1.5, 0.2, 0.5]),
            bone("top", Some(0), [0.0, 1.0, 0.0], [0.0, 1.5, 0.0]),
        ],
        template: None,
        category: Some("other_creature".into()),
    };
    let weights = distance_weights(&skel, &input.mesh.positions, 1.0);
    (syn, input, skel, weights)
}

#[test]
fn gltf_export_keeps_the_document_and_replaces_the_skin() {
    let (syn, input, skel, weights) = glb_case();
    let glb = export_glb(&input, &skel, &weights, &ExportOptions::default()).unwrap();
    let (out, _) = check_round_trip("synthetic glb", &input, &skel, &weights, &glb);
    let a = &input.document.as_ref().unwrap().json;
    let b = &out.document.as_ref().unwrap().json;

    for key in [
        "materials",
        "textures",
        "samplers",
        "images",
        "x_custom",
        "extras",
        "extensionsUsed",
    ] {
        assert_eq!(a[key], b[key], "{key} changed");
    }
    assert_eq!(b["asset"]["copyright"], "CC0");
    assert_eq!(b["asset"]["generator"], "rigserve");
    assert_eq!(b["scenes"][0]["extras"]["keep"], 1);
    assert_eq!(b["scenes"][0]["name"], "main");
    let buffers = b["buffers"].as_array().unwrap();
    assert_eq!(buffers.len(), 1);
    assert!(buffers[0].get("uri").is_none());
    let image_view = b["images"][0]["bufferView"].as_u64().unwrap() as usize;
    assert_eq!(view_bytes(&out, image_view), &syn.png[..]);

    // The UVs (from the data-URI buffer) read back the same through the merged buffer.
    let (da, db) = (
        input.document.as_ref().unwrap(),
        out.document.as_ref().unwrap(),
    );
    let uv_of = |d: &rigserve::mesh::gltf::Document, node: usize| {
        let m = d.root.nodes[node].mesh.unwrap();
        d.read_accessor(d.root.meshes[m].primitives[0].attributes["TEXCOORD_0"], 100)
            .unwrap()
    };
    assert_eq!(uv_of(da, 0), uv_of(db, 0));
    assert_eq!(uv_of(da, 0), uv_of(db, 1));

    // Each instance of the shared mesh has its own copy, with its own weights.
    let nodes = b["nodes"].as_array().unwrap();
    assert_ne!(nodes[0]["mesh"], nodes[1]["mesh"]);
    for n in [0, 1, 2] {
        assert!(nodes[n]["skin"].is_u64(), "node {n} has no skin");
    }
    // grid_a, grid_b and the strip sit in three different frames.
    assert_eq!(b["skins"].as_array().unwrap().len(), 3);
    let new_joint_names: HashSet<&str> = skel.bones.iter().map(|b| b.name.as_str()).collect();
    for s in b["skins"].as_array().unwrap() {
        for j in s["joints"].as_array().unwrap() {
            let name = nodes[j.as_u64().unwrap() as usize]["name"]
                .as_str()
                .unwrap();
            assert!(
                new_joint_names.contains(name),
                "old joint {name} still skins"
            );
        }
    }
    // The old joints stay as plain nodes; the animation on one of them is gone.
    assert_eq!(nodes[3]["name"], "old_root");
    let anims = b["animations"].as_array().unwrap();
    assert_eq!(anims.len(), 1);
    assert_eq!(anims[0]["name"], "prop_bob");
    let out_acc = anims[0]["samplers"][0]["output"].as_u64().unwrap() as usize;
    let in_acc = a["animations"][1]["samplers"][0]["output"]
        .as_u64()
        .unwrap() as usize;
    assert_eq!(
        db.read_accessor(out_acc, 10).unwrap(),
        da.read_accessor(in_acc, 10).unwrap()
    );
    // Points are untouched, old joints/weights gone from the re-skinned strip.
    assert_eq!(b["meshes"][2], a["meshes"][2]);
    let old_strip = &a["meshes"][1]["primitives"][0]["attributes"];
    assert_ne!(
        b["meshes"][1]["primitives"][0]["attributes"]["JOINTS_0"],
        old_strip["JOINTS_0"]
    );
    // What only the old skin and the removed animation used keeps its index but no data;
    // the time accessor the kept animation shares stays whole.
    let accessor = |key: &Value| &b["accessors"][key.as_u64().unwrap() as usize];
    for old in [
        &old_strip["JOINTS_0"],
        &old_strip["WEIGHTS_0"],
        &a["skins"][0]["inverseBindMatrices"],
        &a["animations"][0]["samplers"][0]["output"],
    ] {
        assert!(
            accessor(old).get("bufferView").is_none(),
            "accessor {old} kept its data"
        );
        assert_eq!(
            accessor(old)["count"],
            a["accessors"][old.as_u64().unwrap() as usize]["count"]
        );
    }
    assert!(accessor(&a["animations"][1]["samplers"][0]["input"])["bufferView"].is_u64());

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("synthetic.glb");
    std::fs::write(&path, &glb).unwrap();
    if let Some(reports) = validate(&[path]) {
        assert!(errors_of(&reports).is_empty(), "{reports:#?}");
    }
}

/// Rewrites the JSON chunk of a GLB written by [`write_glb`].
fn edit_glb(glb: &[u8], edit: impl FnOnce(&mut Value)) -> Vec<u8> {
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let mut json: Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    edit(&mut json);
    write_glb(&json, &glb[20 + json_len + 8..])
}

#[test]
fn joints_join_every_scene_that_needs_them_and_mixed_frames_are_refused() {
    let (syn, _, skel, _) = glb_case();
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    // Without scenes every parentless node is shown; the export must keep showing them.
    let sceneless = edit_glb(&syn.bytes, |j| {
        let o = j.as_object_mut().unwrap();
        o.remove("scene");
        o.remove("scenes");
    });
    // A second scene shows one re-skinned node, a third only the prop: the joints must
    // be in the first two (NODE_SKIN_NO_SCENE) and need not be in the third.
    let scenes = edit_glb(&syn.bytes, |j| {
        let list = j["scenes"].as_array_mut().unwrap();
        list.push(json!({"name": "b only", "nodes": [1]}));
        list.push(json!({"name": "prop only", "nodes": [6]}));
    });
    for (name, bytes) in [("sceneless.glb", sceneless), ("scenes.glb", scenes)] {
        let input = load(&bytes, &Limits::default()).unwrap();
        let weights = distance_weights(&skel, &input.mesh.positions, 1.0);
        let glb = export_glb(&input, &skel, &weights, &ExportOptions::default()).unwrap();
        let (out, _) = check_round_trip(name, &input, &skel, &weights, &glb);
        let json = &out.document.as_ref().unwrap().json;
        let before = &input.document.as_ref().unwrap().json["scenes"];
        let scenes = json["scenes"].as_array().unwrap();
        let root_joint = json!(json["nodes"].as_array().unwrap().len() - skel.len());
        for (i, s) in scenes.iter().enumerate() {
            let has_joints = s["nodes"].as_array().unwrap().contains(&root_joint);
            assert_eq!(has_joints, i < 2, "{name}: scene {i}");
            if let Some(b) = before.get(i) {
                assert_eq!(s["name"], b["name"]);
            }
        }
        let path = dir.path().join(name);
        std::fs::write(&path, &glb).unwrap();
        files.push(path);
    }
    if let Some(reports) = validate(&files) {
        assert!(errors_of(&reports).is_empty(), "{reports:#?}");
    }

    // A skinned node whose mesh also has an unskinned triangle primitive: its two
    // primitives live in different frames, which one skin cannot bind.
    let bytes = edit_glb(&syn.bytes, |j| {
        let grid = j["meshes"][0]["primitives"][0].clone();
        j["meshes"][1]["primitives"]
            .as_array_mut()
            .unwrap()
            .push(grid);
    });
    let input = load(&bytes, &Limits::default()).unwrap();
    let weights = distance_weights(&skel, &input.mesh.positions, 1.0);
    let err = export_glb(&input, &skel, &weights, &ExportOptions::default()).unwrap_err();
    assert_eq!(err.code(), "export_unsupported", "{err}");
}

#[test]
fn a_part_flattened_by_its_node_still_reads_back() {
    // A zero scale flattens (or hides) a node's mesh. Its skin's inverse bind matrices are
    // then singular, which says nothing of where the joints rest; the other parts' skins
    // over the same joints do, so the rig must still read back, here and for
    // `--skeleton-from-input`. (It used to fail with "singular inverse bind matrix".)
    let (syn, _, skel, _) = glb_case();
    let bytes = edit_glb(&syn.bytes, |j| {
        let nodes = j["nodes"].as_array_mut().unwrap();
        let n = nodes.iter_mut().find(|n| n.get("mesh").is_some()).unwrap();
        n.as_object_mut().unwrap().remove("matrix");
        n["scale"] = json!([1.0, 1.0, 0.0]);
    });
    let input = load(&bytes, &Limits::default()).unwrap();
    let weights = distance_weights(&skel, &input.mesh.positions, 1.0);
    let glb = export_glb(&input, &skel, &weights, &ExportOptions::default()).unwrap();
    let back = load(&glb, &Limits::default()).unwrap();
    let skins = back.document.as_ref().unwrap().root.skins.len();
    assert!(
        skins >= 2,
        "the flattened part needs a skin of its own: {skins}"
    );
    let gt = extract(&back).unwrap().expect("a rig");
    assert_eq!(gt.skeleton.len(), skel.len());
    for (a, b) in gt.skeleton.bones.iter().zip(&skel.bones) {
        assert!(
            a.head.distance(b.head) < 1e-4,
            "{}: {} vs {}",
            a.name,
            a.head,
            b.head
        );
    }
}

#[test]
fn export_refuses_inconsistent_rigs_with_codes() {
    let input = load(cylinder_obj(3, 6, 1.0).as_bytes(), &Limits::default()).unwrap();
    let n = input.mesh.positions.len();
    let skel = Skeleton {
        bones: vec![bone("a", None, [0.0; 3], [0.0, 1.0, 0.0])],
        ..Default::default()
    };
    let good = SkinWeights {
        per_vertex: vec![vec![(0, 1.0)]; n],
    };
    let code = |s: &Skeleton, w: &SkinWeights, o: &ExportOptions| {
        export_glb(&input, s, w, o).unwrap_err().code()
    };
    let opts = ExportOptions::default();
    assert!(export_glb(&input, &skel, &good, &opts).is_ok());
    let short = SkinWeights {
        per_vertex: vec![vec![(0, 1.0)]; n - 1],
    };
    assert_eq!(code(&skel, &short, &opts), "export_weights_mismatch");
    let mut bad = good.clone();
    bad.per_vertex[2] = vec![(1, 1.0)];
    assert_eq!(code(&skel, &bad, &opts), "export_bone_out_of_range");
    bad.per_vertex[2] = vec![(0, f32::NAN)];
    assert_eq!(code(&skel, &bad, &opts), "export_non_finite_weight");
    assert_eq!(
        code(&Skeleton::default(), &good, &opts),
        "export_invalid_skeleton"
    );
    let five = ExportOptions {
        max_influences: 5,
        ..Default::default()
    };
    assert_eq!(code(&skel, &good, &five), "export_bad_options");
}

#[test]
fn influences_are_capped_and_the_bone_tree_is_optional() {
    let input = load(cylinder_obj(5, 8, 2.0).as_bytes(), &Limits::default()).unwrap();
    let skel = Skeleton {
        bones: vec![
            bone("a", None, [0.0; 3], [0.0, 1.0, 0.0]),
            bone("b", Some(0), [0.0, 1.0, 0.0], [0.0, 2.0, 0.0]),
            bone("c", Some(1), [0.0, 2.0, 0.0], [0.0, 2.5, 0.0]),
        ],
        ..Default::default()
    };
    let weights = distance_weights(&skel, &input.mesh.positions, 2.0);
    let opts = ExportOptions {
        max_influences: 2,
        embed_bone_tree: false,
        ..Default::default()
    };
    let glb = export_glb(&input, &skel, &weights, &opts).unwrap();
    let out = load(&glb, &Limits::default()).unwrap();
    let gt = extract(&out).unwrap().unwrap();
    let mut capped = weights.clone();
    capped.top_k(2);
    for (want, got) in capped.per_vertex.iter().zip(&gt.weights.per_vertex) {
        assert_eq!(want.len(), got.len());
        for (x, y) in want.iter().zip(got) {
            assert_eq!(x.0, y.0);
            assert!((x.1 - y.1).abs() < 1e-6);
        }
    }
    assert!(bone_tree_of(&out.document.as_ref().unwrap().json).is_null());
}

// ---------------------------------------------------------------------------------------
// The artist-rigged data set.

/// Exports a rig from its own ground truth, the way a perfect prediction would come in.
fn export_ground_truth(path: &Path) -> (Asset, Skeleton, SkinWeights, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    let asset = load(&bytes, &Limits::default()).unwrap();
    let gt = extract(&asset).unwrap().unwrap();
    let mut weights = gt.weights;
    weights.top_k(4);
    let glb = export_glb(&asset, &gt.skeleton, &weights, &ExportOptions::default())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (asset, gt.skeleton, weights, glb)
}

#[test]
fn every_shared_rig_round_trips_and_validates() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let entries = common::manifest(&dir);
    let out_dir = tempfile::tempdir().unwrap();
    let mut worst = RoundTrip::default();
    let mut worst_rel = (0f32, String::new());
    let mut files = Vec::new();
    for e in &entries {
        let (asset, skel, weights, glb) = export_ground_truth(&dir.join(&e.file));
        let (_, rt) = check_round_trip(&e.file, &asset, &skel, &weights, &glb);
        let rel = rt.head.max(rt.rest) / mesh_size(&asset);
        if rel > worst_rel.0 {
            worst_rel = (rel, e.file.clone());
        }
        worst.head = worst.head.max(rt.head);
        worst.rest = worst.rest.max(rt.rest);
        worst.weight = worst.weight.max(rt.weight);
        worst.weight_sum = worst.weight_sum.max(rt.weight_sum);
        worst.fallback += rt.fallback;
        let path = out_dir.path().join(&e.file);
        std::fs::write(&path, &glb).unwrap();
        files.push(path);
    }
    eprintln!(
        "{} rigs round-tripped: max head error {:.3e}, max rest-pose error {:.3e} \
         (worst relative to mesh size {:.3e}, {}), max weight error {:.3e}, \
         stored weight sums within {:.1e} of 1, \
         {} vertices without weights bound to their nearest bone",
        entries.len(),
        worst.head,
        worst.rest,
        worst_rel.0,
        worst_rel.1,
        worst.weight,
        worst.weight_sum,
        worst.fallback
    );
    let Some(reports) = validate(&files) else {
        return;
    };
    let failed = errors_of(&reports);
    let warnings: u64 = reports
        .iter()
        .map(|r| r["numWarnings"].as_u64().unwrap())
        .sum();
    eprintln!(
        "glTF validator: {} files, {} with errors, {warnings} warnings in all",
        reports.len(),
        failed.len()
    );
    assert!(failed.is_empty(), "{failed:#?}");
}

/// Minimal spatial hash for matching Blender's vertices to ours by rest position.
struct Grid {
    cell: f32,
    cells: HashMap<(i64, i64, i64), Vec<usize>>,
}

impl Grid {
    fn new(points: &[Vec3], cell: f32) -> Self {
        let mut cells: HashMap<_, Vec<usize>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            cells.entry(Self::key(*p, cell)).or_default().push(i);
        }
        Grid { cell, cells }
    }

    fn key(p: Vec3, cell: f32) -> (i64, i64, i64) {
        let k = (p / cell).floor();
        (k.x as i64, k.y as i64, k.z as i64)
    }

    /// Every point within `cell` of `q`.
    fn near<'a>(&'a self, q: Vec3) -> impl Iterator<Item = usize> + 'a {
        let (x, y, z) = Self::key(q, self.cell);
        (-1..=1)
            .flat_map(move |dx| (-1..=1).flat_map(move |dy| (-1..=1).map(move |dz| (dx, dy, dz))))
            .filter_map(move |(dx, dy, dz)| self.cells.get(&(x + dx, y + dy, z + dz)))
            .flatten()
            .copied()
    }
}

/// The bone whose subtree splits the mesh most evenly into moving and resting vertices,
/// so a pose tests both.
fn pick_bone(skel: &Skeleton, weights: &SkinWeights) -> usize {
    let n = weights.per_vertex.len();
    let children = skel.children();
    (0..skel.len())
        .filter(|&b| skel.bones[b].name.len() < 60 && skel.bones[b].name.is_ascii())
        .max_by_key(|&b| {
            let mut sub = HashSet::new();
            let mut stack = vec![b];
            while let Some(x) = stack.pop() {
                sub.insert(x as u32);
                stack.extend(&children[x]);
            }
            let moved = weights
                .per_vertex
                .iter()
                .filter(|w| w.iter().any(|(j, x)| *x > 0.0 && sub.contains(j)))
                .count();
            (moved.min(n - moved), std::cmp::Reverse(b))
        })
        .unwrap()
}

/// What rigserve expects Blender to show for one exported file.
struct BlenderCase {
    label: String,
    input: Asset,
    skel: Skeleton,
    posed: Vec<Vec3>,
    bone: usize,
}

/// Writes `glb` for Blender and computes rigserve's side of the comparison: the input's
/// rest mesh (so Blender must show the rest pose where the upload had it) deformed with
/// the skeleton and weights read back from the exported file, one bone turned 30°.
fn blender_case(
    label: &str,
    input: Asset,
    glb: &[u8],
    dir: &Path,
    jobs: &mut Vec<Value>,
) -> BlenderCase {
    let path = dir.join(label);
    std::fs::write(&path, glb).unwrap();
    let gt = extract(&load(glb, &Limits::default()).unwrap())
        .unwrap()
        .unwrap();
    let b = pick_bone(&gt.skeleton, &gt.weights);
    let rotation = Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 30f32.to_radians());
    let posed = lbs(
        &input.mesh.positions,
        &gt.weights,
        &pose_one_bone(&gt.skeleton, b, rotation),
    );
    let bone = &gt.skeleton.bones[b];
    jobs.push(json!({
        "file": path,
        "bone": bone.name,
        "rotation": rotation.to_array(),
        "pivot": bone.head.to_array(),
    }));
    BlenderCase {
        label: label.into(),
        input,
        skel: gt.skeleton,
        posed,
        bone: b,
    }
}

/// Compares Blender's report for one file with rigserve's; returns the largest deviation.
fn compare_with_blender(case: &BlenderCase, res: &Value) -> f32 {
    let vec3 = |v: &Value| {
        Vec3::new(
            v[0].as_f64().unwrap() as f32,
            v[1].as_f64().unwrap() as f32,
            v[2].as_f64().unwrap() as f32,
        )
    };
    let (label, input, skel) = (&case.label, &case.input, &case.skel);
    let size = mesh_size(input);
    // Absolute 1e-4 for meshes up to a unit across; larger meshes (centimetre rigs reach
    // hundreds of units) get the same relative precision, as f32 does.
    let tol = 1e-4 * size;
    assert_eq!(
        res["joints"].as_u64().unwrap() as usize,
        skel.len(),
        "{label}"
    );
    assert!(res["vertex_groups"].as_u64().unwrap() > 0, "{label}");
    for bone in &skel.bones {
        let head = &res["bone_heads"][&bone.name];
        assert!(
            !head.is_null(),
            "{label}: Blender has no bone {}",
            bone.name
        );
        let d = vec3(head).distance(bone.head);
        assert!(d <= tol, "{label}: Blender puts {} {d} away", bone.name);
    }
    let rest: Vec<Vec3> = res["rest"].as_array().unwrap().iter().map(vec3).collect();
    let blender_posed: Vec<Vec3> = res["posed"].as_array().unwrap().iter().map(vec3).collect();
    assert_eq!(rest.len(), blender_posed.len());
    let grid = Grid::new(&input.mesh.positions, tol);
    let mut max_dev = 0f32;
    let mut moved = 0;
    for (i, r) in rest.iter().enumerate() {
        // Coincident vertices (UV seams) may carry different weights; the Blender vertex
        // must agree with one of them.
        let dev = grid
            .near(*r)
            .filter(|&j| input.mesh.positions[j].distance(*r) <= tol)
            .map(|j| case.posed[j].distance(blender_posed[i]))
            .fold(f32::INFINITY, f32::min);
        assert!(
            dev.is_finite(),
            "{label}: Blender vertex {i} at {r} has no rest match"
        );
        max_dev = max_dev.max(dev);
        moved += (blender_posed[i].distance(*r) > tol) as usize;
    }
    // Every vertex of ours that a triangle uses must exist in Blender too.
    let bgrid = Grid::new(&rest, tol);
    let used: HashSet<u32> = input.mesh.triangles.iter().flatten().copied().collect();
    for &v in &used {
        let p = input.mesh.positions[v as usize];
        assert!(
            bgrid.near(p).any(|j| rest[j].distance(p) <= tol),
            "{label}: our vertex {v} is missing in Blender"
        );
    }
    let name = &skel.bones[case.bone].name;
    assert!(moved > 0, "{label}: posing {name} moved nothing");
    eprintln!(
        "blender {label}: posed {name:?} by 30°, {} vertices ({moved} moved), \
         max deviation {max_dev:.3e} (mesh size {size:.3})",
        rest.len()
    );
    assert!(
        max_dev <= tol,
        "{label}: Blender deviates by {max_dev} (tolerance {tol})"
    );
    max_dev
}

#[test]
fn blender_deforms_exports_like_rigserve() {
    if !blender_available() {
        return;
    }
    let work = tempfile::tempdir().unwrap();
    let mut jobs = Vec::new();
    let mut cases = Vec::new();
    // The synthetic files cover a skeleton forest, fallback-weighted vertices, instanced
    // meshes, three bind frames and a points primitive.
    let (input, skel, weights, _) = obj_case();
    let glb = export_glb(&input, &skel, &weights, &ExportOptions::default()).unwrap();
    cases.push(blender_case(
        "tube.glb",
        input,
        &glb,
        work.path(),
        &mut jobs,
    ));
    let (_, input, skel, weights) = glb_case();
    let glb = export_glb(&input, &skel, &weights, &ExportOptions::default()).unwrap();
    cases.push(blender_case(
        "synthetic.glb",
        input,
        &glb,
        work.path(),
        &mut jobs,
    ));
    if let Some(dir) = common::shared_rigs() {
        // One rig per category, the first in file-name order: bipeds, quadrupeds,
        // chains, props, several-skin files, for a few seconds of Blender.
        let mut sorted: Vec<common::Entry> = common::manifest(&dir);
        sorted.sort_by(|a, b| a.file.cmp(&b.file));
        let categories = [
            "humanoid",
            "quadruped",
            "fish_snake_tail",
            "robot_prop",
            "insect_spider",
            "bird_flyer",
        ];
        for cat in categories {
            if let Some(e) = sorted.iter().find(|e| e.category == cat) {
                let (input, _, _, glb) = export_ground_truth(&dir.join(&e.file));
                cases.push(blender_case(&e.file, input, &glb, work.path(), &mut jobs));
            }
        }
        assert_eq!(cases.len(), 2 + categories.len());
    }

    let jobs_path = work.path().join("jobs.json");
    let out_path = work.path().join("blender.json");
    std::fs::write(&jobs_path, serde_json::to_vec(&jobs).unwrap()).unwrap();
    let run = Command::new("python3")
        .arg(tools_dir().join("blender_check.py"))
        .args([&jobs_path, &out_path])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "blender_check.py failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let results: Vec<Value> = serde_json::from_slice(&std::fs::read(&out_path).unwrap()).unwrap();
    assert_eq!(results.len(), cases.len());
    let mut worst = (0f32, String::new());
    for (case, res) in cases.iter().zip(&results) {
        let dev = compare_with_blender(case, res) / mesh_size(&case.input);
        if dev >= worst.0 {
            worst = (dev, case.label.clone());
        }
    }
    eprintln!(
        "blender: worst deviation relative to mesh size {:.3e} ({})",
        worst.0, worst.1
    );
}
