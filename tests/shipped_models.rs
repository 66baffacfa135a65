//! What is measured ships: the default rig path of a copy of the committed tree (what a
//! user's clone, `make run` and the image have: no `../shared`, no hint) reads the same
//! models and library as this working tree, and rigs the same.

use rigserve::predict::library::Library;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn ort_lib() -> PathBuf {
    std::env::var_os("RIGSERVE_ORT_LIB")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo().join(".onnxruntime/libonnxruntime.so.1.31.1"))
}

/// `git archive HEAD` unpacked into a fresh directory, or None (with a message) when this
/// is not a git checkout.
fn committed_tree(into: &Path) -> Option<PathBuf> {
    let ok = Command::new("git")
        .current_dir(repo())
        .args(["rev-parse", "--is-inside-work-tree"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!("SKIPPED: not a git checkout, so there is no committed tree to copy");
        return None;
    }
    let tar = into.join("head.tar");
    let out = Command::new("git")
        .current_dir(repo())
        .args(["archive", "--format=tar", "-o"])
        .arg(&tar)
        .arg("HEAD")
        .output()
        .expect("git archive");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let root = into.join("clone");
    std::fs::create_dir_all(&root).unwrap();
    let out = Command::new("tar")
        .arg("-xf")
        .arg(&tar)
        .arg("-C")
        .arg(&root)
        .output()
        .expect("tar");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(root)
}

/// A small two-legged, two-armed figure as OBJ text: something for the default path to rig.
fn figure_obj() -> String {
    let boxes = [
        ([-0.25, 0.9, -0.15], [0.25, 1.5, 0.15]),  // torso
        ([-0.12, 1.5, -0.12], [0.12, 1.75, 0.12]), // head
        ([-0.22, 0.0, -0.1], [-0.05, 0.9, 0.1]),   // legs
        ([0.05, 0.0, -0.1], [0.22, 0.9, 0.1]),
        ([-0.85, 1.35, -0.07], [-0.25, 1.48, 0.07]), // arms
        ([0.25, 1.35, -0.07], [0.85, 1.48, 0.07]),
    ];
    let mut s = String::new();
    for (k, (lo, hi)) in boxes.iter().enumerate() {
        for i in 0..8 {
            let c = |a: usize| if i >> a & 1 == 1 { hi[a] } else { lo[a] };
            s += &format!("v {} {} {}\n", c(0), c(1), c(2));
        }
        let b = k * 8 + 1;
        for f in [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ] {
            s += &format!("f {} {} {} {}\n", b + f[0], b + f[1], b + f[2], b + f[3]);
        }
    }
    s
}

/// `rigserve rig --skeleton-only` with every default, run in `dir`: (stdout, stderr).
fn rig_default(dir: &Path, mesh: &Path) -> (String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .current_dir(dir)
        .env_remove("RIGSERVE_MODELS")
        .env_remove("RIGSERVE_LIBRARY")
        .env("RIGSERVE_ORT_LIB", ort_lib())
        .args(["rig", "--skeleton-only"])
        .arg(mesh)
        .output()
        .expect("rigserve rig");
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    (String::from_utf8_lossy(&out.stdout).to_string(), stderr)
}

#[test]
fn a_copy_of_the_committed_tree_rigs_with_the_same_library_as_the_working_tree() {
    if !ort_lib().is_file() {
        eprintln!(
            "SKIPPED: no ONNX Runtime at {} (make setup fetches it)",
            ort_lib().display()
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let Some(clone) = committed_tree(tmp.path()) else {
        return;
    };
    let lib = Path::new("models/library.bin");
    let committed = std::fs::read(clone.join(lib)).expect("models/library.bin is committed");
    assert_eq!(
        committed,
        std::fs::read(repo().join(lib)).unwrap(),
        "the working tree's library differs from the committed one"
    );
    let mesh = tmp.path().join("figure.obj");
    std::fs::write(&mesh, figure_obj()).unwrap();
    let (tree_here, err_here) = rig_default(&repo(), &mesh);
    let (tree_clone, err_clone) = rig_default(&clone, &mesh);
    for err in [&err_here, &err_clone] {
        assert!(
            err.contains("skeleton library: models/library.bin"),
            "{err}"
        );
    }
    assert_eq!(tree_here, tree_clone, "the clone rigs differently");
    assert!(tree_clone.contains("\"bones\""), "{tree_clone}");
}

#[test]
fn every_rig_of_the_shipped_library_is_credited_in_the_notice() {
    let lib = Library::load(&repo().join("models/library.bin")).expect("the shipped library loads");
    assert!(lib.entries.len() >= 100, "{} entries", lib.entries.len());
    let notice = std::fs::read_to_string(repo().join("models/NOTICE")).expect("models/NOTICE");
    let missing: Vec<&str> = lib
        .entries
        .iter()
        .map(|e| e.name.trim_end_matches(".glb"))
        .filter(|n| !notice.contains(n))
        .collect();
    assert!(
        missing.is_empty(),
        "not credited in models/NOTICE: {missing:?}"
    );
}

/// With `../shared` beside the checkout: the dev figures of a copy of the committed tree
/// are those of the working tree (eval's defaults: no hint, the models folder's library).
#[test]
fn eval_figures_of_the_committed_tree_match_the_working_tree() {
    let rigs = repo().join("../shared/rigs");
    if !rigs.join("manifest.tsv").is_file() || !ort_lib().is_file() {
        eprintln!("SKIPPED: needs ../shared/rigs and ONNX Runtime");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let Some(clone) = committed_tree(tmp.path()) else {
        return;
    };
    let eval = |dir: &Path, out: &Path| {
        let o = Command::new(env!("CARGO_BIN_EXE_rigserve"))
            .current_dir(dir)
            .env_remove("RIGSERVE_MODELS")
            .env_remove("RIGSERVE_LIBRARY")
            .env("RIGSERVE_ORT_LIB", ort_lib())
            .args(["eval", "--skeleton-only", "--split", "dev", "--dataset"])
            .arg(&rigs)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out).unwrap()).unwrap();
        r
    };
    let here = eval(&repo(), &tmp.path().join("here.json"));
    let there = eval(&clone, &tmp.path().join("there.json"));
    assert_eq!(here["overall"], there["overall"]);
    assert_eq!(here["used"]["category_hint"], false);
    assert_eq!(
        here["used"]["library"]["sha256"], there["used"]["library"]["sha256"],
        "{}",
        here["used"]
    );
    assert!(here["per_artist"]
        .as_object()
        .is_some_and(|m| !m.is_empty()));
    // What the README states is what the committed tree measures.
    let (j2j, j2b, b2b) = readme_dev_figures();
    let sk = &there["overall"]["skeleton"];
    for (name, stated) in [("cd_j2j", j2j), ("cd_j2b", j2b), ("cd_b2b", b2b)] {
        let measured = sk[name].as_f64().unwrap();
        assert!(
            (measured - stated).abs() < 0.00006,
            "README states dev {name} {stated}, the committed tree measures {measured:.5}"
        );
    }
}

/// The dev row of the README's skeleton table (the one under `<!-- figures: skeleton -->`).
fn readme_dev_figures() -> (f64, f64, f64) {
    let readme = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let table = readme
        .split("<!-- figures: skeleton -->")
        .nth(1)
        .expect("README has the skeleton figures table");
    let row = table
        .lines()
        .find(|l| l.starts_with("| dev"))
        .expect("a dev row");
    let cells: Vec<f64> = row
        .split('|')
        .filter_map(|c| c.trim().parse().ok())
        .collect();
    assert!(cells.len() >= 3, "{row}");
    (cells[0], cells[1], cells[2])
}
