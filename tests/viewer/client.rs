//! examples/client.py against a running server: upload with options, follow the events
//! to the end, download both results.

use super::helpers::{figure_obj, figure_skeleton, repo, spawn_app};
use super::{assert_valid, output_dir};
use std::process::Command;

#[tokio::test(flavor = "multi_thread")]
async fn the_python_client_uploads_follows_and_downloads() {
    let app = spawn_app(|_| {}).await;
    let out = output_dir("client");
    let mesh = out.join("figure.obj");
    std::fs::write(&mesh, figure_obj()).unwrap();
    let skeleton = format!("skeleton={}", figure_skeleton());
    let (base, m, o) = (app.base.clone(), mesh.clone(), out.clone());
    let run = tokio::task::spawn_blocking(move || {
        Command::new("python3")
            .arg(repo().join("examples/client.py"))
            .arg(&m)
            .args(["--server", base.as_str(), "--out", o.to_str().unwrap()])
            .args(["--option", "skin_only=true", "--option", skeleton.as_str()])
            .args(["--option", "animation=preview"])
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    // The stages it printed as they came, ending in success.
    for stage in ["validating", "skinning", "exporting", "succeeded"] {
        assert!(stdout.contains(stage), "{stage} missing from:\n{stdout}");
    }
    let glb = out.join("figure.rigged.glb");
    let tree: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("figure.skeleton.json")).unwrap()).unwrap();
    assert_eq!(tree["bones"].as_array().unwrap().len(), 7);
    let bytes = std::fs::read(&glb).unwrap();
    assert_eq!(&bytes[..4], b"glTF");
    assert!(String::from_utf8_lossy(&bytes).contains("rigserve_preview"));
    assert_valid(&[glb]);

    // A failing job is reported as such, with the exit status saying so.
    let bad = out.join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n").unwrap();
    let base = app.base.clone();
    let run = tokio::task::spawn_blocking(move || {
        Command::new("python3")
            .arg(repo().join("examples/client.py"))
            .arg(&bad)
            .args(["--server", base.as_str()])
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    // Refused at upload: one line naming the status and the server's error_type.
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("HTTP 422") && stderr.contains("(degenerate_mesh)"),
        "{stderr}"
    );
    app.stop().await;

    // No server there: one line, no traceback.
    let dead = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", dead.local_addr().unwrap());
    drop(dead);
    let run = Command::new("python3")
        .arg(repo().join("examples/client.py"))
        .arg(&mesh)
        .args(["--server", url.as_str()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.starts_with("error: cannot reach rigserve at ") && !stderr.contains("Traceback"),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
}
