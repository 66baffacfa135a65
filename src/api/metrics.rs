//! HTTP metrics (a middleware over every route) and the inference backend's counters,
//! mirrored into Prometheus at scrape time.

use super::error::ErrorType;
use crate::infer::MetricsSnapshot;
use axum::extract::{MatchedPath, Request, State};
use axum::middleware::Next;
use axum::response::Response;
use prometheus::{
    register_gauge_with_registry, register_histogram_vec_with_registry,
    register_int_counter_vec_with_registry, register_int_counter_with_registry,
    register_int_gauge_with_registry, Gauge, HistogramVec, IntCounter, IntCounterVec, IntGauge,
    Registry,
};
use std::sync::{Arc, Mutex};
use std::time::Instant;

#[derive(Clone)]
pub struct HttpMetrics {
    requests: IntCounterVec,
    duration: HistogramVec,
    errors: IntCounterVec,
}

impl HttpMetrics {
    pub fn new(registry: &Registry) -> prometheus::Result<HttpMetrics> {
        Ok(HttpMetrics {
            requests: register_int_counter_vec_with_registry!(
                "rigserve_http_requests_total",
                "HTTP requests by route, method and status",
                &["route", "method", "status"],
                registry
            )?,
            duration: register_histogram_vec_with_registry!(
                "rigserve_http_request_duration_seconds",
                "HTTP request durations by route and method (SSE: the stream's life)",
                &["route", "method"],
                vec![0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0, 60.0],
                registry
            )?,
            errors: register_int_counter_vec_with_registry!(
                "rigserve_http_errors_total",
                "Error responses by error_type",
                &["error_type"],
                registry
            )?,
        })
    }
}

pub async fn track(State(m): State<HttpMetrics>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|p| p.as_str().to_string())
        .unwrap_or_else(|| "unmatched".to_string());
    let method = req.method().as_str().to_string();
    let start = Instant::now();
    let resp = next.run(req).await;
    let status = resp.status().as_u16().to_string();
    m.requests
        .with_label_values(&[route.as_str(), method.as_str(), status.as_str()])
        .inc();
    m.duration
        .with_label_values(&[route.as_str(), method.as_str()])
        .observe(start.elapsed().as_secs_f64());
    if let Some(ErrorType(t)) = resp.extensions().get::<ErrorType>() {
        m.errors
            .with_label_values(&[t.to_str().unwrap_or("unknown")])
            .inc();
    }
    resp
}

/// The inference thread's counters as Prometheus metrics, advanced by the difference
/// from the previous scrape.
pub struct DecodeMetrics {
    tokens: IntCounter,
    steps: IntCounter,
    rows: IntCounter,
    positions: IntCounter,
    real_positions: IntCounter,
    decode_seconds: prometheus::Counter,
    encode_seconds: prometheus::Counter,
    prefill_seconds: prometheus::Counter,
    cache_seconds: prometheus::Counter,
    running: IntGauge,
    waiting: IntGauge,
    tokens_per_second: Gauge,
    last: Mutex<MetricsSnapshot>,
}

impl DecodeMetrics {
    pub fn new(registry: &Registry) -> prometheus::Result<Arc<DecodeMetrics>> {
        Ok(Arc::new(DecodeMetrics {
            tokens: register_int_counter_with_registry!(
                "rigserve_decode_tokens_total",
                "Skeleton tokens generated",
                registry
            )?,
            steps: register_int_counter_with_registry!(
                "rigserve_decode_steps_total",
                "Decoder calls of the running batch",
                registry
            )?,
            rows: register_int_counter_with_registry!(
                "rigserve_decode_batch_rows_total",
                "Sum of batch sizes over decode steps (divide by steps for the mean batch size)",
                registry
            )?,
            positions: register_int_counter_with_registry!(
                "rigserve_decode_cache_positions_total",
                "Cache positions decode steps read (rows x columns with padding for the dense cache; each row's own length for the ragged step)",
                registry
            )?,
            real_positions: register_int_counter_with_registry!(
                "rigserve_decode_cache_real_positions_total",
                "Of those, positions holding a real token (the rest is padding)",
                registry
            )?,
            decode_seconds: prometheus::register_counter_with_registry!(
                "rigserve_decode_seconds_total",
                "Time spent in decode steps",
                registry
            )?,
            encode_seconds: prometheus::register_counter_with_registry!(
                "rigserve_encode_seconds_total",
                "Time spent in point-cloud encoder calls",
                registry
            )?,
            prefill_seconds: prometheus::register_counter_with_registry!(
                "rigserve_prefill_seconds_total",
                "Time spent in prefill calls (prefix and prompt of joining jobs)",
                registry
            )?,
            cache_seconds: prometheus::register_counter_with_registry!(
                "rigserve_decode_cache_seconds_total",
                "Time spent reorganizing the decode cache as rows join and leave",
                registry
            )?,
            running: register_int_gauge_with_registry!(
                "rigserve_batch_size",
                "Sequences in the running decode batch",
                registry
            )?,
            waiting: register_int_gauge_with_registry!(
                "rigserve_batch_waiting",
                "Sequences waiting to join the decode batch",
                registry
            )?,
            tokens_per_second: register_gauge_with_registry!(
                "rigserve_decode_tokens_per_second",
                "Tokens per second of decode time since the previous scrape",
                registry
            )?,
            last: Mutex::new(MetricsSnapshot::default()),
        }))
    }

    pub fn update(&self, now: MetricsSnapshot) {
        let mut last = self.last.lock().expect("metrics lock");
        self.tokens
            .inc_by(now.generated_tokens.saturating_sub(last.generated_tokens));
        self.steps
            .inc_by(now.decode_steps.saturating_sub(last.decode_steps));
        self.rows
            .inc_by(now.decode_rows.saturating_sub(last.decode_rows));
        self.positions
            .inc_by(now.decode_positions.saturating_sub(last.decode_positions));
        self.real_positions.inc_by(
            now.decode_real_positions
                .saturating_sub(last.decode_real_positions),
        );
        let secs = |a: u64, b: u64| a.saturating_sub(b) as f64 * 1e-9;
        self.encode_seconds
            .inc_by(secs(now.encode_ns, last.encode_ns));
        self.prefill_seconds
            .inc_by(secs(now.prefill_ns, last.prefill_ns));
        self.cache_seconds.inc_by(secs(now.cache_ns, last.cache_ns));
        let dns = now.decode_ns.saturating_sub(last.decode_ns);
        self.decode_seconds.inc_by(dns as f64 * 1e-9);
        if dns > 0 {
            let dt = now.generated_tokens.saturating_sub(last.generated_tokens);
            self.tokens_per_second.set(dt as f64 / (dns as f64 * 1e-9));
        }
        self.running.set(now.running as i64);
        self.waiting.set(now.waiting as i64);
        *last = now;
    }
}
