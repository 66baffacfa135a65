//! The worker pool: each worker takes the oldest queued job, runs the pipeline on the
//! blocking pool, reports its stages, keeps its lease alive, and records the outcome.
//!
//! Several workers run at once so that their skeleton candidates meet in the inference
//! thread's decode batch; the CPU-heavy stages around it (loading, skinning, export) are
//! what limits how many pay off on a small machine.
//!
//! Shutdown: a worker stops taking jobs as soon as shutdown starts. A job it is running
//! gets `drain` to finish; after that the job is put back in the queue (its attempt not
//! counted) and the pipeline is told to stop at its next check, so a restart, or another
//! replica, runs it again. A job whose lease is lost (canceled, or taken over after the
//! lease ran out) is abandoned the same way, and nothing it produces is recorded.

use super::blobs::BlobKind;
use super::model::{Job, JobError, JobResult, JobStatus, Stage};
use super::pipeline::{self, Engine, Progress};
use super::store::{Lease, Outcome};
use super::view::JobView;
use super::Context;
use bytes::Bytes;
use sha2::{Digest, Sha256};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn, Instrument};

#[derive(Clone, Debug)]
pub struct WorkerConfig {
    pub workers: usize,
    /// How long a job stays leased without a heartbeat; heartbeats come every third of it.
    pub lease: Duration,
    /// How often an idle worker looks for jobs queued by other replicas.
    pub poll: Duration,
    /// How long results are kept.
    pub result_ttl: Duration,
    /// How long shutdown waits for a running job before re-queueing it.
    pub drain: Duration,
}

/// Starts the workers; they stop when `shutdown` is canceled.
pub fn spawn(
    ctx: Context,
    engine: Arc<Engine>,
    cfg: WorkerConfig,
    instance: &str,
    shutdown: CancellationToken,
) -> Vec<tokio::task::JoinHandle<()>> {
    (0..cfg.workers)
        .map(|n| {
            let w = Worker {
                id: format!("{instance}/{n}"),
                ctx: ctx.clone(),
                engine: engine.clone(),
                cfg: cfg.clone(),
                shutdown: shutdown.clone(),
            };
            tokio::spawn(async move { w.run().await })
        })
        .collect()
}

struct Worker {
    id: String,
    ctx: Context,
    engine: Arc<Engine>,
    cfg: WorkerConfig,
    shutdown: CancellationToken,
}

/// What the blocking pipeline sees of its job.
struct JobProgress {
    canceled: AtomicBool,
    stages: mpsc::UnboundedSender<Stage>,
}

impl Progress for JobProgress {
    fn stage(&self, stage: Stage) {
        let _ = self.stages.send(stage);
    }

    fn canceled(&self) -> bool {
        self.canceled.load(Ordering::Relaxed)
    }
}

impl Worker {
    async fn run(self) {
        while !self.shutdown.is_cancelled() {
            match self.ctx.store.claim(&self.id, self.cfg.lease).await {
                Ok(Some(job)) => {
                    let span = tracing::info_span!("job", job_id = %job.id, worker = %self.id);
                    self.run_job(job).instrument(span).await;
                    // The job's upload, meshes and result are dropped by now.
                    super::memory::give_back_async().await;
                    continue;
                }
                Ok(None) => {}
                Err(e) => warn!(worker = %self.id, error = %e, "cannot take a job"),
            }
            tokio::select! {
                _ = self.shutdown.cancelled() => break,
                _ = self.ctx.notifier.next_queued() => {}
                _ = tokio::time::sleep(self.cfg.poll) => {}
            }
        }
    }

    async fn run_job(&self, job: Job) {
        let started = Instant::now();
        self.ctx.notifier.changed(&job.id);
        info!(attempt = job.attempts, "job started");
        let input = match self.ctx.blobs.get(&job.id, BlobKind::Input).await {
            Ok(Some(b)) => b,
            Ok(None) => {
                let e = JobError {
                    code: "input_missing".into(),
                    message: "the uploaded file is gone from the blob store".into(),
                };
                return self.finish(&job, Outcome::Failed(e), started).await;
            }
            Err(e) => {
                // The blob store is down: give the job back rather than fail it.
                warn!(error = %e, "cannot read the upload; re-queueing");
                let _ = self.ctx.store.release(&job.id, &self.id).await;
                self.ctx.notifier.queued();
                tokio::time::sleep(self.cfg.poll).await;
                return;
            }
        };

        let (tx, mut stages) = mpsc::unbounded_channel();
        let progress = Arc::new(JobProgress {
            canceled: AtomicBool::new(false),
            stages: tx,
        });
        let engine = self.engine.clone();
        let options = job.options.clone();
        let p = progress.clone();
        let mut task =
            tokio::task::spawn_blocking(move || pipeline::run(&engine, &input, &options, p));

        let mut heartbeat = tokio::time::interval(self.cfg.lease / 3);
        heartbeat.tick().await;
        // Taking the job already recorded `validating`.
        let mut current: Option<(Stage, Instant)> = Some((Stage::Validating, Instant::now()));
        let mut drain_until: Option<tokio::time::Instant> = None;
        let result = loop {
            let drain_sleep = async {
                match drain_until {
                    Some(t) => tokio::time::sleep_until(t).await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                r = &mut task => break r,
                Some(stage) = stages.recv() => {
                    self.record_stage(&job, stage, &mut current, &progress).await;
                }
                _ = heartbeat.tick() => {
                    if matches!(self.ctx.store.heartbeat(&job.id, &self.id, self.cfg.lease).await, Ok(Lease::Lost)) {
                        info!("lease lost (canceled or taken over); abandoning the job");
                        progress.canceled.store(true, Ordering::Relaxed);
                    }
                }
                _ = self.shutdown.cancelled(), if drain_until.is_none() => {
                    drain_until = Some(tokio::time::Instant::now() + self.cfg.drain);
                }
                _ = drain_sleep => {
                    progress.canceled.store(true, Ordering::Relaxed);
                    match self.ctx.store.release(&job.id, &self.id).await {
                        Ok(_) => info!("shutdown: job re-queued"),
                        Err(e) => warn!(error = %e, "shutdown: cannot re-queue; its lease will expire"),
                    }
                    self.ctx.notifier.changed(&job.id);
                    return;
                }
            }
        };
        // Stages the pipeline reported just before it returned are still in the channel:
        // record them, so every stage a job went through is an event.
        while let Ok(stage) = stages.try_recv() {
            self.record_stage(&job, stage, &mut current, &progress)
                .await;
        }
        if let Some((s, t)) = current {
            self.ctx.metrics.observe_stage(s, t.elapsed().as_secs_f64());
        }
        if progress.canceled() {
            self.ctx.notifier.changed(&job.id);
            return;
        }
        let outcome = match result {
            Ok(Ok(rigged)) => match self.store_results(&job, rigged).await {
                Ok(r) => Outcome::Succeeded(r),
                Err(e) => Outcome::Failed(e),
            },
            Ok(Err(e)) => Outcome::Failed(JobError {
                code: e.code,
                message: e.message,
            }),
            Err(join) => Outcome::Failed(JobError {
                code: "internal_error".into(),
                message: format!("the rigging pipeline stopped unexpectedly: {join}"),
            }),
        };
        self.finish(&job, outcome, started).await;
    }

    /// Records a stage the pipeline entered (an event; the lease is extended), and the
    /// time spent in the one it left. A lost lease cancels the pipeline.
    async fn record_stage(
        &self,
        job: &Job,
        stage: Stage,
        current: &mut Option<(Stage, Instant)>,
        progress: &JobProgress,
    ) {
        if current.is_some_and(|(s, _)| s == stage) || progress.canceled() {
            return;
        }
        if let Some((s, t)) = current.replace((stage, Instant::now())) {
            self.ctx.metrics.observe_stage(s, t.elapsed().as_secs_f64());
        }
        let lease = self
            .ctx
            .store
            .progress(
                &job.id,
                &self.id,
                stage,
                stage.start_progress(),
                self.cfg.lease,
            )
            .await;
        self.ctx.notifier.changed(&job.id);
        if matches!(lease, Ok(Lease::Lost)) {
            progress.canceled.store(true, Ordering::Relaxed);
        }
    }

    async fn store_results(
        &self,
        job: &Job,
        rigged: pipeline::Rigged,
    ) -> Result<JobResult, JobError> {
        let etag = format!("\"{}\"", hex::encode(&Sha256::digest(&rigged.glb)[..16]));
        let glb_bytes = rigged.glb.len() as u64;
        let tree = serde_json::to_vec_pretty(&rigged.bone_tree).expect("JSON values serialize");
        let blob_err = |e: super::BlobError| JobError {
            code: e.code().into(),
            message: e.to_string(),
        };
        self.ctx
            .blobs
            .put(&job.id, BlobKind::ResultGlb, Bytes::from(rigged.glb))
            .await
            .map_err(blob_err)?;
        self.ctx
            .blobs
            .put(&job.id, BlobKind::Skeleton, Bytes::from(tree))
            .await
            .map_err(blob_err)?;
        Ok(JobResult {
            etag,
            glb_bytes,
            bones: rigged.bones as u32,
        })
    }

    async fn finish(&self, job: &Job, outcome: Outcome, started: Instant) {
        let expires = chrono::Utc::now()
            + chrono::Duration::from_std(self.cfg.result_ttl).unwrap_or(chrono::Duration::MAX);
        let label = match &outcome {
            Outcome::Succeeded(_) => "succeeded",
            Outcome::Failed(_) => "failed",
        };
        // A store outage here is retried: the result is computed, and losing it would
        // mean running the job again.
        let mut delay = Duration::from_millis(200);
        let lease = loop {
            match self
                .ctx
                .store
                .finish(&job.id, &self.id, &outcome, expires)
                .await
            {
                Ok(l) => break l,
                Err(e) if delay < self.cfg.lease => {
                    warn!(error = %e, "cannot record the outcome; retrying");
                    tokio::time::sleep(delay).await;
                    delay *= 2;
                }
                Err(e) => {
                    warn!(error = %e, "cannot record the outcome; the lease will expire and the job run again");
                    return;
                }
            }
        };
        self.ctx.notifier.changed(&job.id);
        if lease == Lease::Lost {
            info!("job ended elsewhere (canceled or taken over); outcome dropped");
            // Canceled while the results were being written: the cancel deleted the
            // blobs before these arrived, so delete them again.
            if let Ok(Some(now)) = self.ctx.store.get(&job.id).await {
                if matches!(now.status, JobStatus::Canceled | JobStatus::Expired) {
                    let _ = self.ctx.blobs.delete_job(&job.id).await;
                }
            }
            return;
        }
        self.ctx
            .metrics
            .job_seconds
            .with_label_values(&[label])
            .observe(started.elapsed().as_secs_f64());
        if let Outcome::Failed(e) = &outcome {
            self.ctx
                .metrics
                .failures
                .with_label_values(&[&e.code])
                .inc();
            info!(code = %e.code, message = %e.message, "job failed");
        } else {
            info!(seconds = started.elapsed().as_secs_f64(), "job succeeded");
        }
        if let (Some(url), Some(hooks)) = (&job.options.webhook_url, &self.ctx.webhooks) {
            if let Ok(Some(done)) = self.ctx.store.get(&job.id).await {
                hooks.spawn_delivery(url.clone(), JobView::new(&done, None));
            }
        }
    }
}
