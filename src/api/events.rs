//! `GET /v1/jobs/{id}/events`: server-sent events of a job's changes.
//!
//! Every event is read from the store, which keeps them all, so a client that reconnects
//! with `Last-Event-ID` gets exactly what it missed, from whichever replica it reaches.
//! Local changes wake the stream at once; changes made by other replicas are picked up by
//! polling. The stream ends after a terminal event, and when the server shuts down.

use super::auth::Caller;
use super::error::ApiError;
use super::jobs::owned_job;
use super::AppState;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use axum::http::HeaderMap;
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::Stream;
use std::convert::Infallible;

#[derive(serde::Deserialize)]
pub struct EventsQuery {
    /// For clients that cannot set headers (e.g. `EventSource` on a first connection).
    last_event_id: Option<i64>,
}

/// Where a stream resumes: the `Last-Event-ID` header, else the query parameter, else the
/// start. Either one that is not an event id is refused rather than read as the start: a
/// client that sent one believes it resumes, and a full replay would say otherwise.
fn resume_after(
    headers: &HeaderMap,
    query: Result<Query<EventsQuery>, QueryRejection>,
) -> Result<i64, ApiError> {
    let Query(q) = query?;
    match headers.get("last-event-id") {
        Some(v) => v
            .to_str()
            .ok()
            .and_then(|v| v.trim().parse::<i64>().ok())
            .ok_or_else(|| {
                let m = format!("Last-Event-ID {v:?} is not an event id");
                ApiError::unprocessable("invalid_options", m)
            }),
        None => Ok(q.last_event_id.unwrap_or(0)),
    }
}

pub async fn events(
    State(state): State<AppState>,
    caller: Caller,
    Path(id): Path<String>,
    query: Result<Query<EventsQuery>, QueryRejection>,
    headers: HeaderMap,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    owned_job(&state, &caller, &id).await?;
    let mut last = resume_after(&headers, query)?;
    let mut watch = state.ctx.notifier.watch(&id);
    let stream = async_stream::stream! {
        loop {
            let events = match state.ctx.store.events_after(&id, last).await {
                Ok(e) => e,
                Err(e) => {
                    // The client reconnects with Last-Event-ID and misses nothing.
                    tracing::warn!(job_id = %id, error = %e, "SSE: store unavailable");
                    break;
                }
            };
            let mut ended = false;
            for e in &events {
                last = e.seq;
                ended |= e.status.is_terminal();
                let data = serde_json::to_string(e).expect("events serialize");
                yield Ok(Event::default().id(e.seq.to_string()).event("job").data(data));
            }
            if ended {
                break;
            }
            if events.is_empty() {
                // Resumed after the end: nothing more will come.
                match state.ctx.store.get(&id).await {
                    Ok(Some(j)) if j.status.is_terminal() && j.seq <= last => break,
                    Ok(None) => break,
                    _ => {}
                }
            }
            tokio::select! {
                _ = state.shutdown.cancelled() => break,
                _ = watch.changed() => {}
                _ = tokio::time::sleep(state.cfg.poll) => {}
            }
        }
    };
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}
