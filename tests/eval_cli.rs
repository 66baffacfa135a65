//! `rigserve eval --pred`, run as a user runs it: the data set scored against itself is
//! perfect, and a copy with known damage reports that damage.
mod common;

use glam::Vec3;
use rigserve::export::{export_glb, ExportOptions};
use rigserve::mesh::{load, Limits, Normalization};
use rigserve::rig::groundtruth::extract;
use serde_json::Value;
use std::ffi::OsStr;
use std::path::Path;
use std::process::Command;

/// Runs `rigserve eval ARGS --out OUT` from the repository root and reads the report.
fn run_eval<S: AsRef<OsStr>>(args: impl IntoIterator<Item = S>, out: &Path) -> Value {
    let status = Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .arg("eval")
        .args(args)
        .arg("--out")
        .arg(out)
        .status()
        .expect("run rigserve eval");
    assert!(status.success());
    serde_json::from_slice(&std::fs::read(out).unwrap()).unwrap()
}

fn eval(dataset: &Path, pred: &Path, out: &Path, split: Option<&str>) -> Value {
    let mut args: Vec<&OsStr> = vec![
        "--dataset".as_ref(),
        dataset.as_os_str(),
        "--pred".as_ref(),
        pred.as_os_str(),
    ];
    if let Some(s) = split {
        args.extend([OsStr::new("--split"), OsStr::new(s)]);
    }
    run_eval(args, out)
}

#[test]
fn the_data_set_scores_perfectly_against_itself() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let r = eval(&dir, &dir, &tmp.path().join("r.json"), None);
    let o = &r["overall"];
    assert_eq!(o["count"], 163);
    assert_eq!(o["valid_fraction"], 1.0);
    for k in ["cd_j2j", "cd_j2b", "cd_b2b"] {
        assert_eq!(o["skeleton"][k], 0.0, "{k}");
    }
    assert_eq!(o["skin"]["l1"], 0.0);
    assert_eq!(o["skin"]["deformation"], 0.0);
    assert_eq!(o["skin"]["precision"], 1.0);
    assert_eq!(o["skin"]["recall"], 1.0);
    assert_eq!(r["per_category"].as_object().unwrap().len(), 8);
    let dev = eval(&dir, &dir, &tmp.path().join("dev.json"), Some("dev"));
    assert_eq!(dev["overall"]["count"], 23);
}

/// A perturbed copy: every joint shifted by a known offset in one file, every weight moved
/// to the root bone in another, and a third file missing.
#[test]
fn a_perturbed_copy_reports_the_expected_error() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let entries = common::manifest(&dir);
    let pick: Vec<_> = entries
        .iter()
        .filter(|e| e.split == "dev")
        .take(3)
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let (data, pred) = (tmp.path().join("data"), tmp.path().join("pred"));
    std::fs::create_dir_all(&data).unwrap();
    std::fs::create_dir_all(&pred).unwrap();
    let mut manifest = String::from("file\tsplit\tcategory\n");
    let mut expected_j2j = 0.0;
    for (i, e) in pick.iter().enumerate() {
        std::fs::copy(dir.join(&e.file), data.join(&e.file)).unwrap();
        manifest += &format!("{}\tdev\t{}\n", e.file, e.category);
        let asset = load(
            &std::fs::read(dir.join(&e.file)).unwrap(),
            &Limits::default(),
        )
        .unwrap();
        let gt = extract(&asset).unwrap().unwrap();
        let mut skel = gt.skeleton.clone();
        let mut weights = gt.weights.clone();
        weights.top_k(4);
        match i {
            0 => {
                let half = Normalization::from_points(&asset.mesh.positions).half_extent;
                // 5% of the half extent along X: every joint's nearest is its own copy.
                let d = Vec3::new(0.05 * half, 0.0, 0.0);
                skel.map_points(|p| p + d);
                expected_j2j = 0.05 / 2.0;
            }
            1 => {
                for w in weights.per_vertex.iter_mut().filter(|w| !w.is_empty()) {
                    *w = vec![(0, 1.0)];
                }
            }
            _ => continue,
        }
        let glb = export_glb(&asset, &skel, &weights, &ExportOptions::default()).unwrap();
        std::fs::write(pred.join(&e.file), glb).unwrap();
    }
    std::fs::write(data.join("manifest.tsv"), manifest).unwrap();
    let r = eval(&data, &pred, &tmp.path().join("r.json"), None);
    let m = r["models"].as_array().unwrap();
    let f = |v: &Value| v.as_f64().unwrap();
    // Shifted joints: J2J is the shift in reported units; skin metrics are untouched.
    assert!(
        (f(&m[0]["skeleton"]["cd_j2j"]) - expected_j2j).abs() < 1e-3,
        "{}",
        m[0]
    );
    assert!(f(&m[0]["skeleton"]["cd_b2b"]) > 0.0);
    assert!(f(&m[0]["skin"]["l1"]) < 1e-5);
    // Weights moved to the root: skeleton exact, skin wrong, deformation visible.
    assert!(f(&m[1]["skeleton"]["cd_j2j"]) < 1e-5);
    assert!(f(&m[1]["skin"]["l1"]) > 0.5, "{}", m[1]);
    assert!(f(&m[1]["skin"]["deformation"]) > 0.0);
    assert!(f(&m[1]["skin"]["recall"]) < 1.0);
    // Missing output: counted as invalid.
    assert_eq!(m[2]["valid"], false);
    assert_eq!(m[2]["error"]["code"], "missing");
    assert!((f(&r["overall"]["valid_fraction"]) - 2.0 / 3.0).abs() < 1e-6);
}

#[test]
fn the_category_medoid_baseline_scores_every_dev_mesh() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("b.json");
    let r = run_eval(
        [
            OsStr::new("--baseline"),
            "--split".as_ref(),
            "dev".as_ref(),
            "--dataset".as_ref(),
            dir.as_os_str(),
        ],
        &out,
    );
    assert_eq!(r["overall"]["count"], 23);
    assert_eq!(r["overall"]["valid_fraction"], 1.0);
    let j2j = r["overall"]["skeleton"]["cd_j2j"].as_f64().unwrap();
    // A stretched stand-in skeleton is roughly placed, never exact.
    assert!(j2j > 0.01 && j2j < 0.5, "{j2j}");
}

/// ../shared/rigs and the repository root, when both the rigs and ONNX Runtime are there.
fn rigs_and_runtime() -> Option<(std::path::PathBuf, &'static Path)> {
    let dir = common::shared_rigs()?;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if !root.join(".onnxruntime/libonnxruntime.so.1.31.1").is_file() {
        eprintln!("SKIPPED: .onnxruntime/ is absent (scripts/setup.sh fetches it)");
        return None;
    }
    Some((dir, root))
}

/// A data set of `(file, category)` rows of `dir`, copied into a temporary folder as a
/// `dev` split (the folder, and the data set inside it).
fn dev_subset(dir: &Path, rows: &[(String, String)]) -> (tempfile::TempDir, std::path::PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    let mut manifest = String::from("file\tsplit\tcategory\n");
    for (file, category) in rows {
        std::fs::copy(dir.join(file), data.join(file)).unwrap();
        manifest += &format!("{file}\tdev\t{category}\n");
    }
    std::fs::write(data.join("manifest.tsv"), manifest).unwrap();
    (tmp, data)
}

/// The model-driven mode, with the tiny random-weight fixture: every mesh must get a
/// valid skeleton and finite scores (the fixture's skeletons are nonsense; the plumbing
/// is what is under test).
#[test]
fn skeleton_only_eval_runs_the_model_on_every_mesh() {
    let Some((dir, _)) = rigs_and_runtime() else {
        return;
    };
    let rows: Vec<(String, String)> = common::manifest(&dir)
        .into_iter()
        .filter(|e| e.split == "dev")
        .take(3)
        .map(|e| (e.file, e.category))
        .collect();
    let (tmp, data) = dev_subset(&dir, &rows);
    let out = tmp.path().join("m.json");
    let r = run_eval(
        [
            OsStr::new("--skeleton-only"),
            "--samples".as_ref(),
            "2".as_ref(),
            "--models".as_ref(),
            "tests/fixtures/tiny_skeleton".as_ref(),
            "--dataset".as_ref(),
            data.as_os_str(),
        ],
        &out,
    );
    assert_eq!(r["overall"]["count"], 3);
    assert_eq!(r["overall"]["valid_fraction"], 1.0);
    assert!(r["overall"]["skeleton"]["cd_j2j"]
        .as_f64()
        .unwrap()
        .is_finite());
    assert!(r["models"]
        .as_array()
        .unwrap()
        .iter()
        .all(|m| m["joints_pred"].as_u64().unwrap() > 0));
}

/// `rigserve library` writes a library from rigged files, and `eval --skeleton-only`
/// borrows from it: a mesh whose sibling (same pack, same rig) is in the library gets the
/// sibling's skeleton moved onto it, and a file being scored never lends its own, even
/// when the library holds it.
#[test]
fn the_library_lends_a_siblings_skeleton_but_never_the_scored_files_own() {
    let Some((dir, root)) = rigs_and_runtime() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (scored, all) = (tmp.path().join("scored"), tmp.path().join("all"));
    let files = [
        ("modular_men__Farmer.glb", "train"),
        ("modular_men__Beach.glb", "train"),
        ("cute_fish_pack__Piranha.glb", "train"),
        ("modular_men__Worker.glb", "dev"),
    ];
    for d in [&scored, &all] {
        std::fs::create_dir_all(d).unwrap();
    }
    let (mut m_scored, mut m_all) = (
        String::from("file\tsplit\tcategory\n"),
        String::from("file\tsplit\tcategory\n"),
    );
    for (f, split) in files {
        let cat = if f.starts_with("cute_fish") {
            "fish_snake_tail"
        } else {
            "humanoid"
        };
        for d in [&scored, &all] {
            std::fs::copy(dir.join(f), d.join(f)).unwrap();
        }
        m_scored += &format!("{f}\t{split}\t{cat}\n");
        m_all += &format!("{f}\tlib\t{cat}\n");
    }
    std::fs::write(scored.join("manifest.tsv"), m_scored).unwrap();
    std::fs::write(all.join("manifest.tsv"), m_all).unwrap();

    let bin = env!("CARGO_BIN_EXE_rigserve");
    let lib = tmp.path().join("library.json");
    let out = Command::new(bin)
        .args(["library", "--split", "lib", "--dataset"])
        .arg(&all)
        .arg("--out")
        .arg(&lib)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let written: Value = serde_json::from_slice(&std::fs::read(&lib).unwrap()).unwrap();
    assert_eq!(written["entries"].as_array().unwrap().len(), 4);

    let report = tmp.path().join("r.json");
    let out = Command::new(bin)
        .current_dir(root)
        .args([
            "eval",
            "--skeleton-only",
            "--split",
            "dev",
            "--samples",
            "2",
        ])
        .args(["--models", "tests/fixtures/tiny_skeleton", "--library"])
        .arg(&lib)
        .arg("--dataset")
        .arg(&scored)
        .arg("--out")
        .arg(&report)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("left out 1 entries, each while its own file is scored"),
        "{stderr}"
    );
    let r: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let m = &r["models"][0];
    assert_eq!(m["file"], "modular_men__Worker.glb");
    let cands = m["candidates"].as_array().unwrap();
    let chosen = &cands[m["chosen"].as_u64().unwrap() as usize];
    assert_eq!(chosen["origin"]["kind"], "library", "{chosen}");
    let name = chosen["origin"]["name"].as_str().unwrap();
    assert!(
        name.starts_with("modular_men__") && name != "modular_men__Worker.glb",
        "{name}"
    );
    // The same rig moved onto a sibling mesh: close to the artist's own.
    let j2j = m["skeleton"]["cd_j2j"].as_f64().unwrap();
    assert!(j2j < 0.03, "{j2j}");

    // A folder with nothing readable makes no library.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    std::fs::write(
        empty.join("manifest.tsv"),
        "file\tsplit\tcategory\nnope.glb\tlib\thumanoid\n",
    )
    .unwrap();
    let out = Command::new(bin)
        .args(["library", "--split", "lib", "--dataset"])
        .arg(&empty)
        .arg("--out")
        .arg(tmp.path().join("none.json"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no rig of split lib"));
}

/// `eval --rotate` turns a data set as a Z-up export or a mesh lying on its side would
/// arrive; `--up` naming the axis that is up then rigs it exactly as upright (a turn is an
/// axis permutation, undone exactly), and `--up auto` finds that axis for these humanoids.
/// Shipped models and library, four dev humanoids.
#[test]
fn a_turned_data_set_rigs_as_upright_when_its_up_axis_is_given_or_found() {
    let Some((dir, _)) = rigs_and_runtime() else {
        return;
    };
    let rows: Vec<(String, String)> = [
        "modular_men__King.glb",
        "modular_men__Worker.glb",
        "Animated_Women_Characters__Female_Dress.glb",
        "Animated_Women_Characters__Female_Casual.glb",
    ]
    .map(|f| (f.to_string(), "humanoid".to_string()))
    .into();
    let (tmp, data) = dev_subset(&dir, &rows);
    let run = |name: &str, extra: &[&str]| {
        let mut args: Vec<&OsStr> = vec![
            "--skeleton-only".as_ref(),
            "--dataset".as_ref(),
            data.as_os_str(),
        ];
        args.extend(extra.iter().map(OsStr::new));
        let r = run_eval(args, &tmp.path().join(format!("{name}.json")));
        r["models"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["skeleton"]["cd_j2j"].as_f64().unwrap())
            .collect::<Vec<f64>>()
    };
    let upright = run("upright", &[]);
    let lying = run("lying", &["--rotate", "z90"]);
    assert_ne!(lying, upright, "z90 must turn the data set");
    for (rotate, up) in [("x90", "z"), ("x-90", "-z"), ("z90", "-x")] {
        let up = format!("--up={up}");
        assert_eq!(
            run(rotate, &["--rotate", rotate, &up]),
            upright,
            "{rotate} {up}"
        );
        let auto = run(rotate, &["--rotate", rotate, "--up", "auto"]);
        assert_eq!(auto, upright, "{rotate} --up auto");
    }
}
