//! Geometric skinning from the outside: the weights' invariants, geodesic distances that
//! do not jump gaps, floating parts bound to one bone, refused skeletons with their
//! codes, and `rigserve rig` writing GLBs the Khronos validator accepts; and the learned
//! model (`models/skin/`) keeping the same invariants, the per-part rules, its data set
//! writer, and beating the geometric weights on the dev split.
mod common;

use glam::Vec3;
use rigserve::export::bone_tree;
use rigserve::infer::{Runtime, SessionConfig, SkinModel};
use rigserve::mesh::{load, Limits, Mesh};
use rigserve::rig::groundtruth::extract;
use rigserve::rig::skin::{prepare, skin, skin_with, SkinConfig};
use rigserve::rig::{Bone, Skeleton, SkinWeights};
use serde_json::{json, Value};
use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::process::{Command, Output};

/// The closed surface of a union of cubes of side `size` (cell (i, j, k) spans
/// `origin + [i, i+1]·size` and so on), one welded vertex per lattice point.
fn cells_mesh(cells: &HashSet<[i32; 3]>, size: f32, origin: Vec3, mesh: &mut Mesh) {
    let mut index: HashMap<[i32; 3], u32> = HashMap::new();
    let mut vertex = |mesh: &mut Mesh, p: [i32; 3]| {
        *index.entry(p).or_insert_with(|| {
            mesh.positions
                .push(origin + Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) * size);
            mesh.positions.len() as u32 - 1
        })
    };
    let mut sorted: Vec<_> = cells.iter().copied().collect();
    sorted.sort();
    for c in sorted {
        for axis in 0..3 {
            for side in [0, 1] {
                let mut n = c;
                n[axis] += if side == 1 { 1 } else { -1 };
                if cells.contains(&n) {
                    continue;
                }
                // The face's four corners, wound outwards.
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let corner = |du: i32, dv: i32| {
                    let mut p = c;
                    p[axis] += side;
                    p[u] += du;
                    p[v] += dv;
                    p
                };
                let mut q = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                if side == 0 {
                    q.reverse();
                }
                let q = q.map(|p| vertex(mesh, p));
                mesh.triangles.push([q[0], q[1], q[2]]);
                mesh.triangles.push([q[0], q[2], q[3]]);
            }
        }
    }
}

fn boxes(ranges: &[[std::ops::Range<i32>; 3]]) -> HashSet<[i32; 3]> {
    let mut out = HashSet::new();
    for [x, y, z] in ranges {
        for i in x.clone() {
            for j in y.clone() {
                for k in z.clone() {
                    out.insert([i, j, k]);
                }
            }
        }
    }
    out
}

const CELL: f32 = 0.05;

/// A Π: two legs 0.4 wide with a 0.05 gap, joined by a pelvis, all one welded part.
/// Bones: hips across the pelvis, a leg bone down the middle of each leg.
fn two_legs() -> (Mesh, Skeleton) {
    let cells = boxes(&[
        [0..8, 0..16, 0..4],
        [9..17, 0..16, 0..4],
        [0..17, 16..20, 0..4],
    ]);
    let mut mesh = Mesh::default();
    cells_mesh(&cells, CELL, Vec3::ZERO, &mut mesh);
    let z = 0.1;
    let skel = Skeleton {
        bones: vec![
            Bone::new(
                "hips",
                None,
                Vec3::new(0.2, 0.9, z),
                Vec3::new(0.65, 0.9, z),
            ),
            Bone::new(
                "leg.L",
                Some(0),
                Vec3::new(0.2, 0.85, z),
                Vec3::new(0.2, 0.02, z),
            ),
            Bone::new(
                "leg.R",
                Some(0),
                Vec3::new(0.65, 0.85, z),
                Vec3::new(0.65, 0.02, z),
            ),
        ],
        ..Skeleton::default()
    };
    (mesh, skel)
}

/// A bone reaching 1e30 units out (a hostile joint transform, or a user's skeleton for
/// `skin_only`) once hung skinning: its half-cell step count overflowed. The walk is
/// clipped to the grid since (`geodesic`'s own test); such a bone is now refused first
/// (`rig::placement`), while one fifty mesh sizes out, as odd as any artist's helper
/// bone could be, still skins. On a thread, so that a regression fails here instead of
/// hanging the suite.
#[test]
fn a_bone_reaching_absurdly_far_is_refused_and_a_long_one_skins() {
    let (mesh, skel) = two_legs();
    let hips = skel.bones[0].head;
    let n = mesh.positions.len();
    let size = {
        let (lo, hi) = mesh.bounds();
        (hi - lo).max_element()
    };
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for reach in [1e30, 50.0 * size] {
            let mut s = skel.clone();
            s.bones.push(Bone::new(
                "target",
                Some(0),
                hips,
                hips + Vec3::new(reach, 0.0, 0.0),
            ));
            let _ = tx.send(skin(&mesh, &s, &SkinConfig::default()));
        }
    });
    let far = rx
        .recv_timeout(std::time::Duration::from_secs(60))
        .expect("skinning returns");
    assert_eq!(far.unwrap_err().code(), "skeleton_outside_mesh");
    let long = rx
        .recv_timeout(std::time::Duration::from_secs(60))
        .expect("skinning returns")
        .unwrap();
    assert_well_formed(&long, n, 4);
}

/// Weights do not depend on the mesh's units: skinning runs in the mesh's unit frame.
/// In the file's own units a figure 1e30 long squared its distances past `f32` (every
/// vertex went to bone 0), and one 1e-10 long fell under the voxelizer's resolution.
#[test]
fn weights_are_the_same_in_any_units() {
    let (mesh, skel) = two_legs();
    let cfg = SkinConfig::default();
    let want = skin(&mesh, &skel, &cfg).unwrap();
    for (scale, shift) in [(1e-10, 0.0), (1e-30, 1e-29), (1e30, -3e30), (1e5, 7e5)] {
        let moved = |p: Vec3| p * scale + Vec3::splat(shift);
        let m = Mesh {
            positions: mesh.positions.iter().map(|&p| moved(p)).collect(),
            ..mesh.clone()
        };
        let mut s = skel.clone();
        s.map_points(moved);
        let got = skin(&m, &s, &cfg).unwrap();
        for (v, (a, b)) in want.per_vertex.iter().zip(&got.per_vertex).enumerate() {
            // Bone by bone (near-ties may list two bones in either order).
            let of =
                |l: &[(u32, f32)], bone: u32| l.iter().find(|x| x.0 == bone).map_or(0.0, |x| x.1);
            for bone in 0..skel.len() as u32 {
                let (x, y) = (of(a, bone), of(b, bone));
                assert!(
                    (x - y).abs() < 1e-3,
                    "scale {scale}: vertex {v}: {a:?} vs {b:?}"
                );
            }
        }
    }
}

/// A column body with a head, and a hat floating above the head (its own closed part).
fn body_with_floating_hat() -> (Mesh, Skeleton) {
    let mut mesh = Mesh::default();
    cells_mesh(
        &boxes(&[[0..4, 0..12, 0..4], [1..3, 12..16, 1..3]]),
        CELL,
        Vec3::ZERO,
        &mut mesh,
    );
    let body_vertices = mesh.positions.len();
    cells_mesh(
        &boxes(&[[0..4, 0..1, 0..4]]),
        CELL,
        Vec3::new(0.0, 0.85, 0.0),
        &mut mesh,
    );
    assert!(mesh.positions.len() > body_vertices);
    let c = Vec3::new(0.1, 0.0, 0.1);
    let skel = Skeleton {
        bones: vec![
            Bone::new("spine", None, c + Vec3::Y * 0.05, c + Vec3::Y * 0.5),
            Bone::new("neck", Some(0), c + Vec3::Y * 0.5, c + Vec3::Y * 0.62),
            Bone::new("head", Some(1), c + Vec3::Y * 0.62, c + Vec3::Y * 0.78),
        ],
        ..Skeleton::default()
    };
    (mesh, skel)
}

fn assert_well_formed(w: &SkinWeights, vertices: usize, bones: usize) {
    assert_eq!(w.per_vertex.len(), vertices);
    for (v, list) in w.per_vertex.iter().enumerate() {
        assert!(!list.is_empty(), "vertex {v} is unweighted");
        assert!(list.len() <= 4, "vertex {v} has {} influences", list.len());
        let sum: f32 = list.iter().map(|x| x.1).sum();
        assert!((sum - 1.0).abs() < 1e-5, "vertex {v} sums to {sum}");
        assert!(list.iter().all(|&(b, x)| x > 0.0 && (b as usize) < bones));
    }
}

fn weight_of(list: &[(u32, f32)], bone: u32) -> f32 {
    list.iter().filter(|x| x.0 == bone).map(|x| x.1).sum()
}

fn segment_distance(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
    p.distance(a + ab * t)
}

#[test]
fn the_left_leg_takes_nothing_from_the_right_leg_bone() {
    let (mesh, skel) = two_legs();
    let w = skin(&mesh, &skel, &SkinConfig::default()).unwrap();
    assert_well_formed(&w, mesh.positions.len(), skel.len());
    let (l, r) = (&skel.bones[1], &skel.bones[2]);
    let mut inner_checked = 0;
    for (v, &p) in mesh.positions.iter().enumerate() {
        if p.y > 0.5 {
            continue;
        }
        let (own, other) = if p.x < 0.42 { (1, 2) } else { (2, 1) };
        assert_eq!(
            weight_of(&w.per_vertex[v], other),
            0.0,
            "vertex {v} at {p} takes weight from the other leg: {:?}",
            w.per_vertex[v]
        );
        assert!(
            weight_of(&w.per_vertex[v], own) > 0.75,
            "{:?}",
            w.per_vertex[v]
        );
        // On the inner faces the other leg's bone is nearly as near in a straight line,
        // so straight-line weights would give it a share: only the geodesic keeps it out.
        let (dl, dr) = (
            segment_distance(p, l.head, l.tail),
            segment_distance(p, r.head, r.tail),
        );
        if (p.x - 0.4).abs() < 1e-4 || (p.x - 0.45).abs() < 1e-4 {
            assert!(dl.max(dr) < 1.3 * dl.min(dr), "{dl} {dr}");
            inner_checked += 1;
        }
    }
    assert!(inner_checked > 10);
}

#[test]
fn a_floating_hat_takes_only_the_head_bone() {
    let (mesh, skel) = body_with_floating_hat();
    let w = skin(&mesh, &skel, &SkinConfig::default()).unwrap();
    assert_well_formed(&w, mesh.positions.len(), skel.len());
    let hat: Vec<usize> = (0..mesh.positions.len())
        .filter(|&v| mesh.positions[v].y >= 0.85 - 1e-4)
        .collect();
    assert!(!hat.is_empty());
    for v in hat {
        assert_eq!(w.per_vertex[v], vec![(2, 1.0)], "hat vertex {v}");
    }
    // The body still blends between its bones.
    assert!(w.per_vertex.iter().any(|l| l.len() > 1));
}

#[test]
fn bad_skeletons_are_refused_with_codes() {
    let (mesh, skel) = two_legs();
    let cfg = SkinConfig::default();
    let code = |s: &Skeleton, cfg: &SkinConfig| skin(&mesh, s, cfg).unwrap_err().code();
    assert_eq!(code(&Skeleton::default(), &cfg), "skeleton_empty");
    let mut s = skel.clone();
    s.bones[0].parent = Some(2);
    assert_eq!(code(&s, &cfg), "skeleton_not_a_tree");
    let mut s = skel.clone();
    s.bones[1].tail.y = f32::NAN;
    assert_eq!(code(&s, &cfg), "skeleton_non_finite");
    let small = SkinConfig {
        max_bones: 2,
        ..SkinConfig::default()
    };
    assert_eq!(code(&skel, &small), "skeleton_too_many_bones");
    let mut s = skel.clone();
    s.map_points(|p| p * 100.0 + Vec3::splat(50.0));
    assert_eq!(code(&s, &cfg), "skeleton_outside_mesh");
    // One joint astray among several is tolerated.
    let mut s = skel.clone();
    s.bones[2].head = Vec3::splat(30.0);
    assert!(skin(&mesh, &s, &cfg).is_ok());
}

#[test]
fn meshes_that_cannot_be_skinned_are_refused_with_codes() {
    let (mesh, skel) = two_legs();
    let cfg = SkinConfig::default();
    let code = |m: &Mesh| {
        let whole = skin(m, &skel, &cfg).unwrap_err().code();
        // Before any skeleton, too: a job prepares its mesh while the skeleton decodes.
        let Err(early) = prepare(m, &cfg) else {
            panic!("prepare accepted a mesh that skin refuses")
        };
        assert_eq!(early.code(), whole);
        whole
    };
    let mut m = mesh.clone();
    m.triangles.clear();
    assert_eq!(code(&m), "skin_empty_mesh");
    let mut m = mesh.clone();
    m.positions[3].x = f32::INFINITY;
    assert_eq!(code(&m), "skin_non_finite_mesh");
    // Refused, not a panic in the welding that comes before the voxels.
    let mut m = mesh.clone();
    m.triangles[7][1] = mesh.positions.len() as u32;
    assert_eq!(code(&m), "skin_bad_triangle");
    let bad = SkinConfig {
        resolution: 2,
        ..SkinConfig::default()
    };
    assert_eq!(
        skin(&mesh, &skel, &bad).unwrap_err().code(),
        "skin_bad_config"
    );
    assert_eq!(
        prepare(&mesh, &bad).err().unwrap().code(),
        "skin_bad_config"
    );
}

#[test]
fn a_prepared_mesh_skins_as_the_whole_call_does() {
    let cfg = SkinConfig::default();
    let model = shipped_model();
    for (mesh, skel) in [two_legs(), body_with_floating_hat()] {
        let prepared = prepare(&mesh, &cfg).unwrap();
        // One preparation serves any skeleton: the mesh's own, and one moved within it.
        let mut moved = skel.clone();
        moved.map_points(|p| p * 0.9 + Vec3::splat(0.02));
        for s in [&skel, &moved] {
            assert_eq!(
                prepared.skin(s, &cfg, None).unwrap(),
                skin(&mesh, s, &cfg).unwrap()
            );
            assert_eq!(
                prepared.skin(s, &cfg, Some(&model)).unwrap(),
                skin_with(&mesh, s, &cfg, Some(&model)).unwrap()
            );
        }
        // And refuses what the whole call refuses of a skeleton.
        let mut far = skel.clone();
        far.map_points(|p| p * 100.0 + Vec3::splat(50.0));
        assert_eq!(
            prepared.skin(&far, &cfg, None).unwrap_err().code(),
            "skeleton_outside_mesh"
        );
    }
}

fn rigserve(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .output()
        .expect("run rigserve")
}

fn write_obj(mesh: &Mesh, path: &Path) {
    let mut s = String::new();
    for p in &mesh.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &mesh.triangles {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn cli_refuses_bad_skeleton_json_with_codes() {
    let tmp = tempfile::tempdir().unwrap();
    let (mesh, skel) = two_legs();
    let obj = tmp.path().join("legs.obj");
    write_obj(&mesh, &obj);
    let good = bone_tree(&skel);
    let mut cases: Vec<(&str, Value)> = Vec::new();
    let mut v = good.clone();
    v["bones"] = json!([]);
    cases.push(("skeleton_empty", v));
    let mut v = good.clone();
    v["bones"][0]["parent"] = json!(1);
    v["bones"][0]["parent_name"] = json!("leg.L");
    v["bones"][1]["parent"] = json!(0);
    cases.push(("skeleton_not_a_tree", v));
    let mut v = good.clone();
    v["bones"][1]["head"] = json!([1e300, 0.0, 0.0]);
    cases.push(("skeleton_non_finite", v));
    let mut v = good.clone();
    let one = v["bones"][0].clone();
    v["bones"] = Value::Array(
        (0..5000)
            .map(|i| {
                let mut b = one.clone();
                b["name"] = json!(format!("b{i}"));
                b
            })
            .collect(),
    );
    cases.push(("skeleton_too_many_bones", v));
    let mut v = good.clone();
    for b in v["bones"].as_array_mut().unwrap() {
        b["head"] = json!([40.0, 40.0, 40.0]);
        b["tail"] = json!([41.0, 40.0, 40.0]);
    }
    cases.push(("skeleton_outside_mesh", v));
    for (code, tree) in cases {
        let path = tmp.path().join(format!("{code}.json"));
        std::fs::write(&path, serde_json::to_vec(&tree).unwrap()).unwrap();
        let out_glb = tmp.path().join(format!("{code}.glb"));
        let out = rigserve(&[
            "rig",
            obj.to_str().unwrap(),
            "-o",
            out_glb.to_str().unwrap(),
            "--skeleton",
            path.to_str().unwrap(),
        ]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{code}: accepted");
        assert!(stderr.contains(&format!("[{code}]")), "{code}: {stderr}");
        assert!(!out_glb.exists());
    }
}

/// Rigs with `rigserve rig` and checks the GLB: rigserve reads back the skeleton and
/// weights it wrote, and the Khronos validator finds no error.
fn rig_and_check(input: &Path, skeleton_args: &[&str], out: &Path) -> Skeleton {
    let mut args = vec!["rig", input.to_str().unwrap(), "-o", out.to_str().unwrap()];
    args.extend_from_slice(skeleton_args);
    let res = rigserve(&args);
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let asset = load(&std::fs::read(out).unwrap(), &Limits::default()).unwrap();
    let gt = extract(&asset).unwrap().expect("a skinned GLB");
    assert_eq!(gt.unweighted, 0);
    assert_well_formed(&gt.weights, asset.mesh.positions.len(), gt.skeleton.len());
    gt.skeleton
}

#[test]
fn cli_writes_valid_rigged_glbs() {
    let tmp = tempfile::tempdir().unwrap();
    let (mesh, skel) = two_legs();
    let obj = tmp.path().join("legs.obj");
    write_obj(&mesh, &obj);
    let bones = tmp.path().join("bones.json");
    std::fs::write(&bones, serde_json::to_vec(&bone_tree(&skel)).unwrap()).unwrap();
    let mut outputs = vec![tmp.path().join("legs.glb")];
    let got = rig_and_check(&obj, &["--skeleton", bones.to_str().unwrap()], &outputs[0]);
    assert_eq!(got.len(), 3);
    if let Some(dir) = common::shared_rigs() {
        let input = dir.join("modular_men__King.glb");
        let out = tmp.path().join("king.glb");
        let bones_out = tmp.path().join("king.json");
        let got = rig_and_check(
            &input,
            &[
                "--skeleton-from-input",
                "--bones",
                bones_out.to_str().unwrap(),
            ],
            &out,
        );
        let asset = load(&std::fs::read(&input).unwrap(), &Limits::default()).unwrap();
        let own = extract(&asset).unwrap().unwrap().skeleton;
        assert_eq!(got.len(), own.len());
        assert!(bones_out.is_file());
        outputs.push(out);
    }
    if let Some(reports) = common::validate(&outputs) {
        assert!(common::errors_of(&reports).is_empty(), "{reports:#?}");
    }
}

#[test]
fn skin_on_gt_eval_scores_every_dev_rig() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let report = tmp.path().join("r.json");
    let out = rigserve(&[
        "eval",
        "--dataset",
        dir.to_str().unwrap(),
        "--split",
        "dev",
        "--skin-on-gt",
        "--out",
        report.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(r["mode"], "skin_on_gt");
    assert_eq!(r["overall"]["count"], 23);
    assert_eq!(r["overall"]["valid_fraction"], 1.0);
    let skin = &r["overall"]["skin"];
    // Far from perfect (0) and far from chance: nearest-bone-only weights score about 1.
    let l1 = skin["l1"].as_f64().unwrap();
    assert!(l1 > 0.05 && l1 < 0.9, "L1 {l1}");
    assert!(skin["recall"].as_f64().unwrap() > 0.6);
    assert!(r["per_category"].as_object().unwrap().len() >= 5);
}

/// The shipped skin model, loaded on the repository's ONNX Runtime.
fn shipped_model() -> SkinModel {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let file = SkinModel::find(&root.join("models")).expect("models/skin holds the skin model");
    let rt = Runtime::init(None).expect("ONNX Runtime (scripts/setup.sh)");
    SkinModel::load(&rt, &file, &SessionConfig::default()).expect("a skin-v1 model")
}

#[test]
fn learned_weights_are_well_formed_and_keep_the_per_part_rules() {
    let model = shipped_model();
    let cfg = SkinConfig::default();
    let (mesh, skel) = body_with_floating_hat();
    let learned = skin_with(&mesh, &skel, &cfg, Some(&model)).unwrap();
    assert_well_formed(&learned, mesh.positions.len(), skel.len());
    let geometric = skin(&mesh, &skel, &cfg).unwrap();
    assert_eq!(skin_with(&mesh, &skel, &cfg, None).unwrap(), geometric);
    // The floating hat stays bound rigidly to the head, as the geometric rules bind it.
    let hat = mesh
        .positions
        .iter()
        .enumerate()
        .filter(|(_, p)| p.y > 0.84);
    for (v, _) in hat {
        assert_eq!(learned.per_vertex[v], vec![(2, 1.0)], "hat vertex {v}");
    }
    // Separate legs: the model only picks among each vertex's allowed bones.
    let (mesh, skel) = two_legs();
    let w = skin_with(&mesh, &skel, &cfg, Some(&model)).unwrap();
    assert_well_formed(&w, mesh.positions.len(), skel.len());
    for (v, p) in mesh.positions.iter().enumerate() {
        if p.y < 0.4 {
            let other = if p.x < 0.42 { 2 } else { 1 };
            assert_eq!(weight_of(&w.per_vertex[v], other), 0.0, "vertex {v} at {p}");
        }
    }
}

/// The mesh with every triangle given its own three vertices, as a flat-shaded glTF
/// stores it: copies of a position differ only in their faces (so in their normals).
fn split_per_triangle(mesh: &Mesh) -> Mesh {
    let mut out = Mesh::default();
    for t in &mesh.triangles {
        let base = out.positions.len() as u32;
        out.positions
            .extend(t.iter().map(|&i| mesh.positions[i as usize]));
        out.triangles.push([base, base + 1, base + 2]);
    }
    out
}

#[test]
fn copies_of_a_position_get_the_same_learned_weights() {
    let model = shipped_model();
    let cfg = SkinConfig::default();
    let (mesh, skel) = two_legs();
    let split = split_per_triangle(&mesh);
    let w = skin_with(&split, &skel, &cfg, Some(&model)).unwrap();
    assert_well_formed(&w, split.positions.len(), skel.len());
    let mut at: HashMap<[u32; 3], usize> = HashMap::new();
    let mut seams = 0;
    for (v, p) in split.positions.iter().enumerate() {
        let first = *at.entry(p.to_array().map(f32::to_bits)).or_insert(v);
        if first != v {
            seams += 1;
            assert_eq!(
                w.per_vertex[v], w.per_vertex[first],
                "copies {first} and {v} at {p}"
            );
        }
    }
    assert!(
        seams > 1000,
        "the split mesh has seams everywhere ({seams})"
    );
    // And the weights are those of the welded mesh.
    let welded = skin_with(&mesh, &skel, &cfg, Some(&model)).unwrap();
    let index: HashMap<[u32; 3], usize> = mesh
        .positions
        .iter()
        .enumerate()
        .map(|(v, p)| (p.to_array().map(f32::to_bits), v))
        .collect();
    for (v, p) in split.positions.iter().enumerate() {
        assert_eq!(
            w.per_vertex[v],
            welded.per_vertex[index[&p.to_array().map(f32::to_bits)]]
        );
    }
}

#[test]
fn learned_method_without_a_model_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let (mesh, skel) = two_legs();
    let obj = tmp.path().join("legs.obj");
    write_obj(&mesh, &obj);
    let bones = tmp.path().join("bones.json");
    std::fs::write(&bones, serde_json::to_vec(&bone_tree(&skel)).unwrap()).unwrap();
    let out_glb = tmp.path().join("legs.glb");
    let run = |method: &str| {
        rigserve(&[
            "rig",
            obj.to_str().unwrap(),
            "-o",
            out_glb.to_str().unwrap(),
            "--skeleton",
            bones.to_str().unwrap(),
            "--skin-method",
            method,
            "--skin-model",
            tmp.path().join("nowhere").to_str().unwrap(),
        ])
    };
    let out = run("learned");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("[model_not_found]"));
    assert!(!out_glb.exists());
    // auto falls back to geometric weights.
    let out = run("auto");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("(geometric)"));
}

#[test]
fn skin_dataset_rows_match_the_index_and_targets_are_weights() {
    let tmp = tempfile::tempdir().unwrap();
    let (mesh, skel) = two_legs();
    let obj = tmp.path().join("legs.obj");
    write_obj(&mesh, &obj);
    let bones = tmp.path().join("bones.json");
    std::fs::write(&bones, serde_json::to_vec(&bone_tree(&skel)).unwrap()).unwrap();
    let data = tmp.path().join("data");
    std::fs::create_dir(&data).unwrap();
    rig_and_check(
        &obj,
        &[
            "--skeleton",
            bones.to_str().unwrap(),
            "--skin-method",
            "geometric",
        ],
        &data.join("legs.glb"),
    );
    std::fs::write(
        data.join("manifest.tsv"),
        "file\tcategory\tsplit\nlegs.glb\tother_creature\ttrain\n",
    )
    .unwrap();
    let out = tmp.path().join("ds");
    let res = rigserve(&[
        "dataset",
        "--skin",
        "--input",
        data.to_str().unwrap(),
        "--split",
        "train",
        "--out",
        out.to_str().unwrap(),
        "--points",
        "50",
        "--augment",
        "2",
        "--candidates",
        "3",
    ]);
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let index: Vec<Value> = std::fs::read_to_string(out.join("index.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(index.len(), 3);
    let rows: u64 = index.iter().map(|i| i["rows"].as_u64().unwrap()).sum();
    let nbones: u64 = index.iter().map(|i| i["bones"].as_u64().unwrap()).sum();
    assert_eq!(rows, 150);
    assert_eq!(nbones, 9);
    let floats = |name: &str| -> Vec<f32> {
        std::fs::read(out.join(name))
            .unwrap()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    assert_eq!(floats("vert.f32").len() as u64, rows * 6);
    assert_eq!(floats("pair.f32").len() as u64, rows * 3 * 11);
    assert_eq!(floats("bone.f32").len() as u64, nbones * 17);
    let cand: Vec<i32> = std::fs::read(out.join("cand.i32"))
        .unwrap()
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let target = floats("target.f32");
    assert_eq!(cand.len() as u64, rows * 3);
    assert!(cand.iter().all(|&c| (-1..3).contains(&c)));
    for (r, t) in target.chunks_exact(3).enumerate() {
        let sum: f32 = t.iter().sum();
        assert!(
            sum <= 1.0 + 1e-5 && t.iter().all(|&x| x >= 0.0),
            "row {r}: {t:?}"
        );
        // The rig was skinned from these very candidates: all its weight is on them.
        assert!(sum > 0.999, "row {r}: {t:?}");
        for (j, &x) in t.iter().enumerate() {
            assert!(x == 0.0 || cand[r * 3 + j] >= 0);
        }
    }
}

#[test]
fn learned_skin_beats_geometric_on_dev() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let score = |method: &str| -> Value {
        let report = tmp.path().join(format!("{method}.json"));
        let out = rigserve(&[
            "eval",
            "--dataset",
            dir.to_str().unwrap(),
            "--split",
            "dev",
            "--skin-on-gt",
            "--skin-method",
            method,
            "--out",
            report.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let r: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
        assert_eq!(r["overall"]["valid_fraction"], 1.0);
        r["overall"]["skin"].clone()
    };
    let (learned, geometric) = (score("learned"), score("geometric"));
    let f = |v: &Value, k: &str| v[k].as_f64().unwrap();
    assert!(
        f(&learned, "l1") < f(&geometric, "l1"),
        "{learned} vs {geometric}"
    );
    assert!(
        f(&learned, "recall") > f(&geometric, "recall"),
        "{learned} vs {geometric}"
    );
    assert!(f(&learned, "deformation") < 1.1 * f(&geometric, "deformation"));
}
