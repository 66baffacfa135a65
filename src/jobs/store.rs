//! The job store: jobs, their events, idempotency keys and the queue, behind one trait so
//! the embedded SQLite store and a server database run the same service code.
//!
//! Every state change goes through the store, and each one appends an event in the same
//! transaction: SSE replays events from the store, so whatever replica a client reaches
//! sees the same history.
//!
//! Workers hold a job by a lease (`worker` id + deadline) and renew it while they work. A
//! change by a worker that no longer holds the lease (the job was canceled, or its lease
//! ran out and another worker took it) is refused with [`Lease::Lost`], so a job finishes
//! at most once.

use super::model::{Job, JobError, JobEvent, JobResult, JobStatus, NewJob, Stage};
use async_trait::async_trait;
use chrono::{DateTime, Utc};
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The database cannot be reached or refused the operation; retrying later may work.
    #[error("job store unavailable: {0}")]
    Unavailable(String),
    /// A stored row does not decode: a bug or a hand-edited database.
    #[error("job store holds an unreadable row: {0}")]
    Corrupt(String),
}

impl StoreError {
    pub fn code(&self) -> &'static str {
        match self {
            StoreError::Unavailable(_) => "store_unavailable",
            StoreError::Corrupt(_) => "store_corrupt",
        }
    }
}

/// What became of a submission.
#[derive(Clone, Debug)]
pub enum Admission {
    Created(Job),
    /// The idempotency key was used before with the same payload: the original job.
    Replayed(Job),
    /// The idempotency key was used before with another payload.
    KeyConflict,
    /// `max_queued` jobs are already waiting.
    QueueFull {
        queued: u64,
    },
}

/// Whether the calling worker still holds the job.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lease {
    Held,
    Lost,
}

#[derive(Clone, Debug)]
pub enum Outcome {
    Succeeded(JobResult),
    Failed(JobError),
}

/// An idempotency key and the hash of the payload it was first used with.
#[derive(Clone, Copy, Debug)]
pub struct Idempotency<'a> {
    pub key: &'a str,
    pub payload_hash: &'a str,
}

#[async_trait]
pub trait JobStore: Send + Sync + 'static {
    /// Queues `job` unless the queue is full or the key was used (atomic with the check).
    async fn admit(
        &self,
        job: &NewJob,
        idem: Option<Idempotency<'_>>,
        max_queued: u64,
    ) -> Result<Admission, StoreError>;

    async fn get(&self, id: &str) -> Result<Option<Job>, StoreError>;

    /// Queued jobs ahead of `job` (0: next to run); `None` unless it is queued.
    async fn queue_position(&self, job: &Job) -> Result<Option<u64>, StoreError>;

    /// Jobs per status (all statuses, zeros included).
    async fn counts(&self) -> Result<Vec<(JobStatus, u64)>, StoreError>;

    /// Takes the oldest queued job for `worker` until `now + lease`, counting an attempt.
    async fn claim(&self, worker: &str, lease: Duration) -> Result<Option<Job>, StoreError>;

    /// Extends the lease; `Lost` when the worker no longer holds it.
    async fn heartbeat(&self, id: &str, worker: &str, lease: Duration)
        -> Result<Lease, StoreError>;

    /// Records progress (an event) and extends the lease.
    async fn progress(
        &self,
        id: &str,
        worker: &str,
        stage: Stage,
        progress: f32,
        lease: Duration,
    ) -> Result<Lease, StoreError>;

    /// Ends the job; its results are kept until `expires_at`.
    async fn finish(
        &self,
        id: &str,
        worker: &str,
        outcome: &Outcome,
        expires_at: DateTime<Utc>,
    ) -> Result<Lease, StoreError>;

    /// Puts a running job back in the queue without counting the attempt (shutdown).
    async fn release(&self, id: &str, worker: &str) -> Result<Lease, StoreError>;

    /// Cancels a queued or running job; returns the job after the change (unchanged when it
    /// had already ended), `None` when there is no such job.
    async fn cancel(&self, id: &str, expires_at: DateTime<Utc>) -> Result<Option<Job>, StoreError>;

    /// Running jobs whose lease ended (or every running job, with `all`: a single process
    /// starting up owns none of them) go back to the queue, or fail once they have had
    /// `max_attempts`. Returns how many were touched.
    async fn recover(&self, all: bool, max_attempts: u32) -> Result<u64, StoreError>;

    /// Ended jobs whose results are due to expire become `expired`; returns their ids so
    /// the caller deletes their blobs.
    async fn expire_due(&self, now: DateTime<Utc>) -> Result<Vec<String>, StoreError>;

    /// Events of `id` after `seq`, oldest first.
    async fn events_after(&self, id: &str, seq: i64) -> Result<Vec<JobEvent>, StoreError>;

    /// A cheap round trip (readiness).
    async fn ping(&self) -> Result<(), StoreError>;
}
