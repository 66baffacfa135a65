//! Prometheus metrics of jobs and workers. Names follow text-generation-inference's
//! pattern: `rigserve_<thing>_<unit>`; durations are histograms in seconds.

use super::model::{JobStatus, Stage};
use prometheus::{
    register_histogram_vec_with_registry, register_int_counter_vec_with_registry,
    register_int_gauge_vec_with_registry, register_int_gauge_with_registry, HistogramVec,
    IntCounterVec, IntGauge, IntGaugeVec, Registry,
};

#[derive(Clone)]
pub struct JobMetrics {
    /// Jobs by status, as last counted from the store.
    pub jobs: IntGaugeVec,
    pub queue_depth: IntGauge,
    pub stage_seconds: HistogramVec,
    pub job_seconds: HistogramVec,
    /// Failed jobs by error code.
    pub failures: IntCounterVec,
    pub webhook_deliveries: IntCounterVec,
}

impl JobMetrics {
    pub fn new(registry: &Registry) -> prometheus::Result<JobMetrics> {
        let stage_buckets = vec![
            0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0,
        ];
        Ok(JobMetrics {
            jobs: register_int_gauge_vec_with_registry!(
                "rigserve_jobs",
                "Jobs in the store by status",
                &["status"],
                registry
            )?,
            queue_depth: register_int_gauge_with_registry!(
                "rigserve_queue_depth",
                "Jobs waiting for a worker",
                registry
            )?,
            stage_seconds: register_histogram_vec_with_registry!(
                "rigserve_stage_duration_seconds",
                "Time spent in each job stage",
                &["stage"],
                stage_buckets.clone(),
                registry
            )?,
            job_seconds: register_histogram_vec_with_registry!(
                "rigserve_job_duration_seconds",
                "Time from a worker taking a job to its end, by outcome",
                &["outcome"],
                stage_buckets,
                registry
            )?,
            failures: register_int_counter_vec_with_registry!(
                "rigserve_job_failures_total",
                "Failed jobs by error code",
                &["error_type"],
                registry
            )?,
            webhook_deliveries: register_int_counter_vec_with_registry!(
                "rigserve_webhook_deliveries_total",
                "Webhook deliveries by result",
                &["result"],
                registry
            )?,
        })
    }

    pub fn set_counts(&self, counts: &[(JobStatus, u64)]) {
        for (s, n) in counts {
            self.jobs.with_label_values(&[s.as_str()]).set(*n as i64);
            if *s == JobStatus::Queued {
                self.queue_depth.set(*n as i64);
            }
        }
    }

    pub fn observe_stage(&self, stage: Stage, seconds: f64) {
        self.stage_seconds
            .with_label_values(&[stage.as_str()])
            .observe(seconds);
    }
}
