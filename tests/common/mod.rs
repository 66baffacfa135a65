//! Helpers shared by the integration tests.
#![allow(dead_code)]

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

/// The artist-rigged data set beside the checkout, or None (with a message) when a
/// fresh clone has no `../shared`.
pub fn shared_rigs() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/rigs");
    if dir.join("manifest.tsv").is_file() {
        Some(dir)
    } else {
        eprintln!("SKIPPED: ../shared/rigs is absent; the data-set tests need it");
        None
    }
}

pub struct Entry {
    pub file: String,
    pub split: String,
    pub category: String,
}

pub fn manifest(dir: &std::path::Path) -> Vec<Entry> {
    let text = std::fs::read_to_string(dir.join("manifest.tsv")).expect("manifest");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split('\t').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (f, s, c) = (col("file"), col("split"), col("category"));
    lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split('\t').collect();
            Entry {
                file: v[f].into(),
                split: v[s].into(),
                category: v[c].into(),
            }
        })
        .collect()
}

// ---------------------------------------------------------------------------------------
// The Khronos glTF validator (tools/validate.mjs).

pub fn tools_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tools")
}

/// Installs tools/node_modules once per test run; false (with a message) when npm cannot.
pub fn node_tools_ready() -> bool {
    static READY: Mutex<Option<bool>> = Mutex::new(None);
    let mut ready = READY.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(r) = *ready {
        return r;
    }
    let installed = |d: &Path| {
        d.join("node_modules/gltf-validator/package.json").is_file()
            && d.join("node_modules/ajv/package.json").is_file()
    };
    let dir = tools_dir();
    let mut ok = installed(&dir);
    if !ok {
        for args in [&["ci"][..], &["install"][..]] {
            let status = Command::new("npm")
                .args(args)
                .args(["--prefix", dir.to_str().unwrap(), "--no-audit", "--no-fund"])
                .status();
            if matches!(status, Ok(s) if s.success()) && installed(&dir) {
                ok = true;
                break;
            }
        }
    }
    if !ok {
        eprintln!(
            "SKIPPED: the glTF validator is not installed and `npm ci --prefix tools` failed"
        );
    }
    *ready = Some(ok);
    ok
}

/// Runs tools/validate.mjs on `files`; one report per file, or None when node is missing.
/// Image files an input named by URI are not in the data set, so missing external
/// resources are not counted (everything else about them is).
pub fn validate(files: &[PathBuf]) -> Option<Vec<Value>> {
    if !node_tools_ready() {
        return None;
    }
    let out = Command::new("node")
        .arg(tools_dir().join("validate.mjs"))
        .arg("--allow-missing-external")
        .arg("--bone-tree-schema")
        .arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("proto/bone_tree.schema.json"))
        .args(files)
        .output();
    let out = match out {
        Ok(o) => o,
        Err(e) => {
            eprintln!("SKIPPED: cannot run node: {e}");
            return None;
        }
    };
    let text = String::from_utf8_lossy(&out.stdout);
    let reports: Vec<Value> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("validator output {l:?}: {e}")))
        .collect();
    assert_eq!(
        reports.len(),
        files.len(),
        "validator: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(reports)
}

pub fn errors_of(reports: &[Value]) -> Vec<&Value> {
    reports
        .iter()
        .filter(|r| r["numErrors"].as_u64() != Some(0))
        .collect()
}

/// Every file passes the Khronos validator with no errors (nothing checked, with the
/// validator's own message, when node or the validator is missing).
pub fn assert_valid(files: &[PathBuf]) {
    if let Some(reports) = validate(files) {
        let bad = errors_of(&reports);
        assert!(bad.is_empty(), "validator errors: {bad:#?}");
    }
}

/// ONNX Runtime as `scripts/setup.sh` unpacks it; false (with a message) when absent, for
/// tests that run the shipped models through the CLI.
pub fn ort_ready() -> bool {
    let lib =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(".onnxruntime/libonnxruntime.so.1.31.1");
    if !lib.is_file() {
        eprintln!("SKIPPED: .onnxruntime/ is absent (scripts/setup.sh fetches it)");
    }
    lib.is_file()
}

/// Runs `rigserve rig INPUT ARGS` from the repository root (so with the shipped models)
/// and fails the test with its standard error when it fails.
pub fn rig(input: &Path, args: &[&str]) {
    let run = Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .arg("rig")
        .arg(input)
        .args(args)
        .output()
        .expect("run rigserve rig");
    assert!(
        run.status.success(),
        "rigserve rig {}: {}",
        input.display(),
        String::from_utf8_lossy(&run.stderr)
    );
}
