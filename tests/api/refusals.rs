//! Refusals the HTTP stack makes before a handler runs, sent as raw bytes so nothing in
//! a client library shapes them: each must be the service's `{error, error_type}`.

use super::helpers::*;
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Sends `request` on a fresh connection and reads the whole answer (the server closes
/// after an error, or the request says `connection: close`).
async fn raw(app: &TestApp, request: &[u8]) -> (u16, Value) {
    let addr = app.base.trim_start_matches("http://");
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    // The server may answer and close before it has read everything: a failed write
    // then is fine, the answer is what is checked.
    let _ = s.write_all(request).await;
    let mut out = Vec::new();
    let _ = tokio::time::timeout(std::time::Duration::from_secs(20), s.read_to_end(&mut out)).await;
    let text = String::from_utf8_lossy(&out);
    let status: u16 = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or_else(|| panic!("no status line in {:?}", &text[..text.len().min(300)]));
    let body = text.split_once("\r\n\r\n").map_or("", |(_, b)| b);
    let json = serde_json::from_str(body.trim()).unwrap_or_else(|_| {
        panic!(
            "{status}: body is not JSON: {:?}",
            &body[..body.len().min(300)]
        )
    });
    (status, json)
}

fn get(target: &str, extra_headers: &str) -> Vec<u8> {
    format!("GET {target} HTTP/1.1\r\nhost: x\r\n{extra_headers}connection: close\r\n\r\n")
        .into_bytes()
}

fn assert_refusal((status, body): (u16, Value), want: u16, error_type: &str) {
    assert_eq!(
        (status, body["error_type"].as_str().unwrap_or("")),
        (want, error_type),
        "{body}"
    );
    assert!(
        body["error"].as_str().is_some_and(|m| !m.is_empty()),
        "{body}"
    );
}

#[tokio::test]
async fn long_urls_large_headers_and_bad_paths_get_json_refusals() {
    let app = spawn_app(|_| {}).await;
    let long_query = format!("/v1/jobs?seed={}", "1".repeat(100 << 10));
    assert_refusal(raw(&app, &get(&long_query, "")).await, 414, "uri_too_long");
    let huge_query = format!("/v1/jobs?x={}", "a".repeat(1 << 20));
    assert_refusal(raw(&app, &get(&huge_query, "")).await, 414, "uri_too_long");
    let long_path = format!("/v1/jobs/{}", "z".repeat(20 << 10));
    assert_refusal(raw(&app, &get(&long_path, "")).await, 414, "uri_too_long");

    let big_header = format!("x-big: {}\r\n", "h".repeat(1 << 20));
    assert_refusal(
        raw(&app, &get("/healthz", &big_header)).await,
        431,
        "headers_too_large",
    );
    let many: String = (0..20_000).map(|i| format!("x-h{i}: v\r\n")).collect();
    assert_refusal(
        raw(&app, &get("/healthz", &many)).await,
        431,
        "headers_too_large",
    );

    assert_refusal(
        raw(&app, &get("/v1/jobs/%ZZ%ff", "")).await,
        400,
        "invalid_path",
    );
    assert_refusal(
        raw(&app, &get("/v1/jobs/%ff%fe/result.glb", "")).await,
        400,
        "invalid_path",
    );
    assert_refusal(
        raw(&app, &get("/no/such/route", "")).await,
        404,
        "not_found",
    );

    // Ordinary requests are untouched by the limits.
    let ok = app.get("/healthz").await;
    assert_eq!(ok.status(), 200);
    app.stop().await;
}

#[tokio::test]
async fn a_form_missing_only_its_closing_boundary_is_multipart_invalid() {
    let app = spawn_app(|_| {}).await;
    let mesh = figure_obj();
    let mut body = Vec::new();
    body.extend_from_slice(
        b"--XyZ\r\ncontent-disposition: form-data; name=\"file\"; filename=\"m.obj\"\r\n\
          content-type: model/obj\r\n\r\n",
    );
    body.extend_from_slice(&mesh);
    body.extend_from_slice(b"\r\n");
    let mut req = format!(
        "POST /v1/jobs HTTP/1.1\r\nhost: x\r\ncontent-type: multipart/form-data; boundary=XyZ\r\n\
         content-length: {}\r\nconnection: close\r\n\r\n",
        body.len()
    )
    .into_bytes();
    req.extend_from_slice(&body);
    assert_refusal(raw(&app, &req).await, 400, "multipart_invalid");
    app.stop().await;
}
