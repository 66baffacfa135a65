//! The service as one value: `Application::build(config)` opens the store and blobs,
//! loads the models, binds the listener and starts workers and the sweeper;
//! `run_until_stopped` serves until a shutdown signal and then drains in order.

use crate::api::auth::{ApiKeys, KeysError};
use crate::api::metrics::{DecodeMetrics, HttpMetrics};
use crate::api::{router, ApiConfig, AppState, SnapshotFn};
use crate::infer::SkinModel;
use crate::infer::{
    Backend, BackendConfig, InferError, ModelFiles, Runtime, SessionConfig, SkeletonModel, Variant,
};
use crate::jobs::pipeline::Engine;
use crate::jobs::slots::CpuSlots;
use crate::jobs::sql::SqlStore;
use crate::jobs::sweeper::{self, SweeperConfig};
use crate::jobs::webhook::WebhookError;
use crate::jobs::worker::{self, WorkerConfig};
use crate::jobs::{
    BlobError, Blobs, Context, JobMetrics, JobStore, Notifier, StoreError, Webhooks,
};
use crate::mesh::Limits;
use crate::predict::library::{Library, LibraryError};
use crate::rig::skin::SkinConfig;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tracing::info;

/// Where the skeleton model comes from.
#[derive(Clone, Debug)]
pub struct ModelSetup {
    pub dir: PathBuf,
    pub variant: Variant,
    pub ort_lib: Option<PathBuf>,
    pub threads: usize,
    /// Most sequences in one decode batch (all jobs' candidates together).
    pub max_batch: usize,
    /// Use the ragged decode step when the model has one ([`BackendConfig::ragged`]).
    pub ragged: bool,
    /// The inference thread's nice value ([`BackendConfig::nice`]).
    pub decode_nice: i32,
    /// Inference threads ([`Backend::with_lanes`]); at least one.
    pub decode_lanes: usize,
    /// Skeleton library file whose entries join the model's candidates
    /// ([`crate::predict::library`]); `None`: the model alone.
    pub library: Option<PathBuf>,
}

impl ModelSetup {
    /// Two inference threads where there are two cores: on a 2-core server under load the
    /// second decodes on the core that otherwise idles while every job waits for its
    /// skeleton (README, "An Intel Xeon": 32 clients +6.4 % jobs/min, 10 of 14 pairs).
    pub fn default_decode_lanes() -> usize {
        std::thread::available_parallelism().map_or(1, |n| n.get().min(2))
    }
}

/// What this process does: everything, only the HTTP API, or only the workers (with a
/// health/metrics listener), so API and worker replicas scale separately.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Role {
    All,
    Api,
    Worker,
}

#[derive(Clone, Debug)]
pub struct Config {
    pub bind: SocketAddr,
    pub role: Role,
    /// `postgres://…` for the shared job store; `None`: SQLite in `data_dir`.
    pub database_url: Option<String>,
    pub db_max_connections: u32,
    /// `s3://bucket/prefix` or `file:///dir`; `None`: files under `data_dir/blobs`.
    pub blob_url: Option<String>,
    /// Holds `rigserve.db`, `blobs/` and `tmp/`.
    pub data_dir: PathBuf,
    /// `None`: no skeleton model; only `skin_only` jobs are accepted.
    pub model: Option<ModelSetup>,
    pub limits: Limits,
    pub sync_max_bytes: u64,
    pub sync_timeout: Duration,
    pub request_timeout: Duration,
    pub upload_timeout: Duration,
    pub workers: usize,
    /// Jobs skinning and exporting at once (`CpuSlots`); 0: one core fewer than the
    /// machine has.
    pub cpu_jobs: usize,
    pub max_queued: u64,
    pub lease: Duration,
    pub poll: Duration,
    pub result_ttl: Duration,
    pub drain: Duration,
    pub max_attempts: u32,
    pub sweep_every: Duration,
    pub max_samples: usize,
    pub max_bones: usize,
    pub api_keys_file: Option<PathBuf>,
    pub webhook_secret: Option<String>,
    pub webhook_attempts: u32,
    pub webhook_first_delay: Duration,
    /// Let webhooks go to loopback and private addresses (off: only public ones).
    pub webhook_allow_private: bool,
    /// Origins allowed cross-origin access from browsers (`*` for any); empty: CORS off.
    pub cors_origins: Vec<String>,
}

impl Config {
    /// Defaults for a 2-core machine, serving on `bind` from `data_dir`.
    pub fn new(bind: SocketAddr, data_dir: PathBuf) -> Config {
        Config {
            bind,
            role: Role::All,
            database_url: None,
            db_max_connections: 10,
            blob_url: None,
            data_dir,
            model: None,
            limits: Limits::default(),
            sync_max_bytes: 32 << 20,
            sync_timeout: Duration::from_secs(120),
            request_timeout: Duration::from_secs(30),
            upload_timeout: Duration::from_secs(300),
            workers: 8,
            cpu_jobs: 0,
            max_queued: 1000,
            lease: Duration::from_secs(30),
            poll: Duration::from_millis(500),
            result_ttl: Duration::from_secs(24 * 3600),
            drain: Duration::from_secs(20),
            max_attempts: 3,
            sweep_every: Duration::from_secs(5),
            max_samples: 8,
            max_bones: 128,
            api_keys_file: None,
            webhook_secret: None,
            webhook_attempts: 6,
            webhook_first_delay: Duration::from_secs(1),
            webhook_allow_private: false,
            cors_origins: Vec::new(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum AppError {
    #[error("data directory {0}: {1}")]
    DataDir(String, std::io::Error),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Blobs(#[from] BlobError),
    #[error("skeleton model: {0}")]
    Model(#[from] InferError),
    #[error(transparent)]
    Library(#[from] LibraryError),
    #[error(transparent)]
    Keys(#[from] KeysError),
    #[error(transparent)]
    Cors(#[from] crate::api::cors::BadOrigin),
    #[error(transparent)]
    Webhook(#[from] WebhookError),
    #[error("metrics: {0}")]
    Metrics(#[from] prometheus::Error),
    #[error("binding {0}: {1}")]
    Bind(SocketAddr, std::io::Error),
}

impl AppError {
    pub fn code(&self) -> &'static str {
        match self {
            AppError::DataDir(..) => "data_dir",
            AppError::Store(e) => e.code(),
            AppError::Blobs(e) => e.code(),
            AppError::Model(e) => e.code(),
            AppError::Library(e) => e.code(),
            AppError::Keys(_) => "api_keys_file",
            AppError::Cors(_) => "cors_origin_invalid",
            AppError::Webhook(e) => e.code(),
            AppError::Metrics(_) => "metrics",
            AppError::Bind(..) => "bind",
        }
    }
}

pub struct Application {
    listener: TcpListener,
    router: axum::Router,
    shutdown: CancellationToken,
    tasks: Vec<tokio::task::JoinHandle<()>>,
    /// Kept so the inference thread lives as long as the server.
    _engine: Arc<Engine>,
}

/// The skeleton model's inference thread, and the learned skin model when the models
/// folder has one (`skin/`; geometric weights otherwise).
fn load_models(m: &ModelSetup) -> Result<(Backend, Option<SkinModel>), AppError> {
    let rt = Runtime::init(m.ort_lib.as_deref())?;
    let session = SessionConfig {
        intra_threads: m.threads,
    };
    let files = ModelFiles::in_dir(&m.dir, m.variant);
    let models = (0..m.decode_lanes.max(1))
        .map(|_| SkeletonModel::load(&rt, &files, &session))
        .collect::<Result<Vec<_>, _>>()?;
    let skin = SkinModel::load_if_present(&rt, &m.dir, &session)?;
    let backend = Backend::with_lanes(
        models,
        BackendConfig {
            max_batch: m.max_batch,
            kv_cache: true,
            ragged: m.ragged,
            nice: m.decode_nice,
        },
    )?;
    Ok((backend, skin))
}

impl Application {
    pub async fn build(cfg: Config) -> Result<Application, AppError> {
        // Settings first: a bad one fails before anything is opened.
        let cors = crate::api::cors::Origins::parse(&cfg.cors_origins)?;
        let dir_err = |e| AppError::DataDir(cfg.data_dir.display().to_string(), e);
        let tmp_dir = cfg.data_dir.join("tmp");
        std::fs::create_dir_all(&tmp_dir).map_err(dir_err)?;

        let (store, embedded) = match &cfg.database_url {
            Some(url) => (
                SqlStore::open_postgres(url, cfg.db_max_connections).await?,
                false,
            ),
            None => (
                SqlStore::open_sqlite(&cfg.data_dir.join("rigserve.db")).await?,
                true,
            ),
        };
        if embedded {
            // One process owns the embedded store: whatever was running when it stopped
            // (crash, kill -9) has no worker any more. A shared store waits for leases to
            // run out instead (the sweeper), since other replicas may be running them.
            let recovered = store.recover(true, cfg.max_attempts).await?;
            if recovered > 0 {
                info!(
                    jobs = recovered,
                    "re-queued jobs left running by the previous process"
                );
            }
        }
        let blobs = match &cfg.blob_url {
            Some(url) => Blobs::from_url(url)?,
            None => Blobs::local(&cfg.data_dir.join("blobs"))?,
        };

        let registry = prometheus::Registry::new();
        let job_metrics = JobMetrics::new(&registry)?;
        let http_metrics = HttpMetrics::new(&registry)?;
        let runs_jobs = cfg.role != Role::Api;
        let (backend, skin_model, library) = match (&cfg.model, runs_jobs) {
            (Some(m), true) => {
                let (b, s) = load_models(m)?;
                let lib = m.library.as_deref().map(Library::load).transpose()?;
                if let Some(l) = &lib {
                    info!(entries = l.entries.len(), "skeleton library loaded");
                }
                (Some(b), s, lib.map(Arc::new))
            }
            _ => (None, None, None),
        };
        if runs_jobs {
            info!(
                learned = skin_model.is_some(),
                "skin weights: {}",
                if skin_model.is_some() {
                    "learned model"
                } else {
                    "geometric"
                }
            );
        }
        let keys = match &cfg.api_keys_file {
            Some(p) => ApiKeys::from_file(p)?,
            None => ApiKeys::disabled(),
        };
        let webhooks = Webhooks::new(
            cfg.webhook_secret.as_deref(),
            cfg.webhook_attempts,
            cfg.webhook_first_delay,
            job_metrics.clone(),
            cfg.webhook_allow_private,
        )?;
        let ctx = Context {
            store: Arc::new(store) as Arc<dyn JobStore>,
            blobs,
            notifier: Notifier::default(),
            metrics: job_metrics,
            webhooks: Some(webhooks),
        };
        // An API replica accepts predictions when the cluster has a model (its workers
        // load it); a process that runs jobs accepts them when it loaded one.
        let accepts_predictions = cfg.model.is_some();
        let skeleton_model = backend.is_some();
        let engine = Arc::new(Engine {
            skeleton: backend,
            limits: cfg.limits,
            skin: SkinConfig::default(),
            skin_model,
            library,
            max_samples: cfg.max_samples,
            max_bones: cfg.max_bones,
            cpu_slots: CpuSlots::new(match cfg.cpu_jobs {
                0 => CpuSlots::default_permits(),
                n => n,
            }),
        });
        let (decode, engine_metrics) = if skeleton_model {
            let e = engine.clone();
            let f: SnapshotFn =
                Arc::new(move || e.skeleton.as_ref().map(|b| b.metrics()).unwrap_or_default());
            (Some(DecodeMetrics::new(&registry)?), Some(f))
        } else {
            (None, None)
        };

        let shutdown = CancellationToken::new();
        let instance = format!("{}-{}", std::process::id(), &crate::jobs::new_job_id()[..8]);
        let mut tasks = worker::spawn(
            ctx.clone(),
            engine.clone(),
            WorkerConfig {
                workers: if runs_jobs { cfg.workers } else { 0 },
                lease: cfg.lease,
                poll: cfg.poll,
                result_ttl: cfg.result_ttl,
                drain: cfg.drain,
            },
            &instance,
            shutdown.clone(),
        );
        tasks.push(sweeper::spawn(
            ctx.clone(),
            SweeperConfig {
                every: cfg.sweep_every,
                max_attempts: cfg.max_attempts,
            },
            shutdown.clone(),
        ));

        let state = AppState {
            ctx,
            keys,
            cfg: Arc::new(ApiConfig {
                limits: cfg.limits,
                sync_max_bytes: cfg.sync_max_bytes.min(cfg.limits.max_bytes),
                sync_timeout: cfg.sync_timeout,
                max_queued: cfg.max_queued,
                queue_full_retry_after: 5,
                result_ttl: cfg.result_ttl,
                poll: cfg.poll,
                max_samples: cfg.max_samples,
                max_bones: cfg.max_bones,
                skeleton_model: accepts_predictions,
                tmp_dir,
                request_timeout: cfg.request_timeout,
                upload_timeout: cfg.upload_timeout,
                webhook_allow_private: cfg.webhook_allow_private,
                cors,
            }),
            registry,
            decode,
            engine_metrics,
            shutdown: shutdown.clone(),
        };
        let router = match cfg.role {
            Role::Worker => crate::api::health_router(state, http_metrics),
            Role::All | Role::Api => router(state, http_metrics),
        };
        let listener = TcpListener::bind(cfg.bind)
            .await
            .map_err(|e| AppError::Bind(cfg.bind, e))?;
        Ok(Application {
            listener,
            router,
            shutdown,
            tasks,
            _engine: engine,
        })
    }

    pub fn port(&self) -> u16 {
        self.listener.local_addr().map(|a| a.port()).unwrap_or(0)
    }

    /// Cancel it to shut the server down as a signal would.
    pub fn shutdown_token(&self) -> CancellationToken {
        self.shutdown.clone()
    }

    /// Serves until `shutdown_token()` is canceled or the process gets SIGINT/SIGTERM.
    ///
    /// Order: stop accepting connections and end SSE streams (the token), let in-flight
    /// requests finish, then wait for the workers, which finish or re-queue their jobs
    /// within the drain time.
    pub async fn run_until_stopped(self) -> std::io::Result<()> {
        let token = self.shutdown.clone();
        tokio::spawn({
            let token = token.clone();
            async move {
                shutdown_signal().await;
                info!("shutdown signal: draining");
                token.cancel();
            }
        });
        let served = crate::api::listener::serve(self.listener, self.router, token.clone()).await;
        token.cancel();
        for t in self.tasks {
            let _ = t.await;
        }
        info!("stopped");
        served
    }
}

async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = term => {}
    }
}
