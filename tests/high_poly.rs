//! High-poly inputs skin on a coarse copy (`SkinConfig::max_vertices`, `rig
//! --skin-max-vertices`) and every vertex blends its clusters' weights: the subdivided test
//! figure, with the cap set below its size, rigs into a GLB the validator passes, every
//! vertex weighted, and its weights close to those of the figure skinned whole.
mod common;
#[allow(dead_code)]
#[path = "api/helpers.rs"]
mod helpers;

use rigserve::mesh::{load, Limits, Mesh};
use rigserve::rig::skin::{skin_with, SkinConfig};
use rigserve::rig::SkinWeights;

fn write_obj(m: &Mesh) -> String {
    let mut s = String::new();
    for p in &m.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &m.triangles {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

/// Mean over vertices of the L1 distance between two weight sets, per bone.
fn l1(a: &SkinWeights, b: &SkinWeights, bones: usize) -> f32 {
    let dense = |w: &[(u32, f32)]| {
        let mut d = vec![0f32; bones];
        for &(j, x) in w {
            d[j as usize] += x;
        }
        d
    };
    let total: f32 = a
        .per_vertex
        .iter()
        .zip(&b.per_vertex)
        .map(|(x, y)| {
            dense(x)
                .iter()
                .zip(dense(y))
                .map(|(p, q)| (p - q).abs())
                .sum::<f32>()
        })
        .sum();
    total / a.per_vertex.len() as f32
}

#[test]
fn a_coarse_copy_skins_like_the_whole_mesh() {
    let dense = helpers::figure_mesh().subdivided().subdivided();
    let skeleton = rigserve::export::parse_bone_tree(&helpers::figure_skeleton()).unwrap();
    let whole = SkinConfig {
        max_vertices: 0,
        ..SkinConfig::default()
    };
    let n = dense.positions.len();
    let coarse = SkinConfig {
        max_vertices: n / 2,
        ..SkinConfig::default()
    };
    let a = skin_with(&dense, &skeleton, &whole, None).unwrap();
    let b = skin_with(&dense, &skeleton, &coarse, None).unwrap();
    assert_eq!(b.per_vertex.len(), n);
    assert!(
        b.per_vertex.iter().all(|w| !w.is_empty()),
        "an unweighted vertex"
    );
    let d = l1(&a, &b, skeleton.len());
    // Geometric weights; the learned model is measured on dev and xdev (MODEL_CARD).
    assert!(d < 0.1, "mean L1 {d} between the coarse and the whole skin");
}

#[test]
fn a_subdivided_mesh_rigs_into_a_valid_glb_on_the_coarse_path() {
    if !common::ort_ready() {
        return;
    }
    let dense = helpers::figure_mesh().subdivided().subdivided();
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("dense.obj");
    std::fs::write(&input, write_obj(&dense)).unwrap();
    let out = tmp.path().join("dense.glb");
    let cap = (dense.positions.len() / 8).to_string();
    common::rig(
        &input,
        &[
            "--out",
            out.to_str().unwrap(),
            "--category",
            "humanoid",
            "--skin-max-vertices",
            &cap,
        ],
    );
    let back = load(&std::fs::read(&out).unwrap(), &Limits::default()).unwrap();
    assert_eq!(back.mesh.positions.len(), dense.positions.len());
    let gt = rigserve::rig::groundtruth::extract(&back).unwrap().unwrap();
    assert!(gt.weights.per_vertex.iter().all(|w| !w.is_empty()));
    common::assert_valid(&[out]);
}
