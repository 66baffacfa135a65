//! A server on a random port per test, driven over HTTP only (zero-to-production style).

use reqwest::{Client, Response};
use rigserve::app::{Application, Config, ModelSetup};
use rigserve::infer::Variant;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

pub struct TestApp {
    pub base: String,
    pub client: Client,
    pub data: tempfile::TempDir,
    shutdown: CancellationToken,
    server: Option<tokio::task::JoinHandle<std::io::Result<()>>>,
}

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub fn model_setup() -> ModelSetup {
    ModelSetup {
        dir: repo().join("models"),
        variant: Variant::Fp32,
        ort_lib: Some(repo().join(".onnxruntime/libonnxruntime.so.1.31.1")),
        threads: 1,
        max_batch: 16,
        ragged: true,
        decode_nice: 0,
        decode_lanes: ModelSetup::default_decode_lanes(),
        library: None,
    }
}

/// Fast timers so tests do not wait on production intervals.
pub fn test_config(data: &Path) -> Config {
    let mut c = Config::new("127.0.0.1:0".parse().unwrap(), data.to_path_buf());
    c.model = Some(model_setup());
    c.poll = Duration::from_millis(50);
    c.sweep_every = Duration::from_millis(200);
    c.workers = 2;
    c.drain = Duration::from_secs(5);
    c.webhook_first_delay = Duration::from_millis(100);
    c
}

pub async fn spawn_app(tweak: impl FnOnce(&mut Config)) -> TestApp {
    let data = tempfile::tempdir().unwrap();
    let mut cfg = test_config(data.path());
    tweak(&mut cfg);
    let app = Application::build(cfg).await.expect("the server starts");
    let base = format!("http://127.0.0.1:{}", app.port());
    let shutdown = app.shutdown_token();
    let server = tokio::spawn(app.run_until_stopped());
    TestApp {
        base,
        client: Client::new(),
        data,
        shutdown,
        server: Some(server),
    }
}

impl TestApp {
    pub fn url(&self, path: &str) -> String {
        format!("{}{}", self.base, path)
    }

    pub async fn post_mesh(&self, bytes: Vec<u8>, content_type: &str, query: &str) -> Response {
        self.client
            .post(self.url(&format!("/v1/jobs{query}")))
            .header("content-type", content_type)
            .body(bytes)
            .send()
            .await
            .unwrap()
    }

    /// Submits [`figure_obj`] with `query`; the job from the 202 answer.
    pub async fn submit_figure(&self, query: &str) -> Value {
        let r = self.post_mesh(figure_obj(), "model/obj", query).await;
        assert_eq!(r.status(), 202);
        r.json().await.unwrap()
    }

    /// The bone tree a finished job links to.
    pub async fn skeleton_of(&self, done: &Value) -> Value {
        self.get(done["result"]["skeleton"].as_str().unwrap())
            .await
            .json()
            .await
            .unwrap()
    }

    pub async fn get(&self, path: &str) -> Response {
        self.client.get(self.url(path)).send().await.unwrap()
    }

    pub async fn job(&self, id: &str) -> Value {
        self.get(&format!("/v1/jobs/{id}"))
            .await
            .json()
            .await
            .unwrap()
    }

    /// Polls until the job ends; panics after `timeout`.
    pub async fn wait_end(&self, id: &str, timeout: Duration) -> Value {
        let start = Instant::now();
        loop {
            let j = self.job(id).await;
            let s = j["status"].as_str().unwrap().to_string();
            if !matches!(s.as_str(), "queued" | "running") {
                return j;
            }
            assert!(
                start.elapsed() < timeout,
                "job {id} still {s} after {timeout:?}"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Shuts the server down as SIGTERM would and waits for it to stop.
    pub async fn stop(mut self) {
        self.shutdown.cancel();
        if let Some(s) = self.server.take() {
            s.await.unwrap().unwrap();
        }
    }
}

/// Asserts the status and `error_type` of an error answer.
pub async fn assert_error(r: Response, status: u16, error_type: &str) -> Value {
    let got = r.status().as_u16();
    let body: Value = r.json().await.unwrap_or(Value::Null);
    assert_eq!(
        (got, body["error_type"].as_str().unwrap_or("")),
        (status, error_type),
        "answer {body}"
    );
    assert!(body["error"].as_str().is_some_and(|m| !m.is_empty()));
    body
}

/// [`figure_obj`] as loaded (for the test binaries that include these helpers by path).
#[allow(dead_code)]
pub fn figure_mesh() -> rigserve::mesh::Mesh {
    rigserve::mesh::load(&figure_obj(), &rigserve::mesh::Limits::default())
        .unwrap()
        .mesh
}

/// A small standing figure as OBJ boxes: torso, head, two arms, two legs (about 200
/// triangles), for tests that must not depend on the shared data set.
pub fn figure_obj() -> Vec<u8> {
    let boxes: [([f32; 3], [f32; 3]); 6] = [
        ([-0.2, 0.9, -0.1], [0.2, 1.5, 0.1]),
        ([-0.12, 1.5, -0.12], [0.12, 1.75, 0.12]),
        ([-0.7, 1.35, -0.06], [-0.2, 1.45, 0.06]),
        ([0.2, 1.35, -0.06], [0.7, 1.45, 0.06]),
        ([-0.18, 0.0, -0.08], [-0.04, 0.9, 0.08]),
        ([0.04, 0.0, -0.08], [0.18, 0.9, 0.08]),
    ];
    let mut s = String::from("# test figure\n");
    let mut base = 0;
    for (lo, hi) in boxes {
        // Each box subdivided 2x along its long axis so skinning has vertices to bend.
        let n = 3;
        let long = (0..3)
            .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
            .unwrap();
        let mut verts = Vec::new();
        for k in 0..n {
            let t = k as f32 / (n - 1) as f32;
            for c in 0..4 {
                let mut p = [0.0f32; 3];
                let (u, v) = ((c & 1) as f32, (c >> 1) as f32);
                let others: Vec<usize> = (0..3).filter(|&a| a != long).collect();
                p[long] = lo[long] + t * (hi[long] - lo[long]);
                p[others[0]] = lo[others[0]] + u * (hi[others[0]] - lo[others[0]]);
                p[others[1]] = lo[others[1]] + v * (hi[others[1]] - lo[others[1]]);
                verts.push(p);
            }
        }
        for p in &verts {
            s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        let idx = |k: usize, c: usize| base + k * 4 + c + 1;
        for k in 0..n - 1 {
            for (a, b) in [(0, 1), (1, 3), (3, 2), (2, 0)] {
                s += &format!("f {} {} {}\n", idx(k, a), idx(k + 1, a), idx(k + 1, b));
                s += &format!("f {} {} {}\n", idx(k, a), idx(k + 1, b), idx(k, b));
            }
        }
        s += &format!("f {} {} {}\n", idx(0, 0), idx(0, 1), idx(0, 3));
        s += &format!("f {} {} {}\n", idx(0, 0), idx(0, 3), idx(0, 2));
        s += &format!("f {} {} {}\n", idx(n - 1, 0), idx(n - 1, 3), idx(n - 1, 1));
        s += &format!("f {} {} {}\n", idx(n - 1, 0), idx(n - 1, 2), idx(n - 1, 3));
        base += verts.len();
    }
    s.into_bytes()
}

/// A bone tree for [`figure_obj`] (hips → spine → head, arms and legs).
pub fn figure_skeleton() -> Value {
    let bones = [
        ("hips", None, [0.0, 0.95, 0.0], [0.0, 1.2, 0.0]),
        ("spine", Some(0), [0.0, 1.2, 0.0], [0.0, 1.5, 0.0]),
        ("head", Some(1), [0.0, 1.5, 0.0], [0.0, 1.75, 0.0]),
        ("arm.L", Some(1), [0.2, 1.4, 0.0], [0.7, 1.4, 0.0]),
        ("arm.R", Some(1), [-0.2, 1.4, 0.0], [-0.7, 1.4, 0.0]),
        ("leg.L", Some(0), [0.11, 0.9, 0.0], [0.11, 0.0, 0.0]),
        ("leg.R", Some(0), [-0.11, 0.9, 0.0], [-0.11, 0.0, 0.0]),
    ];
    let list: Vec<Value> = bones
        .iter()
        .map(|(name, parent, head, tail)| {
            serde_json::json!({"name": name, "parent": parent, "head": head, "tail": tail})
        })
        .collect();
    serde_json::json!({"version": 1, "frame": rigserve::export::BONE_TREE_FRAME, "bones": list})
}
