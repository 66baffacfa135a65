//! `serve --cors-origin` in a real browser (tools/cors_e2e.mjs): a page from the listed
//! loopback origin uploads, follows SSE and downloads; a page from another port is blocked.

use super::helpers::{figure_obj, spawn_app};
use super::{browser_ready, node, output_dir};
use serde_json::Value;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[tokio::test(flavor = "multi_thread")]
async fn a_page_on_a_listed_origin_rigs_through_the_api_and_another_is_blocked() {
    if !browser_ready() {
        return;
    }
    let (listed, unlisted) = (free_port(), free_port());
    let app = spawn_app(|c| c.cors_origins = vec![format!("http://127.0.0.1:{listed}")]).await;
    let mesh = output_dir("cors").join("figure.obj");
    std::fs::write(&mesh, figure_obj()).unwrap();
    let base = app.base.clone();
    let m = mesh.to_str().unwrap().to_string();
    let text = tokio::task::spawn_blocking(move || {
        node(
            "cors_e2e.mjs",
            &[&base, &listed.to_string(), &unlisted.to_string(), &m],
        )
    })
    .await
    .unwrap();
    let r: Value = serde_json::from_str(&text).unwrap();
    eprintln!("cors_e2e: {r}");
    let ok = &r["listed"];
    assert!(ok["error"].is_null(), "{r:#}");
    assert_eq!(ok["status"], 202, "{r:#}");
    assert!(
        ok["location"].as_str().unwrap().starts_with("/v1/jobs/"),
        "{r:#}"
    );
    assert_eq!(ok["final"], "succeeded", "{r:#}");
    assert_eq!(ok["glbMagic"], "glTF", "{r:#}");
    assert!(ok["bones"].as_u64().unwrap() >= 2, "{r:#}");
    let blocked = &r["unlisted"];
    assert!(
        blocked["error"]
            .as_str()
            .unwrap_or("")
            .contains("Failed to fetch"),
        "{r:#}"
    );
    // Refused at the preflight, so the browser never sent the upload itself.
    assert!(blocked["steps"].as_array().unwrap().is_empty(), "{r:#}");
    assert!(
        blocked["pageErrors"].to_string().contains("preflight"),
        "{r:#}"
    );
    app.stop().await;
}
