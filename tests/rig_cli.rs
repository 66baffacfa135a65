//! `rigserve rig` as a user runs it, with the shipped models and library, on a dev
//! humanoid of `../shared/rigs` (skipped without it or without ONNX Runtime).
mod common;

use std::path::Path;
use std::process::Command;

fn bone_names(mesh: &Path, extra: &[&str]) -> Vec<String> {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bones.json");
    let mut args = vec!["--skeleton-only", "--bones", out.to_str().unwrap()];
    args.extend(extra);
    common::rig(mesh, &args);
    let tree: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    tree["bones"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["name"].as_str().unwrap().to_string())
        .collect()
}

/// `--template mixamo` decodes the Mixamo body template, so Mixamo clips find their bones;
/// `--template none` decodes freely; an unknown name is refused by the parser.
#[test]
fn rig_template_names_the_bones_the_way_asked() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    if !common::ort_ready() {
        return;
    }
    let king = dir.join("modular_men__King.glb");
    let mixamo = bone_names(&king, &["--template", "mixamo"]);
    for want in [
        "mixamorig:Hips",
        "mixamorig:Spine",
        "mixamorig:Head",
        "mixamorig:LeftArm",
    ] {
        assert!(
            mixamo.iter().any(|n| n == want),
            "{want} missing: {mixamo:?}"
        );
    }
    let free = bone_names(&king, &["--template", "none"]);
    assert!(!free.iter().any(|n| n == "mixamorig:Hips"), "{free:?}");

    let run = Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .arg("rig")
        .arg(&king)
        .args(["--template", "unity"])
        .output()
        .unwrap();
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("--template"));
}
