//! `rigserve serve`: the HTTP service (embedded SQLite + local blobs under `--data-dir`).

use super::rig::ModelArgs;
use super::LimitArgs;
use rigserve::app::{Application, Config, ModelSetup, Role};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

fn secs(s: &str) -> Result<Duration, String> {
    s.parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0)
        .map(Duration::from_secs_f64)
        .ok_or_else(|| format!("{s:?} is not a number of seconds"))
}

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "RIGSERVE_BIND", default_value = "127.0.0.1:8080")]
    pub bind: SocketAddr,
    /// all: API and workers; api: the HTTP API only; worker: workers, with /healthz,
    /// /readyz and /metrics on --bind.
    #[arg(long, env = "RIGSERVE_ROLE", value_enum, default_value = "all")]
    pub role: Role,
    /// PostgreSQL for jobs (`postgres://user:pass@host/db`); default: SQLite in --data-dir.
    #[arg(long, env = "RIGSERVE_DATABASE_URL", hide_env_values = true)]
    pub database_url: Option<String>,
    /// Connections per process to --database-url.
    #[arg(long, env = "RIGSERVE_DB_MAX_CONNECTIONS", default_value_t = 10)]
    pub db_max_connections: u32,
    /// Blobs in S3 (`s3://bucket/prefix`; AWS_ENDPOINT_URL, AWS_REGION, AWS_ACCESS_KEY_ID,
    /// AWS_SECRET_ACCESS_KEY from the environment) or `file:///dir`; default: --data-dir.
    #[arg(long, env = "RIGSERVE_BLOB_URL")]
    pub blob_url: Option<String>,
    /// Jobs database, blobs and spooled uploads live here.
    #[arg(long, env = "RIGSERVE_DATA_DIR", default_value = "data")]
    pub data_dir: PathBuf,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Run without a skeleton model (only `skin_only` jobs are accepted).
    #[arg(long, env = "RIGSERVE_NO_SKELETON_MODEL")]
    pub no_skeleton_model: bool,
    /// Most candidate sequences decoded together, across all jobs.
    #[arg(long, env = "RIGSERVE_MAX_BATCH", default_value_t = 32)]
    pub max_batch: usize,
    /// Nice value of the inference thread (-20..19; 0: the process's). High by default:
    /// under load the jobs' own CPU work goes first and their skeleton candidates wait
    /// for each other to share decode steps; with a core free it changes nothing.
    #[arg(long, env = "RIGSERVE_DECODE_NICE", default_value_t = 19,
          value_parser = clap::value_parser!(i32).range(-20..=19))]
    pub decode_nice: i32,
    /// Inference threads, each decoding its own batch of skeleton candidates (default: 2,
    /// or 1 on a single core). The second uses the core that idles while every running
    /// job waits for its skeleton, at the price of smaller batches.
    #[arg(long, env = "RIGSERVE_DECODE_LANES",
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=8))]
    pub decode_lanes: Option<usize>,
    #[command(flatten)]
    pub limits: LimitArgs,
    /// Largest upload for the synchronous `POST /v1/rig`, in bytes.
    #[arg(long, env = "RIGSERVE_SYNC_MAX_BYTES", default_value_t = 32 << 20)]
    pub sync_max_bytes: u64,
    /// Seconds `POST /v1/rig` waits before answering 504 (the job goes on).
    #[arg(long, env = "RIGSERVE_SYNC_TIMEOUT", default_value = "120", value_parser = secs)]
    pub sync_timeout: Duration,
    /// Seconds allowed for requests other than uploads and streams.
    #[arg(long, env = "RIGSERVE_REQUEST_TIMEOUT", default_value = "30", value_parser = secs)]
    pub request_timeout: Duration,
    /// Seconds allowed for an upload to `POST /v1/jobs`.
    #[arg(long, env = "RIGSERVE_UPLOAD_TIMEOUT", default_value = "300", value_parser = secs)]
    pub upload_timeout: Duration,
    /// Jobs run at once (their skeleton candidates share decode batches); 0 runs no
    /// worker in this process (API only).
    #[arg(long, env = "RIGSERVE_WORKERS", default_value_t = 8)]
    pub workers: usize,
    /// Of those, jobs skinning and exporting at once (CPU-bound); 0: as many as the
    /// machine has cores.
    #[arg(long, env = "RIGSERVE_CPU_JOBS", default_value_t = 0)]
    pub cpu_jobs: usize,
    /// Queued jobs at most; more get 429.
    #[arg(long, env = "RIGSERVE_MAX_QUEUED", default_value_t = 1000)]
    pub max_queued: u64,
    /// Seconds a job's lease lasts without a heartbeat.
    #[arg(long, env = "RIGSERVE_LEASE", default_value = "30", value_parser = secs)]
    pub lease: Duration,
    /// Seconds between store polls of idle workers and waiting streams.
    #[arg(long, env = "RIGSERVE_POLL", default_value = "0.5", value_parser = secs)]
    pub poll: Duration,
    /// Seconds results are kept (then 410 and deleted).
    #[arg(long, env = "RIGSERVE_RESULT_TTL", default_value = "86400", value_parser = secs)]
    pub result_ttl: Duration,
    /// Seconds shutdown waits for running jobs before re-queueing them.
    #[arg(long, env = "RIGSERVE_DRAIN", default_value = "20", value_parser = secs)]
    pub drain: Duration,
    /// A job whose worker stopped this many times fails.
    #[arg(long, env = "RIGSERVE_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,
    /// Seconds between sweeps (lease recovery, expiry).
    #[arg(long, env = "RIGSERVE_SWEEP_EVERY", default_value = "5", value_parser = secs)]
    pub sweep_every: Duration,
    /// Most skeleton candidates a job may ask for.
    #[arg(long, env = "RIGSERVE_MAX_SAMPLES", default_value_t = 8)]
    pub max_samples: usize,
    /// Most bones a job may ask for.
    #[arg(long, env = "RIGSERVE_MAX_BONES", default_value_t = 128)]
    pub max_bones: usize,
    /// API keys, one per line (`name:key`); without it the API is open.
    #[arg(long, env = "RIGSERVE_API_KEYS_FILE")]
    pub api_keys_file: Option<PathBuf>,
    /// `whsec_…` secret that signs webhooks.
    #[arg(long, env = "RIGSERVE_WEBHOOK_SECRET", hide_env_values = true)]
    pub webhook_secret: Option<String>,
    /// Delivery attempts per webhook.
    #[arg(long, env = "RIGSERVE_WEBHOOK_ATTEMPTS", default_value_t = 6)]
    pub webhook_attempts: u32,
    /// Let `webhook_url` name loopback and private-network addresses (a local receiver
    /// while testing). Off, webhooks go only to public addresses, so clients cannot make
    /// the server call into its own network.
    #[arg(long, env = "RIGSERVE_WEBHOOK_ALLOW_PRIVATE")]
    pub webhook_allow_private: bool,
    /// Let browser pages from this origin (`http://host:port`, or `*`) call the API:
    /// repeatable, or comma-separated in the env. Off when unset.
    #[arg(
        long = "cors-origin",
        env = "RIGSERVE_CORS_ORIGINS",
        value_delimiter = ','
    )]
    pub cors_origins: Vec<String>,
    /// Log as JSON lines.
    #[arg(long, env = "RIGSERVE_LOG_JSON")]
    pub log_json: bool,
}

fn init_logs(json: bool) {
    let filter = tracing_subscriber::EnvFilter::try_from_env("RIGSERVE_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,sqlx=warn"));
    let b = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    if json {
        b.json().with_current_span(true).with_span_list(true).init();
    } else {
        b.init();
    }
}

pub fn run(a: ServeArgs) -> anyhow::Result<()> {
    init_logs(a.log_json);
    let mut cfg = Config::new(a.bind, a.data_dir.clone());
    cfg.role = a.role;
    cfg.database_url = a.database_url.clone();
    cfg.db_max_connections = a.db_max_connections;
    cfg.blob_url = a.blob_url.clone();
    cfg.model = (!a.no_skeleton_model).then(|| ModelSetup {
        dir: a.model.models.clone(),
        variant: a.model.variant,
        ort_lib: a.model.ort_lib.clone(),
        threads: a.model.threads,
        max_batch: a.max_batch,
        ragged: !a.model.dense_decode,
        decode_nice: a.decode_nice,
        decode_lanes: a
            .decode_lanes
            .unwrap_or_else(ModelSetup::default_decode_lanes),
        library: a.model.library_path(),
    });
    cfg.limits = a.limits.limits();
    cfg.sync_max_bytes = a.sync_max_bytes;
    cfg.sync_timeout = a.sync_timeout;
    cfg.request_timeout = a.request_timeout;
    cfg.upload_timeout = a.upload_timeout;
    cfg.workers = a.workers;
    cfg.cpu_jobs = a.cpu_jobs;
    cfg.max_queued = a.max_queued;
    cfg.lease = a.lease;
    cfg.poll = a.poll;
    cfg.result_ttl = a.result_ttl;
    cfg.drain = a.drain;
    cfg.max_attempts = a.max_attempts;
    cfg.sweep_every = a.sweep_every;
    cfg.max_samples = a.max_samples;
    cfg.max_bones = a.max_bones;
    cfg.api_keys_file = a.api_keys_file.clone();
    cfg.webhook_secret = a.webhook_secret.clone();
    cfg.webhook_attempts = a.webhook_attempts;
    cfg.webhook_allow_private = a.webhook_allow_private;
    cfg.cors_origins = a.cors_origins.clone();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let app = Application::build(cfg)
            .await
            .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
        // Tests and scripts read this line to find the port (with --bind 127.0.0.1:0).
        println!(
            "rigserve listening on http://{}:{}",
            a.bind.ip(),
            app.port()
        );
        tracing::info!(port = app.port(), data_dir = %a.data_dir.display(), "listening");
        app.run_until_stopped().await?;
        Ok(())
    })
}
