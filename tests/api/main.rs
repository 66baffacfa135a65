//! Black-box tests of the HTTP service: every endpoint, bad inputs, cancellation,
//! idempotency, expiry, auth isolation, SSE resumption, webhooks, and (in `restart.rs`)
//! recovery after kill -9.

mod cors;
mod helpers;
#[path = "../cluster/infra.rs"]
mod infra;
mod openapi;
mod refusals;
mod restart;

use helpers::*;
use serde_json::Value;
use std::time::Duration;

const JOB_TIMEOUT: Duration = Duration::from_secs(120);

fn id_of(v: &Value) -> String {
    v["id"].as_str().expect("a job id").to_string()
}

#[tokio::test]
async fn a_mesh_is_rigged_end_to_end() {
    let app = spawn_app(|_| {}).await;
    let r = app
        .post_mesh(figure_obj(), "model/obj", "?seed=3&category=humanoid")
        .await;
    assert_eq!(r.status(), 202);
    let location = r.headers()["location"].to_str().unwrap().to_string();
    assert_eq!(r.headers()["retry-after"], "1");
    assert!(r.headers().contains_key("x-request-id"));
    let job: Value = r.json().await.unwrap();
    assert_eq!(location, format!("/v1/jobs/{}", id_of(&job)));
    assert_eq!(job["status"], "queued");
    assert_eq!(job["options"]["seed"], 3);
    assert_eq!(job["input"]["format"], "obj");

    let done = app.wait_end(&id_of(&job), JOB_TIMEOUT).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(done["progress"], 1.0);
    assert!(done["expires_at"].is_string() && done["finished_at"].is_string());
    let bones = done["result"]["bones"].as_u64().unwrap();
    assert!(bones >= 1);

    let r = app.get(done["result"]["glb"].as_str().unwrap()).await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "model/gltf-binary");
    let etag = r.headers()["etag"].to_str().unwrap().to_string();
    assert!(r.headers()["content-disposition"]
        .to_str()
        .unwrap()
        .starts_with("attachment; filename="));
    let glb = r.bytes().await.unwrap();
    assert_eq!(
        glb.len() as u64,
        done["result"]["glb_bytes"].as_u64().unwrap()
    );
    // The GLB is a rig rigserve itself reads back, with the advertised bone count.
    let asset = rigserve::mesh::load(&glb, &Default::default()).unwrap();
    let gt = rigserve::rig::groundtruth::extract(&asset)
        .unwrap()
        .unwrap();
    assert_eq!(gt.skeleton.len() as u64, bones);

    let r = app
        .client
        .get(app.url(done["result"]["glb"].as_str().unwrap()))
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);

    let tree = app.skeleton_of(&done).await;
    assert_eq!(tree["bones"].as_array().unwrap().len() as u64, bones);
    app.stop().await;
}

/// Rigs the figure with `query` and returns the bone names of its skeleton.json.
async fn rigged_bone_names(app: &TestApp, query: &str) -> Vec<String> {
    let job = app.submit_figure(query).await;
    let done = app.wait_end(&id_of(&job), JOB_TIMEOUT).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let tree = app.skeleton_of(&done).await;
    tree["bones"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["name"].as_str().unwrap().to_string())
        .collect()
}

/// A library holding a rig of this very figure: the job borrows it (the artist's bone
/// names come back), unless the job asks for the Mixamo template; a broken library file
/// stops the server at start-up with its code.
#[tokio::test]
async fn a_library_rig_of_a_close_relative_is_borrowed() {
    use rigserve::predict::library::{Entry, Library};
    use rigserve::rig::{Bone, Skeleton};
    let asset = rigserve::mesh::load(&figure_obj(), &Default::default()).unwrap();
    let joints = [
        ("lib_hips", None, [0.0, 0.95, 0.0]),
        ("lib_head", Some(0), [0.0, 1.6, 0.0]),
        ("lib_arm_l", Some(0), [-0.6, 1.4, 0.0]),
        ("lib_arm_r", Some(0), [0.6, 1.4, 0.0]),
    ];
    let mut skel = Skeleton {
        bones: joints
            .iter()
            .map(|&(name, parent, p)| Bone::new(name, parent, p.into(), glam::Vec3::ZERO))
            .collect(),
        ..Skeleton::default()
    };
    skel.infer_tails();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("library.json");
    Library::new(vec![Entry::new("figure", "humanoid", &asset.mesh, &skel)])
        .save(&file)
        .unwrap();
    let lib = file.clone();
    let app = spawn_app(move |c| c.model.as_mut().unwrap().library = Some(lib)).await;
    let got = rigged_bone_names(&app, "?category=humanoid").await;
    assert_eq!(got.len(), 4, "{got:?}");
    assert!(got.iter().all(|n| n.starts_with("lib_")), "{got:?}");
    // template=mixamo or none leaves the skeleton to the model.
    for t in ["mixamo", "none"] {
        let got = rigged_bone_names(&app, &format!("?category=humanoid&template={t}")).await;
        assert!(got.iter().all(|n| !n.starts_with("lib_")), "{t}: {got:?}");
    }
    app.stop().await;

    std::fs::write(&file, b"{\"version\": 1, \"entries\": 7}").unwrap();
    let data = tempfile::tempdir().unwrap();
    let mut cfg = test_config(data.path());
    cfg.model.as_mut().unwrap().library = Some(file);
    let err = rigserve::app::Application::build(cfg)
        .await
        .err()
        .expect("refused");
    assert_eq!(err.code(), "library_malformed", "{err}");
}

#[tokio::test]
async fn multipart_with_options_and_skin_only_skeleton() {
    let app = spawn_app(|_| {}).await;
    let options = serde_json::json!({"skin_only": true, "skeleton": figure_skeleton()});
    let form = reqwest::multipart::Form::new()
        .part(
            "file",
            reqwest::multipart::Part::bytes(figure_obj())
                .file_name("robot figure.obj")
                .mime_str("model/obj")
                .unwrap(),
        )
        .text("options", options.to_string());
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    let job: Value = r.json().await.unwrap();
    assert_eq!(job["input"]["filename"], "robot figure.obj");
    let done = app.wait_end(&id_of(&job), JOB_TIMEOUT).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    // skin_only keeps the given skeleton exactly.
    assert_eq!(done["result"]["bones"], 7);
    let r = app.get(done["result"]["glb"].as_str().unwrap()).await;
    let cd = r.headers()["content-disposition"]
        .to_str()
        .unwrap()
        .to_string();
    assert!(cd.contains("robotfigure_rigged.glb"), "{cd}");
    app.stop().await;
}

#[tokio::test]
async fn sync_rig_returns_the_glb() {
    let app = spawn_app(|_| {}).await;
    let r = app
        .client
        .post(app.url("/v1/rig?seed=1"))
        .header("content-type", "model/obj")
        .body(figure_obj())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "model/gltf-binary");
    let id = r.headers()["x-job-id"].to_str().unwrap().to_string();
    let glb = r.bytes().await.unwrap();
    assert_eq!(&glb[..4], b"glTF");
    let tree = app.get(&format!("/v1/jobs/{id}/skeleton.json")).await;
    assert_eq!(tree.status(), 200);
    // The bone tree also rides in the GLB.
    let asset = rigserve::mesh::load(&glb, &Default::default()).unwrap();
    let doc = asset.document.unwrap();
    assert!(doc.json.to_string().contains("\"rigserve\""));
    app.stop().await;
}

#[tokio::test]
async fn every_malformed_corpus_file_gets_its_code() {
    let app = spawn_app(|_| {}).await;
    let corpus = repo().join("tests/corpus");
    let expected = std::fs::read_to_string(corpus.join("EXPECTED.tsv")).unwrap();
    let mut checked = 0;
    for line in expected.lines().skip(1) {
        let f: Vec<&str> = line.split('\t').collect();
        let (file, stage, code, limits) = (f[0], f[1], f[2], f[3]);
        if stage != "load" || limits != "default" {
            continue;
        }
        let bytes = std::fs::read(corpus.join(file)).unwrap();
        let r = app.post_mesh(bytes, "application/octet-stream", "").await;
        let status = r.status().as_u16();
        let body: Value = r.json().await.unwrap();
        assert_eq!(body["error_type"], code, "{file}: {body}");
        let want = if code == "file_too_large" { 413 } else { 422 };
        assert_eq!(status, want, "{file}");
        checked += 1;
    }
    assert!(checked >= 100, "only {checked} corpus files checked");
    // Nothing was queued for any of them.
    let m = app.get("/metrics").await.text().await.unwrap();
    assert!(m.contains("rigserve_jobs{status=\"queued\"} 0"), "{m}");
    app.stop().await;
}

#[tokio::test]
async fn bad_requests_get_typed_errors() {
    let app = spawn_app(|c| c.limits.max_bytes = 100_000).await;
    let r = app.post_mesh(figure_obj(), "image/png", "").await;
    assert_error(r, 415, "unsupported_media_type").await;
    let r = app
        .post_mesh(b"glTF\x02\0\0\0....".to_vec(), "model/gltf+json", "")
        .await;
    assert_error(r, 415, "content_type_mismatch").await;
    let r = app.post_mesh(vec![b'#'; 200_000], "model/obj", "").await;
    assert_error(r, 413, "file_too_large").await;
    let r = app.post_mesh(Vec::new(), "model/obj", "").await;
    assert_error(r, 422, "empty_file").await;
    for q in [
        "?samples=0",
        "?samples=abc",
        "?category=dragon",
        "?frobnicate=1",
        "?template=maybe",
    ] {
        let r = app.post_mesh(figure_obj(), "model/obj", q).await;
        assert_error(r, 422, "invalid_options").await;
    }
    let r = app
        .post_mesh(figure_obj(), "model/obj", "?webhook_url=ftp://x")
        .await;
    assert_error(r, 422, "webhook_url_invalid").await;
    let bad_tree = serde_json::json!({"version": 1, "bones": []}).to_string();
    let r = app
        .post_mesh(
            figure_obj(),
            "model/obj",
            &format!("?skeleton={}", urlencode(&bad_tree)),
        )
        .await;
    assert_eq!(r.status(), 422);
    // A bare mesh has no skeleton of its own to re-skin.
    let r = app
        .post_mesh(figure_obj(), "model/obj", "?skin_only=true")
        .await;
    assert_error(r, 422, "no_skeleton").await;
    // A tree in other units (centimetres on a mesh in metres), or with one joint at 1e30,
    // is refused at upload by the rule the job would apply after queueing: skinning it,
    // or continuing from it as bones to keep.
    let moved = |f: &dyn Fn(usize, f64) -> f64| {
        let mut tree = figure_skeleton();
        for (i, b) in tree["bones"].as_array_mut().unwrap().iter_mut().enumerate() {
            for key in ["head", "tail"] {
                for c in b[key].as_array_mut().unwrap() {
                    *c = f(i, c.as_f64().unwrap()).into();
                }
            }
        }
        urlencode(&tree.to_string())
    };
    let centimetres = moved(&|_, x| x * 100.0);
    let one_far = moved(&|i, x| if i == 3 { 1e30 } else { x });
    for (tree, skin_only, code) in [
        (&centimetres, true, "skeleton_outside_mesh"),
        (&one_far, true, "skeleton_outside_mesh"),
        (&centimetres, false, "keep_bones_outside_mesh"),
        (&one_far, false, "keep_bones_outside_mesh"),
    ] {
        let q = format!("?skin_only={skin_only}&skeleton={tree}");
        let r = app.post_mesh(figure_obj(), "model/obj", &q).await;
        assert_error(r, 422, code).await;
    }
    assert_error(app.get("/v1/jobs/nope").await, 404, "job_not_found").await;
    assert_error(app.get("/v1/nothing").await, 404, "not_found").await;
    let r = app.client.put(app.url("/v1/jobs")).send().await.unwrap();
    assert_error(r, 405, "method_not_allowed").await;
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("content-type", "multipart/form-data; boundary=x")
        .body("--x\r\nContent-Disposition: form-data; name=\"other\"\r\n\r\nhi\r\n--x--\r\n")
        .send()
        .await
        .unwrap();
    assert_error(r, 400, "multipart_invalid").await;
    app.stop().await;
}

fn urlencode(s: &str) -> String {
    url::form_urlencoded::byte_serialize(s.as_bytes()).collect()
}

#[tokio::test]
async fn queued_jobs_can_be_canceled_and_the_queue_has_a_cap() {
    // No workers: jobs stay queued.
    let app = spawn_app(|c| {
        c.workers = 0;
        c.max_queued = 2;
    })
    .await;
    let a: Value = app.submit_figure("").await;
    let b: Value = app.submit_figure("?seed=2").await;
    assert_eq!(a["queue_position"], 0);
    assert_eq!(b["queue_position"], 1);
    let r = app.post_mesh(figure_obj(), "model/obj", "?seed=3").await;
    assert!(r.headers().contains_key("retry-after"));
    assert_error(r, 429, "queue_full").await;

    let r = app
        .client
        .delete(app.url(&format!("/v1/jobs/{}", id_of(&a))))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let canceled: Value = r.json().await.unwrap();
    assert_eq!(canceled["status"], "canceled");
    assert_eq!(app.job(&id_of(&b)).await["queue_position"], 0);
    let r = app.get(&format!("/v1/jobs/{}/result.glb", id_of(&a))).await;
    assert_error(r, 410, "job_canceled").await;
    let r = app.get(&format!("/v1/jobs/{}/result.glb", id_of(&b))).await;
    assert_error(r, 409, "job_not_ready").await;
    // The upload of the canceled job is gone.
    let blob_dir = app.data.path().join("blobs/jobs").join(id_of(&a));
    assert!(!blob_dir.join("input").exists());
    // Room again.
    assert_eq!(
        app.post_mesh(figure_obj(), "model/obj", "?seed=3")
            .await
            .status(),
        202
    );
    app.stop().await;
}

#[tokio::test]
async fn idempotency_keys_replay_or_conflict() {
    let app = spawn_app(|c| c.workers = 0).await;
    let send = |body: Vec<u8>, key: &'static str| {
        app.client
            .post(app.url("/v1/jobs"))
            .header("content-type", "model/obj")
            .header("idempotency-key", key)
            .body(body)
            .send()
    };
    let first = send(figure_obj(), "k-1").await.unwrap();
    assert_eq!(first.status(), 202);
    let first: Value = first.json().await.unwrap();
    let again = send(figure_obj(), "k-1").await.unwrap();
    assert_eq!(again.status(), 202);
    assert_eq!(again.headers()["idempotent-replayed"], "true");
    let again: Value = again.json().await.unwrap();
    assert_eq!(id_of(&again), id_of(&first));
    let mut other = figure_obj();
    other.extend_from_slice(b"# changed\n");
    assert_error(
        send(other, "k-1").await.unwrap(),
        422,
        "idempotency_key_reused",
    )
    .await;
    let r = send(figure_obj(), "k-2").await.unwrap();
    assert_ne!(id_of(&r.json::<Value>().await.unwrap()), id_of(&first));
    app.stop().await;
}

#[tokio::test]
async fn results_expire() {
    let app = spawn_app(|c| c.result_ttl = Duration::from_millis(600)).await;
    let job: Value = app.submit_figure("").await;
    let id = id_of(&job);
    let done = app.wait_end(&id, JOB_TIMEOUT).await;
    assert_eq!(done["status"], "succeeded");
    let mut status = String::new();
    for _ in 0..100 {
        tokio::time::sleep(Duration::from_millis(100)).await;
        status = app.job(&id).await["status"].as_str().unwrap().to_string();
        if status == "expired" {
            break;
        }
    }
    assert_eq!(status, "expired");
    assert_error(
        app.get(&format!("/v1/jobs/{id}/result.glb")).await,
        410,
        "job_expired",
    )
    .await;
    assert_error(
        app.get(&format!("/v1/jobs/{id}/skeleton.json")).await,
        410,
        "job_expired",
    )
    .await;
    assert!(!app
        .data
        .path()
        .join("blobs/jobs")
        .join(&id)
        .join("result.glb")
        .exists());
    app.stop().await;
}

#[tokio::test]
async fn api_keys_isolate_jobs() {
    let keys = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(keys.path(), "alice:sk-alice\nbob:sk-bob\n").unwrap();
    let path = keys.path().to_path_buf();
    let app = spawn_app(move |c| {
        c.api_keys_file = Some(path);
        c.workers = 0;
    })
    .await;
    let r = app.post_mesh(figure_obj(), "model/obj", "").await;
    assert_error(r, 401, "unauthorized").await;
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .bearer_auth("sk-alice")
        .header("content-type", "model/obj")
        .body(figure_obj())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    let id = id_of(&r.json::<Value>().await.unwrap());
    let as_key =
        |k: &'static str, path: String| app.client.get(app.url(&path)).bearer_auth(k).send();
    assert_eq!(
        as_key("sk-alice", format!("/v1/jobs/{id}"))
            .await
            .unwrap()
            .status(),
        200
    );
    assert_error(
        as_key("sk-bob", format!("/v1/jobs/{id}")).await.unwrap(),
        404,
        "job_not_found",
    )
    .await;
    assert_error(
        as_key("sk-bob", format!("/v1/jobs/{id}/events"))
            .await
            .unwrap(),
        404,
        "job_not_found",
    )
    .await;
    let r = app
        .client
        .delete(app.url(&format!("/v1/jobs/{id}")))
        .bearer_auth("sk-bob")
        .send()
        .await
        .unwrap();
    assert_error(r, 404, "job_not_found").await;
    assert_error(
        as_key("sk-nobody", format!("/v1/jobs/{id}")).await.unwrap(),
        401,
        "unauthorized",
    )
    .await;
    // Health and metrics stay open for probes.
    assert_eq!(app.get("/healthz").await.status(), 200);
    app.stop().await;
}

/// Parses an SSE body into (id, data) pairs.
fn sse_events(text: &str) -> Vec<(i64, Value)> {
    let mut out = Vec::new();
    for block in text.split("\n\n") {
        let mut id = None;
        let mut data = None;
        for line in block.lines() {
            if let Some(v) = line.strip_prefix("id:") {
                id = v.trim().parse().ok();
            } else if let Some(v) = line.strip_prefix("data:") {
                data = serde_json::from_str(v.trim()).ok();
            }
        }
        if let (Some(i), Some(d)) = (id, data) {
            out.push((i, d));
        }
    }
    out
}

#[tokio::test]
async fn events_stream_to_the_end_and_resume() {
    let app = spawn_app(|_| {}).await;
    let job: Value = app.submit_figure("").await;
    let id = id_of(&job);
    // The stream closes by itself after the terminal event.
    let r = app.get(&format!("/v1/jobs/{id}/events")).await;
    assert_eq!(r.headers()["content-type"], "text/event-stream");
    let text = tokio::time::timeout(JOB_TIMEOUT, r.text())
        .await
        .unwrap()
        .unwrap();
    let events = sse_events(&text);
    assert!(events.len() >= 4, "{text}");
    assert_eq!(events[0].1["status"], "queued");
    assert_eq!(events.last().unwrap().1["status"], "succeeded");
    let ids: Vec<i64> = events.iter().map(|e| e.0).collect();
    assert!(ids.windows(2).all(|w| w[1] == w[0] + 1), "{ids:?}");
    let stages: Vec<&str> = events
        .iter()
        .filter_map(|e| e.1["stage"].as_str())
        .collect();
    for s in [
        "validating",
        "encoding",
        "skeleton",
        "skinning",
        "exporting",
    ] {
        assert!(stages.contains(&s), "no {s} in {stages:?}");
    }
    // Resuming after event 2 replays exactly the rest.
    let r = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/events")))
        .header("last-event-id", "2")
        .send()
        .await
        .unwrap();
    let rest = sse_events(&r.text().await.unwrap());
    assert_eq!(
        rest.iter().map(|e| e.0).collect::<Vec<_>>(),
        ids[2..].to_vec()
    );
    // Resuming after the end returns at once with nothing.
    let last = ids.last().unwrap().to_string();
    let r = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/events?last_event_id={last}")))
        .send()
        .await
        .unwrap();
    let tail = tokio::time::timeout(Duration::from_secs(10), r.text())
        .await
        .unwrap()
        .unwrap();
    assert!(sse_events(&tail).is_empty());
    app.stop().await;
}

#[tokio::test]
async fn a_resume_point_that_is_not_an_event_id_is_refused() {
    // No workers: the job stays queued, and the answers come before any stream opens.
    let app = spawn_app(|c| c.workers = 0).await;
    let id = id_of(&app.submit_figure("").await);
    let base = format!("/v1/jobs/{id}/events");
    for (query, header) in [
        ("?last_event_id=null", None),
        ("?last_event_id=1&last_event_id=2", None),
        ("", Some("abc")),
        ("?last_event_id=1", Some("")),
    ] {
        let mut req = app.client.get(app.url(&format!("{base}{query}")));
        if let Some(h) = header {
            req = req.header("last-event-id", h);
        }
        let r = req.send().await.unwrap();
        assert_eq!(r.status(), 422, "{query} {header:?}");
        let body: Value = r.json().await.unwrap();
        assert_eq!(
            body["error_type"], "invalid_options",
            "{query} {header:?}: {body}"
        );
    }
    // An unknown job is still not found, whatever the resume point.
    let r = app.get("/v1/jobs/missing/events?last_event_id=x").await;
    assert_eq!(r.status(), 404);
    app.stop().await;
}

#[tokio::test]
async fn health_readiness_and_metrics() {
    let app = spawn_app(|_| {}).await;
    let r = app.get("/healthz").await;
    assert_eq!(r.status(), 200);
    let r: Value = app.get("/readyz").await.json().await.unwrap();
    assert_eq!(r["status"], "ready");
    assert_eq!(r["checks"]["skeleton_model"], "loaded");
    let job: Value = app.submit_figure("").await;
    app.wait_end(&id_of(&job), JOB_TIMEOUT).await;
    app.get("/v1/jobs/missing").await;
    let m = app.get("/metrics").await.text().await.unwrap();
    for needle in [
        "rigserve_http_requests_total{method=\"POST\",route=\"/v1/jobs\",status=\"202\"} 1",
        "rigserve_http_errors_total{error_type=\"job_not_found\"} 1",
        "rigserve_http_request_duration_seconds_bucket",
        "rigserve_jobs{status=\"succeeded\"} 1",
        "rigserve_queue_depth 0",
        "rigserve_stage_duration_seconds_count{stage=\"skeleton\"} 1",
        "rigserve_job_duration_seconds_count{outcome=\"succeeded\"} 1",
        "rigserve_decode_tokens_total",
        "rigserve_decode_tokens_per_second",
        "rigserve_batch_size",
    ] {
        assert!(m.contains(needle), "no {needle} in\n{m}");
    }
    app.stop().await;
}

#[tokio::test]
async fn webhooks_are_signed_and_delivered() {
    use axum::routing::post;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let calls = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let hook = {
        let calls = calls.clone();
        axum::Router::new().route(
            "/hook",
            post(move |headers: axum::http::HeaderMap, body: String| {
                let tx = tx.clone();
                let calls = calls.clone();
                async move {
                    // Refuse the first delivery: the retry must come.
                    if calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst) == 0 {
                        return axum::http::StatusCode::SERVICE_UNAVAILABLE;
                    }
                    let h = |k: &str| headers[k].to_str().unwrap().to_string();
                    tx.send((
                        h("webhook-id"),
                        h("webhook-timestamp"),
                        h("webhook-signature"),
                        body,
                    ))
                    .unwrap();
                    axum::http::StatusCode::NO_CONTENT
                }
            }),
        )
    };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let hook_url = format!("http://{}/hook", listener.local_addr().unwrap());
    tokio::spawn(async move { axum::serve(listener, hook).await });
    // By default a client cannot make the server call into its own network: the
    // receiver on loopback is refused, by address or by name.
    let port = hook_url.rsplit(':').next().unwrap();
    let closed = spawn_app(|_| {}).await;
    for url in [
        hook_url.clone(),
        format!("http://localhost:{port}"),
        "http://169.254.169.254/latest/meta-data/".to_string(),
        "http://[::1]/hook".to_string(),
    ] {
        let q = format!("?webhook_url={}", urlencode(&url));
        let r = closed.post_mesh(figure_obj(), "model/obj", &q).await;
        assert_error(r, 422, "webhook_url_invalid").await;
    }
    closed.stop().await;
    let secret = "whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw";
    let app = spawn_app(|c| {
        c.webhook_secret = Some(secret.into());
        c.webhook_allow_private = true;
    })
    .await;
    let job: Value = app
        .post_mesh(
            figure_obj(),
            "model/obj",
            &format!("?webhook_url={}", urlencode(&hook_url)),
        )
        .await
        .json()
        .await
        .unwrap();
    let (wid, ts, sig, body) = tokio::time::timeout(JOB_TIMEOUT, rx.recv())
        .await
        .unwrap()
        .unwrap();
    let key = base64_decode("MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw");
    assert_eq!(
        sig,
        rigserve::jobs::Webhooks::sign(&key, &wid, ts.parse().unwrap(), &body)
    );
    let v: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(v["type"], "job.succeeded");
    assert_eq!(v["data"]["id"], job["id"]);
    assert_eq!(wid, format!("{}.succeeded", id_of(&job)));
    assert_eq!(calls.load(std::sync::atomic::Ordering::SeqCst), 2);
    app.stop().await;
}

fn base64_decode(s: &str) -> Vec<u8> {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.decode(s).unwrap()
}

#[tokio::test]
async fn concurrent_jobs_share_decode_batches() {
    // One inference thread, so all six jobs meet in its batch (with two, each gets half).
    let app = spawn_app(|c| {
        c.workers = 4;
        if let Some(m) = c.model.as_mut() {
            m.decode_lanes = 1;
        }
    })
    .await;
    let mut ids = Vec::new();
    for seed in 0..6 {
        let j: Value = app.submit_figure(&format!("?seed={seed}")).await;
        ids.push(id_of(&j));
    }
    for id in &ids {
        assert_eq!(app.wait_end(id, JOB_TIMEOUT).await["status"], "succeeded");
    }
    let m = app.get("/metrics").await.text().await.unwrap();
    let value = |name: &str| -> f64 {
        m.lines()
            .find(|l| l.starts_with(name) && l[name.len()..].starts_with(' '))
            .and_then(|l| l.rsplit(' ').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no {name}"))
    };
    // 6 jobs × 4 candidates: if jobs never met, the mean batch would be at most 4.
    let mean_batch =
        value("rigserve_decode_batch_rows_total") / value("rigserve_decode_steps_total");
    assert!(mean_batch > 4.0, "mean decode batch {mean_batch}");
    app.stop().await;
}
