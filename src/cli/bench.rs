//! `rigserve bench`: decoder throughput per batch size, with and without the KV cache,
//! the end-to-end time of one skeleton prediction, and the time of geometric skinning.

use super::rig::ModelArgs;
use super::LimitArgs;
use anyhow::Context;
use rigserve::infer::{Backend, BackendConfig, MetricsSnapshot, SamplingParams, SkeletonRequest};
use rigserve::mesh::{self, sample::SplitMix64};
use rigserve::predict::{predict_from_samples, samples_for, PredictConfig, MODEL_POINTS};
use rigserve::rig::groundtruth::extract;
use rigserve::rig::skin::{skin_with_timed, CandidateScorer, SkinTimings};
use rigserve::rig::tokenizer::{BOS, CLS_NONE};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Decode throughput: every item runs exactly --tokens steps (`<eos>` is masked, the
    /// token grammar still applies), so batch sizes compare like for like.
    Decode(DecodeArgs),
    /// One mesh end to end: sampling, encoder, best-of-N decode, scoring.
    Skeleton(SkeletonArgs),
    /// Geometric skinning of one rigged mesh with its own skeleton: voxelization,
    /// geodesic distances and weights, timed separately.
    Skin(SkinArgs),
    /// A full `rigserve rig`, whole process, on one mesh subdivided to several sizes:
    /// wall time and peak memory by mesh size.
    Rig(super::bench_rig::RigArgs),
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// With the KV cache.
    Kv,
    /// Recomputing the whole sequence every step.
    Recompute,
    Both,
}

#[derive(clap::Args, Debug)]
pub struct DecodeArgs {
    /// Batch sizes to measure.
    #[arg(long, value_delimiter = ',', default_value = "1,8,16,32")]
    pub batch: Vec<usize>,
    /// Generated tokens per item.
    #[arg(long, default_value_t = 256)]
    pub tokens: usize,
    #[arg(long, value_enum, default_value_t = Mode::Both)]
    pub mode: Mode,
    /// Shorthand for `--mode recompute`.
    #[arg(long)]
    pub no_kv_cache: bool,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub model: ModelArgs,
}

#[derive(clap::Args, Debug)]
pub struct SkeletonArgs {
    #[arg(long)]
    pub mesh: PathBuf,
    /// Candidates (best-of-N).
    #[arg(long, default_value_t = 4)]
    pub samples: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Timed runs after one warm-up run.
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub limits: LimitArgs,
}

#[derive(clap::Args, Debug)]
pub struct SkinArgs {
    /// A rigged file (its skeleton is skinned); the default is a ~22k-vertex, 49-bone
    /// artist rig of the data set.
    #[arg(long, default_value = "../shared/rigs/modular_men__King.glb")]
    pub input: PathBuf,
    /// Timed runs after one warm-up run.
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub skin: super::rig::SkinArgs,
    /// The ONNX Runtime library, for the learned skin model.
    #[arg(long, env = "RIGSERVE_ORT_LIB")]
    pub ort_lib: Option<PathBuf>,
    #[command(flatten)]
    pub limits: LimitArgs,
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Decode(a) => decode(a),
        BenchCommand::Skeleton(a) => skeleton(a),
        BenchCommand::Skin(a) => skin(a),
        BenchCommand::Rig(a) => super::bench_rig::run(a),
    }
}

#[derive(Serialize)]
struct SkinReport {
    input: String,
    vertices: usize,
    triangles: usize,
    bones: usize,
    voxels: usize,
    method: &'static str,
    runs: Vec<SkinTimings>,
    mean: SkinTimings,
    mean_total_ms: f64,
}

fn skin(a: SkinArgs) -> anyhow::Result<()> {
    let bytes =
        std::fs::read(&a.input).with_context(|| format!("reading {}", a.input.display()))?;
    let asset = mesh::load(&bytes, &a.limits.limits())
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let skeleton = extract(&asset)
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?
        .ok_or_else(|| anyhow::anyhow!("{} has no skeleton [no_skin]", a.input.display()))?
        .skeleton;
    let cfg = a.skin.config();
    let model = a.skin.load_model(a.ort_lib.as_deref())?;
    let mut runs = Vec::new();
    for r in 0..=a.repeat {
        let (_, t) = skin_with_timed(
            &asset.mesh,
            &skeleton,
            &cfg,
            model.as_ref().map(|m| m as &dyn CandidateScorer),
        )
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
        if r > 0 {
            runs.push(t);
        }
    }
    let n = runs.len().max(1) as f64;
    let mean = SkinTimings {
        voxelize_ms: runs.iter().map(|t| t.voxelize_ms).sum::<f64>() / n,
        geodesic_ms: runs.iter().map(|t| t.geodesic_ms).sum::<f64>() / n,
        weights_ms: runs.iter().map(|t| t.weights_ms).sum::<f64>() / n,
        model_ms: runs.iter().map(|t| t.model_ms).sum::<f64>() / n,
        ..runs.last().copied().unwrap_or_default()
    };
    let report = SkinReport {
        input: a.input.display().to_string(),
        vertices: asset.mesh.positions.len(),
        triangles: asset.mesh.triangles.len(),
        bones: skeleton.len(),
        voxels: cfg.resolution,
        method: if model.is_some() {
            "learned"
        } else {
            "geometric"
        },
        runs,
        mean,
        mean_total_ms: mean.voxelize_ms + mean.geodesic_ms + mean.model_ms + mean.weights_ms,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        eprintln!(
            "{}: {} vertices, {} bones, {}: {:.1} ms (voxelize {:.1}, geodesic {:.1}, model {:.1}, weights {:.1}; {} solid voxels, {} parts)",
            report.input, report.vertices, report.bones, report.method, report.mean_total_ms, mean.voxelize_ms,
            mean.geodesic_ms, mean.model_ms, mean.weights_ms, mean.solid_cells, mean.parts
        );
    }
    Ok(())
}

#[derive(Serialize)]
struct DecodeRow {
    mode: &'static str,
    batch: usize,
    tokens: usize,
    decode_steps: u64,
    ms_per_step: f64,
    /// Tokens from decode steps per second of decode time.
    decode_tokens_per_s: f64,
    prefill_ms: f64,
    wall_ms: f64,
    /// All generated tokens per second of wall time (prefill and encoder included).
    tokens_per_s: f64,
}

#[derive(Serialize)]
struct Speedup {
    batch: usize,
    /// KV tokens/s over recompute tokens/s (wall time).
    kv_over_recompute: f64,
}

#[derive(Serialize)]
struct DecodeReport {
    models: String,
    model: rigserve::infer::ModelInfo,
    intra_threads: usize,
    tokens: usize,
    results: Vec<DecodeRow>,
    speedup: Vec<Speedup>,
}

fn random_points(seed: u64) -> Arc<[[f32; 6]]> {
    let mut rng = SplitMix64::new(seed);
    (0..MODEL_POINTS)
        .map(|_| {
            let p = [0; 3].map(|_| rng.next_f32() * 2.0 - 1.0);
            let n = rng.unit_vec3();
            [p[0], p[1], p[2], n.x, n.y, n.z]
        })
        .collect::<Vec<_>>()
        .into()
}

/// Runs `batch` forced-length items together; returns the metrics delta and wall time.
fn run_batch(
    backend: &Backend,
    points: &Arc<[[f32; 6]]>,
    batch: usize,
    tokens: usize,
    seed: u64,
) -> anyhow::Result<(MetricsSnapshot, f64)> {
    let reqs = (0..batch as u64)
        .map(|k| SkeletonRequest {
            points: points.clone(),
            prompt: vec![BOS, CLS_NONE],
            sampling: SamplingParams {
                temperature: 1.0,
                top_k: 0,
                top_p: 1.0,
                seed: seed.wrapping_add(k),
            },
            max_bones: usize::MAX,
            max_tokens: 2 + tokens,
            no_templates: false,
            ignore_eos: true,
        })
        .collect();
    let before = backend.metrics();
    let t = Instant::now();
    let pending = backend
        .submit_many(reqs)
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    for p in pending {
        let g = p
            .wait()
            .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
        anyhow::ensure!(
            g.generated().len() == tokens,
            "an item stopped after {} of {tokens} tokens",
            g.generated().len()
        );
    }
    let wall = t.elapsed().as_secs_f64() * 1e3;
    Ok((backend.metrics().since(&before), wall))
}

fn decode(a: DecodeArgs) -> anyhow::Result<()> {
    let mode = if a.no_kv_cache {
        Mode::Recompute
    } else {
        a.mode
    };
    anyhow::ensure!(a.tokens >= 1, "--tokens must be at least 1");
    anyhow::ensure!(
        a.batch.iter().all(|&b| b >= 1),
        "batch sizes must be at least 1"
    );
    let max_batch = a.batch.iter().copied().max().unwrap_or(1);
    let modes: Vec<(bool, &'static str)> = match mode {
        Mode::Kv => vec![(true, "kv")],
        Mode::Recompute => vec![(false, "recompute")],
        Mode::Both => vec![(true, "kv"), (false, "recompute")],
    };
    let points = random_points(a.seed);
    let mut rows = Vec::new();
    let mut info = None;
    for (kv, name) in modes {
        let backend = a.model.backend(BackendConfig {
            max_batch,
            kv_cache: kv,
            ragged: true,
            ..BackendConfig::default()
        })?;
        anyhow::ensure!(
            a.tokens + 2 <= backend.info().max_tokens,
            "--tokens {} does not fit the model's {} tokens (prompt of 2 included)",
            a.tokens,
            backend.info().max_tokens
        );
        info = Some(backend.info().clone());
        // The first calls pay for ONNX Runtime's lazy initialization.
        run_batch(&backend, &points, 1, a.tokens.min(8), a.seed)?;
        for &b in &a.batch {
            let (m, wall) = run_batch(&backend, &points, b, a.tokens, a.seed)?;
            let row = DecodeRow {
                mode: name,
                batch: b,
                tokens: a.tokens,
                decode_steps: m.decode_steps,
                ms_per_step: m.ms_per_step(),
                decode_tokens_per_s: m.decode_tokens_per_s(),
                prefill_ms: m.prefill_ns as f64 / 1e6,
                wall_ms: wall,
                tokens_per_s: (b * a.tokens) as f64 / (wall / 1e3),
            };
            if !a.json {
                eprintln!(
                    "{:>9} batch {:>3}: {:>9.1} tokens/s ({:>9.1} decode), {:>8.3} ms/step, prefill {:.1} ms, {:.0} ms",
                    name, b, row.tokens_per_s, row.decode_tokens_per_s, row.ms_per_step, row.prefill_ms, wall
                );
            }
            rows.push(row);
        }
    }
    let speedup: Vec<Speedup> = a
        .batch
        .iter()
        .filter_map(|&b| {
            let get = |m: &str| {
                rows.iter()
                    .find(|r| r.mode == m && r.batch == b)
                    .map(|r| r.tokens_per_s)
            };
            Some(Speedup {
                batch: b,
                kv_over_recompute: get("kv")? / get("recompute")?,
            })
        })
        .collect();
    let report = DecodeReport {
        models: a.model.models.display().to_string(),
        model: info.expect("at least one mode ran"),
        intra_threads: a.model.threads,
        tokens: a.tokens,
        results: rows,
        speedup,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for s in &report.speedup {
            eprintln!(
                "batch {:>3}: KV cache {:.1}× faster than recompute",
                s.batch, s.kv_over_recompute
            );
        }
    }
    Ok(())
}

#[derive(Serialize, Default)]
struct SkeletonTimes {
    sample_ms: f64,
    encode_ms: f64,
    prefill_ms: f64,
    decode_ms: f64,
    decode_steps: u64,
    /// Detokenizing and scoring the candidates, and the batching loop itself.
    other_ms: f64,
    total_ms: f64,
    generated_tokens: u64,
    bones: usize,
}

#[derive(Serialize)]
struct SkeletonReport {
    mesh: String,
    vertices: usize,
    triangles: usize,
    samples: usize,
    load_ms: f64,
    runs: Vec<SkeletonTimes>,
    mean: SkeletonTimes,
}

fn skeleton(a: SkeletonArgs) -> anyhow::Result<()> {
    let t = Instant::now();
    let bytes = std::fs::read(&a.mesh).with_context(|| format!("reading {}", a.mesh.display()))?;
    let asset = mesh::load(&bytes, &a.limits.limits())
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let load_ms = t.elapsed().as_secs_f64() * 1e3;
    let backend = a.model.backend(BackendConfig {
        max_batch: a.samples.max(1),
        kv_cache: true,
        ragged: true,
        ..BackendConfig::default()
    })?;
    let cfg = PredictConfig {
        samples: a.samples,
        seed: a.seed,
        library: a.model.load_library()?,
        ..PredictConfig::default()
    };
    let mut runs = Vec::new();
    for r in 0..=a.repeat {
        let t0 = Instant::now();
        let samples =
            samples_for(&asset.mesh, &cfg).map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
        let sample_ms = t0.elapsed().as_secs_f64() * 1e3;
        let before = backend.metrics();
        let t1 = Instant::now();
        let pred = predict_from_samples(&backend, &samples, &cfg, None)
            .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
        let predict_ms = t1.elapsed().as_secs_f64() * 1e3;
        let m = backend.metrics().since(&before);
        let ms = |ns: u64| ns as f64 / 1e6;
        let model_ms = ms(m.encode_ns + m.prefill_ns + m.decode_ns);
        let times = SkeletonTimes {
            sample_ms,
            encode_ms: ms(m.encode_ns),
            prefill_ms: ms(m.prefill_ns),
            decode_ms: ms(m.decode_ns),
            decode_steps: m.decode_steps,
            other_ms: (predict_ms - model_ms).max(0.0),
            total_ms: sample_ms + predict_ms,
            generated_tokens: m.generated_tokens,
            bones: pred.skeleton.len(),
        };
        if r > 0 {
            runs.push(times);
        }
    }
    let n = runs.len().max(1) as f64;
    let mean = SkeletonTimes {
        sample_ms: runs.iter().map(|t| t.sample_ms).sum::<f64>() / n,
        encode_ms: runs.iter().map(|t| t.encode_ms).sum::<f64>() / n,
        prefill_ms: runs.iter().map(|t| t.prefill_ms).sum::<f64>() / n,
        decode_ms: runs.iter().map(|t| t.decode_ms).sum::<f64>() / n,
        decode_steps: (runs.iter().map(|t| t.decode_steps).sum::<u64>() as f64 / n).round() as u64,
        other_ms: runs.iter().map(|t| t.other_ms).sum::<f64>() / n,
        total_ms: runs.iter().map(|t| t.total_ms).sum::<f64>() / n,
        generated_tokens: (runs.iter().map(|t| t.generated_tokens).sum::<u64>() as f64 / n).round()
            as u64,
        bones: runs.last().map_or(0, |t| t.bones),
    };
    let report = SkeletonReport {
        mesh: a.mesh.display().to_string(),
        vertices: asset.mesh.positions.len(),
        triangles: asset.mesh.triangles.len(),
        samples: a.samples,
        load_ms,
        runs,
        mean,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        let m = &report.mean;
        eprintln!(
            "{}: best of {} in {:.1} ms (sample {:.1}, encoder {:.1}, prefill {:.1}, decode {:.1} over {} steps, other {:.1}); {} tokens, {} bones",
            report.mesh, a.samples, m.total_ms, m.sample_ms, m.encode_ms, m.prefill_ms, m.decode_ms, m.decode_steps, m.other_ms,
            m.generated_tokens, m.bones
        );
    }
    Ok(())
}
