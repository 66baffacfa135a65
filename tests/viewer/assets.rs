//! `GET /` and `GET /assets/{file}`: embedded, typed, cacheable, and the vendored
//! three.js is the pinned npm version, byte for byte.

use super::helpers::{repo, spawn_app};

#[tokio::test]
async fn the_page_and_its_assets_are_served_with_types_and_caching() {
    let app = spawn_app(|c| c.workers = 0).await;
    let page = app.get("/").await;
    assert_eq!(page.status(), 200);
    let h = page.headers().clone();
    assert_eq!(h["content-type"], "text/html; charset=utf-8");
    assert_eq!(h["cache-control"], "no-cache");
    let html = page.text().await.unwrap();
    // Every module the page and its import map name is served from the binary.
    for path in [
        "/assets/app.js",
        "/assets/motion.js",
        "/assets/style.css",
        "/assets/vendor/three/build/three.module.js",
        "/assets/vendor/three/build/three.core.js",
        "/assets/vendor/three/examples/jsm/loaders/GLTFLoader.js",
        "/assets/vendor/three/examples/jsm/controls/OrbitControls.js",
        "/assets/vendor/three/examples/jsm/utils/BufferGeometryUtils.js",
        "/assets/vendor/three/examples/jsm/utils/SkeletonUtils.js",
        "/assets/vendor/three/LICENSE",
    ] {
        let r = app.get(path).await;
        assert_eq!(r.status(), 200, "{path}");
        let ty = r.headers()["content-type"].to_str().unwrap().to_string();
        let want = if path.ends_with(".js") {
            "text/javascript"
        } else if path.ends_with(".css") {
            "text/css"
        } else {
            "text/plain"
        };
        assert!(ty.starts_with(want), "{path}: {ty}");
        let cache = r.headers()["cache-control"].to_str().unwrap().to_string();
        assert_eq!(
            cache.contains("max-age"),
            path.contains("/vendor/"),
            "{path}: {cache}"
        );
        assert!(r.bytes().await.unwrap().len() > 100, "{path}");
    }
    assert!(
        html.contains("/assets/app.js")
            && html.contains("/assets/vendor/three/build/three.module.js")
    );

    // Revalidation: the ETag answers 304 without a body.
    let etag = app.get("/assets/app.js").await.headers()["etag"].clone();
    let again = app
        .client
        .get(app.url("/assets/app.js"))
        .header("if-none-match", etag.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(again.status(), 304);
    assert_eq!(again.headers()["etag"], etag);
    assert!(again.bytes().await.unwrap().is_empty());

    for missing in [
        "/assets/nope.js",
        "/assets/../Cargo.toml",
        "/assets/vendor/three/package.json",
    ] {
        let r = app.get(missing).await;
        assert_eq!(r.status(), 404, "{missing}");
        let body: serde_json::Value = r.json().await.unwrap();
        assert_eq!(body["error_type"], "not_found", "{missing}");
    }
    app.stop().await;
}

#[test]
fn vendored_three_is_the_pinned_npm_version() {
    let npm = repo().join("tools/node_modules/three");
    if !npm.join("package.json").is_file() {
        eprintln!("SKIPPED: tools/node_modules/three is absent (npm ci --prefix tools)");
        return;
    }
    let vendored = repo().join("web/vendor/three");
    let pkg: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(npm.join("package.json")).unwrap()).unwrap();
    let version = std::fs::read_to_string(vendored.join("VERSION")).unwrap();
    assert_eq!(
        version.trim(),
        pkg["version"].as_str().unwrap(),
        "run tools/vendor_three.sh"
    );
    for f in [
        "LICENSE",
        "build/three.module.js",
        "build/three.core.js",
        "examples/jsm/loaders/GLTFLoader.js",
        "examples/jsm/controls/OrbitControls.js",
        "examples/jsm/utils/BufferGeometryUtils.js",
        "examples/jsm/utils/SkeletonUtils.js",
    ] {
        assert!(
            std::fs::read(vendored.join(f)).unwrap() == std::fs::read(npm.join(f)).unwrap(),
            "web/vendor/three/{f} differs from npm's; run tools/vendor_three.sh"
        );
    }
}
