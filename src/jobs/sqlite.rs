//! The embedded job store: one SQLite file in the data directory.
//!
//! Writes go through a pool of exactly one connection, so transactions never contend for
//! SQLite's write lock inside the process; reads use their own pool, and WAL lets them run
//! while a write is in progress (status polls never wait behind a worker's update).
//! `synchronous=FULL`: a job is durable once `POST /v1/jobs` has answered, even if the
//! process or the machine dies right after.

use super::model::{Job, JobError, JobEvent, JobOptions, JobResult, JobStatus, NewJob, Stage};
use super::store::{Admission, Idempotency, JobStore, Lease, Outcome, StoreError};
use async_trait::async_trait;
use chrono::{DateTime, TimeZone, Utc};
use sqlx::migrate::{Migration, MigrationType, Migrator};
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteRow, SqliteSynchronous,
};
use sqlx::{Row, Sqlite, SqlitePool, Transaction};
use std::borrow::Cow;
use std::path::Path;
use std::time::Duration;

const MIGRATIONS: &[(i64, &str, &str)] = &[(
    1,
    "jobs",
    include_str!("../../migrations/sqlite/0001_jobs.sql"),
)];

const JOB_COLUMNS: &str = "id, owner, status, stage, progress, options, input_format, \
    input_bytes, filename, created_at, started_at, finished_at, expires_at, error_code, \
    error_message, attempts, result, seq";

pub struct SqliteStore {
    writer: SqlitePool,
    reader: SqlitePool,
}

impl From<sqlx::Error> for StoreError {
    fn from(e: sqlx::Error) -> Self {
        match e {
            sqlx::Error::ColumnDecode { .. } | sqlx::Error::Decode(_) => {
                StoreError::Corrupt(e.to_string())
            }
            _ => StoreError::Unavailable(e.to_string()),
        }
    }
}

impl SqliteStore {
    /// Opens (creating if needed) the database at `path` and applies the migrations.
    pub async fn open(path: &Path) -> Result<SqliteStore, StoreError> {
        let opts = SqliteConnectOptions::new()
            .filename(path)
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Full)
            .busy_timeout(Duration::from_secs(10))
            .foreign_keys(true);
        let writer = SqlitePoolOptions::new()
            .max_connections(1)
            .connect_with(opts.clone())
            .await?;
        migrator()
            .run(&writer)
            .await
            .map_err(|e| StoreError::Unavailable(format!("migrations: {e}")))?;
        let reader = SqlitePoolOptions::new()
            .max_connections(4)
            .connect_with(opts.read_only(true))
            .await?;
        Ok(SqliteStore { writer, reader })
    }
}

fn migrator() -> Migrator {
    let migrations = MIGRATIONS
        .iter()
        .map(|&(version, name, sql)| {
            Migration::new(
                version,
                Cow::Borrowed(name),
                MigrationType::Simple,
                Cow::Borrowed(sql),
                false,
            )
        })
        .collect();
    Migrator {
        migrations: Cow::Owned(migrations),
        ..Migrator::DEFAULT
    }
}

fn ms(t: DateTime<Utc>) -> i64 {
    t.timestamp_millis()
}

fn from_ms(v: Option<i64>) -> Option<DateTime<Utc>> {
    v.and_then(|m| Utc.timestamp_millis_opt(m).single())
}

fn lease_deadline(lease: Duration) -> i64 {
    ms(Utc::now()) + lease.as_millis() as i64
}

fn corrupt(what: &str, v: &str) -> StoreError {
    StoreError::Corrupt(format!("{what} {v:?}"))
}

fn job_from_row(row: &SqliteRow) -> Result<Job, StoreError> {
    let status: String = row.try_get("status")?;
    let stage: Option<String> = row.try_get("stage")?;
    let options: String = row.try_get("options")?;
    let result: Option<String> = row.try_get("result")?;
    let error_code: Option<String> = row.try_get("error_code")?;
    let error_message: Option<String> = row.try_get("error_message")?;
    let created: i64 = row.try_get("created_at")?;
    Ok(Job {
        id: row.try_get("id")?,
        owner: row.try_get("owner")?,
        status: JobStatus::parse(&status).ok_or_else(|| corrupt("status", &status))?,
        stage: match stage {
            Some(s) => Some(Stage::parse(&s).ok_or_else(|| corrupt("stage", &s))?),
            None => None,
        },
        progress: row.try_get::<f64, _>("progress")? as f32,
        options: serde_json::from_str::<JobOptions>(&options)
            .map_err(|e| StoreError::Corrupt(format!("options: {e}")))?,
        input_format: row.try_get("input_format")?,
        input_bytes: row.try_get::<i64, _>("input_bytes")? as u64,
        filename: row.try_get("filename")?,
        created_at: from_ms(Some(created)).ok_or_else(|| corrupt("created_at", ""))?,
        started_at: from_ms(row.try_get("started_at")?),
        finished_at: from_ms(row.try_get("finished_at")?),
        expires_at: from_ms(row.try_get("expires_at")?),
        error: error_code.map(|code| JobError {
            code,
            message: error_message.unwrap_or_default(),
        }),
        attempts: row.try_get::<i64, _>("attempts")? as u32,
        result: match result {
            Some(r) => Some(
                serde_json::from_str::<JobResult>(&r)
                    .map_err(|e| StoreError::Corrupt(format!("result: {e}")))?,
            ),
            None => None,
        },
        seq: row.try_get("seq")?,
    })
}

/// Bumps the job's sequence number and records its current state as the next event.
/// Call inside the transaction that changed the job.
async fn append_event(tx: &mut Transaction<'_, Sqlite>, id: &str) -> Result<(), StoreError> {
    let row = sqlx::query(&format!(
        "UPDATE jobs SET seq = seq + 1 WHERE id = ? RETURNING {JOB_COLUMNS}"
    ))
    .bind(id)
    .fetch_one(&mut **tx)
    .await?;
    let job = job_from_row(&row)?;
    let event = JobEvent {
        seq: job.seq,
        status: job.status,
        stage: job.stage,
        progress: job.progress,
        error: job.error.clone(),
        at: Utc::now(),
    };
    sqlx::query("INSERT INTO job_events (job_id, seq, data) VALUES (?, ?, ?)")
        .bind(id)
        .bind(job.seq)
        .bind(serde_json::to_string(&event).expect("events serialize"))
        .execute(&mut **tx)
        .await?;
    Ok(())
}

impl SqliteStore {
    async fn get_with(&self, pool: &SqlitePool, id: &str) -> Result<Option<Job>, StoreError> {
        let row = sqlx::query(&format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?"))
            .bind(id)
            .fetch_optional(pool)
            .await?;
        row.as_ref().map(job_from_row).transpose()
    }

    /// Runs `update` (an UPDATE guarded by the worker's lease, binding `id` and `worker`
    /// last) and records an event when it matched.
    async fn leased_update(
        &self,
        sql: &str,
        binds: Vec<Bind>,
        id: &str,
        worker: &str,
    ) -> Result<Lease, StoreError> {
        let mut tx = self.writer.begin().await?;
        let mut q = sqlx::query(sql);
        for b in binds {
            q = match b {
                Bind::I(v) => q.bind(v),
                Bind::F(v) => q.bind(v),
                Bind::S(v) => q.bind(v),
            };
        }
        let n = q
            .bind(id)
            .bind(worker)
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if n == 0 {
            return Ok(Lease::Lost);
        }
        append_event(&mut tx, id).await?;
        tx.commit().await?;
        Ok(Lease::Held)
    }
}

enum Bind {
    I(Option<i64>),
    F(f64),
    S(Option<String>),
}

const LEASED: &str = "WHERE id = ? AND status = 'running' AND lease_owner = ?";

#[async_trait]
impl JobStore for SqliteStore {
    async fn admit(
        &self,
        job: &NewJob,
        idem: Option<Idempotency<'_>>,
        max_queued: u64,
    ) -> Result<Admission, StoreError> {
        let mut tx = self.writer.begin().await?;
        if let Some(k) = idem {
            let prior = sqlx::query(
                "SELECT payload_hash, job_id FROM idempotency_keys WHERE owner = ? AND key = ?",
            )
            .bind(&job.owner)
            .bind(k.key)
            .fetch_optional(&mut *tx)
            .await?;
            if let Some(row) = prior {
                let hash: String = row.try_get("payload_hash")?;
                if hash != k.payload_hash {
                    return Ok(Admission::KeyConflict);
                }
                let id: String = row.try_get("job_id")?;
                drop(tx);
                return match self.get_with(&self.writer, &id).await? {
                    Some(j) => Ok(Admission::Replayed(j)),
                    None => Err(StoreError::Corrupt(format!("idempotency key of {id}"))),
                };
            }
        }
        let queued: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM jobs WHERE status = 'queued'")
            .fetch_one(&mut *tx)
            .await?;
        if queued as u64 >= max_queued {
            return Ok(Admission::QueueFull {
                queued: queued as u64,
            });
        }
        let now = ms(Utc::now());
        sqlx::query(
            "INSERT INTO jobs (id, owner, status, progress, options, input_format, input_bytes, \
             filename, created_at) VALUES (?, ?, 'queued', 0, ?, ?, ?, ?, ?)",
        )
        .bind(&job.id)
        .bind(&job.owner)
        .bind(serde_json::to_string(&job.options).expect("options serialize"))
        .bind(&job.input_format)
        .bind(job.input_bytes as i64)
        .bind(&job.filename)
        .bind(now)
        .execute(&mut *tx)
        .await?;
        if let Some(k) = idem {
            sqlx::query(
                "INSERT INTO idempotency_keys (owner, key, payload_hash, job_id, created_at) \
                 VALUES (?, ?, ?, ?, ?)",
            )
            .bind(&job.owner)
            .bind(k.key)
            .bind(k.payload_hash)
            .bind(&job.id)
            .bind(now)
            .execute(&mut *tx)
            .await?;
        }
        append_event(&mut tx, &job.id).await?;
        tx.commit().await?;
        match self.get_with(&self.writer, &job.id).await? {
            Some(j) => Ok(Admission::Created(j)),
            None => Err(StoreError::Corrupt(format!("job {} vanished", job.id))),
        }
    }

    async fn get(&self, id: &str) -> Result<Option<Job>, StoreError> {
        self.get_with(&self.reader, id).await
    }

    async fn queue_position(&self, job: &Job) -> Result<Option<u64>, StoreError> {
        if job.status != JobStatus::Queued {
            return Ok(None);
        }
        let ahead: i64 = sqlx::query_scalar(
            "SELECT COUNT(*) FROM jobs WHERE status = 'queued' AND \
             (created_at < ? OR (created_at = ? AND id < ?))",
        )
        .bind(ms(job.created_at))
        .bind(ms(job.created_at))
        .bind(&job.id)
        .fetch_one(&self.reader)
        .await?;
        Ok(Some(ahead as u64))
    }

    async fn counts(&self) -> Result<Vec<(JobStatus, u64)>, StoreError> {
        let rows = sqlx::query("SELECT status, COUNT(*) AS n FROM jobs GROUP BY status")
            .fetch_all(&self.reader)
            .await?;
        let mut out: Vec<(JobStatus, u64)> = JobStatus::ALL.iter().map(|&s| (s, 0)).collect();
        for row in rows {
            let s: String = row.try_get("status")?;
            let n: i64 = row.try_get("n")?;
            let status = JobStatus::parse(&s).ok_or_else(|| corrupt("status", &s))?;
            if let Some(slot) = out.iter_mut().find(|(x, _)| *x == status) {
                slot.1 = n as u64;
            }
        }
        Ok(out)
    }

    async fn claim(&self, worker: &str, lease: Duration) -> Result<Option<Job>, StoreError> {
        let mut tx = self.writer.begin().await?;
        let id: Option<String> = sqlx::query_scalar(
            "UPDATE jobs SET status = 'running', stage = 'validating', progress = 0, \
             attempts = attempts + 1, started_at = ?, lease_owner = ?, lease_until = ? \
             WHERE id = (SELECT id FROM jobs WHERE status = 'queued' \
                         ORDER BY created_at, id LIMIT 1) RETURNING id",
        )
        .bind(ms(Utc::now()))
        .bind(worker)
        .bind(lease_deadline(lease))
        .fetch_optional(&mut *tx)
        .await?;
        let Some(id) = id else {
            return Ok(None);
        };
        append_event(&mut tx, &id).await?;
        tx.commit().await?;
        self.get_with(&self.writer, &id).await
    }

    async fn heartbeat(
        &self,
        id: &str,
        worker: &str,
        lease: Duration,
    ) -> Result<Lease, StoreError> {
        // No event: a heartbeat changes nothing a client sees.
        let n = sqlx::query(&format!("UPDATE jobs SET lease_until = ? {LEASED}"))
            .bind(lease_deadline(lease))
            .bind(id)
            .bind(worker)
            .execute(&self.writer)
            .await?
            .rows_affected();
        Ok(if n == 1 { Lease::Held } else { Lease::Lost })
    }

    async fn progress(
        &self,
        id: &str,
        worker: &str,
        stage: Stage,
        progress: f32,
        lease: Duration,
    ) -> Result<Lease, StoreError> {
        self.leased_update(
            &format!("UPDATE jobs SET stage = ?, progress = ?, lease_until = ? {LEASED}"),
            vec![
                Bind::S(Some(stage.as_str().to_string())),
                Bind::F(progress.clamp(0.0, 1.0) as f64),
                Bind::I(Some(lease_deadline(lease))),
            ],
            id,
            worker,
        )
        .await
    }

    async fn finish(
        &self,
        id: &str,
        worker: &str,
        outcome: &Outcome,
        expires_at: DateTime<Utc>,
    ) -> Result<Lease, StoreError> {
        let (status, progress, result, code, message) = match outcome {
            Outcome::Succeeded(r) => (
                JobStatus::Succeeded,
                1.0,
                Some(serde_json::to_string(r).expect("results serialize")),
                None,
                None,
            ),
            Outcome::Failed(e) => (
                JobStatus::Failed,
                0.0,
                None,
                Some(e.code.clone()),
                Some(e.message.clone()),
            ),
        };
        // A failed job keeps the stage it failed in; its progress says how far it got.
        let progress_sql = if status == JobStatus::Succeeded {
            "progress = ?,"
        } else {
            "progress = MAX(progress, ?),"
        };
        self.leased_update(
            &format!(
                "UPDATE jobs SET status = ?, {progress_sql} result = ?, error_code = ?, \
                 error_message = ?, finished_at = ?, expires_at = ?, lease_owner = NULL, \
                 lease_until = NULL {LEASED}"
            ),
            vec![
                Bind::S(Some(status.as_str().to_string())),
                Bind::F(progress),
                Bind::S(result),
                Bind::S(code),
                Bind::S(message),
                Bind::I(Some(ms(Utc::now()))),
                Bind::I(Some(ms(expires_at))),
            ],
            id,
            worker,
        )
        .await
    }

    async fn release(&self, id: &str, worker: &str) -> Result<Lease, StoreError> {
        self.leased_update(
            &format!(
                "UPDATE jobs SET status = 'queued', stage = NULL, progress = 0, \
                 attempts = MAX(attempts - 1, 0), started_at = NULL, lease_owner = NULL, \
                 lease_until = NULL {LEASED}"
            ),
            vec![],
            id,
            worker,
        )
        .await
    }

    async fn cancel(&self, id: &str, expires_at: DateTime<Utc>) -> Result<Option<Job>, StoreError> {
        let mut tx = self.writer.begin().await?;
        let now = ms(Utc::now());
        // Queued or running: canceled. Finished: its results are deleted, so it expires now.
        let n = sqlx::query(
            "UPDATE jobs SET \
               status = CASE WHEN status IN ('queued', 'running') THEN 'canceled' \
                             ELSE 'expired' END, \
               finished_at = COALESCE(finished_at, ?), expires_at = ?, \
               lease_owner = NULL, lease_until = NULL \
             WHERE id = ? AND status IN ('queued', 'running', 'succeeded', 'failed')",
        )
        .bind(now)
        .bind(ms(expires_at))
        .bind(id)
        .execute(&mut *tx)
        .await?
        .rows_affected();
        if n == 1 {
            append_event(&mut tx, id).await?;
        }
        tx.commit().await?;
        self.get_with(&self.writer, id).await
    }

    async fn recover(&self, all: bool, max_attempts: u32) -> Result<u64, StoreError> {
        let mut tx = self.writer.begin().await?;
        let ids: Vec<(String, i64)> = sqlx::query_as(
            "SELECT id, attempts FROM jobs WHERE status = 'running' AND (? OR lease_until < ?)",
        )
        .bind(all)
        .bind(ms(Utc::now()))
        .fetch_all(&mut *tx)
        .await?;
        for (id, attempts) in &ids {
            if *attempts as u32 >= max_attempts {
                sqlx::query(
                    "UPDATE jobs SET status = 'failed', error_code = 'attempts_exhausted', \
                     error_message = ?, finished_at = ?, expires_at = ?, lease_owner = NULL, \
                     lease_until = NULL WHERE id = ?",
                )
                .bind(format!(
                    "the job's worker stopped {attempts} times before it finished"
                ))
                .bind(ms(Utc::now()))
                .bind(ms(Utc::now()))
                .bind(id)
                .execute(&mut *tx)
                .await?;
            } else {
                sqlx::query(
                    "UPDATE jobs SET status = 'queued', stage = NULL, progress = 0, \
                     lease_owner = NULL, lease_until = NULL WHERE id = ?",
                )
                .bind(id)
                .execute(&mut *tx)
                .await?;
            }
            append_event(&mut tx, id).await?;
        }
        tx.commit().await?;
        Ok(ids.len() as u64)
    }

    async fn expire_due(&self, now: DateTime<Utc>) -> Result<Vec<String>, StoreError> {
        let mut tx = self.writer.begin().await?;
        let ids: Vec<String> = sqlx::query_scalar(
            "UPDATE jobs SET status = 'expired' WHERE expires_at <= ? AND \
             status IN ('succeeded', 'failed', 'canceled') RETURNING id",
        )
        .bind(ms(now))
        .fetch_all(&mut *tx)
        .await?;
        for id in &ids {
            append_event(&mut tx, id).await?;
        }
        tx.commit().await?;
        Ok(ids)
    }

    async fn events_after(&self, id: &str, seq: i64) -> Result<Vec<JobEvent>, StoreError> {
        let rows: Vec<String> = sqlx::query_scalar(
            "SELECT data FROM job_events WHERE job_id = ? AND seq > ? ORDER BY seq",
        )
        .bind(id)
        .bind(seq)
        .fetch_all(&self.reader)
        .await?;
        rows.iter()
            .map(|d| {
                serde_json::from_str(d).map_err(|e| StoreError::Corrupt(format!("event: {e}")))
            })
            .collect()
    }

    async fn ping(&self) -> Result<(), StoreError> {
        sqlx::query("SELECT 1").execute(&self.reader).await?;
        Ok(())
    }
}
