//! The HTTP API: routes, auth, limits, SSE and metrics over the job store. Handlers never
//! run rigging themselves; they validate, queue, and read what workers recorded.

pub mod auth;
pub mod cors;
pub mod error;
pub mod events;
pub mod health;
pub mod jobs;
pub mod listener;
pub mod metrics;
pub mod refusals;
pub mod rig;
pub mod upload;
pub mod viewer;

use crate::infer::MetricsSnapshot;
use crate::jobs::Context;
use crate::mesh::Limits;
use auth::ApiKeys;
use axum::body::Body;
use axum::extract::{DefaultBodyLimit, FromRef};
use axum::http::{Request, StatusCode};
use axum::response::IntoResponse;
use axum::routing::{get, post};
use axum::Router;
use error::ApiError;
use metrics::{DecodeMetrics, HttpMetrics};
use prometheus::Registry;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;
use tower_http::catch_panic::CatchPanicLayer;
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::timeout::TimeoutLayer;
use tower_http::trace::TraceLayer;

/// Settings the handlers read.
#[derive(Clone, Debug)]
pub struct ApiConfig {
    /// Upload caps (bytes, vertices, triangles) for `POST /v1/jobs`.
    pub limits: Limits,
    /// Largest upload for `POST /v1/rig`.
    pub sync_max_bytes: u64,
    pub sync_timeout: Duration,
    pub max_queued: u64,
    pub queue_full_retry_after: u64,
    pub result_ttl: Duration,
    /// How often waiting SSE streams and sync requests re-read the store.
    pub poll: Duration,
    pub max_samples: usize,
    pub max_bones: usize,
    pub skeleton_model: bool,
    /// Where uploads are spooled.
    pub tmp_dir: PathBuf,
    /// Time limit of requests other than uploads, SSE and `/v1/rig`.
    pub request_timeout: Duration,
    pub upload_timeout: Duration,
    /// `webhook_url` may name a loopback or private address.
    pub webhook_allow_private: bool,
    /// Browser origins allowed cross-origin access; `None`: CORS off.
    pub cors: Option<cors::Origins>,
}

pub type SnapshotFn = Arc<dyn Fn() -> MetricsSnapshot + Send + Sync>;

#[derive(Clone)]
pub struct AppState {
    pub ctx: Context,
    pub keys: ApiKeys,
    pub cfg: Arc<ApiConfig>,
    pub registry: Registry,
    pub decode: Option<Arc<DecodeMetrics>>,
    pub engine_metrics: Option<SnapshotFn>,
    /// Canceled when the server starts shutting down: SSE streams and waiting sync
    /// requests end, `/readyz` turns 503.
    pub shutdown: CancellationToken,
}

impl FromRef<AppState> for ApiKeys {
    fn from_ref(s: &AppState) -> ApiKeys {
        s.keys.clone()
    }
}

async fn no_route() -> ApiError {
    ApiError::new(StatusCode::NOT_FOUND, "not_found", "no such route")
}

async fn wrong_method() -> ApiError {
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        "method_not_allowed",
        "this route does not take that method",
    )
}

fn panic_response(_: Box<dyn std::any::Any + Send + 'static>) -> axum::response::Response {
    ApiError::new(
        StatusCode::INTERNAL_SERVER_ERROR,
        "internal_error",
        "the server hit a bug while handling this request",
    )
    .into_response()
}

/// A worker replica's listener: probes and metrics only.
pub fn health_router(state: AppState, http: HttpMetrics) -> Router {
    Router::new()
        .route("/healthz", get(health::healthz))
        .route("/readyz", get(health::readyz))
        .route("/metrics", get(health::metrics))
        .fallback(no_route)
        .layer(axum::middleware::from_fn(refusals::json_errors))
        .layer(axum::middleware::from_fn_with_state(http, metrics::track))
        .with_state(state)
}

pub fn router(state: AppState, http: HttpMetrics) -> Router {
    let cfg = state.cfg.clone();
    // Multipart reads go through axum's own limit; raw bodies are counted while spooling.
    let body_limit = DefaultBodyLimit::max((cfg.limits.max_bytes as usize).saturating_add(2 << 20));
    let submit =
        Router::new()
            .route("/v1/jobs", post(jobs::create))
            .layer(TimeoutLayer::with_status_code(
                StatusCode::REQUEST_TIMEOUT,
                cfg.upload_timeout,
            ));
    let sync = Router::new().route("/v1/rig", post(rig::rig));
    let quick = Router::new()
        .route("/v1/jobs/{id}", get(jobs::get).delete(jobs::delete))
        .route("/v1/jobs/{id}/result.glb", get(jobs::result_glb))
        .route("/v1/jobs/{id}/skeleton.json", get(jobs::skeleton_json))
        .route("/healthz", get(health::healthz))
        .route("/readyz", get(health::readyz))
        .route("/metrics", get(health::metrics))
        .layer(TimeoutLayer::with_status_code(
            StatusCode::REQUEST_TIMEOUT,
            cfg.request_timeout,
        ));
    let streams = Router::new().route("/v1/jobs/{id}/events", get(events::events));
    let mut app = Router::new()
        .merge(submit)
        .merge(sync)
        .merge(quick)
        .merge(streams)
        .merge(viewer::routes())
        .fallback(no_route)
        .method_not_allowed_fallback(wrong_method)
        .layer(body_limit)
        .layer(axum::middleware::from_fn(refusals::json_errors))
        .layer(axum::middleware::from_fn(refusals::http_limits))
        .layer(axum::middleware::from_fn_with_state(http, metrics::track))
        .layer(CatchPanicLayer::custom(panic_response));
    // Outside auth and the error mapping: a preflight carries no credentials and is
    // answered here, never by a handler.
    if let Some(origins) = &cfg.cors {
        app = app
            .layer(origins.layer())
            .layer(axum::middleware::from_fn_with_state(
                origins.clone(),
                cors::only_listed,
            ));
    }
    app.layer(
            TraceLayer::new_for_http().make_span_with(|req: &Request<Body>| {
                let id = req
                    .headers()
                    .get("x-request-id")
                    .and_then(|v| v.to_str().ok())
                    .unwrap_or("-");
                tracing::info_span!("request", request_id = %id, method = %req.method(), path = %req.uri().path())
            }),
        )
        .layer(PropagateRequestIdLayer::x_request_id())
        .layer(SetRequestIdLayer::x_request_id(MakeRequestUuid))
        .with_state(state)
}
