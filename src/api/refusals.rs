//! Refusals made before, or instead of, a handler: long URLs, large headers, and every
//! error response the framework writes itself (an undecodable path segment, a body that
//! is not what the extractor wanted, a timeout). Each leaves as `{error, error_type}`
//! like the handlers' own, so a client parses one error shape whatever refused it.

use super::error::{ApiError, ErrorType};
use axum::extract::Request;
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

/// Longest path and query, in bytes. Uploads carry their options in the body or a short
/// query; 8 KiB is what common proxies allow.
pub const MAX_URI: usize = 8 << 10;
/// Total size of names and values of the headers, in bytes.
pub const MAX_HEADER_BYTES: usize = 64 << 10;
/// Most headers a request may carry.
pub const MAX_HEADERS: usize = 200;
/// Largest framework error text kept as the message.
const MAX_MESSAGE: usize = 4 << 10;

/// 414 for a long URL and 431 for large or many headers, before routing.
pub async fn http_limits(req: Request, next: Next) -> Response {
    let uri = req.uri().path_and_query().map_or(0, |pq| pq.as_str().len());
    if uri > MAX_URI {
        return ApiError::new(
            StatusCode::URI_TOO_LONG,
            "uri_too_long",
            format!("the path and query are {uri} bytes; at most {MAX_URI}"),
        )
        .into_response();
    }
    let headers = req.headers();
    let bytes: usize = headers
        .iter()
        .map(|(k, v)| k.as_str().len() + v.len())
        .sum();
    if headers.len() > MAX_HEADERS || bytes > MAX_HEADER_BYTES {
        return ApiError::new(
            StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
            "headers_too_large",
            format!(
                "{} headers of {bytes} bytes; at most {MAX_HEADERS} headers and \
                 {MAX_HEADER_BYTES} bytes",
                headers.len()
            ),
        )
        .into_response();
    }
    next.run(req).await
}

/// Rewrites an error response that did not come from an [`ApiError`] into one that did.
pub async fn json_errors(req: Request, next: Next) -> Response {
    let r = next.run(req).await;
    let status = r.status();
    if !(status.is_client_error() || status.is_server_error())
        || r.extensions().get::<ErrorType>().is_some()
    {
        return r;
    }
    let (parts, body) = r.into_parts();
    let text = axum::body::to_bytes(body, MAX_MESSAGE)
        .await
        .map(|b| String::from_utf8_lossy(&b).trim().to_string())
        .unwrap_or_default();
    let (error_type, fallback) = classify(status, &text);
    let message = if text.is_empty() { fallback } else { &text };
    let mut out = ApiError::new(status, error_type, message).into_response();
    // Keep what the framework said beside the status (`allow`, `retry-after`, ...).
    for (k, v) in &parts.headers {
        if k != header::CONTENT_TYPE && k != header::CONTENT_LENGTH {
            out.headers_mut().entry(k).or_insert_with(|| v.clone());
        }
    }
    out
}

/// The stable `error_type` and a message for a status the framework chose.
fn classify(status: StatusCode, text: &str) -> (&'static str, &'static str) {
    match status {
        // axum's `Path` extractor: a segment that is not valid percent-encoded UTF-8.
        StatusCode::BAD_REQUEST if text.starts_with("Invalid URL") => {
            ("invalid_path", "the path does not decode")
        }
        StatusCode::BAD_REQUEST => ("bad_request", "the request is malformed"),
        StatusCode::NOT_FOUND => ("not_found", "no such route"),
        StatusCode::METHOD_NOT_ALLOWED => {
            ("method_not_allowed", "this route does not take that method")
        }
        StatusCode::REQUEST_TIMEOUT => ("request_timeout", "the request took too long"),
        StatusCode::LENGTH_REQUIRED => ("length_required", "the request needs a length"),
        StatusCode::PAYLOAD_TOO_LARGE => ("file_too_large", "the body is over the limit"),
        StatusCode::URI_TOO_LONG => ("uri_too_long", "the URL is too long"),
        StatusCode::UNSUPPORTED_MEDIA_TYPE => (
            "unsupported_media_type",
            "the body's type is not accepted here",
        ),
        StatusCode::UNPROCESSABLE_ENTITY => ("invalid_request", "the request cannot be read"),
        StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE => {
            ("headers_too_large", "the headers are too large")
        }
        StatusCode::SERVICE_UNAVAILABLE => ("unavailable", "try again later"),
        s if s.is_server_error() => ("internal_error", "the server failed"),
        _ => ("http_error", "the request was refused"),
    }
}
