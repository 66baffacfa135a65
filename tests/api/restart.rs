//! Jobs survive kill -9: the server runs as a separate process, is killed with SIGKILL
//! while jobs are queued and running, and a new process on the same data directory
//! finishes every one of them.

use super::helpers::{figure_obj, model_setup, repo};
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn start(data: &std::path::Path, workers: usize) -> (Child, String) {
    let m = model_setup();
    let mut child = Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .args([
            "serve",
            "--bind",
            "127.0.0.1:0",
            "--poll",
            "0.05",
            "--lease",
            "3",
        ])
        .arg("--data-dir")
        .arg(data)
        .arg("--models")
        .arg(&m.dir)
        .arg("--ort-lib")
        .arg(m.ort_lib.unwrap())
        .args(["--workers", &workers.to_string()])
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let base = line
        .trim()
        .strip_prefix("rigserve listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    (child, base)
}

#[tokio::test]
async fn jobs_survive_kill_9() {
    let data = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    let (mut first, base) = start(data.path(), 1);
    let mut ids = Vec::new();
    for seed in 0..5 {
        let r = client
            .post(format!("{base}/v1/jobs?seed={seed}"))
            .header("content-type", "model/obj")
            .body(figure_obj())
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 202);
        ids.push(
            r.json::<Value>().await.unwrap()["id"]
                .as_str()
                .unwrap()
                .to_string(),
        );
    }
    // Let the single worker get into the first jobs, then kill without warning.
    let start_wait = Instant::now();
    loop {
        let j: Value = client
            .get(format!("{base}/v1/jobs/{}", ids[0]))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if j["status"] != "queued" || start_wait.elapsed() > Duration::from_secs(30) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    first.kill().unwrap();
    first.wait().unwrap();

    let (mut second, base) = start(data.path(), 2);
    let deadline = Instant::now() + Duration::from_secs(180);
    for id in &ids {
        loop {
            let j: Value = client
                .get(format!("{base}/v1/jobs/{id}"))
                .send()
                .await
                .unwrap()
                .json()
                .await
                .unwrap();
            match j["status"].as_str().unwrap() {
                "succeeded" => {
                    let r = client
                        .get(format!("{base}/v1/jobs/{id}/result.glb"))
                        .send()
                        .await
                        .unwrap();
                    assert_eq!(r.status(), 200);
                    break;
                }
                "queued" | "running" => {}
                other => panic!("job {id} ended {other}: {j}"),
            }
            assert!(Instant::now() < deadline, "job {id} never finished");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
    second.kill().unwrap();
    second.wait().unwrap();
}
