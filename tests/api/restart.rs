//! Jobs survive kill -9: the server runs as a separate process, is killed with SIGKILL
//! while jobs are queued and running, and a new process on the same data directory
//! finishes every one of them.

use super::helpers::figure_obj;
use super::infra::{job, spawn_serve, submit_obj, wait_job};
use std::time::{Duration, Instant};

fn start(data: &std::path::Path, workers: usize) -> (super::infra::Kill, String) {
    let args: Vec<String> = vec![
        "--poll=0.05".into(),
        "--lease=3".into(),
        format!("--data-dir={}", data.display()),
        format!("--workers={workers}"),
    ];
    spawn_serve(&args, &[])
}

#[tokio::test]
async fn jobs_survive_kill_9() {
    let data = tempfile::tempdir().unwrap();
    let c = reqwest::Client::new();
    let (mut first, base) = start(data.path(), 1);
    let mut ids = Vec::new();
    for seed in 0..5 {
        ids.push(submit_obj(&c, &base, &format!("?seed={seed}"), &figure_obj()).await);
    }
    // Let the single worker get into the first jobs, then kill without warning.
    let t = Instant::now();
    while job(&c, &base, &ids[0]).await["status"] == "queued" && t.elapsed().as_secs() < 30 {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    first.0.kill().unwrap();
    first.0.wait().unwrap();

    let (_second, base) = start(data.path(), 2);
    for id in &ids {
        let j = wait_job(&c, &base, id, Duration::from_secs(180)).await;
        assert_eq!(j["status"], "succeeded", "{j}");
        let r = c
            .get(format!("{base}/v1/jobs/{id}/result.glb"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
    }
}
