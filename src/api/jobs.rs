//! `/v1/jobs`: submit, look up, cancel, and download results.

use super::auth::Caller;
use super::error::ApiError;
use super::upload;
use super::AppState;
use crate::export::parse_bone_tree;
use crate::jobs::webhook::check_url;
use crate::jobs::{
    new_job_id, Admission, BlobKind, Idempotency, Job, JobOptions, JobStatus, JobView, NewJob,
};
use crate::mesh::Mesh;
use crate::rig::tokenizer::CATEGORIES;
use crate::rig::{groundtruth, placement, Skeleton};
use axum::body::Body;
use axum::extract::{Path, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use sha2::{Digest, Sha256};

/// Longest `Idempotency-Key` accepted.
const MAX_KEY_LEN: usize = 255;

/// A job the caller may see, or 404 (also for other keys' jobs: their existence is not
/// revealed).
pub async fn owned_job(state: &AppState, caller: &Caller, id: &str) -> Result<Job, ApiError> {
    if id.len() > 64 {
        return Err(ApiError::not_found());
    }
    match state.ctx.store.get(id).await? {
        Some(j) if j.owner == caller.owner => Ok(j),
        _ => Err(ApiError::not_found()),
    }
}

pub async fn view(state: &AppState, job: &Job) -> Result<JobView, ApiError> {
    let pos = state.ctx.store.queue_position(job).await?;
    Ok(JobView::new(job, pos))
}

/// Checks the options on their own; returns the `skeleton` option parsed.
fn check_options(state: &AppState, o: &JobOptions) -> Result<Option<Skeleton>, ApiError> {
    let bad = |m: String| ApiError::unprocessable("invalid_options", m);
    if let Some(c) = &o.category {
        if !CATEGORIES.contains(&c.as_str()) {
            return Err(bad(format!(
                "unknown category {c:?}; one of {}",
                CATEGORIES.join(", ")
            )));
        }
    }
    if o.samples == 0 || o.samples > state.cfg.max_samples {
        return Err(bad(format!(
            "samples must be 1 to {}",
            state.cfg.max_samples
        )));
    }
    if o.max_bones == 0 || o.max_bones > state.cfg.max_bones {
        return Err(bad(format!(
            "max_bones must be 1 to {}",
            state.cfg.max_bones
        )));
    }
    if let Some(url) = &o.webhook_url {
        check_url(url, state.cfg.webhook_allow_private)
            .map_err(|e| ApiError::unprocessable(e.code(), e.to_string()))?;
    }
    let skeleton = match &o.skeleton {
        Some(tree) => {
            let skel = parse_bone_tree(tree)
                .map_err(|e| ApiError::unprocessable(e.code(), format!("skeleton: {e}")))?;
            skel.validate(o.max_bones)
                .map_err(|e| ApiError::unprocessable(e.code(), format!("skeleton: {e}")))?;
            Some(skel)
        }
        None => None,
    };
    if !o.skin_only && !state.cfg.skeleton_model {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "model_unavailable",
            "this server has no skeleton model loaded; only skin_only jobs are accepted",
        ));
    }
    Ok(skeleton)
}

/// The `skeleton` option against the mesh it came with, by the rule the job would apply
/// later (skinning a given skeleton, or continuing bones to keep): a tree in other units
/// is the client's error now, not a failed job after its turn in the queue.
fn check_placement(skel: &Skeleton, mesh: &Mesh, skin_only: bool) -> Result<(), ApiError> {
    let (lo, hi) = mesh.bounds();
    placement::check(skel, lo, hi, placement::OUTSIDE_MARGIN).map_err(|e| {
        let code = if skin_only {
            "skeleton_outside_mesh"
        } else {
            "keep_bones_outside_mesh"
        };
        ApiError::unprocessable(code, format!("skeleton: {e}"))
    })
}

fn payload_hash(bytes: &[u8], options: &JobOptions) -> String {
    let mut h = Sha256::new();
    h.update(Sha256::digest(bytes));
    h.update(serde_json::to_vec(options).expect("options serialize"));
    hex::encode(h.finalize())
}

/// Validates and queues an upload. Shared by `POST /v1/jobs` and `POST /v1/rig`.
pub async fn submit(
    state: &AppState,
    caller: &Caller,
    req: Request<Body>,
    limit: u64,
) -> Result<(Job, bool), ApiError> {
    let query = req.uri().query().map(str::to_string);
    let key = match req.headers().get("idempotency-key") {
        Some(v) => {
            let k = v.to_str().unwrap_or("");
            if k.is_empty() || k.len() > MAX_KEY_LEN {
                return Err(ApiError::bad_request(
                    "idempotency_key_invalid",
                    format!("Idempotency-Key must be 1 to {MAX_KEY_LEN} visible ASCII characters"),
                ));
            }
            Some(k.to_string())
        }
        None => None,
    };
    let up = upload::read(req, limit, &state.cfg.tmp_dir).await?;
    let declared = upload::declared_format(up.content_type.as_deref())?;
    upload::check_magic(declared, &up.bytes)?;
    let options = upload::options(query.as_deref(), up.options)?;
    let given = check_options(state, &options)?;

    // Parse before accepting: a file the loader refuses is the client's error now, not
    // a failed job later.
    let limits = state.cfg.limits;
    let bytes = up.bytes.clone();
    let needs_own_skeleton = options.skin_only && options.skeleton.is_none();
    let skin_only = options.skin_only;
    let checked = tokio::task::spawn_blocking(move || {
        let asset = crate::mesh::load(&bytes, &limits)?;
        if let Some(skel) = &given {
            check_placement(skel, &asset.mesh, skin_only)?;
        }
        if needs_own_skeleton {
            match groundtruth::extract(&asset) {
                Ok(Some(gt)) => check_placement(&gt.skeleton, &asset.mesh, true)?,
                Ok(None) => {
                    return Err(ApiError::unprocessable(
                        "no_skeleton",
                        "skin_only without `skeleton` needs a file that has a skeleton",
                    ))
                }
                Err(e) => return Err(e.into()),
            }
        }
        Ok(format!("{:?}", asset.format).to_lowercase())
    })
    .await
    .map_err(|e| {
        ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "internal_error",
            e.to_string(),
        )
    });
    // The parsed mesh is dropped, refused or not: its pages go back now.
    crate::jobs::memory::give_back_async().await;
    let format = checked??;

    let hash = payload_hash(&up.bytes, &options);
    let job = NewJob {
        id: new_job_id(),
        owner: caller.owner.clone(),
        options,
        input_format: format,
        input_bytes: up.bytes.len() as u64,
        filename: up.filename,
    };
    // The input is stored first, so a worker never takes a job without its file.
    state
        .ctx
        .blobs
        .put(&job.id, BlobKind::Input, up.bytes)
        .await?;
    let idem = key.as_deref().map(|k| Idempotency {
        key: k,
        payload_hash: &hash,
    });
    let admission = state
        .ctx
        .store
        .admit(&job, idem, state.cfg.max_queued)
        .await;
    let outcome = match admission {
        Ok(Admission::Created(j)) => {
            state.ctx.notifier.queued();
            state.ctx.notifier.changed(&j.id);
            return Ok((j, false));
        }
        Ok(Admission::Replayed(j)) => Ok((j, true)),
        Ok(Admission::KeyConflict) => Err(ApiError::unprocessable(
            "idempotency_key_reused",
            "this Idempotency-Key was used with a different payload",
        )),
        Ok(Admission::QueueFull { queued }) => Err(ApiError::new(
            StatusCode::TOO_MANY_REQUESTS,
            "queue_full",
            format!("{queued} jobs are waiting; try again later"),
        )
        .retry_after(state.cfg.queue_full_retry_after)),
        Err(e) => Err(e.into()),
    };
    let _ = state.ctx.blobs.delete_job(&job.id).await;
    outcome
}

fn accepted(job_view: JobView, replayed: bool) -> Response {
    let mut r = (StatusCode::ACCEPTED, Json(&job_view)).into_response();
    let h = r.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&job_view.links.this) {
        h.insert(header::LOCATION, v);
    }
    h.insert(header::RETRY_AFTER, HeaderValue::from(1));
    if replayed {
        h.insert("idempotent-replayed", HeaderValue::from_static("true"));
    }
    r
}

pub async fn create(
    State(state): State<AppState>,
    caller: Caller,
    req: Request<Body>,
) -> Result<Response, ApiError> {
    let (job, replayed) = submit(&state, &caller, req, state.cfg.limits.max_bytes).await?;
    Ok(accepted(view(&state, &job).await?, replayed))
}

pub async fn get(
    State(state): State<AppState>,
    caller: Caller,
    Path(id): Path<String>,
) -> Result<Json<JobView>, ApiError> {
    let job = owned_job(&state, &caller, &id).await?;
    Ok(Json(view(&state, &job).await?))
}

pub async fn delete(
    State(state): State<AppState>,
    caller: Caller,
    Path(id): Path<String>,
) -> Result<Json<JobView>, ApiError> {
    owned_job(&state, &caller, &id).await?;
    let until = chrono::Utc::now()
        + chrono::Duration::from_std(state.cfg.result_ttl).unwrap_or(chrono::Duration::MAX);
    let job = state
        .ctx
        .store
        .cancel(&id, until)
        .await?
        .ok_or_else(ApiError::not_found)?;
    state.ctx.blobs.delete_job(&id).await?;
    state.ctx.notifier.changed(&id);
    Ok(Json(view(&state, &job).await?))
}

/// The job's results, or why there are none.
async fn result_blob(
    state: &AppState,
    caller: &Caller,
    id: &str,
    kind: BlobKind,
) -> Result<(Job, bytes::Bytes), ApiError> {
    let job = owned_job(state, caller, id).await?;
    let gone = |t: &str, m: &str| ApiError::new(StatusCode::GONE, t, m);
    match job.status {
        JobStatus::Succeeded => {}
        JobStatus::Expired => return Err(gone("job_expired", "the results have expired")),
        JobStatus::Canceled => return Err(gone("job_canceled", "the job was canceled")),
        JobStatus::Failed => {
            let e = job.error.clone().unwrap_or_else(|| crate::jobs::JobError {
                code: "unknown".into(),
                message: String::new(),
            });
            return Err(ApiError::new(
                StatusCode::CONFLICT,
                "job_failed",
                format!("the job failed ({}): {}", e.code, e.message),
            ));
        }
        JobStatus::Queued | JobStatus::Running => {
            return Err(ApiError::new(
                StatusCode::CONFLICT,
                "job_not_ready",
                "the job has not finished yet",
            )
            .retry_after(1))
        }
    }
    match state.ctx.blobs.get(id, kind).await? {
        Some(b) => Ok((job, b)),
        // Expired between the two reads.
        None => Err(gone("job_expired", "the results have expired")),
    }
}

fn download_name(job: &Job, suffix: &str) -> String {
    let stem = job
        .filename
        .as_deref()
        .and_then(|f| std::path::Path::new(f).file_stem())
        .and_then(|s| s.to_str())
        .map(|s| {
            s.chars()
                .filter(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
                .take(100)
                .collect::<String>()
        })
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| job.id.clone());
    format!("{stem}{suffix}")
}

pub async fn result_glb(
    State(state): State<AppState>,
    caller: Caller,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let (job, bytes) = result_blob(&state, &caller, &id, BlobKind::ResultGlb).await?;
    let etag = job
        .result
        .as_ref()
        .map(|r| r.etag.clone())
        .unwrap_or_default();
    let matches = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == etag || t.trim() == "*"));
    let mut r = if matches {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        (StatusCode::OK, bytes).into_response()
    };
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("model/gltf-binary"),
    );
    if let Ok(v) = HeaderValue::from_str(&etag) {
        h.insert(header::ETAG, v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!(
        "attachment; filename=\"{}\"",
        download_name(&job, "_rigged.glb")
    )) {
        h.insert(header::CONTENT_DISPOSITION, v);
    }
    h.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("private, max-age=0"),
    );
    Ok(r)
}

pub async fn skeleton_json(
    State(state): State<AppState>,
    caller: Caller,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let (job, bytes) = result_blob(&state, &caller, &id, BlobKind::Skeleton).await?;
    let mut r = (StatusCode::OK, bytes).into_response();
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    if let Ok(v) = HeaderValue::from_str(&format!(
        "inline; filename=\"{}\"",
        download_name(&job, "_skeleton.json")
    )) {
        h.insert(header::CONTENT_DISPOSITION, v);
    }
    Ok(r)
}
