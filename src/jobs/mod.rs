//! Durable rigging jobs: the store (jobs, events, idempotency keys, the queue), blobs
//! (uploads and results), the worker pool that runs the rigging pipeline, and the sweeper
//! that expires results.
//!
//! Everything a client can see lives in the store and the blob store, never only in
//! memory, so a job survives a restart and any replica can answer for it.

pub mod blobs;
pub mod events;
pub mod memory;
pub mod metrics;
pub mod model;
pub mod pipeline;
pub mod slots;
pub mod sql;
pub mod store;
pub mod sweeper;
pub mod view;
pub mod webhook;
pub mod webhook_target;
pub mod worker;

pub use blobs::{BlobError, BlobKind, Blobs};
pub use events::Notifier;
pub use metrics::JobMetrics;
pub use model::{
    new_job_id, Job, JobError, JobEvent, JobOptions, JobResult, JobStatus, NewJob, Stage,
    TemplateChoice,
};
pub use store::{Admission, Idempotency, JobStore, Lease, Outcome, StoreError};
pub use view::JobView;
pub use webhook::Webhooks;

use std::sync::Arc;

/// What the API and the workers share.
#[derive(Clone)]
pub struct Context {
    pub store: Arc<dyn JobStore>,
    pub blobs: Blobs,
    pub notifier: Notifier,
    pub metrics: JobMetrics,
    pub webhooks: Option<Webhooks>,
}
