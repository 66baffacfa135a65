//! `proto/openapi.yaml` against the running server: every documented operation is served,
//! and the documented job fields are exactly the ones a job answer carries.

use super::helpers::{figure_obj, repo, spawn_app};
use serde_json::Value;
use std::collections::BTreeSet;

fn spec() -> Value {
    let text = std::fs::read_to_string(repo().join("proto/openapi.yaml")).unwrap();
    serde_yaml::from_str(&text).unwrap()
}

#[tokio::test]
async fn every_documented_operation_is_served() {
    // No workers, and /v1/rig gives up quickly: every operation answers at once.
    let app = spawn_app(|c| {
        c.workers = 0;
        c.sync_timeout = std::time::Duration::from_millis(300);
    })
    .await;
    let job: Value = app.submit_figure("").await;
    let id = job["id"].as_str().unwrap();
    let spec = spec();
    let mut ops = 0;
    for (path, item) in spec["paths"].as_object().unwrap() {
        for method in ["get", "post", "delete", "put", "patch"] {
            if item.get(method).is_none() {
                continue;
            }
            let url = app.url(&path.replace("{id}", id).replace("{file}", "app.js"));
            let req = app
                .client
                .request(method.to_uppercase().parse().unwrap(), url)
                .header("content-type", "model/obj");
            // Streams would stay open on a queued job; the headers are enough.
            let r = tokio::time::timeout(
                std::time::Duration::from_secs(5),
                req.body(figure_obj()).send(),
            )
            .await
            .expect("headers within 5 s")
            .unwrap();
            let status = r.status().as_u16();
            let body: Value = if r
                .headers()
                .get("content-type")
                .is_some_and(|v| v == "application/json")
            {
                r.json().await.unwrap_or(Value::Null)
            } else {
                Value::Null
            };
            let et = body["error_type"].as_str().unwrap_or("");
            assert!(
                et != "not_found" && et != "method_not_allowed" && status != 405,
                "{method} {path}: {status} {body}"
            );
            let documented: Vec<&String> = item[method]["responses"]
                .as_object()
                .unwrap()
                .keys()
                .collect();
            assert!(
                documented.iter().any(|c| **c == status.to_string()),
                "{method} {path} answered {status}, not among {documented:?}"
            );
            ops += 1;
        }
    }
    assert_eq!(ops, 12, "operations in the spec");
    app.stop().await;
}

#[tokio::test]
async fn job_fields_match_the_schema() {
    let app = spawn_app(|c| c.workers = 0).await;
    let job: Value = app.submit_figure("").await;
    let spec = spec();
    let documented: BTreeSet<String> = spec["components"]["schemas"]["Job"]["properties"]
        .as_object()
        .unwrap()
        .keys()
        .cloned()
        .collect();
    let actual: BTreeSet<String> = job.as_object().unwrap().keys().cloned().collect();
    assert_eq!(actual, documented);
    let options: BTreeSet<String> = job["options"]
        .as_object()
        .unwrap()
        .keys()
        .cloned()
        .collect();
    let doc_options: BTreeSet<String> = spec["components"]["schemas"]["JobOptions"]["properties"]
        .as_object()
        .unwrap()
        .keys()
        .cloned()
        .collect();
    assert_eq!(options, doc_options);
    app.stop().await;
}
