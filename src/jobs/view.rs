//! A job as clients see it (`GET /v1/jobs/{id}`, webhooks, the 202 answer).

use super::model::{Job, JobError, JobOptions, JobStatus, Stage};
use chrono::{DateTime, Utc};
use serde::Serialize;

#[derive(Clone, Debug, Serialize)]
pub struct JobView {
    pub id: String,
    pub status: JobStatus,
    pub stage: Option<Stage>,
    pub progress: f32,
    /// Queued jobs ahead of this one; present only while it is queued.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub queue_position: Option<u64>,
    pub created_at: DateTime<Utc>,
    pub started_at: Option<DateTime<Utc>>,
    pub finished_at: Option<DateTime<Utc>>,
    /// When the results are deleted (then `GET` of them answers 410).
    pub expires_at: Option<DateTime<Utc>>,
    pub attempts: u32,
    pub input: InputView,
    pub options: JobOptions,
    pub error: Option<JobError>,
    pub result: Option<ResultView>,
    pub links: Links,
}

#[derive(Clone, Debug, Serialize)]
pub struct InputView {
    pub format: String,
    pub bytes: u64,
    pub filename: Option<String>,
}

#[derive(Clone, Debug, Serialize)]
pub struct ResultView {
    pub glb: String,
    pub skeleton: String,
    pub glb_bytes: u64,
    pub bones: u32,
}

#[derive(Clone, Debug, Serialize)]
pub struct Links {
    #[serde(rename = "self")]
    pub this: String,
    pub events: String,
}

pub fn job_path(id: &str) -> String {
    format!("/v1/jobs/{id}")
}

impl JobView {
    pub fn new(job: &Job, queue_position: Option<u64>) -> JobView {
        let base = job_path(&job.id);
        let result = match (&job.result, job.status) {
            (Some(r), JobStatus::Succeeded) => Some(ResultView {
                glb: format!("{base}/result.glb"),
                skeleton: format!("{base}/skeleton.json"),
                glb_bytes: r.glb_bytes,
                bones: r.bones,
            }),
            _ => None,
        };
        let mut options = job.options.clone();
        // The kept skeleton can be large; clients sent it and can fetch skeleton.json.
        if options.skeleton.is_some() {
            options.skeleton = Some(serde_json::Value::String("<given>".into()));
        }
        JobView {
            id: job.id.clone(),
            status: job.status,
            stage: job.stage,
            progress: job.progress,
            queue_position,
            created_at: job.created_at,
            started_at: job.started_at,
            finished_at: job.finished_at,
            expires_at: job.expires_at,
            attempts: job.attempts,
            input: InputView {
                format: job.input_format.clone(),
                bytes: job.input_bytes,
                filename: job.filename.clone(),
            },
            options,
            error: job.error.clone(),
            result,
            links: Links {
                events: format!("{base}/events"),
                this: base,
            },
        }
    }
}
