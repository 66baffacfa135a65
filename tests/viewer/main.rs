//! The viewer page and what it relies on: the embedded assets, the page driven in
//! headless Chromium, the preview animation, rigserve's GLBs deforming the same in
//! Blender, three.js and rigserve's own skinning, and the example Python client.
//!
//! Browser tests need `chromium` (Debian) and `npm ci --prefix tools` (playwright-core,
//! three, gltf-validator); Blender tests need PyPI `bpy`. `scripts/setup.sh` installs all
//! of them; without them those tests skip with a message.

#[path = "../common/mod.rs"]
mod common;
#[allow(dead_code)]
#[path = "../api/helpers.rs"]
mod helpers;

mod assets;
mod client;
mod cors;
mod deform;
mod page;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

/// Where the tests leave what a person may want to look at (screenshots).
pub fn output_dir(name: &str) -> PathBuf {
    let dir = helpers::repo().join("target/test-output/viewer").join(name);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Chromium and the npm packages that drive it; false (with a message) when absent.
pub fn browser_ready() -> bool {
    static READY: Mutex<Option<bool>> = Mutex::new(None);
    let mut ready = READY.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(r) = *ready {
        return r;
    }
    let chromium = std::env::var_os("RIGSERVE_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    let tools = common::tools_dir();
    let installed = |d: &Path| {
        d.join("node_modules/playwright-core/package.json")
            .is_file()
    };
    let ok = if !chromium.is_file() {
        eprintln!(
            "SKIPPED: no Chromium at {} (apt-get install chromium, or scripts/setup.sh)",
            chromium.display()
        );
        false
    } else if !common::node_tools_ready() {
        false
    } else if installed(&tools) {
        true
    } else {
        let status = Command::new("npm")
            .args([
                "ci",
                "--prefix",
                tools.to_str().unwrap(),
                "--no-audit",
                "--no-fund",
            ])
            .status();
        let ok = matches!(status, Ok(s) if s.success()) && installed(&tools);
        if !ok {
            eprintln!(
                "SKIPPED: playwright-core is not installed and `npm ci --prefix tools` failed"
            );
        }
        ok
    };
    *ready = Some(ok);
    ok
}

/// Runs a node script from tools/ and returns its standard output; panics with its
/// standard error when it fails.
pub fn node(script: &str, args: &[&str]) -> String {
    let out = Command::new("node")
        .arg(common::tools_dir().join(script))
        .args(args)
        .output()
        .expect("node runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{script} failed: {stderr}");
    if !stderr.trim().is_empty() {
        eprintln!("{script}: {stderr}");
    }
    String::from_utf8(out.stdout).unwrap()
}

/// Every GLB in `files` passes the Khronos validator with no errors (skips when the
/// validator is not installed).
pub fn assert_valid(files: &[PathBuf]) {
    let Some(reports) = common::validate(files) else {
        return;
    };
    let bad = common::errors_of(&reports);
    assert!(bad.is_empty(), "validator errors: {bad:#?}");
}
