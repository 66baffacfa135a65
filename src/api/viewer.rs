//! The viewer page (`GET /`) and its static assets (`GET /assets/{file}`), compiled into
//! the binary so that a single executable serves them with no CDN or files beside it.
//!
//! The page talks to the public API only, like any other client. Its own files are
//! revalidated on every load (`no-cache` plus a strong ETag), so a new binary's page is
//! picked up at once; the vendored three.js modules change only with the pinned version
//! and may be cached for a day.

use super::error::ApiError;
use axum::extract::Path;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use sha2::{Digest, Sha256};
use std::sync::OnceLock;

struct Asset {
    /// The path below `/assets/` (the page's own files at the top, three.js under
    /// `vendor/three/` in the npm package's layout, so its relative imports resolve).
    path: &'static str,
    content_type: &'static str,
    bytes: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $type:expr) => {
        Asset {
            path: $path,
            content_type: $type,
            bytes: include_bytes!(concat!("../../web/", $path)),
        }
    };
}

const JS: &str = "text/javascript; charset=utf-8";

static ASSETS: &[Asset] = &[
    asset!("index.html", "text/html; charset=utf-8"),
    asset!("app.js", JS),
    asset!("motion.js", JS),
    asset!("style.css", "text/css; charset=utf-8"),
    asset!("vendor/three/LICENSE", "text/plain; charset=utf-8"),
    asset!("vendor/three/build/three.module.js", JS),
    asset!("vendor/three/build/three.core.js", JS),
    asset!("vendor/three/examples/jsm/loaders/GLTFLoader.js", JS),
    asset!("vendor/three/examples/jsm/controls/OrbitControls.js", JS),
    asset!("vendor/three/examples/jsm/utils/BufferGeometryUtils.js", JS),
    asset!("vendor/three/examples/jsm/utils/SkeletonUtils.js", JS),
];

/// Strong ETags of [`ASSETS`], in the same order, computed on first use.
fn etags() -> &'static [String] {
    static TAGS: OnceLock<Vec<String>> = OnceLock::new();
    TAGS.get_or_init(|| {
        ASSETS
            .iter()
            .map(|a| format!("\"{}\"", &hex::encode(Sha256::digest(a.bytes))[..32]))
            .collect()
    })
}

pub fn routes<S: Clone + Send + Sync + 'static>() -> Router<S> {
    Router::new()
        .route("/", get(index))
        .route("/assets/{*file}", get(asset))
}

async fn index(headers: HeaderMap) -> Response {
    serve(0, &headers)
}

async fn asset(Path(file): Path<String>, headers: HeaderMap) -> Result<Response, ApiError> {
    let i = ASSETS.iter().position(|a| a.path == file).ok_or_else(|| {
        ApiError::new(
            StatusCode::NOT_FOUND,
            "not_found",
            format!("no asset {file:?}"),
        )
    })?;
    Ok(serve(i, &headers))
}

fn serve(i: usize, headers: &HeaderMap) -> Response {
    let a = &ASSETS[i];
    let etag = &etags()[i];
    let cache = if a.path.starts_with("vendor/") {
        "public, max-age=86400"
    } else {
        "no-cache"
    };
    let fresh = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == etag || t.trim() == "*"));
    let mut r = if fresh {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        let mut r = a.bytes.into_response();
        r.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static(a.content_type),
        );
        r
    };
    let h = r.headers_mut();
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static(cache));
    h.insert(
        header::ETAG,
        HeaderValue::from_str(etag).expect("hex ETags are valid header values"),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_asset_is_embedded_with_a_distinct_etag() {
        assert_eq!(ASSETS[0].path, "index.html");
        let tags: std::collections::HashSet<_> = etags().iter().collect();
        assert_eq!(tags.len(), ASSETS.len());
        assert!(ASSETS.iter().all(|a| !a.bytes.is_empty()));
    }
}
