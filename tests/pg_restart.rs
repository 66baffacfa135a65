//! A PostgreSQL restart during a run: while the database is down, requests fail cleanly
//! (503 with an `error_type`, readiness 503) and nothing panics; once it is back the
//! replica recovers by itself and jobs run again. Restarts the machine's own cluster
//! (`pg_ctlcluster`), so it lives alone in this test binary.

#[path = "cluster/infra.rs"]
mod infra;

use infra::*;
use serde_json::Value;
use std::process::Command;
use std::time::{Duration, Instant};

fn pg_ctl(action: &str) -> bool {
    Command::new("pg_ctlcluster")
        .args(["15", "main", action, "-m", "fast"])
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}

/// Starts the cluster again even if the test fails midway.
struct Restart;

impl Drop for Restart {
    fn drop(&mut self) {
        let _ = Command::new("pg_ctlcluster")
            .args(["15", "main", "start"])
            .status();
    }
}

#[tokio::test]
async fn the_service_rides_out_a_database_restart() {
    if let Some(why) = missing() {
        eprintln!("skipping: {why}");
        return;
    }
    if Command::new("pg_ctlcluster")
        .arg("--help")
        .output()
        .is_err()
    {
        eprintln!("skipping: no pg_ctlcluster to restart PostgreSQL with");
        return;
    }
    let db = fresh_database().await;
    let s3 = start_s3().await;
    let r = start_replica(&db, &s3, "all", &["--workers", "1"]);
    let c = reqwest::Client::new();
    let mesh = figure(&repo().join("tests/corpus/base.obj"));
    let submit = || {
        c.post(format!("{}/v1/jobs", r.base))
            .header("content-type", "model/obj")
            .body(mesh.clone())
            .send()
    };
    let first: Value = submit().await.unwrap().json().await.unwrap();
    let id = first["id"].as_str().unwrap().to_string();
    assert_eq!(
        wait_job(&c, &r.base, &id, Duration::from_secs(120)).await["status"],
        "succeeded"
    );

    let _guard = Restart;
    assert!(pg_ctl("stop"), "pg_ctlcluster stop failed");
    let resp = c
        .get(format!("{}/v1/jobs/{id}", r.base))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status(), 503);
    assert!(resp.headers().contains_key("retry-after"));
    let body: Value = resp.json().await.unwrap();
    assert_eq!(body["error_type"], "store_unavailable", "{body}");
    let resp = submit().await.unwrap();
    assert_eq!(resp.status(), 503);
    assert_eq!(
        c.get(format!("{}/readyz", r.base))
            .send()
            .await
            .unwrap()
            .status(),
        503
    );
    assert_eq!(
        c.get(format!("{}/healthz", r.base))
            .send()
            .await
            .unwrap()
            .status(),
        200
    );

    assert!(pg_ctl("start"), "pg_ctlcluster start failed");
    let t = Instant::now();
    loop {
        let s = c
            .get(format!("{}/readyz", r.base))
            .send()
            .await
            .unwrap()
            .status();
        if s == 200 {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "never ready again");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let again = submit().await.unwrap();
    assert_eq!(again.status(), 202);
    let again: Value = again.json().await.unwrap();
    let j = wait_job(
        &c,
        &r.base,
        again["id"].as_str().unwrap(),
        Duration::from_secs(120),
    )
    .await;
    assert_eq!(j["status"], "succeeded", "{j}");
}
