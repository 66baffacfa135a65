//! The inference thread: owns the model, takes requests over a channel, and decodes them
//! with continuous batching.
//!
//! Each loop iteration
//! 1. takes every request that has arrived (blocking only when there is nothing to do);
//! 2. admits waiting requests up to `max_batch`: encodes their points (each distinct point
//!    set once) and prefills them as a batch of their own ([`super::prefill`]), samples
//!    their first token, and appends their cache rows to the running batch;
//! 3. runs one decode step for the whole running batch;
//! 4. samples each item's next token under its own grammar and random stream;
//! 5. replies to finished items (`<eos>`, length) and drops their rows.
//!
//! The cache stays in place ([`DecodeCache`]): with the model's ragged step
//! (`decoder_step.onnx`, [`super::RaggedKv`]) each row keeps its own length and the step
//! reads only that; without it ([`KvCache`](super::KvCache)) rows share one length and the ones that joined
//! later are left-padded to it. A step writes one new column; joining copies only the new
//! rows, and a finished row is replaced by the last one. Callers get a
//! [`Pending`] (a one-shot reply channel); dropping it cancels the request at the next
//! step.

use super::cache::DecodeCache;
use super::model::{ModelInfo, PointEncoder, SkeletonModel};
use super::prefill::{self, Prepared};
use super::sampling::{completion_cost, constrain_logits, Sampler, SamplingParams};
use super::InferError;
use crate::rig::grammar::Grammar;
use ndarray::{Array2, Array3, ArrayView1, Axis};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{channel, Receiver, RecvError, Sender};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// One sequence to generate.
#[derive(Clone, Debug)]
pub struct SkeletonRequest {
    /// Surface samples `x y z nx ny nz`, normalized as `rigserve dataset` does. Shared so
    /// best-of-N candidates of one mesh hold (and encode) one copy.
    pub points: Arc<[[f32; 6]]>,
    /// `<bos> <cls:…>` and optionally the tokens of bones to keep (no `<eos>`).
    pub prompt: Vec<u32>,
    pub sampling: SamplingParams,
    pub max_bones: usize,
    /// Longest sequence, prompt included; 0, or more than the model allows, means the
    /// model's `max_tokens`.
    pub max_tokens: usize,
    /// Refuse template blocks (`<mixamo:body>`): a free-form skeleton was asked for.
    pub no_templates: bool,
    /// Benchmarks only: never choose `<eos>` (while anything else is allowed), so the item
    /// runs to exactly `max_tokens`. The result may then not detokenize.
    pub ignore_eos: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FinishReason {
    Eos,
    /// Reached `max_tokens` (only with `ignore_eos`: the grammar budget otherwise ends
    /// every sequence with `<eos>` in time).
    Length,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Generation {
    /// The whole sequence: prompt, then generated tokens.
    pub tokens: Vec<u32>,
    pub prompt_len: usize,
    pub finish: FinishReason,
}

impl Generation {
    pub fn generated(&self) -> &[u32] {
        &self.tokens[self.prompt_len..]
    }
}

#[derive(Clone, Debug)]
pub struct BackendConfig {
    /// Most sequences decoded together; more wait in the queue.
    pub max_batch: usize,
    /// `false` recomputes every sequence in full at each step (the baseline the cache is
    /// benchmarked and tested against).
    pub kv_cache: bool,
    /// Decode with the model's ragged step (`decoder_step.onnx`) when it has one: each
    /// row attends over its own length instead of the batch's longest.
    pub ragged: bool,
    /// The inference thread's nice value (0: the process's): a server sets it high so
    /// that under load rows wait for each other and share steps ([`super::priority`]).
    pub nice: i32,
}

impl Default for BackendConfig {
    fn default() -> Self {
        BackendConfig {
            max_batch: 32,
            kv_cache: true,
            ragged: true,
            nice: 0,
        }
    }
}

/// Counters the worker updates; read them with [`Metrics::snapshot`].
#[derive(Debug, Default)]
pub struct Metrics {
    requests: AtomicU64,
    completed: AtomicU64,
    pub(super) failed: AtomicU64,
    pub(super) cancelled: AtomicU64,
    generated_tokens: AtomicU64,
    decode_steps: AtomicU64,
    decode_rows: AtomicU64,
    decode_ns: AtomicU64,
    decode_positions: AtomicU64,
    decode_real_positions: AtomicU64,
    pub(super) prefill_calls: AtomicU64,
    pub(super) prefill_rows: AtomicU64,
    pub(super) prefill_ns: AtomicU64,
    pub(super) encode_calls: AtomicU64,
    pub(super) encode_rows: AtomicU64,
    pub(super) encode_ns: AtomicU64,
    cache_rebuilds: AtomicU64,
    cache_ns: AtomicU64,
    running: AtomicU64,
    waiting: AtomicU64,
    max_batch_seen: AtomicU64,
}

/// A copy of the counters at one moment. Durations in nanoseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct MetricsSnapshot {
    pub requests: u64,
    pub completed: u64,
    pub failed: u64,
    pub cancelled: u64,
    pub generated_tokens: u64,
    /// Decoder calls of the running batch (one new token per row).
    pub decode_steps: u64,
    /// Sum of the batch sizes of those calls.
    pub decode_rows: u64,
    pub decode_ns: u64,
    /// Cache positions the decode steps attended over (rows × cache columns, summed over
    /// steps), and how many of them were real (the rest is left padding and unwritten
    /// capacity, read and masked).
    pub decode_positions: u64,
    pub decode_real_positions: u64,
    pub prefill_calls: u64,
    pub prefill_rows: u64,
    pub prefill_ns: u64,
    pub encode_calls: u64,
    pub encode_rows: u64,
    pub encode_ns: u64,
    /// Cache copies for membership changes (joins and leaves).
    pub cache_rebuilds: u64,
    pub cache_ns: u64,
    /// Gauges: items decoding and waiting now.
    pub running: u64,
    pub waiting: u64,
    pub max_batch_seen: u64,
}

impl Metrics {
    pub fn snapshot(&self) -> MetricsSnapshot {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        MetricsSnapshot {
            requests: g(&self.requests),
            completed: g(&self.completed),
            failed: g(&self.failed),
            cancelled: g(&self.cancelled),
            generated_tokens: g(&self.generated_tokens),
            decode_steps: g(&self.decode_steps),
            decode_rows: g(&self.decode_rows),
            decode_ns: g(&self.decode_ns),
            decode_positions: g(&self.decode_positions),
            decode_real_positions: g(&self.decode_real_positions),
            prefill_calls: g(&self.prefill_calls),
            prefill_rows: g(&self.prefill_rows),
            prefill_ns: g(&self.prefill_ns),
            encode_calls: g(&self.encode_calls),
            encode_rows: g(&self.encode_rows),
            encode_ns: g(&self.encode_ns),
            cache_rebuilds: g(&self.cache_rebuilds),
            cache_ns: g(&self.cache_ns),
            running: g(&self.running),
            waiting: g(&self.waiting),
            max_batch_seen: g(&self.max_batch_seen),
        }
    }

    pub(super) fn add(a: &AtomicU64, v: u64) {
        a.fetch_add(v, Ordering::Relaxed);
    }

    pub(super) fn add_time(a: &AtomicU64, since: Instant) {
        a.fetch_add(since.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }
}

impl MetricsSnapshot {
    /// Counters accumulated since `earlier` (gauges are kept as they are now).
    pub fn since(&self, earlier: &MetricsSnapshot) -> MetricsSnapshot {
        let d = |a: u64, b: u64| a.saturating_sub(b);
        MetricsSnapshot {
            requests: d(self.requests, earlier.requests),
            completed: d(self.completed, earlier.completed),
            failed: d(self.failed, earlier.failed),
            cancelled: d(self.cancelled, earlier.cancelled),
            generated_tokens: d(self.generated_tokens, earlier.generated_tokens),
            decode_steps: d(self.decode_steps, earlier.decode_steps),
            decode_rows: d(self.decode_rows, earlier.decode_rows),
            decode_ns: d(self.decode_ns, earlier.decode_ns),
            decode_positions: d(self.decode_positions, earlier.decode_positions),
            decode_real_positions: d(self.decode_real_positions, earlier.decode_real_positions),
            prefill_calls: d(self.prefill_calls, earlier.prefill_calls),
            prefill_rows: d(self.prefill_rows, earlier.prefill_rows),
            prefill_ns: d(self.prefill_ns, earlier.prefill_ns),
            encode_calls: d(self.encode_calls, earlier.encode_calls),
            encode_rows: d(self.encode_rows, earlier.encode_rows),
            encode_ns: d(self.encode_ns, earlier.encode_ns),
            cache_rebuilds: d(self.cache_rebuilds, earlier.cache_rebuilds),
            cache_ns: d(self.cache_ns, earlier.cache_ns),
            ..*self
        }
    }

    /// Mean rows per decode step.
    pub fn mean_batch(&self) -> f64 {
        self.decode_rows as f64 / self.decode_steps.max(1) as f64
    }

    pub fn ms_per_step(&self) -> f64 {
        self.decode_ns as f64 / 1e6 / self.decode_steps.max(1) as f64
    }

    /// Tokens produced by decode steps per second of decode time.
    pub fn decode_tokens_per_s(&self) -> f64 {
        self.decode_rows as f64 / (self.decode_ns.max(1) as f64 / 1e9)
    }

    /// All generated tokens per second of model time (encoder, prefill, decode, cache).
    pub fn tokens_per_s(&self) -> f64 {
        let ns = self.encode_ns + self.prefill_ns + self.decode_ns + self.cache_ns;
        self.generated_tokens as f64 / (ns.max(1) as f64 / 1e9)
    }
}

/// The reply to one request. Dropping it cancels the request.
#[derive(Debug)]
pub struct Pending {
    rx: Receiver<Result<Generation, InferError>>,
    cancel: Arc<AtomicBool>,
    /// The load count of the lane it went to.
    load: Option<Arc<AtomicUsize>>,
}

impl Pending {
    /// Blocks until the request finishes.
    pub fn wait(self) -> Result<Generation, InferError> {
        self.rx.recv().unwrap_or(Err(InferError::BackendGone))
    }

    /// Like [`wait`](Pending::wait), but gives up (canceling the request) once `canceled`
    /// says so; it is asked every few milliseconds.
    pub fn wait_unless(self, canceled: &dyn Fn() -> bool) -> Result<Generation, InferError> {
        loop {
            match self.rx.recv_timeout(std::time::Duration::from_millis(20)) {
                Ok(r) => return r,
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(InferError::BackendGone)
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) if canceled() => {
                    return Err(InferError::Canceled)
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
            }
        }
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        self.cancel.store(true, Ordering::Relaxed);
        if let Some(load) = &self.load {
            load.fetch_sub(1, Ordering::Relaxed);
        }
    }
}

/// A validated request on its way to the worker.
pub(super) struct Job {
    pub(super) points: Arc<[[f32; 6]]>,
    pub(super) prompt: Vec<u32>,
    grammar: Grammar,
    sampler: Sampler,
    max_tokens: usize,
    ignore_eos: bool,
    reply: Sender<Result<Generation, InferError>>,
    pub(super) cancel: Arc<AtomicBool>,
    /// The encoder's output, which the submitting thread computes (see [`Backend`]).
    pub(super) prefix: Option<Arc<Array2<f32>>>,
}

enum Command {
    Submit(Vec<Job>),
    /// Logits at every position of a given sequence ([`Backend::teacher_forced`]).
    TeacherForced {
        prefix: Arc<Array2<f32>>,
        tokens: Vec<u32>,
        reply: Sender<Result<Array2<f32>, InferError>>,
    },
}

/// Handle to the inference thread (or threads: see [`Backend::with_lanes`]). `Send +
/// Sync`: share it (e.g. in an `Arc`) between request handlers. Dropping it stops the
/// threads after failing whatever is still queued.
pub struct Backend {
    lanes: Vec<Lane>,
    /// The model's encoder session, run by the submitting threads under a lock rather than
    /// by the inference thread, so encoding one job overlaps the decode steps of the others:
    /// under load the inference thread is the bottleneck, and the encoder took a fifth of it.
    encoder: Mutex<PointEncoder>,
    info: ModelInfo,
    config: BackendConfig,
    metrics: Arc<Metrics>,
}

impl std::fmt::Debug for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Backend")
            .field("info", &self.info)
            .field("config", &self.config)
            .finish()
    }
}

/// One inference thread: its own sessions, batch and cache.
struct Lane {
    tx: Option<Sender<Command>>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// Rows submitted to this lane whose [`Pending`] is still held.
    load: Arc<AtomicUsize>,
}

impl Lane {
    fn start(
        index: usize,
        model: SkeletonModel,
        config: &BackendConfig,
        metrics: &Arc<Metrics>,
    ) -> Result<Lane, InferError> {
        let (tx, rx) = channel();
        let worker = Worker {
            cache: DecodeCache::for_model(&model, config.ragged),
            model,
            kv_cache: config.kv_cache,
            max_batch: config.max_batch.max(1),
            rx,
            waiting: VecDeque::new(),
            running: Vec::new(),
            metrics: metrics.clone(),
            shown: (0, 0),
        };
        let nice = config.nice;
        let name = match index {
            0 => "rigserve-infer".to_string(),
            i => format!("rigserve-infer-{i}"),
        };
        let thread = std::thread::Builder::new()
            .name(name)
            .spawn(move || {
                if nice != 0 {
                    if let Err(e) = super::priority::set_thread_nice(nice) {
                        tracing::warn!(nice, error = %e, "cannot set the inference thread's priority");
                    }
                }
                worker.run()
            })
            .map_err(|e| {
                InferError::Environment(format!("cannot start the inference thread: {e}"))
            })?;
        Ok(Lane {
            tx: Some(tx),
            thread: Some(thread),
            load: Arc::default(),
        })
    }
}

impl Backend {
    /// Moves `model` onto a new inference thread.
    pub fn new(model: SkeletonModel, config: BackendConfig) -> Result<Backend, InferError> {
        Backend::with_lanes(vec![model], config)
    }

    /// One inference thread per model (the same model loaded once per thread; the first
    /// one's encoder serves them all). Each request goes to the lane with the fewest rows
    /// outstanding, so one lane takes everything until it holds more than the others.
    ///
    /// Why more than one: at a high nice value (a server's default) the decode runs in the
    /// gaps the jobs' own work leaves, and under load there are moments when every job
    /// waits for its skeleton and one core decodes while the other idles. A second lane
    /// decodes on that core; the price is smaller batches (each step's weights read by
    /// two threads), README "An Intel Xeon".
    pub fn with_lanes(
        mut models: Vec<SkeletonModel>,
        config: BackendConfig,
    ) -> Result<Backend, InferError> {
        let first = models
            .first_mut()
            .ok_or_else(|| InferError::Environment("no model for the inference thread".into()))?;
        let info = first.info().clone();
        let encoder = Mutex::new(first.take_encoder()?);
        let metrics = Arc::new(Metrics::default());
        let mut lanes = Vec::with_capacity(models.len());
        for (i, mut model) in models.into_iter().enumerate() {
            if i > 0 {
                if model.info() != &info {
                    return Err(InferError::Environment(
                        "the inference threads' models differ".into(),
                    ));
                }
                // Only the first lane's encoder runs.
                drop(model.take_encoder()?);
            }
            lanes.push(Lane::start(i, model, &config, &metrics)?);
        }
        Ok(Backend {
            lanes,
            encoder,
            info,
            config,
            metrics,
        })
    }

    pub fn info(&self) -> &ModelInfo {
        &self.info
    }

    pub fn config(&self) -> &BackendConfig {
        &self.config
    }

    pub fn metrics(&self) -> MetricsSnapshot {
        self.metrics.snapshot()
    }

    /// Rows outstanding per inference thread: submitted, and their [`Pending`] not yet
    /// dropped.
    pub fn lane_loads(&self) -> Vec<usize> {
        self.lanes
            .iter()
            .map(|l| l.load.load(Ordering::Relaxed))
            .collect()
    }

    /// Queues one request. Invalid requests are refused here, before they reach the queue.
    pub fn submit(&self, req: SkeletonRequest) -> Result<Pending, InferError> {
        self.submit_many(vec![req]).map(|mut v| v.remove(0))
    }

    /// Queues requests together: they are admitted in the same iteration (as far as
    /// `max_batch` allows), so they share prefill and decode steps. Either all are queued
    /// or, when one is invalid, none.
    pub fn submit_many(&self, reqs: Vec<SkeletonRequest>) -> Result<Vec<Pending>, InferError> {
        let mut jobs = Vec::with_capacity(reqs.len());
        let mut pending = Vec::with_capacity(reqs.len());
        for (i, r) in reqs.into_iter().enumerate() {
            let (job, p) = self.validate(r).map_err(|e| match e {
                InferError::InvalidRequest(m) if i > 0 => {
                    InferError::InvalidRequest(format!("request {i}: {m}"))
                }
                e => e,
            })?;
            jobs.push(job);
            pending.push(p);
        }
        self.encode_here(&mut jobs)?;
        let n = jobs.len() as u64;
        let lane = self.least_loaded();
        let tx = lane.tx.as_ref().ok_or(InferError::BackendGone)?;
        tx.send(Command::Submit(jobs))
            .map_err(|_| InferError::BackendGone)?;
        lane.load.fetch_add(pending.len(), Ordering::Relaxed);
        for p in &mut pending {
            p.load = Some(lane.load.clone());
        }
        Metrics::add(&self.metrics.requests, n);
        Ok(pending)
    }

    /// The lane with the fewest rows outstanding.
    fn least_loaded(&self) -> &Lane {
        self.lanes
            .iter()
            .min_by_key(|l| l.load.load(Ordering::Relaxed))
            .expect("a backend has a lane")
    }

    /// The encoder's output (L, d) for the mesh `points`, computed on this thread: what
    /// [`Backend::teacher_forced`] reads, encoded once per mesh however many sequences it
    /// scores.
    pub fn encode(&self, points: &[[f32; 6]]) -> Result<Arc<Array2<f32>>, InferError> {
        if points.is_empty() || points.iter().flatten().any(|v| !v.is_finite()) {
            return Err(InferError::InvalidRequest(
                "points are empty or hold a non-finite value".into(),
            ));
        }
        self.encode_points(points)
    }

    /// Logits (T, V) at every position of `tokens` (a skeleton's sequence: `<bos>`, a class
    /// token, …) given the encoder's output `prefix` ([`Backend::encode`]): row `t` is the
    /// model's distribution of token `t + 1`. Runs on an inference thread between decode
    /// steps.
    pub fn teacher_forced(
        &self,
        prefix: &Arc<Array2<f32>>,
        tokens: Vec<u32>,
    ) -> Result<Array2<f32>, InferError> {
        if let Some(&t) = tokens.iter().find(|&&t| t as usize >= self.info.vocab_size) {
            return Err(InferError::InvalidRequest(format!(
                "token {t} is outside this model's vocabulary of {}",
                self.info.vocab_size
            )));
        }
        let (reply, rx) = channel();
        let lane = self.least_loaded();
        let tx = lane.tx.as_ref().ok_or(InferError::BackendGone)?;
        tx.send(Command::TeacherForced {
            prefix: prefix.clone(),
            tokens,
            reply,
        })
        .map_err(|_| InferError::BackendGone)?;
        rx.recv().map_err(|_| InferError::BackendGone)?
    }

    /// The encoder's output (L, d) for one point set, computed on this thread.
    fn encode_points(&self, pts: &[[f32; 6]]) -> Result<Arc<Array2<f32>>, InferError> {
        let mut x = Array3::<f32>::zeros((1, pts.len(), 6));
        for (k, p) in pts.iter().enumerate() {
            for (c, &v) in p.iter().enumerate() {
                x[[0, k, c]] = v;
            }
        }
        let t = Instant::now();
        let out = self
            .encoder
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .encode(&x)?;
        Metrics::add_time(&self.metrics.encode_ns, t);
        Metrics::add(&self.metrics.encode_calls, 1);
        Metrics::add(&self.metrics.encode_rows, 1);
        Ok(Arc::new(out.index_axis(Axis(0), 0).to_owned()))
    }

    /// Encodes each distinct point set of `jobs` on this thread (candidates of one mesh
    /// share one set, so one call).
    fn encode_here(&self, jobs: &mut [Job]) -> Result<(), InferError> {
        for i in 0..jobs.len() {
            if jobs[i].prefix.is_some() {
                continue;
            }
            let pts = jobs[i].points.clone();
            let prefix = self.encode_points(&pts)?;
            for j in jobs[i..]
                .iter_mut()
                .filter(|j| Arc::ptr_eq(&j.points, &pts))
            {
                j.prefix = Some(prefix.clone());
            }
        }
        Ok(())
    }

    /// Submits and waits.
    pub fn generate(&self, req: SkeletonRequest) -> Result<Generation, InferError> {
        self.submit(req)?.wait()
    }

    fn validate(&self, r: SkeletonRequest) -> Result<(Job, Pending), InferError> {
        let bad = |m: String| InferError::InvalidRequest(m);
        if r.points.is_empty() {
            return Err(bad("no points".into()));
        }
        if r.points.iter().flatten().any(|v| !v.is_finite()) {
            return Err(bad("points hold a non-finite value".into()));
        }
        r.sampling.validate().map_err(bad)?;
        if let Some(&t) = r
            .prompt
            .iter()
            .find(|&&t| t as usize >= self.info.vocab_size)
        {
            return Err(bad(format!(
                "prompt token {t} is outside this model's vocabulary of {}",
                self.info.vocab_size
            )));
        }
        let mut grammar = Grammar::from_prefix(r.max_bones, &r.prompt)
            .map_err(|e| bad(format!("prompt rejected: {e}")))?;
        if r.no_templates {
            grammar = grammar.without_templates();
        }
        if grammar.class_token().is_none() {
            return Err(bad(
                "the prompt must start with <bos> and a class token".into()
            ));
        }
        if grammar.is_done() {
            return Err(bad("the prompt already ends with <eos>".into()));
        }
        let model_max = self.info.max_tokens;
        let max_tokens = if r.max_tokens == 0 {
            model_max
        } else {
            r.max_tokens.min(model_max)
        };
        if r.prompt.len() >= max_tokens {
            return Err(bad(format!(
                "the prompt has {} tokens; at most {} fit with room to generate",
                r.prompt.len(),
                max_tokens - 1
            )));
        }
        if !r.ignore_eos {
            let need = completion_cost(&grammar).unwrap_or(usize::MAX);
            if need > max_tokens - r.prompt.len() {
                return Err(bad(format!(
                    "the prompt needs {need} more tokens to end but only {} fit in {max_tokens}",
                    max_tokens - r.prompt.len()
                )));
            }
        }
        let (reply, rx) = channel();
        let cancel = Arc::new(AtomicBool::new(false));
        Ok((
            Job {
                points: r.points,
                prompt: r.prompt,
                grammar,
                sampler: Sampler::new(r.sampling),
                max_tokens,
                ignore_eos: r.ignore_eos,
                reply,
                cancel: cancel.clone(),
                prefix: None,
            },
            Pending {
                rx,
                cancel,
                load: None,
            },
        ))
    }

    /// Stops the thread; queued and running requests fail with [`InferError::BackendGone`].
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        // Every channel first, so the lanes wind down together.
        for lane in &mut self.lanes {
            lane.tx.take();
        }
        for lane in &mut self.lanes {
            if let Some(t) = lane.thread.take() {
                let _ = t.join();
            }
        }
    }
}

impl Drop for Backend {
    fn drop(&mut self) {
        self.stop();
    }
}

/// A sequence being decoded. `tokens` ends with the token sampled last, which the cache
/// has not seen yet (it is the next step's input).
struct Item {
    tokens: Vec<u32>,
    prompt_len: usize,
    grammar: Grammar,
    sampler: Sampler,
    max_tokens: usize,
    ignore_eos: bool,
    reply: Sender<Result<Generation, InferError>>,
    cancel: Arc<AtomicBool>,
    /// Encoder output (L, d); kept only without a KV cache, which recomputes from it.
    prefix: Option<Arc<Array2<f32>>>,
}

impl Item {
    /// Samples the next token from this item's row of logits. `Some` when it finished.
    fn choose(&mut self, logits: ArrayView1<f32>) -> Result<Option<FinishReason>, InferError> {
        let mut l = logits.to_vec();
        let remaining = self.max_tokens - self.tokens.len();
        constrain_logits(&self.grammar, remaining, self.ignore_eos, &mut l);
        let step = self.tokens.len() - self.prompt_len;
        let tok = self
            .sampler
            .sample(&l)
            .ok_or(InferError::NoAllowedToken { step })?;
        self.grammar.advance(tok).map_err(|e| {
            InferError::run("sampling", format!("grammar refused its own choice: {e}"))
        })?;
        self.tokens.push(tok);
        Ok(if self.grammar.is_done() {
            Some(FinishReason::Eos)
        } else if self.tokens.len() >= self.max_tokens {
            Some(FinishReason::Length)
        } else {
            None
        })
    }

    fn last(&self) -> u32 {
        *self.tokens.last().expect("prompt is never empty")
    }
}

struct Worker {
    model: SkeletonModel,
    kv_cache: bool,
    max_batch: usize,
    rx: Receiver<Command>,
    waiting: VecDeque<Job>,
    running: Vec<Item>,
    /// Rows in `running` order; empty without a KV cache or when nothing runs.
    cache: DecodeCache,
    metrics: Arc<Metrics>,
    /// This lane's share of the `running` and `waiting` gauges, which add up the lanes.
    shown: (u64, u64),
}

impl Worker {
    fn run(mut self) {
        loop {
            if self.running.is_empty() && self.waiting.is_empty() {
                match self.rx.recv() {
                    Ok(cmd) => self.take(cmd),
                    Err(RecvError) => break,
                }
            }
            let mut closed = false;
            loop {
                match self.rx.try_recv() {
                    Ok(cmd) => self.take(cmd),
                    Err(std::sync::mpsc::TryRecvError::Empty) => break,
                    Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                        closed = true;
                        break;
                    }
                }
            }
            if closed {
                break;
            }
            self.drop_cancelled();
            self.admit();
            if !self.running.is_empty() {
                self.step();
            }
            self.gauges();
        }
        let gone = || Err(InferError::BackendGone);
        for job in self.waiting.drain(..) {
            let _ = job.reply.send(gone());
        }
        for item in self.running.drain(..) {
            let _ = item.reply.send(gone());
        }
    }

    fn take(&mut self, cmd: Command) {
        match cmd {
            Command::Submit(jobs) => self.waiting.extend(jobs),
            // Inline: one decoder call, no cache kept, so the running batch only waits.
            Command::TeacherForced {
                prefix,
                tokens,
                reply,
            } => {
                let _ = reply.send(self.model.teacher_forced(prefix.view(), &tokens));
            }
        }
        self.gauges();
    }

    fn gauges(&mut self) {
        let now = (self.running.len() as u64, self.waiting.len() as u64);
        // Wrapping adds of the change: the gauges are the sums over the lanes.
        let m = &self.metrics;
        m.running
            .fetch_add(now.0.wrapping_sub(self.shown.0), Ordering::Relaxed);
        m.waiting
            .fetch_add(now.1.wrapping_sub(self.shown.1), Ordering::Relaxed);
        self.shown = now;
    }

    /// Prefills as many waiting jobs as the batch has room for, together, and lets them
    /// join it.
    fn admit(&mut self) {
        let room = self.max_batch.saturating_sub(self.running.len());
        if room == 0 || self.waiting.is_empty() {
            return;
        }
        let n = room.min(self.waiting.len());
        let jobs: Vec<Job> = self.waiting.drain(..n).collect();
        match prefill::prepare(&mut self.model, &self.metrics, jobs) {
            Ok(p) => self.join(p),
            Err((jobs, e)) => fail_jobs(&self.metrics, jobs, e),
        }
    }

    fn drop_cancelled(&mut self) {
        let live = |c: &AtomicBool| !c.load(Ordering::Relaxed);
        let before = self.waiting.len();
        self.waiting.retain(|j| live(&j.cancel));
        let mut gone = (before - self.waiting.len()) as u64;
        let keep: Vec<usize> = (0..self.running.len())
            .filter(|&i| live(&self.running[i].cancel))
            .collect();
        if keep.len() < self.running.len() {
            gone += (self.running.len() - keep.len()) as u64;
            self.retain_rows(&keep);
        }
        Metrics::add(&self.metrics.cancelled, gone);
    }

    /// Keeps the running items (and cache rows) at `keep` (ascending). The cache may
    /// move rows to fill the gaps; the items follow it, so row `i` is always `running[i]`.
    fn retain_rows(&mut self, keep: &[usize]) {
        let mut slots: Vec<Option<Item>> = self.running.drain(..).map(Some).collect();
        let order = if self.kv_cache {
            let t = Instant::now();
            let order = self.cache.retain(keep);
            Metrics::add(&self.metrics.cache_rebuilds, 1);
            Metrics::add_time(&self.metrics.cache_ns, t);
            match order {
                Ok(o) => o,
                Err(e) => {
                    self.running = slots.into_iter().flatten().collect();
                    return self.fail_running(e);
                }
            }
        } else {
            keep.to_vec()
        };
        self.running = order
            .iter()
            .map(|&i| slots[i].take().expect("distinct rows"))
            .collect();
    }

    fn fail_running(&mut self, e: InferError) {
        Metrics::add(&self.metrics.failed, self.running.len() as u64);
        for item in self.running.drain(..) {
            let _ = item.reply.send(Err(e.clone()));
        }
        self.cache.retain(&[]).expect("empty keep list is valid");
    }

    /// Prefilled jobs join the batch: each samples its first token, and those still going
    /// copy their row of the prefill's cache into the running cache.
    fn join(&mut self, p: Prepared) {
        let (part, src) = (p.ready, p.cache);
        let kv = self.kv_cache;
        let rows: Vec<usize> = part.iter().map(|r| r.row).collect();
        let views: Vec<_> = part.iter().map(|r| r.logits.view()).collect();
        let logits = ndarray::stack(Axis(0), &views).expect("rows of one vocabulary");
        let mut items: Vec<Item> = part
            .into_iter()
            .map(|r| {
                let j = r.job;
                Item {
                    prompt_len: j.prompt.len(),
                    tokens: j.prompt,
                    grammar: j.grammar,
                    sampler: j.sampler,
                    max_tokens: j.max_tokens,
                    ignore_eos: j.ignore_eos,
                    reply: j.reply,
                    cancel: j.cancel,
                    prefix: if kv { None } else { j.prefix },
                }
            })
            .collect();
        let keep = self.sample_rows(&mut items, &logits);
        if keep.is_empty() {
            return;
        }
        let mut slots: Vec<Option<Item>> = items.into_iter().map(Some).collect();
        self.running.extend(
            keep.iter()
                .map(|&i| slots[i].take().expect("distinct rows")),
        );
        if kv {
            let t = Instant::now();
            let rows: Vec<usize> = keep.iter().map(|&i| rows[i]).collect();
            let joined = self.cache.append_rows(&src, &rows);
            Metrics::add(&self.metrics.cache_rebuilds, 1);
            Metrics::add_time(&self.metrics.cache_ns, t);
            if let Err(e) = joined {
                self.fail_running(e);
            }
        }
        let size = self.running.len() as u64;
        self.metrics
            .max_batch_seen
            .fetch_max(size, Ordering::Relaxed);
    }

    /// Samples one token for each item from its row of `logits`, replies to the items that
    /// finished or failed, and returns the rows still going.
    fn sample_rows(&self, items: &mut [Item], logits: &Array2<f32>) -> Vec<usize> {
        let mut keep = Vec::with_capacity(items.len());
        for (r, item) in items.iter_mut().enumerate() {
            match item.choose(logits.row(r)) {
                Ok(None) => keep.push(r),
                Ok(Some(finish)) => {
                    Metrics::add(&self.metrics.completed, 1);
                    Metrics::add(
                        &self.metrics.generated_tokens,
                        (item.tokens.len() - item.prompt_len) as u64,
                    );
                    let _ = item.reply.send(Ok(Generation {
                        tokens: std::mem::take(&mut item.tokens),
                        prompt_len: item.prompt_len,
                        finish,
                    }));
                }
                Err(e) => {
                    Metrics::add(&self.metrics.failed, 1);
                    let _ = item.reply.send(Err(e));
                }
            }
        }
        keep
    }

    fn step(&mut self) {
        let b = self.running.len();
        let t = Instant::now();
        let res = if self.kv_cache {
            let tokens: Vec<u32> = self.running.iter().map(Item::last).collect();
            Metrics::add(
                &self.metrics.decode_positions,
                self.cache.read_positions() as u64,
            );
            Metrics::add(
                &self.metrics.decode_real_positions,
                self.cache.real_positions() as u64,
            );
            self.cache.step(&mut self.model, &tokens)
        } else {
            let info = self.model.info();
            let mut stacked = Array3::<f32>::zeros((b, info.n_latents, info.d_model));
            for (j, item) in self.running.iter().enumerate() {
                if let Some(p) = &item.prefix {
                    stacked.index_axis_mut(Axis(0), j).assign(p.as_ref());
                }
            }
            let seqs: Vec<&[u32]> = self.running.iter().map(|i| i.tokens.as_slice()).collect();
            self.model.forward_full(&stacked, &seqs)
        };
        Metrics::add_time(&self.metrics.decode_ns, t);
        Metrics::add(&self.metrics.decode_steps, 1);
        Metrics::add(&self.metrics.decode_rows, b as u64);
        let logits = match res {
            Ok(l) => l,
            Err(e) => return self.fail_running(e),
        };
        let mut items = std::mem::take(&mut self.running);
        let keep = self.sample_rows(&mut items, &logits);
        self.running = items;
        if keep.len() < b {
            self.retain_rows(&keep);
        }
    }
}

fn fail_jobs(metrics: &Metrics, jobs: Vec<Job>, e: InferError) {
    Metrics::add(&metrics.failed, jobs.len() as u64);
    for j in jobs {
        let _ = j.reply.send(Err(e.clone()));
    }
}
