//! Deployment files: the Kubernetes manifests (schema and the invariants a schema
//! cannot see: shutdown timing, security, roles), the compose stack, the Dockerfile
//! against its Docker-less mirror, and that mirror's smoke test of the built binary.

use serde::Deserialize;
use serde_yaml::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(repo().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn docs(rel: &str) -> Vec<Value> {
    let text = read(rel);
    serde_yaml::Deserializer::from_str(&text)
        .map(|d| Value::deserialize(d).unwrap_or_else(|e| panic!("{rel}: {e}")))
        .filter(|v| !v.is_null())
        .collect()
}

fn s<'a>(v: &'a Value, path: &[&str]) -> &'a Value {
    path.iter().fold(v, |v, k| &v[*k])
}

fn kind<'a>(all: &'a [Value], kind: &str) -> Vec<&'a Value> {
    all.iter().filter(|d| d["kind"] == kind).collect()
}

/// Every manifest kustomization.yaml lists, plus the example Secret.
fn manifests() -> Vec<Value> {
    let k = &docs("deploy/k8s/kustomization.yaml")[0];
    let mut all: Vec<Value> = k["resources"]
        .as_sequence()
        .expect("resources")
        .iter()
        .flat_map(|f| docs(&format!("deploy/k8s/{}", f.as_str().unwrap())))
        .collect();
    all.extend(docs("deploy/k8s/secret.example.yaml"));
    all
}

fn cpu_millis(v: &Value) -> u64 {
    let t = v
        .as_str()
        .map(str::to_string)
        .unwrap_or_else(|| format!("{}", v.as_u64().unwrap()));
    match t.strip_suffix('m') {
        Some(m) => m.parse().unwrap(),
        None => t.parse::<u64>().unwrap() * 1000,
    }
}

/// KEY=VALUE pairs of the Dockerfile's ENV instructions.
fn dockerfile_env() -> BTreeMap<String, String> {
    let text = read("Dockerfile").replace("\\\n", " ");
    text.lines()
        .filter_map(|l| l.strip_prefix("ENV "))
        .flat_map(|l| l.split_whitespace().map(str::to_string).collect::<Vec<_>>())
        .map(|kv| {
            let (k, v) = kv.split_once('=').expect("ENV KEY=VALUE");
            (k.to_string(), v.to_string())
        })
        .collect()
}

fn dockerfile_uid() -> u64 {
    let text = read("Dockerfile");
    let user = text
        .lines()
        .find_map(|l| l.strip_prefix("USER "))
        .expect("USER");
    user.split(':')
        .next()
        .unwrap()
        .trim()
        .parse()
        .expect("numeric USER")
}

#[test]
fn k8s_manifests_pass_the_schema_check() {
    let out = Command::new(repo().join("scripts/k8s_check.sh"))
        .output()
        .expect("scripts/k8s_check.sh runs");
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    if out.status.code() == Some(3) {
        eprintln!("SKIPPED: {}", text.trim());
        return;
    }
    assert!(
        out.status.success(),
        "deploy/k8s does not validate:\n{text}"
    );
}

#[test]
fn k8s_deployments_drain_before_kill_and_run_locked_down() {
    let all = manifests();
    let config = &kind(&all, "ConfigMap")[0]["data"];
    let drain: u64 = config["RIGSERVE_DRAIN"].as_str().unwrap().parse().unwrap();
    let data_dir = config["RIGSERVE_DATA_DIR"].as_str().unwrap();
    let deployments = kind(&all, "Deployment");
    let mut roles = Vec::new();
    let mut requested_cpu = 0;
    for d in &deployments {
        let name = d["metadata"]["name"].as_str().unwrap();
        let spec = s(d, &["spec", "template", "spec"]);
        assert!(
            d["spec"]["replicas"].is_null(),
            "{name}: replicas belongs to the HPA"
        );
        let c = &spec["containers"][0];
        let env = c["env"].as_sequence().unwrap();
        let role = env
            .iter()
            .find(|e| e["name"] == "RIGSERVE_ROLE")
            .and_then(|e| e["value"].as_str())
            .unwrap_or_else(|| panic!("{name}: no RIGSERVE_ROLE"));
        assert_eq!(name, format!("rigserve-{role}"));
        roles.push(role.to_string());

        let pre_stop: u64 = match s(c, &["lifecycle", "preStop", "exec", "command"]).as_sequence() {
            Some(cmd) => cmd[1].as_str().unwrap().parse().unwrap(),
            None => 0,
        };
        let grace = spec["terminationGracePeriodSeconds"].as_u64().unwrap();
        assert!(
            grace >= pre_stop + drain + 10,
            "{name}: grace {grace}s < preStop {pre_stop}s + drain {drain}s + 10s margin"
        );
        if role == "api" {
            assert!(pre_stop > 0, "api: no preStop sleep before SIGTERM");
        }

        assert_eq!(
            s(c, &["readinessProbe", "httpGet", "path"]),
            "/readyz",
            "{name}"
        );
        assert_eq!(
            s(c, &["livenessProbe", "httpGet", "path"]),
            "/healthz",
            "{name}"
        );

        let pod_sc = &spec["securityContext"];
        assert_eq!(pod_sc["runAsNonRoot"], true, "{name}");
        assert_eq!(
            pod_sc["runAsUser"].as_u64(),
            Some(dockerfile_uid()),
            "{name}"
        );
        assert_eq!(
            c["securityContext"]["readOnlyRootFilesystem"], true,
            "{name}"
        );
        assert_eq!(
            c["securityContext"]["allowPrivilegeEscalation"], false,
            "{name}"
        );

        // Every writable path must be an emptyDir, or the read-only root breaks start-up.
        for path in [data_dir, "/tmp"] {
            let mount = c["volumeMounts"]
                .as_sequence()
                .unwrap()
                .iter()
                .find(|m| m["mountPath"] == path)
                .unwrap_or_else(|| panic!("{name}: nothing mounted at {path}"));
            let vol = spec["volumes"]
                .as_sequence()
                .unwrap()
                .iter()
                .find(|v| v["name"] == mount["name"])
                .unwrap();
            assert!(
                vol["emptyDir"].is_mapping(),
                "{name}: {path} is not an emptyDir"
            );
        }
        requested_cpu += cpu_millis(s(c, &["resources", "requests", "cpu"]));
        assert!(
            cpu_millis(s(c, &["resources", "limits", "cpu"])) <= 2000,
            "{name}"
        );

        let labels = s(d, &["spec", "selector", "matchLabels"]);
        let hpa = kind(&all, "HorizontalPodAutoscaler")
            .into_iter()
            .find(|h| h["spec"]["scaleTargetRef"]["name"] == name);
        assert!(hpa.is_some(), "{name}: no HorizontalPodAutoscaler");
        assert!(
            kind(&all, "PodDisruptionBudget")
                .iter()
                .any(|p| &p["spec"]["selector"]["matchLabels"] == labels),
            "{name}: no PodDisruptionBudget"
        );
    }
    roles.sort();
    assert_eq!(roles, ["api", "worker"]);
    // One api and one worker pod must fit on a 2-core node (less system reserve).
    assert!(
        requested_cpu <= 1500,
        "requests {requested_cpu}m do not fit a 2-core node"
    );

    let svc = &kind(&all, "Service")[0];
    assert_eq!(
        svc["spec"]["selector"]["app.kubernetes.io/component"],
        "api"
    );
}

#[test]
fn compose_runs_api_and_worker_on_shared_postgres_and_s3() {
    let mut c = docs("deploy/compose.yaml").remove(0);
    c.apply_merge().unwrap();
    let services = c["services"].as_mapping().expect("services");
    for s in [
        "postgres",
        "seaweedfs",
        "s3-init",
        "rigserve-api",
        "rigserve-worker",
    ] {
        assert!(services.contains_key(s), "compose.yaml has no service {s}");
    }
    let api = &c["services"]["rigserve-api"];
    let worker = &c["services"]["rigserve-worker"];
    let envs = [&api["environment"], &worker["environment"]];
    assert_eq!(envs[0]["RIGSERVE_ROLE"], "api");
    assert_eq!(envs[1]["RIGSERVE_ROLE"], "worker");
    for k in [
        "RIGSERVE_DATABASE_URL",
        "RIGSERVE_BLOB_URL",
        "AWS_ENDPOINT_URL",
    ] {
        assert!(envs[0][k].is_string(), "{k} missing");
        assert_eq!(envs[0][k], envs[1][k], "{k} differs between the replicas");
    }
    assert!(envs[0]["RIGSERVE_DATABASE_URL"]
        .as_str()
        .unwrap()
        .starts_with("postgres://"));

    // The bucket the init step creates is the one the replicas use.
    let blob = envs[0]["RIGSERVE_BLOB_URL"].as_str().unwrap();
    let bucket = blob
        .strip_prefix("s3://")
        .unwrap()
        .split('/')
        .next()
        .unwrap();
    let init = serde_yaml::to_string(&c["services"]["s3-init"]["command"]).unwrap();
    assert!(
        init.contains(&format!("s3.bucket.create -name {bucket}")),
        "{init}"
    );
    // Its credentials are an identity of the S3 server's config.
    let s3: serde_json::Value = serde_json::from_str(&read("deploy/seaweedfs-s3.json")).unwrap();
    let key = envs[0]["AWS_ACCESS_KEY_ID"].as_str().unwrap();
    let secret = envs[0]["AWS_SECRET_ACCESS_KEY"].as_str().unwrap();
    assert!(
        s3["identities"]
            .as_array()
            .unwrap()
            .iter()
            .any(|i| i["credentials"]
                .as_array()
                .unwrap()
                .iter()
                .any(|c| c["accessKey"] == key && c["secretKey"] == secret)),
        "AWS keys of the replicas are not in deploy/seaweedfs-s3.json"
    );

    let drain: u64 = envs[0]["RIGSERVE_DRAIN"].as_str().unwrap().parse().unwrap();
    let grace = api["stop_grace_period"].as_str().unwrap();
    let grace: u64 = grace.strip_suffix('s').unwrap().parse().unwrap();
    assert!(
        grace > drain,
        "stop_grace_period {grace}s <= drain {drain}s"
    );
}

#[test]
fn dockerfile_and_image_build_script_agree() {
    let docker = read("Dockerfile");
    let script = read("scripts/image_build.sh");

    // The same environment: the script's IMAGE_ENV block lists the Dockerfile's ENV.
    let block = script
        .split("IMAGE_ENV=(")
        .nth(1)
        .and_then(|r| r.split(')').next())
        .expect("IMAGE_ENV=( … ) in image_build.sh");
    let script_env: BTreeMap<String, String> = block
        .split_whitespace()
        .map(|kv| {
            let (k, v) = kv.split_once('=').unwrap();
            (k.to_string(), v.to_string())
        })
        .collect();
    assert_eq!(dockerfile_env(), script_env);
    let uid = dockerfile_uid();
    assert!(
        script.contains(&format!("IMAGE_UID={uid}")),
        "image_build.sh runs as another uid"
    );

    // The same layout: every COPY destination is assembled by the script too.
    let dests: Vec<&str> = docker
        .lines()
        .filter(|l| l.starts_with("COPY --from=") || l.starts_with("COPY models"))
        .chain(docker.lines().filter(|l| l.starts_with("COPY deploy/")))
        .map(|l| l.split_whitespace().last().unwrap())
        .collect();
    assert_eq!(dests.len(), 4, "{dests:?}");
    for d in dests {
        assert!(
            script.contains(&format!("\"$root{d}\"")),
            "image_build.sh does not build {d}"
        );
    }
    // The layout's paths are the ones the environment names.
    let env = dockerfile_env();
    assert!(docker.contains(&format!(
        "/out/libonnxruntime.so.1.31.1 {}",
        env["RIGSERVE_ORT_LIB"]
    )));
    assert!(docker.contains(&format!("COPY models {}", env["RIGSERVE_MODELS"])));

    // Every COPY source survives .dockerignore (a `*` that re-includes what is copied).
    let ignore = read(".dockerignore");
    for src in [
        "Cargo.toml",
        "Cargo.lock",
        "src/",
        "migrations/",
        "models/",
        "scripts/fetch_ort.sh",
        "deploy/healthcheck.sh",
    ] {
        assert!(
            ignore.lines().any(|l| l == format!("!{src}")),
            ".dockerignore drops {src}"
        );
        assert!(repo().join(src).exists(), "{src} is gone");
    }
    assert!(
        ignore.lines().any(|l| l == "models/library.json"),
        ".dockerignore lets a locally built library.json into the image"
    );
    assert!(
        !ignore
            .lines()
            .any(|l| l == "models/library.bin" || l == "models/NOTICE"),
        ".dockerignore keeps the shipped library or its notice out of the image"
    );

    // The builder is the toolchain this repository builds with.
    let rustc = Command::new("rustc")
        .arg("--version")
        .output()
        .expect("rustc");
    let version = String::from_utf8_lossy(&rustc.stdout);
    let minor: Vec<&str> = version
        .split_whitespace()
        .nth(1)
        .unwrap()
        .split('.')
        .take(2)
        .collect();
    let image = format!("FROM rust:{}-", minor.join("."));
    assert!(
        docker.contains(&image),
        "Dockerfile's builder is not {image}…"
    );
}

#[test]
fn image_layout_serves_rigs_and_drains_on_sigterm() {
    for tool in ["curl", "python3"] {
        if Command::new(tool).arg("--version").output().is_err() {
            eprintln!("SKIPPED: {tool} is not installed; scripts/image_build.sh needs it");
            return;
        }
    }
    // Under target/ (not a 0700 temp dir): the smoke test runs as the image's uid.
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("image-root");
    let out = Command::new(repo().join("scripts/image_build.sh"))
        .args(["--binary", env!("CARGO_BIN_EXE_rigserve"), "--root"])
        .arg(&root)
        .output()
        .expect("scripts/image_build.sh runs");
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "image smoke test failed:\n{text}");
    assert!(text.contains("smoke test passed"), "{text}");
    for p in [
        "app/rigserve",
        "app/models/skeleton/decoder.onnx",
        "app/models/library.bin",
        "app/models/NOTICE",
        "app/lib/libonnxruntime.so.1.31.1",
        "app/healthcheck.sh",
    ] {
        assert!(root.join(p).is_file(), "{p} missing from the layout");
    }
    assert!(
        !root.join("app/models/library.json").exists(),
        "a locally built library.json is in the image layout"
    );
    let _ = std::fs::remove_dir_all(&root);
}
