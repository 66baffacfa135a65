//! rigserve's GLBs read the same in Blender and in three.js: the same joints, and a posed
//! vertex lands where rigserve's own linear blend skinning puts it (within 1e-4), both for
//! one bone turned by hand and for the baked preview clip sampled on a key.

use super::helpers::{figure_skeleton, spawn_app, TestApp};
use super::{assert_valid, browser_ready, node, output_dir};
use glam::{Mat4, Quat, Vec3};
use rigserve::export::animation::{preview_pose, PREVIEW_CLIP};
use rigserve::export::parse_bone_tree;
use rigserve::mesh::{self, Limits};
use rigserve::rig::groundtruth::extract;
use rigserve::rig::metrics::{lbs, pose_one_bone, skinning_matrices};
use rigserve::rig::{Skeleton, SkinWeights};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

const TOLERANCE: f32 = 1e-4;
/// The clip is sampled on a key (k / 20 s), where every reader must agree exactly.
const CLIP_TIME: f32 = 0.5;

/// A finished job's GLB, with what rigserve itself reads back from it.
struct Rigged {
    label: String,
    url: String,
    file: PathBuf,
    skeleton: Skeleton,
    weights: SkinWeights,
    positions: Vec<Vec3>,
    animated: bool,
}

async fn rig(app: &TestApp, label: &str, query: &[(&str, String)], dir: &Path) -> Rigged {
    let q: String = url::form_urlencoded::Serializer::new(String::new())
        .extend_pairs(query)
        .finish();
    let job: Value = app.submit_figure(&format!("?{q}")).await;
    let id = job["id"].as_str().unwrap().to_string();
    let job = app.wait_end(&id, Duration::from_secs(120)).await;
    assert_eq!(job["status"], "succeeded", "{label}: {job}");
    let url = format!("/v1/jobs/{id}/result.glb");
    let glb = app.get(&url).await.bytes().await.unwrap().to_vec();
    let file = dir.join(format!("{label}.glb"));
    std::fs::write(&file, &glb).unwrap();
    let asset = mesh::load(&glb, &Limits::default()).unwrap();
    let gt = extract(&asset).unwrap().expect("a skinned GLB");
    // The clip was made from the bone tree (tails and all); a glTF skin only keeps heads.
    let tree: Value = app
        .get(&format!("/v1/jobs/{id}/skeleton.json"))
        .await
        .json()
        .await
        .unwrap();
    let skeleton = parse_bone_tree(&tree).unwrap();
    // Joint k of the GLB is bone k of the tree; reading it back may reorder bones (Mixamo
    // names are put in template order), so weights are mapped back by name.
    let to_tree: Vec<u32> = gt
        .skeleton
        .bones
        .iter()
        .map(|b| {
            let k = skeleton
                .bones
                .iter()
                .position(|t| t.name == b.name)
                .unwrap();
            assert!(
                skeleton.bones[k].head.distance(b.head) < 1e-6,
                "{label}: {} moved",
                b.name
            );
            k as u32
        })
        .collect();
    let weights = SkinWeights {
        per_vertex: gt
            .weights
            .per_vertex
            .iter()
            .map(|w| w.iter().map(|&(b, x)| (to_tree[b as usize], x)).collect())
            .collect(),
    };
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let doc: Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    let animated = doc["animations"]
        .as_array()
        .is_some_and(|a| a.iter().any(|a| a["name"] == PREVIEW_CLIP));
    assert_eq!(gt.skeleton.len(), skeleton.len());
    assert_eq!(
        skeleton.len() as u64,
        job["result"]["bones"].as_u64().unwrap()
    );
    Rigged {
        label: label.into(),
        url,
        file,
        skeleton,
        weights,
        positions: asset.mesh.positions,
        animated,
    }
}

/// The bone (not a root) that moves the most vertices, so the check has something to see.
fn busiest_bone(r: &Rigged) -> usize {
    let mut count = vec![0usize; r.skeleton.len()];
    for w in &r.weights.per_vertex {
        for &(b, x) in w {
            if x > 0.3 {
                count[b as usize] += 1;
            }
        }
    }
    (0..r.skeleton.len())
        .filter(|&b| r.skeleton.bones[b].parent.is_some())
        .max_by_key(|&b| count[b])
        .unwrap()
}

fn rotation() -> Quat {
    Quat::from_axis_angle(Vec3::new(0.3, 0.2, 0.93).normalize(), 30f32.to_radians())
}

/// What rigserve says the posed mesh is, for a bone job or for the clip.
fn expected(r: &Rigged, bone: Option<usize>) -> Vec<Vec3> {
    let matrices: Vec<Mat4> = match bone {
        Some(b) => pose_one_bone(&r.skeleton, b, rotation()),
        None => skinning_matrices(&r.skeleton, &preview_pose(&r.skeleton, CLIP_TIME)),
    };
    lbs(&r.positions, &r.weights, &matrices)
}

fn vec3(v: &Value) -> Vec3 {
    let a = v.as_array().unwrap();
    Vec3::new(
        a[0].as_f64().unwrap() as f32,
        a[1].as_f64().unwrap() as f32,
        a[2].as_f64().unwrap() as f32,
    )
}

/// Worst distance between a reader's posed vertices and rigserve's, matching vertices
/// by rest position (readers may reorder, split or merge them). Also checks the pose
/// moved something, so agreeing at rest cannot pass for agreeing when posed.
fn worst(label: &str, r: &Rigged, want: &[Vec3], res: &Value) -> f32 {
    let rest: Vec<Vec3> = res["rest"].as_array().unwrap().iter().map(vec3).collect();
    let posed: Vec<Vec3> = res["posed"].as_array().unwrap().iter().map(vec3).collect();
    assert_eq!(rest.len(), posed.len(), "{label}");
    assert!(!rest.is_empty(), "{label}: no vertices");
    let (mut worst, mut moved) = (0f32, 0f32);
    for (p, q) in rest.iter().zip(&posed) {
        let candidates: Vec<usize> = (0..r.positions.len())
            .filter(|&i| r.positions[i].distance(*p) < 1e-5)
            .collect();
        assert!(
            !candidates.is_empty(),
            "{label}: a vertex at {p} that rigserve does not have"
        );
        let d = candidates
            .iter()
            .map(|&i| want[i].distance(*q))
            .fold(f32::INFINITY, f32::min);
        worst = worst.max(d);
        moved = moved.max(q.distance(*p));
    }
    assert!(moved > 0.02, "{label}: the pose moved nothing ({moved})");
    eprintln!(
        "{label}: {} vertices, worst {worst:.2e}, largest move {moved:.3}",
        rest.len()
    );
    worst
}

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

#[tokio::test(flavor = "multi_thread")]
async fn blender_three_js_and_rigserve_deform_alike() {
    let app = spawn_app(|_| {}).await;
    let out = output_dir("deform");
    let skeleton = figure_skeleton().to_string();
    let given = |animation: &str| {
        vec![
            ("skin_only", "true".to_string()),
            ("skeleton", skeleton.clone()),
            ("animation", animation.to_string()),
        ]
    };
    let predicted = vec![
        ("category", "humanoid".to_string()),
        ("template", "mixamo".to_string()),
        ("animation", "preview".to_string()),
    ];
    let rigs = [
        rig(&app, "given", &given("none"), &out).await,
        rig(&app, "given_preview", &given("preview"), &out).await,
        rig(&app, "predicted_preview", &predicted, &out).await,
    ];
    assert!(!rigs[0].animated && rigs[1].animated && rigs[2].animated);
    assert_valid(&rigs.iter().map(|r| r.file.clone()).collect::<Vec<_>>());

    // One job per rig posing its busiest bone, and one per animated rig playing the clip.
    let mut cases: Vec<(usize, Option<usize>)> = Vec::new();
    for (i, r) in rigs.iter().enumerate() {
        cases.push((i, Some(busiest_bone(r))));
        if r.animated {
            cases.push((i, None));
        }
    }
    let label = |&(i, b): &(usize, Option<usize>)| {
        format!(
            "{} {}",
            rigs[i].label,
            b.map_or("clip".into(), |b| rigs[i].skeleton.bones[b].name.clone())
        )
    };
    let q = rotation().to_array();

    if browser_ready() {
        let jobs: Vec<Value> = cases
            .iter()
            .map(|&(i, b)| match b {
                Some(b) => json!({"url": rigs[i].url, "bone": b, "rotation": q}),
                None => json!({"url": rigs[i].url, "time": CLIP_TIME}),
            })
            .collect();
        let jobs_path = out.join("three_jobs.json");
        let res_path = out.join("three.json");
        std::fs::write(&jobs_path, serde_json::to_string(&jobs).unwrap()).unwrap();
        let (base, j, o) = (
            app.base.clone(),
            jobs_path.to_str().unwrap().to_string(),
            res_path.to_str().unwrap().to_string(),
        );
        tokio::task::spawn_blocking(move || node("three_deform.mjs", &[&base, &j, &o]))
            .await
            .unwrap();
        let results: Vec<Value> =
            serde_json::from_str(&std::fs::read_to_string(&res_path).unwrap()).unwrap();
        for (case, res) in cases.iter().zip(&results) {
            let r = &rigs[case.0];
            let name = format!("three.js {}", label(case));
            assert_eq!(
                res["joints"].as_u64(),
                Some(r.skeleton.len() as u64),
                "{name}"
            );
            assert_eq!(
                res["clips"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|c| c == PREVIEW_CLIP),
                r.animated,
                "{name}"
            );
            let d = worst(&name, r, &expected(r, case.1), res);
            assert!(d < TOLERANCE, "{name}: off by {d}");
        }
    }

    if blender_available() {
        let jobs: Vec<Value> = cases
            .iter()
            .map(|&(i, b)| {
                let file = rigs[i].file.to_str().unwrap();
                match b {
                    Some(b) => {
                        let bone = &rigs[i].skeleton.bones[b];
                        json!({"file": file, "bone": bone.name, "rotation": q, "pivot": bone.head.to_array()})
                    }
                    None => json!({"file": file, "time": CLIP_TIME}),
                }
            })
            .collect();
        let jobs_path = out.join("blender_jobs.json");
        let res_path = out.join("blender.json");
        std::fs::write(&jobs_path, serde_json::to_string(&jobs).unwrap()).unwrap();
        let status = tokio::task::spawn_blocking(move || {
            Command::new("python3")
                .arg(super::common::tools_dir().join("blender_check.py"))
                .args([&jobs_path, &res_path])
                .output()
                .unwrap()
        })
        .await
        .unwrap();
        assert!(
            status.status.success(),
            "blender_check.py failed: {}",
            String::from_utf8_lossy(&status.stderr)
        );
        let results: Vec<Value> =
            serde_json::from_str(&std::fs::read_to_string(out.join("blender.json")).unwrap())
                .unwrap();
        for (case, res) in cases.iter().zip(&results) {
            let r = &rigs[case.0];
            let name = format!("Blender {}", label(case));
            assert_eq!(
                res["joints"].as_u64(),
                Some(r.skeleton.len() as u64),
                "{name}"
            );
            assert_eq!(res["actions"].as_u64().unwrap() > 0, r.animated, "{name}");
            let d = worst(&name, r, &expected(r, case.1), res);
            assert!(d < TOLERANCE, "{name}: off by {d}");
        }
    }
    app.stop().await;
}
