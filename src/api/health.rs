//! `/healthz` (the process answers), `/readyz` (it can do work: store and blobs reachable,
//! models loaded, not shutting down), `/metrics` (Prometheus text).

use super::AppState;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use prometheus::Encoder;
use serde_json::json;

pub async fn healthz() -> Json<serde_json::Value> {
    Json(json!({"status": "ok"}))
}

pub async fn readyz(State(state): State<AppState>) -> Response {
    let store = state.ctx.store.ping().await.err().map(|e| e.to_string());
    let blobs = state.ctx.blobs.ping().await.err().map(|e| e.to_string());
    let stopping = state.shutdown.is_cancelled();
    let ready = store.is_none() && blobs.is_none() && !stopping;
    let body = json!({
        "status": if ready { "ready" } else { "not_ready" },
        "checks": {
            "store": store.unwrap_or_else(|| "ok".into()),
            "blobs": blobs.unwrap_or_else(|| "ok".into()),
            "skeleton_model": if state.cfg.skeleton_model { "loaded" } else { "absent" },
            "shutting_down": stopping,
        }
    });
    let status = if ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (status, Json(body)).into_response()
}

pub async fn metrics(State(state): State<AppState>) -> Response {
    if let Ok(counts) = state.ctx.store.counts().await {
        state.ctx.metrics.set_counts(&counts);
    }
    if let (Some(d), Some(snap)) = (&state.decode, state.engine_metrics.as_ref()) {
        d.update(snap());
    }
    let mut buf = Vec::new();
    let enc = prometheus::TextEncoder::new();
    if let Err(e) = enc.encode(&state.registry.gather(), &mut buf) {
        return (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response();
    }
    ([(header::CONTENT_TYPE, enc.format_type().to_string())], buf).into_response()
}
