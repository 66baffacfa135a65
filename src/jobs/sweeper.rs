//! Housekeeping on a timer: jobs whose worker died (lease ended) go back to the queue,
//! results past their TTL are deleted, and the job gauges are refreshed. Every replica
//! may run it; each step is a single guarded update in the store, so running it twice at
//! once does no harm.

use super::Context;
use std::time::Duration;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

#[derive(Clone, Debug)]
pub struct SweeperConfig {
    pub every: Duration,
    /// A job whose worker stopped this many times fails instead of running again.
    pub max_attempts: u32,
}

pub async fn sweep_once(ctx: &Context, max_attempts: u32) {
    match ctx.store.recover(false, max_attempts).await {
        Ok(0) => {}
        Ok(n) => {
            info!(jobs = n, "re-queued jobs whose lease ended");
            ctx.notifier.queued();
        }
        Err(e) => warn!(error = %e, "lease recovery failed"),
    }
    match ctx.store.expire_due(chrono::Utc::now()).await {
        Ok(ids) => {
            for id in ids {
                if let Err(e) = ctx.blobs.delete_job(&id).await {
                    warn!(job_id = %id, error = %e, "cannot delete expired results");
                }
                ctx.notifier.changed(&id);
            }
        }
        Err(e) => warn!(error = %e, "expiry failed"),
    }
    if let Ok(counts) = ctx.store.counts().await {
        ctx.metrics.set_counts(&counts);
    }
}

pub fn spawn(
    ctx: Context,
    cfg: SweeperConfig,
    shutdown: CancellationToken,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(cfg.every);
        loop {
            tokio::select! {
                _ = shutdown.cancelled() => return,
                _ = tick.tick() => sweep_once(&ctx, cfg.max_attempts).await,
            }
        }
    })
}
