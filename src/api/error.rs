//! Every error a client gets: an HTTP status and `{error, error_type}`, mapped here and
//! nowhere else. `error_type` values are stable; messages are for people.

use crate::jobs::{BlobError, StoreError};
use crate::mesh::MeshError;
use axum::extract::rejection::QueryRejection;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;

#[derive(Debug, Clone)]
pub struct ApiError {
    pub status: StatusCode,
    pub error_type: String,
    pub message: String,
    /// Seconds, for 429 and 503.
    pub retry_after: Option<u64>,
}

impl ApiError {
    pub fn new(status: StatusCode, error_type: &str, message: impl Into<String>) -> ApiError {
        ApiError {
            status,
            error_type: error_type.to_string(),
            message: message.into(),
            retry_after: None,
        }
    }

    pub fn retry_after(mut self, seconds: u64) -> ApiError {
        self.retry_after = Some(seconds);
        self
    }

    pub fn not_found() -> ApiError {
        ApiError::new(StatusCode::NOT_FOUND, "job_not_found", "no such job")
    }

    pub fn bad_request(error_type: &str, message: impl Into<String>) -> ApiError {
        ApiError::new(StatusCode::BAD_REQUEST, error_type, message)
    }

    pub fn unprocessable(error_type: &str, message: impl Into<String>) -> ApiError {
        ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, error_type, message)
    }
}

#[derive(serde::Serialize)]
struct Body<'a> {
    error: &'a str,
    error_type: &'a str,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let mut r = (
            self.status,
            Json(Body {
                error: &self.message,
                error_type: &self.error_type,
            }),
        )
            .into_response();
        if let Some(s) = self.retry_after {
            r.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(s));
        }
        // The metrics layer counts errors by type without parsing bodies.
        if let Ok(v) = HeaderValue::from_str(&self.error_type) {
            r.extensions_mut().insert(ErrorType(v));
        }
        r
    }
}

/// The `error_type` of an error response, for the metrics layer.
#[derive(Clone, Debug)]
pub struct ErrorType(pub HeaderValue);

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        tracing::error!(error = %e, "job store");
        ApiError::new(StatusCode::SERVICE_UNAVAILABLE, e.code(), e.to_string()).retry_after(5)
    }
}

impl From<BlobError> for ApiError {
    fn from(e: BlobError) -> Self {
        tracing::error!(error = %e, "blob store");
        ApiError::new(StatusCode::SERVICE_UNAVAILABLE, e.code(), e.to_string()).retry_after(5)
    }
}

/// A query string the route's parameters cannot be read from: the framework's own answer is
/// plain text, not `{error, error_type}`.
impl From<QueryRejection> for ApiError {
    fn from(e: QueryRejection) -> Self {
        ApiError::unprocessable("invalid_options", format!("query: {}", e.body_text()))
    }
}

impl From<MeshError> for ApiError {
    fn from(e: MeshError) -> Self {
        let status = match e {
            MeshError::TooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            _ => StatusCode::UNPROCESSABLE_ENTITY,
        };
        ApiError::new(status, e.code(), e.to_string())
    }
}
