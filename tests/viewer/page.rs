//! The viewer page end to end in headless Chromium (tools/viewer_e2e.mjs): upload, stages
//! over SSE with the progress bar, the rig drawn with the job's bone count, the heat map,
//! the motion, downloads, and a screenshot to look at.

use super::helpers::{figure_obj, spawn_app};
use super::{assert_valid, browser_ready, node, output_dir};
use serde_json::{json, Value};

#[tokio::test(flavor = "multi_thread")]
async fn the_page_rigs_a_mesh_and_shows_it_moving() {
    if !browser_ready() {
        return;
    }
    let app = spawn_app(|_| {}).await;
    let out = output_dir("page");
    let mesh = out.join("figure.obj");
    std::fs::write(&mesh, figure_obj()).unwrap();
    let options = json!({"category": "humanoid", "animation": true}).to_string();
    let base = app.base.clone();
    let (m, o) = (
        mesh.to_str().unwrap().to_string(),
        out.to_str().unwrap().to_string(),
    );
    let text =
        tokio::task::spawn_blocking(move || node("viewer_e2e.mjs", &[&base, &m, &o, &options]))
            .await
            .unwrap();
    let report: Value = serde_json::from_str(&text).unwrap();
    assert!(report["failure"].is_null(), "{:#}", report);
    assert_eq!(report["errors"], json!([]), "errors in the page");

    // The job the page made, seen through the API.
    let loaded = &report["loaded"];
    let id = loaded["jobId"].as_str().unwrap();
    let job = app.job(id).await;
    assert_eq!(job["status"], "succeeded");
    assert_eq!(job["options"]["animation"], "preview");
    assert_eq!(job["options"]["category"], "humanoid");
    let bones = job["result"]["bones"].as_u64().unwrap();
    let tree: Value = app
        .get(&format!("/v1/jobs/{id}/skeleton.json"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(tree["bones"].as_array().unwrap().len() as u64, bones);
    assert_eq!(loaded["bones"].as_u64(), Some(bones), "bones drawn");
    assert_eq!(loaded["joints"].as_u64(), Some(bones), "joints of the skin");
    assert_eq!(loaded["clip"], "rigserve_preview");
    assert!(
        report["overlayPixels"].as_u64().unwrap() > 50,
        "no skeleton pixels: {report}"
    );

    // Every stage was shown, in order, and the bar only moved forward to full.
    let stages: Vec<&str> = loaded["stagesSeen"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s.as_str().unwrap())
        .collect();
    assert_eq!(
        stages,
        [
            "validating",
            "encoding",
            "skeleton",
            "skinning",
            "exporting"
        ]
    );
    assert_eq!(report["stagesShown"].as_array().unwrap().len(), 5);
    let bar: Vec<f64> = report["progress"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["bar"].as_f64().unwrap())
        .collect();
    assert!(
        bar.windows(2).all(|w| w[0] <= w[1]),
        "progress went back: {bar:?}"
    );
    assert_eq!(bar.last().copied(), Some(1.0));

    for (link, path) in [
        ("download-glb", format!("/v1/jobs/{id}/result.glb")),
        ("download-skeleton", format!("/v1/jobs/{id}/skeleton.json")),
    ] {
        assert_eq!(report["downloads"][link]["href"], path.as_str());
        assert_eq!(report["downloads"][link]["status"], 200);
    }
    assert_eq!(report["heat"], 1);
    assert_eq!(report["playing"]["playing"], true);
    assert!(report["playing"]["time"].as_f64().unwrap() > 0.5);
    assert_eq!(report["paused"]["playing"], false);
    assert_eq!(report["canvasChangedWhilePlaying"], true);
    let shot = out.join("viewer.png");
    assert!(std::fs::metadata(&shot).unwrap().len() > 10_000);
    eprintln!("screenshot: {}", shot.display());

    let glb = app
        .get(&format!("/v1/jobs/{id}/result.glb"))
        .await
        .bytes()
        .await
        .unwrap();
    let file = out.join("page_result.glb");
    std::fs::write(&file, &glb).unwrap();
    assert_valid(&[file]);
    app.stop().await;
}
