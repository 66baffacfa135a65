//! A bounded soak of hostile uploads against one real `rigserve serve` process: the
//! malformed corpus, JSON-heavy glTF (a million accessors, a 24-million-element
//! `extras`, a 96 MiB string) and ordinary meshes, 200 uploads at concurrency 8. Every
//! answer must be a refusal with a JSON `error_type` or a job that ends succeeded or
//! failed with a code; the server must stay up; peak RSS must stay under 1.5 GB and,
//! 10 s after the last request, come back under twice the idle RSS plus 200 MB.

#[path = "cluster/infra.rs"]
mod infra;

use futures_util::StreamExt;
use infra::{repo, spawn_serve, wait_job};
use serde_json::Value;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

const UPLOADS: usize = 200;
const CONCURRENCY: usize = 8;
const PEAK_CAP: u64 = 1536 << 20;

fn rss_of(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map_or(0, |kb| kb << 10)
}

/// The corpus's base glTF with `edit` applied to its JSON text's top-level object.
fn heavy(tail: &str) -> Vec<u8> {
    let base = std::fs::read_to_string(repo().join("tests/corpus/base.gltf")).unwrap();
    let open = base.trim_end().strip_suffix('}').expect("an object");
    format!("{open},{tail}}}").into_bytes()
}

fn heavy_inputs() -> Vec<(String, Vec<u8>)> {
    let accessors = {
        let one = r#"{"componentType":5126,"count":1,"type":"SCALAR"}"#;
        let mut s = String::from(r#"{"asset":{"version":"2.0"},"accessors":["#);
        for i in 0..1_000_000 {
            if i > 0 {
                s.push(',');
            }
            s.push_str(one);
        }
        s.push_str("]}");
        s.into_bytes()
    };
    let extras = {
        let mut s = String::from(r#""extras":["#);
        s.push_str(&"0,".repeat(24_000_000));
        s.push_str("0]");
        heavy(&s)
    };
    let string = heavy(&format!(r#""extensionsUsed":["{}"]"#, "a".repeat(96 << 20)));
    vec![
        ("a million accessors".into(), accessors),
        ("24M-element extras".into(), extras),
        ("a 96 MiB string".into(), string),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn hostile_uploads_leave_the_server_up_and_its_memory_bounded() {
    let lib = repo().join(".onnxruntime/libonnxruntime.so.1.31.1");
    if !lib.is_file() {
        eprintln!("SKIPPED: needs ONNX Runtime (make setup)");
        return;
    }
    let data = tempfile::tempdir().unwrap();
    let (server, base) = spawn_serve(
        &[
            "--data-dir".into(),
            data.path().display().to_string(),
            "--workers".into(),
            "2".into(),
        ],
        &[],
    );
    let pid = server.0.id();
    let c = reqwest::Client::new();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let idle = rss_of(pid);
    assert!(idle > 0);

    let peak = Arc::new(AtomicU64::new(idle));
    let sampling = {
        let peak = peak.clone();
        tokio::spawn(async move {
            loop {
                peak.fetch_max(rss_of(pid), Ordering::Relaxed);
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        })
    };

    // Heavy inputs first, each alone, then the corpus and good meshes mixed.
    let mut inputs = heavy_inputs();
    let corpus = repo().join("tests/corpus");
    let mut files: Vec<_> = std::fs::read_dir(&corpus)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x != "tsv" && x != "md"))
        .collect();
    files.sort();
    let mut k = 0;
    while inputs.len() < UPLOADS {
        let p = &files[k % files.len()];
        inputs.push((p.display().to_string(), std::fs::read(p).unwrap()));
        k += 1;
    }

    let outcomes = futures_util::stream::iter(inputs.into_iter().enumerate())
        .map(|(i, (name, bytes))| {
            let (c, base) = (c.clone(), base.clone());
            async move {
                let r = c
                    .post(format!("{base}/v1/jobs?seed={i}"))
                    .header("content-type", "application/octet-stream")
                    .body(bytes)
                    .send()
                    .await
                    .unwrap_or_else(|e| panic!("{name}: no answer: {e}"));
                let status = r.status().as_u16();
                let body: Value = r
                    .json()
                    .await
                    .unwrap_or_else(|e| panic!("{name}: {status} without a JSON body: {e}"));
                if status == 202 {
                    let id = body["id"].as_str().unwrap().to_string();
                    let done = wait_job(&c, &base, &id, Duration::from_secs(300)).await;
                    let end = done["status"].as_str().unwrap_or("").to_string();
                    assert!(
                        end == "succeeded"
                            || (end == "failed" && done["error"]["code"].is_string()),
                        "{name}: job ended {done}"
                    );
                    end
                } else {
                    assert!((400..500).contains(&status), "{name}: {status} {body}");
                    let code = body["error_type"].as_str().unwrap_or("");
                    assert!(!code.is_empty(), "{name}: {body}");
                    code.to_string()
                }
            }
        })
        .buffer_unordered(CONCURRENCY)
        .collect::<Vec<String>>()
        .await;
    assert_eq!(outcomes.len(), UPLOADS);
    let ok = c.get(format!("{base}/healthz")).send().await.unwrap();
    assert_eq!(ok.status(), 200, "the server is down");

    tokio::time::sleep(Duration::from_secs(10)).await;
    sampling.abort();
    let after = rss_of(pid);
    let peak = peak.load(Ordering::Relaxed);
    let mb = |b: u64| b >> 20;
    eprintln!(
        "idle {} MB, peak {} MB, 10 s after {} MB; outcomes: {} refused, {} succeeded, {} failed",
        mb(idle),
        mb(peak),
        mb(after),
        outcomes
            .iter()
            .filter(|o| *o != "succeeded" && *o != "failed")
            .count(),
        outcomes.iter().filter(|o| *o == "succeeded").count(),
        outcomes.iter().filter(|o| *o == "failed").count(),
    );
    assert!(peak <= PEAK_CAP, "peak RSS {} MB", mb(peak));
    assert!(
        after <= 2 * idle + (200 << 20),
        "RSS {} MB 10 s after the run, idle {} MB",
        mb(after),
        mb(idle)
    );
    drop(server);
}
