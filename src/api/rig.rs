//! `POST /v1/rig`: the synchronous convenience for small meshes. The upload becomes an
//! ordinary job (so it shares the queue and the decode batches), and the answer waits for
//! it: the rigged GLB, or the job's error. If it takes longer than the sync timeout, the
//! answer is 504 with the job's id, and the job goes on.

use super::auth::Caller;
use super::error::ApiError;
use super::jobs::submit;
use super::AppState;
use crate::jobs::{BlobKind, JobStatus};
use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};

pub async fn rig(
    State(state): State<AppState>,
    caller: Caller,
    req: Request<Body>,
) -> Result<Response, ApiError> {
    let (job, _) = submit(&state, &caller, req, state.cfg.sync_max_bytes).await?;
    let id = job.id.clone();
    let job_headers = |mut r: Response| {
        let h = r.headers_mut();
        if let Ok(v) = HeaderValue::from_str(&id) {
            h.insert("x-job-id", v);
        }
        if let Ok(v) = HeaderValue::from_str(&format!(
            "</v1/jobs/{id}/skeleton.json>; rel=\"skeleton\", </v1/jobs/{id}>; rel=\"job\""
        )) {
            h.insert(header::LINK, v);
        }
        r
    };
    let mut watch = state.ctx.notifier.watch(&id);
    let deadline = tokio::time::Instant::now() + state.cfg.sync_timeout;
    let done = loop {
        match state.ctx.store.get(&id).await? {
            Some(j) if j.status.is_terminal() => break j,
            Some(_) => {}
            None => return Err(ApiError::not_found()),
        }
        tokio::select! {
            _ = watch.changed() => {}
            _ = tokio::time::sleep(state.cfg.poll) => {}
            _ = tokio::time::sleep_until(deadline) => {
                return Ok(job_headers(ApiError::new(
                    StatusCode::GATEWAY_TIMEOUT,
                    "sync_timeout",
                    format!("the job is still running; follow /v1/jobs/{id}"),
                ).into_response()));
            }
            _ = state.shutdown.cancelled() => {
                return Err(ApiError::new(
                    StatusCode::SERVICE_UNAVAILABLE,
                    "shutting_down",
                    format!("the server is shutting down; the job goes on as /v1/jobs/{id}"),
                ).retry_after(5));
            }
        }
    };
    match done.status {
        JobStatus::Succeeded => {
            let Some(glb) = state.ctx.blobs.get(&id, BlobKind::ResultGlb).await? else {
                return Err(ApiError::new(
                    StatusCode::GONE,
                    "job_expired",
                    "the results have expired",
                ));
            };
            let mut r = (StatusCode::OK, glb).into_response();
            r.headers_mut().insert(
                header::CONTENT_TYPE,
                HeaderValue::from_static("model/gltf-binary"),
            );
            if let Some(Ok(v)) = done.result.as_ref().map(|x| HeaderValue::from_str(&x.etag)) {
                r.headers_mut().insert(header::ETAG, v);
            }
            Ok(job_headers(r))
        }
        JobStatus::Failed => {
            let e = done.error.unwrap_or_else(|| crate::jobs::JobError {
                code: "unknown".into(),
                message: "the job failed".into(),
            });
            Ok(job_headers(
                ApiError::unprocessable(&e.code, e.message).into_response(),
            ))
        }
        _ => Ok(job_headers(
            ApiError::new(StatusCode::GONE, "job_canceled", "the job was canceled").into_response(),
        )),
    }
}
