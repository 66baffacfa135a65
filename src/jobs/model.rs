//! What a job is: its options, its state, and the events clients follow.

use crate::export::Animation;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobStatus {
    Queued,
    Running,
    Succeeded,
    Failed,
    Canceled,
    Expired,
}

impl JobStatus {
    pub const ALL: [JobStatus; 6] = [
        JobStatus::Queued,
        JobStatus::Running,
        JobStatus::Succeeded,
        JobStatus::Failed,
        JobStatus::Canceled,
        JobStatus::Expired,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            JobStatus::Queued => "queued",
            JobStatus::Running => "running",
            JobStatus::Succeeded => "succeeded",
            JobStatus::Failed => "failed",
            JobStatus::Canceled => "canceled",
            JobStatus::Expired => "expired",
        }
    }

    pub fn parse(s: &str) -> Option<JobStatus> {
        JobStatus::ALL.into_iter().find(|x| x.as_str() == s)
    }

    /// No further change but expiry: clients stop following the job.
    pub fn is_terminal(self) -> bool {
        !matches!(self, JobStatus::Queued | JobStatus::Running)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    Validating,
    Encoding,
    Skeleton,
    Skinning,
    Exporting,
}

impl Stage {
    pub const ALL: [Stage; 5] = [
        Stage::Validating,
        Stage::Encoding,
        Stage::Skeleton,
        Stage::Skinning,
        Stage::Exporting,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Stage::Validating => "validating",
            Stage::Encoding => "encoding",
            Stage::Skeleton => "skeleton",
            Stage::Skinning => "skinning",
            Stage::Exporting => "exporting",
        }
    }

    pub fn parse(s: &str) -> Option<Stage> {
        Stage::ALL.into_iter().find(|x| x.as_str() == s)
    }

    /// Overall progress when the stage starts: stages take roughly these shares of a job
    /// on a typical mesh, so a progress bar moves evenly.
    pub fn start_progress(self) -> f32 {
        match self {
            Stage::Validating => 0.0,
            Stage::Encoding => 0.05,
            Stage::Skeleton => 0.1,
            Stage::Skinning => 0.6,
            Stage::Exporting => 0.9,
        }
    }
}

/// `template`: whether the skeleton follows the Mixamo humanoid template.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TemplateChoice {
    /// The model decides.
    #[default]
    Auto,
    /// Force the Mixamo body template (humanoids).
    Mixamo,
    /// Never use a template.
    None,
}

impl From<TemplateChoice> for crate::predict::TemplateMode {
    fn from(t: TemplateChoice) -> Self {
        use crate::predict::TemplateMode;
        match t {
            TemplateChoice::Auto => TemplateMode::Auto,
            TemplateChoice::Mixamo => TemplateMode::Force,
            TemplateChoice::None => TemplateMode::Forbid,
        }
    }
}

impl std::str::FromStr for TemplateChoice {
    type Err = String;
    /// The API's words (`auto`, `mixamo`, `none`), for the CLI's `--template`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        serde_json::from_value(serde_json::Value::String(s.to_string()))
            .map_err(|_| format!("template must be auto, mixamo or none, not {s:?}"))
    }
}

/// What the client asked for. Defaults suit an unknown mesh.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JobOptions {
    pub category: Option<String>,
    pub template: TemplateChoice,
    /// The mesh's up axis ([`crate::predict::orient::Up`]).
    pub up: crate::predict::orient::Up,
    pub seed: u64,
    /// Skeleton candidates decoded (best-of-N).
    pub samples: usize,
    pub max_bones: usize,
    /// A bone tree (as `skeleton.json`): the bones to keep, or with `skin_only` the
    /// skeleton to skin.
    pub skeleton: Option<serde_json::Value>,
    /// Skin `skeleton` (or the upload's own skeleton when `skeleton` is absent) without
    /// predicting one.
    pub skin_only: bool,
    pub webhook_url: Option<String>,
    /// A test motion baked into the GLB as an animation clip.
    pub animation: Animation,
}

impl Default for JobOptions {
    fn default() -> Self {
        JobOptions {
            category: None,
            template: TemplateChoice::Auto,
            up: crate::predict::orient::Up::default(),
            seed: 0,
            samples: 4,
            max_bones: 128,
            skeleton: None,
            skin_only: false,
            webhook_url: None,
            animation: Animation::None,
        }
    }
}

/// Why a job failed: a stable code and a message for people.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct JobError {
    pub code: String,
    pub message: String,
}

/// What a finished job produced.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobResult {
    /// Strong ETag of `result.glb`.
    pub etag: String,
    pub glb_bytes: u64,
    pub bones: u32,
}

/// A job as stored.
#[derive(Clone, Debug, PartialEq)]
pub struct Job {
    pub id: String,
    /// The API key that created it ("" without keys); only it can see the job.
    pub owner: String,
    pub status: JobStatus,
    pub stage: Option<Stage>,
    pub progress: f32,
    pub options: JobOptions,
    pub input_format: String,
    pub input_bytes: u64,
    pub filename: Option<String>,
    pub created_at: DateTime<Utc>,
    pub started_at: Option<DateTime<Utc>>,
    pub finished_at: Option<DateTime<Utc>>,
    pub expires_at: Option<DateTime<Utc>>,
    pub error: Option<JobError>,
    pub attempts: u32,
    pub result: Option<JobResult>,
    /// Sequence number of the job's latest event.
    pub seq: i64,
}

/// A job about to be queued.
#[derive(Clone, Debug)]
pub struct NewJob {
    pub id: String,
    pub owner: String,
    pub options: JobOptions,
    pub input_format: String,
    pub input_bytes: u64,
    pub filename: Option<String>,
}

/// One change of a job, as SSE sends it (`id:` is `seq`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobEvent {
    pub seq: i64,
    pub status: JobStatus,
    pub stage: Option<Stage>,
    pub progress: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<JobError>,
    pub at: DateTime<Utc>,
}

pub fn new_job_id() -> String {
    // v7: time-ordered, so ids sort roughly by submission and index well.
    uuid::Uuid::now_v7().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for s in JobStatus::ALL {
            assert_eq!(JobStatus::parse(s.as_str()), Some(s));
            let json = serde_json::to_string(&s).unwrap();
            assert_eq!(json, format!("\"{}\"", s.as_str()));
        }
        for s in Stage::ALL {
            assert_eq!(Stage::parse(s.as_str()), Some(s));
        }
        assert!(JobStatus::Canceled.is_terminal() && !JobStatus::Running.is_terminal());
    }

    #[test]
    fn options_reject_unknown_fields() {
        let o: JobOptions = serde_json::from_str(r#"{"seed": 3}"#).unwrap();
        assert_eq!(o.seed, 3);
        assert_eq!(o.samples, 4);
        assert!(serde_json::from_str::<JobOptions>(r#"{"sed": 3}"#).is_err());
        let o: JobOptions = serde_json::from_str(r#"{"animation": "preview"}"#).unwrap();
        assert_eq!(o.animation, Animation::Preview);
        assert!(serde_json::from_str::<JobOptions>(r#"{"animation": "dance"}"#).is_err());
    }
}
