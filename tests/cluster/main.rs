//! Cluster mode against real servers: two replicas on one PostgreSQL + S3; a worker
//! replica killed with SIGKILL mid-job; every job still completes exactly once.

mod infra;

use infra::*;
use serde_json::Value;
use std::time::{Duration, Instant};

async fn get_json(c: &reqwest::Client, url: String) -> (u16, Value) {
    let r = c.get(url).send().await.unwrap();
    let s = r.status().as_u16();
    (s, r.json().await.unwrap_or(Value::Null))
}

#[tokio::test]
async fn replicas_share_jobs_and_survive_a_killed_worker() {
    if let Some(why) = missing() {
        eprintln!("skipping cluster test: {why}");
        return;
    }
    let db = fresh_database().await;
    let s3 = start_s3().await;
    // A takes uploads and runs jobs (one at a time); B only answers.
    let mut a = start_replica(&db, &s3, "all", &["--workers", "1"]);
    let b = start_replica(&db, &s3, "api", &[]);
    let c = reqwest::Client::new();
    let mesh = figure(&repo().join("tests/corpus/base.obj"));
    let mut ids = Vec::new();
    for seed in 0..6 {
        ids.push(submit_obj(&c, &a.base, &format!("?seed={seed}"), &mesh).await);
    }
    // B sees A's jobs at once (one store).
    let r = c
        .get(format!("{}/v1/jobs/{}", b.base, ids[5]))
        .send()
        .await
        .unwrap();
    let (s, h) = (r.status().as_u16(), format!("{:?}", r.headers()));
    let text = r.text().await.unwrap();
    assert_eq!(s, 200, "{} {h} {text}", b.base);
    let j: Value = serde_json::from_str(&text).unwrap();
    assert!(
        matches!(j["status"].as_str(), Some("queued" | "running")),
        "{j}"
    );

    // Kill A while it runs a job (A is the only worker, so a running job is A's).
    let t = Instant::now();
    let victim = loop {
        let mut running = None;
        for id in &ids {
            let (_, j) = get_json(&c, format!("{}/v1/jobs/{id}", b.base)).await;
            if j["status"] == "running" {
                running = Some(id.clone());
            }
        }
        if let Some(v) = running {
            break v;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "no job started");
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    a.child.0.kill().unwrap();
    a.child.0.wait().unwrap();
    // A new worker replica takes over the queue and, once its lease ends, A's job.
    let _w = start_replica(&db, &s3, "worker", &["--workers", "2"]);

    for id in &ids {
        let j = wait_job(&c, &b.base, id, Duration::from_secs(180)).await;
        assert_eq!(j["status"], "succeeded", "{j}");
        let r = c
            .get(format!("{}/v1/jobs/{id}/result.glb", b.base))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        assert_eq!(&r.bytes().await.unwrap()[..4], b"glTF");
        // Exactly once from the client's view: one terminal event, no second run after it.
        let text = c
            .get(format!("{}/v1/jobs/{id}/events", b.base))
            .send()
            .await
            .unwrap()
            .text()
            .await
            .unwrap();
        assert_eq!(
            text.matches("\"status\":\"succeeded\"").count(),
            1,
            "{text}"
        );
    }
    let (_, v) = get_json(&c, format!("{}/v1/jobs/{victim}", b.base)).await;
    assert_eq!(v["attempts"], 2, "the killed job ran again once: {v}");
    // The worker replica serves probes and metrics only.
    let (s, _) = get_json(&c, format!("{}/readyz", _w.base)).await;
    assert_eq!(s, 200);
    let (s, body) = get_json(&c, format!("{}/v1/jobs/{victim}", _w.base)).await;
    assert_eq!((s, body["error_type"].as_str()), (404, Some("not_found")));
}
