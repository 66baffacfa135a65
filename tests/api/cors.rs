//! `serve --cors-origin`: preflights and responses for a listed origin, nothing for an
//! unlisted one, nothing at all when CORS is off. The browser side is `tests/viewer/cors.rs`.

use super::helpers::*;
use reqwest::Method;

const PAGE: &str = "http://127.0.0.1:8099";

async fn preflight(app: &TestApp, path: &str, method: &str, origin: &str) -> reqwest::Response {
    app.client
        .request(Method::OPTIONS, app.url(path))
        .header("origin", origin)
        .header("access-control-request-method", method)
        .header(
            "access-control-request-headers",
            "authorization,content-type",
        )
        .send()
        .await
        .unwrap()
}

fn cors_headers(r: &reqwest::Response) -> Vec<String> {
    r.headers()
        .keys()
        .map(|k| k.as_str().to_string())
        .filter(|k| k.starts_with("access-control-"))
        .collect()
}

#[tokio::test]
async fn a_listed_origin_is_allowed_and_an_unlisted_one_gets_no_cors_headers() {
    let app = spawn_app(|c| c.cors_origins = vec![PAGE.into()]).await;
    for (path, method) in [
        ("/v1/jobs", "POST"),
        ("/v1/rig", "POST"),
        ("/v1/jobs/some-id", "GET"),
        ("/v1/jobs/some-id/events", "GET"),
        ("/v1/jobs/some-id/result.glb", "GET"),
    ] {
        let r = preflight(&app, path, method, PAGE).await;
        assert!(r.status().is_success(), "{path}: {}", r.status());
        let h = r.headers();
        assert_eq!(h["access-control-allow-origin"], PAGE, "{path}");
        let methods = h["access-control-allow-methods"].to_str().unwrap();
        assert!(methods.contains(method), "{path}: {methods}");
        let allowed = h["access-control-allow-headers"].to_str().unwrap();
        for want in [
            "authorization",
            "content-type",
            "idempotency-key",
            "last-event-id",
        ] {
            assert!(allowed.contains(want), "{path}: {allowed}");
        }

        let r = preflight(&app, path, method, "http://127.0.0.1:8098").await;
        assert_eq!(cors_headers(&r), Vec::<String>::new(), "{path}");
    }

    // The upload itself: the page may read the answer and its Location.
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("origin", PAGE)
        .header("content-type", "model/obj")
        .body(figure_obj())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    assert_eq!(r.headers()["access-control-allow-origin"], PAGE);
    let exposed = r.headers()["access-control-expose-headers"]
        .to_str()
        .unwrap();
    for want in ["location", "retry-after", "etag", "x-request-id"] {
        assert!(exposed.contains(want), "{exposed}");
    }
    let r = app
        .client
        .get(app.url("/healthz"))
        .header("origin", "http://evil.example")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(cors_headers(&r), Vec::<String>::new());
    app.stop().await;
}

#[tokio::test]
async fn without_origins_cors_is_off_and_a_wildcard_allows_any() {
    let app = spawn_app(|_| {}).await;
    let r = preflight(&app, "/v1/jobs", "POST", PAGE).await;
    assert_eq!(r.status(), 405);
    assert_eq!(cors_headers(&r), Vec::<String>::new());
    app.stop().await;

    let app = spawn_app(|c| c.cors_origins = vec!["*".into()]).await;
    let r = preflight(&app, "/v1/jobs", "POST", "http://anything.example:1234").await;
    assert!(r.status().is_success());
    assert_eq!(r.headers()["access-control-allow-origin"], "*");
    app.stop().await;
}

#[tokio::test]
async fn a_malformed_origin_is_a_start_up_error() {
    let data = tempfile::tempdir().unwrap();
    let mut cfg = test_config(data.path());
    cfg.cors_origins = vec!["127.0.0.1:8099".into()];
    let err = rigserve::app::Application::build(cfg)
        .await
        .err()
        .expect("refused");
    assert_eq!(err.code(), "cors_origin_invalid");
}
