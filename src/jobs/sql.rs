//! The job store on SQL: the embedded SQLite file by default, PostgreSQL in cluster mode.
//! One implementation over `sqlx::Any`; the few places the dialects differ (row locking
//! in the queue, `MAX` vs `GREATEST`, column types in the migrations) are [`Dialect`]'s.
//!
//! SQLite: writes go through a pool of exactly one connection, so transactions never
//! contend for SQLite's write lock inside the process; reads use their own pool, and WAL
//! lets them run while a write is in progress (status polls never wait behind a worker's
//! update). `synchronous=FULL`: a job is durable once `POST /v1/jobs` has answered, even
//! if the process or the machine dies right after.
//!
//! PostgreSQL: one pool; workers of any number of replicas take jobs with `FOR UPDATE
//! SKIP LOCKED`, so each queued job goes to exactly one of them. While the server is
//! down every call fails fast with `Unavailable` (503 for clients); the pool reconnects
//! by itself when it is back.

use super::model::{Job, JobError, JobEvent, JobOptions, JobResult, JobStatus, NewJob, Stage};
use super::store::{Admission, Idempotency, JobStore, Lease, Outcome, StoreError};
use async_trait::async_trait;
use chrono::{DateTime, TimeZone, Utc};
use sqlx::any::{AnyPoolOptions, AnyRow};
use sqlx::migrate::{Migration, MigrationType, Migrator};
use sqlx::{Any, AnyPool, Executor, Row, Transaction};
use std::borrow::Cow;
use std::path::Path;
use std::time::Duration;

const SQLITE_MIGRATIONS: &[(i64, &str, &str)] = &[(
    1,
    "jobs",
    include_str!("../../migrations/sqlite/0001_jobs.sql"),
)];
const POSTGRES_MIGRATIONS: &[(i64, &str, &str)] = &[(
    1,
    "jobs",
    include_str!("../../migrations/postgres/0001_jobs.sql"),
)];

const JOB_COLUMNS: &str = "id, owner, status, stage, progress, options, input_format, \
    input_bytes, filename, created_at, started_at, finished_at, expires_at, error_code, \
    error_message, attempts, result, seq";

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dialect {
    Sqlite,
    Postgres,
}

impl Dialect {
    /// Row locking for the queue's `SELECT … LIMIT 1` (SQLite has one writer anyway).
    fn skip_locked(self) -> &'static str {
        match self {
            Dialect::Sqlite => "",
            Dialect::Postgres => " FOR UPDATE SKIP LOCKED",
        }
    }

    fn greatest(self) -> &'static str {
        match self {
            Dialect::Sqlite => "MAX",
            Dialect::Postgres => "GREATEST",
        }
    }

    fn migrations(self) -> &'static [(i64, &'static str, &'static str)] {
        match self {
            Dialect::Sqlite => SQLITE_MIGRATIONS,
            Dialect::Postgres => POSTGRES_MIGRATIONS,
        }
    }
}

pub struct SqlStore {
    writer: AnyPool,
    reader: AnyPool,
    dialect: Dialect,
    q: Queries,
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

impl SqlStore {
    /// Opens (creating if needed) the SQLite database at `path` and applies the migrations.
    pub async fn open_sqlite(path: &Path) -> Result<SqlStore, StoreError> {
        sqlx::any::install_default_drivers();
        let url = format!("sqlite://{}?mode=rwc", path.display());
        let writer = AnyPoolOptions::new()
            .max_connections(1)
            .after_connect(sqlite_pragmas)
            .connect(&url)
            .await?;
        let store = SqlStore {
            reader: AnyPoolOptions::new()
                .max_connections(4)
                .after_connect(sqlite_pragmas)
                .connect(&url)
                .await?,
            writer,
            dialect: Dialect::Sqlite,
            q: Queries::new(Dialect::Sqlite),
        };
        store.migrate().await?;
        Ok(store)
    }

    /// Connects to PostgreSQL at `url` and applies the migrations (under the migrator's
    /// advisory lock, so replicas starting together do not race).
    pub async fn open_postgres(url: &str, max_connections: u32) -> Result<SqlStore, StoreError> {
        sqlx::any::install_default_drivers();
        let pool = AnyPoolOptions::new()
            .max_connections(max_connections.max(2))
            // Fail fast while the server is down: clients get 503, workers retry.
            .acquire_timeout(Duration::from_secs(3))
            .connect(url)
            .await?;
        let store = SqlStore {
            reader: pool.clone(),
            writer: pool,
            dialect: Dialect::Postgres,
            q: Queries::new(Dialect::Postgres),
        };
        store.migrate().await?;
        Ok(store)
    }

    async fn migrate(&self) -> Result<(), StoreError> {
        let migrations = self
            .dialect
            .migrations()
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
        .run(&self.writer)
        .await
        .map_err(|e| StoreError::Unavailable(format!("migrations: {e}")))
    }
}

/// WAL (readers never wait for the writer), FULL sync (an answered job is on disk), a
/// busy timeout instead of immediate SQLITE_BUSY, and enforced foreign keys.
fn sqlite_pragmas(
    conn: &mut sqlx::AnyConnection,
    _: sqlx::pool::PoolConnectionMetadata,
) -> futures_util::future::BoxFuture<'_, Result<(), sqlx::Error>> {
    Box::pin(async move {
        conn.execute(
            "PRAGMA journal_mode = WAL; PRAGMA synchronous = FULL; \
             PRAGMA busy_timeout = 10000; PRAGMA foreign_keys = ON;",
        )
        .await?;
        Ok(())
    })
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

/// Every statement, written once with `?` placeholders and numbered (`$1`, `$2`, …) for
/// PostgreSQL.
struct Queries {
    get: String,
    bump_seq: String,
    insert_event: String,
    idem_lookup: String,
    count_queued: String,
    insert_job: String,
    insert_idem: String,
    queue_position: String,
    counts: String,
    claim: String,
    heartbeat: String,
    progress: String,
    finish_ok: String,
    finish_failed: String,
    release: String,
    cancel: String,
    orphaned: String,
    fail_orphan: String,
    requeue_orphan: String,
    expire_due: String,
    events_after: String,
    ping: String,
}

/// The lease guard every worker update ends with (binds `id`, `worker`).
const LEASED: &str = "WHERE id = ? AND status = 'running' AND lease_owner = ?";

impl Queries {
    fn new(d: Dialect) -> Queries {
        let n = |q: String| match d {
            Dialect::Sqlite => q,
            Dialect::Postgres => {
                let mut out = String::with_capacity(q.len() + 16);
                let mut k = 0;
                for c in q.chars() {
                    if c == '?' {
                        k += 1;
                        out += &format!("${k}");
                    } else {
                        out.push(c);
                    }
                }
                out
            }
        };
        let (max, lock) = (d.greatest(), d.skip_locked());
        Queries {
            get: n(format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?")),
            bump_seq: n(format!(
                "UPDATE jobs SET seq = seq + 1 WHERE id = ? RETURNING {JOB_COLUMNS}"
            )),
            insert_event: n("INSERT INTO job_events (job_id, seq, data) VALUES (?, ?, ?)".into()),
            idem_lookup: n(
                "SELECT payload_hash, job_id FROM idempotency_keys WHERE owner = ? AND key = ?"
                    .into(),
            ),
            count_queued: "SELECT COUNT(*) FROM jobs WHERE status = 'queued'".into(),
            insert_job: n(
                "INSERT INTO jobs (id, owner, status, progress, options, input_format, \
                 input_bytes, filename, created_at) VALUES (?, ?, 'queued', 0, ?, ?, ?, ?, ?)"
                    .into(),
            ),
            // A concurrent submission with the same key (another replica) inserts nothing.
            insert_idem: n(
                "INSERT INTO idempotency_keys (owner, key, payload_hash, job_id, \
                 created_at) VALUES (?, ?, ?, ?, ?) ON CONFLICT DO NOTHING"
                    .into(),
            ),
            queue_position: n("SELECT COUNT(*) FROM jobs WHERE status = 'queued' AND \
                 (created_at < ? OR (created_at = ? AND id < ?))"
                .into()),
            counts: "SELECT status, COUNT(*) AS n FROM jobs GROUP BY status".into(),
            claim: n(format!(
                "UPDATE jobs SET status = 'running', stage = 'validating', progress = 0, \
                 attempts = attempts + 1, started_at = ?, lease_owner = ?, lease_until = ? \
                 WHERE id = (SELECT id FROM jobs WHERE status = 'queued' \
                             ORDER BY created_at, id LIMIT 1{lock}) \
                 AND status = 'queued' RETURNING id"
            )),
            heartbeat: n(format!("UPDATE jobs SET lease_until = ? {LEASED}")),
            progress: n(format!(
                "UPDATE jobs SET stage = ?, progress = ?, lease_until = ? {LEASED}"
            )),
            finish_ok: n(format!(
                "UPDATE jobs SET status = 'succeeded', progress = 1, result = ?, \
                 finished_at = ?, expires_at = ?, lease_owner = NULL, lease_until = NULL \
                 {LEASED}"
            )),
            // A failed job keeps the stage it failed in and how far it got.
            finish_failed: n(format!(
                "UPDATE jobs SET status = 'failed', error_code = ?, error_message = ?, \
                 finished_at = ?, expires_at = ?, lease_owner = NULL, lease_until = NULL \
                 {LEASED}"
            )),
            release: n(format!(
                "UPDATE jobs SET status = 'queued', stage = NULL, progress = 0, \
                 attempts = {max}(attempts - 1, 0), started_at = NULL, lease_owner = NULL, \
                 lease_until = NULL {LEASED}"
            )),
            // Queued or running: canceled. Finished: its results are deleted, so it
            // expires now.
            cancel: n("UPDATE jobs SET \
                   status = CASE WHEN status IN ('queued', 'running') THEN 'canceled' \
                                 ELSE 'expired' END, \
                   finished_at = COALESCE(finished_at, ?), expires_at = ?, \
                   lease_owner = NULL, lease_until = NULL \
                 WHERE id = ? AND status IN ('queued', 'running', 'succeeded', 'failed')"
                .into()),
            orphaned: n(format!(
                "SELECT id, attempts FROM jobs WHERE status = 'running' AND \
                 (? OR lease_until < ?){lock}"
            )),
            fail_orphan: n(
                "UPDATE jobs SET status = 'failed', error_code = 'attempts_exhausted', \
                 error_message = ?, finished_at = ?, expires_at = ?, lease_owner = NULL, \
                 lease_until = NULL WHERE id = ? AND status = 'running'"
                    .into(),
            ),
            requeue_orphan: n(
                "UPDATE jobs SET status = 'queued', stage = NULL, progress = 0, \
                 lease_owner = NULL, lease_until = NULL WHERE id = ? AND status = 'running'"
                    .into(),
            ),
            expire_due: n(
                "UPDATE jobs SET status = 'expired' WHERE expires_at <= ? AND \
                 status IN ('succeeded', 'failed', 'canceled') RETURNING id"
                    .into(),
            ),
            events_after: n(
                "SELECT data FROM job_events WHERE job_id = ? AND seq > ? ORDER BY seq".into(),
            ),
            ping: "SELECT 1".into(),
        }
    }
}

fn job_from_row(row: &AnyRow) -> Result<Job, StoreError> {
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

type Tx<'a> = Transaction<'a, Any>;

impl SqlStore {
    /// Bumps the job's sequence number and records its current state as the next event.
    /// Call inside the transaction that changed the job.
    async fn append_event(&self, tx: &mut Tx<'_>, id: &str) -> Result<(), StoreError> {
        let row = sqlx::query(&self.q.bump_seq)
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
        sqlx::query(&self.q.insert_event)
            .bind(id)
            .bind(job.seq)
            .bind(serde_json::to_string(&event).expect("events serialize"))
            .execute(&mut **tx)
            .await?;
        Ok(())
    }

    async fn get_with(&self, pool: &AnyPool, id: &str) -> Result<Option<Job>, StoreError> {
        let row = sqlx::query(&self.q.get)
            .bind(id)
            .fetch_optional(pool)
            .await?;
        row.as_ref().map(job_from_row).transpose()
    }

    /// Runs a lease-guarded UPDATE (`binds`, then `id` and `worker`) and records an event
    /// when it matched.
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
        self.append_event(&mut tx, id).await?;
        tx.commit().await?;
        Ok(Lease::Held)
    }

    /// The outcome of an idempotency key already used.
    async fn replay(
        &self,
        owner: &str,
        k: Idempotency<'_>,
    ) -> Result<Option<Admission>, StoreError> {
        let prior = sqlx::query(&self.q.idem_lookup)
            .bind(owner)
            .bind(k.key)
            .fetch_optional(&self.writer)
            .await?;
        let Some(row) = prior else {
            return Ok(None);
        };
        let hash: String = row.try_get("payload_hash")?;
        if hash != k.payload_hash {
            return Ok(Some(Admission::KeyConflict));
        }
        let id: String = row.try_get("job_id")?;
        match self.get_with(&self.writer, &id).await? {
            Some(j) => Ok(Some(Admission::Replayed(j))),
            None => Err(StoreError::Corrupt(format!("idempotency key of {id}"))),
        }
    }
}

enum Bind {
    I(Option<i64>),
    F(f64),
    S(Option<String>),
}

#[async_trait]
impl JobStore for SqlStore {
    async fn admit(
        &self,
        job: &NewJob,
        idem: Option<Idempotency<'_>>,
        max_queued: u64,
    ) -> Result<Admission, StoreError> {
        if let Some(k) = idem {
            if let Some(a) = self.replay(&job.owner, k).await? {
                return Ok(a);
            }
        }
        let mut tx = self.writer.begin().await?;
        let queued: i64 = sqlx::query_scalar(&self.q.count_queued)
            .fetch_one(&mut *tx)
            .await?;
        if queued as u64 >= max_queued {
            return Ok(Admission::QueueFull {
                queued: queued as u64,
            });
        }
        let now = ms(Utc::now());
        sqlx::query(&self.q.insert_job)
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
            let n = sqlx::query(&self.q.insert_idem)
                .bind(&job.owner)
                .bind(k.key)
                .bind(k.payload_hash)
                .bind(&job.id)
                .bind(now)
                .execute(&mut *tx)
                .await?
                .rows_affected();
            if n == 0 {
                // Lost a race for the key: the other submission's job stands.
                drop(tx);
                return match self.replay(&job.owner, k).await? {
                    Some(a) => Ok(a),
                    None => Err(StoreError::Corrupt("idempotency key vanished".into())),
                };
            }
        }
        self.append_event(&mut tx, &job.id).await?;
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
        let ahead: i64 = sqlx::query_scalar(&self.q.queue_position)
            .bind(ms(job.created_at))
            .bind(ms(job.created_at))
            .bind(&job.id)
            .fetch_one(&self.reader)
            .await?;
        Ok(Some(ahead as u64))
    }

    async fn counts(&self) -> Result<Vec<(JobStatus, u64)>, StoreError> {
        let rows = sqlx::query(&self.q.counts).fetch_all(&self.reader).await?;
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
        let id: Option<String> = sqlx::query_scalar(&self.q.claim)
            .bind(ms(Utc::now()))
            .bind(worker)
            .bind(lease_deadline(lease))
            .fetch_optional(&mut *tx)
            .await?;
        let Some(id) = id else {
            return Ok(None);
        };
        self.append_event(&mut tx, &id).await?;
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
        let n = sqlx::query(&self.q.heartbeat)
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
            &self.q.progress,
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
        let (sql, mut binds) = match outcome {
            Outcome::Succeeded(r) => (
                &self.q.finish_ok,
                vec![Bind::S(Some(
                    serde_json::to_string(r).expect("results serialize"),
                ))],
            ),
            Outcome::Failed(e) => (
                &self.q.finish_failed,
                vec![
                    Bind::S(Some(e.code.clone())),
                    Bind::S(Some(e.message.clone())),
                ],
            ),
        };
        binds.push(Bind::I(Some(ms(Utc::now()))));
        binds.push(Bind::I(Some(ms(expires_at))));
        self.leased_update(sql, binds, id, worker).await
    }

    async fn release(&self, id: &str, worker: &str) -> Result<Lease, StoreError> {
        self.leased_update(&self.q.release, vec![], id, worker)
            .await
    }

    async fn cancel(&self, id: &str, expires_at: DateTime<Utc>) -> Result<Option<Job>, StoreError> {
        let mut tx = self.writer.begin().await?;
        let n = sqlx::query(&self.q.cancel)
            .bind(ms(Utc::now()))
            .bind(ms(expires_at))
            .bind(id)
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if n == 1 {
            self.append_event(&mut tx, id).await?;
        }
        tx.commit().await?;
        self.get_with(&self.writer, id).await
    }

    async fn recover(&self, all: bool, max_attempts: u32) -> Result<u64, StoreError> {
        let mut tx = self.writer.begin().await?;
        let now = ms(Utc::now());
        let ids: Vec<(String, i64)> = sqlx::query_as(&self.q.orphaned)
            .bind(all)
            .bind(now)
            .fetch_all(&mut *tx)
            .await?;
        for (id, attempts) in &ids {
            if *attempts as u32 >= max_attempts {
                sqlx::query(&self.q.fail_orphan)
                    .bind(format!(
                        "the job's worker stopped {attempts} times before it finished"
                    ))
                    .bind(now)
                    .bind(now)
                    .bind(id)
                    .execute(&mut *tx)
                    .await?;
            } else {
                sqlx::query(&self.q.requeue_orphan)
                    .bind(id)
                    .execute(&mut *tx)
                    .await?;
            }
            self.append_event(&mut tx, id).await?;
        }
        tx.commit().await?;
        Ok(ids.len() as u64)
    }

    async fn expire_due(&self, now: DateTime<Utc>) -> Result<Vec<String>, StoreError> {
        let mut tx = self.writer.begin().await?;
        let ids: Vec<String> = sqlx::query_scalar(&self.q.expire_due)
            .bind(ms(now))
            .fetch_all(&mut *tx)
            .await?;
        for id in &ids {
            self.append_event(&mut tx, id).await?;
        }
        tx.commit().await?;
        Ok(ids)
    }

    async fn events_after(&self, id: &str, seq: i64) -> Result<Vec<JobEvent>, StoreError> {
        let rows: Vec<String> = sqlx::query_scalar(&self.q.events_after)
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
        sqlx::query(&self.q.ping).execute(&self.reader).await?;
        Ok(())
    }
}
