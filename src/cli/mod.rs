//! Subcommands. Each one is a thin shell over the library, so tests drive the same code.

mod bench;
mod bench_rig;
mod dataset;
mod eval;
mod inspect;
mod rig;
mod serve;

use anyhow::Context;
use clap::{Parser, Subcommand};
use rigserve::mesh::Limits;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "rigserve",
    version,
    about = "Auto-rigging for 3D meshes: skeletons, skin weights, rigged GLB"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(clap::Args, Debug, Clone)]
pub struct LimitArgs {
    /// Largest upload accepted, in bytes.
    #[arg(long, env = "RIGSERVE_MAX_BYTES", default_value_t = 256 << 20)]
    pub max_bytes: u64,
    /// Most vertices a mesh may have.
    #[arg(long, env = "RIGSERVE_MAX_VERTICES", default_value_t = 2_000_000)]
    pub max_vertices: u64,
    /// Most triangles a mesh may have.
    #[arg(long, env = "RIGSERVE_MAX_TRIANGLES", default_value_t = 2_000_000)]
    pub max_triangles: u64,
}

impl LimitArgs {
    pub fn limits(&self) -> Limits {
        Limits {
            max_bytes: self.max_bytes,
            max_vertices: self.max_vertices,
            max_triangles: self.max_triangles,
            ..Limits::default()
        }
    }
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Prints the bone tree (and mesh statistics) of a rigged file.
    Inspect {
        file: PathBuf,
        /// Print the bone tree as JSON (the same document the service returns).
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        limits: LimitArgs,
    },
    /// Scores rigs against a data set's artist rigs and writes a JSON report.
    Eval(eval::EvalArgs),
    /// Writes training arrays and token sequences from rigged meshes (see `training/`).
    Dataset(DatasetArgs),
    /// Rigs a mesh: skeleton (predicted, given, or the input's own) and skin weights.
    Rig(rig::RigArgs),
    /// Runs the HTTP service (embedded SQLite + local files under --data-dir).
    Serve(serve::ServeArgs),
    /// Measures model throughput and latency.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Writes a skeleton library from rigged files: meshes like one of them borrow its
    /// skeleton, moved onto them (see `--library`).
    Library(LibraryArgs),
}

#[derive(clap::Args, Debug)]
pub struct LibraryArgs {
    /// Folder holding `manifest.tsv` and the rigged files it lists (repeat for several).
    #[arg(long, required = true)]
    pub dataset: Vec<PathBuf>,
    /// Only the rows of this split (e.g. `train`), in every data set.
    #[arg(long)]
    pub split: String,
    /// Leave out rows whose `license` contains this text, case-insensitively (repeatable;
    /// e.g. `BY-SA`: share-alike rigs may train a model but are not shipped in a library).
    #[arg(long)]
    pub exclude_license: Vec<String>,
    /// Leave out this file of the data sets (repeatable), e.g. one whose manifest licence
    /// its source's own licence file contradicts.
    #[arg(long)]
    pub exclude: Vec<String>,
    /// Where to write the library (e.g. models/library.bin; `.json` writes JSON).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub limits: LimitArgs,
}

#[derive(clap::Args, Debug)]
pub struct DatasetArgs {
    /// Folder holding `manifest.tsv` and the rigged files it lists.
    #[arg(long)]
    pub input: PathBuf,
    /// Only the rows of this split (e.g. `train`).
    #[arg(long)]
    pub split: Option<String>,
    #[arg(long)]
    pub out: PathBuf,
    /// Surface samples per item.
    #[arg(long, default_value_t = 4096)]
    pub points: usize,
    /// Augmented variations per file, besides the original.
    #[arg(long, default_value_t = 0)]
    pub augment: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Files whose skeletons have more bones are skipped.
    #[arg(long, default_value_t = 128)]
    pub max_bones: usize,
    /// Write the skin model's data set instead (vertices, candidate bones, features and
    /// the artist's weights; see `src/dataset/skin.rs`). `--points` is then the most
    /// vertices per item.
    #[arg(long)]
    pub skin: bool,
    /// With --skin: candidate bones per vertex.
    #[arg(long, default_value_t = rigserve::rig::skin::LEARNED_CANDIDATES)]
    pub candidates: usize,
    #[command(flatten)]
    pub limits: LimitArgs,
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Inspect { file, json, limits } => inspect::run(&file, json, &limits.limits()),
        Command::Dataset(a) if a.skin => {
            let cfg = rigserve::dataset::skin::SkinDatasetConfig {
                rows: a.points,
                k: a.candidates,
                augment: a.augment,
                seed: a.seed,
                max_bones: a.max_bones,
                skin: Default::default(),
                augment_config: Default::default(),
            };
            dataset::run_skin(
                &a.input,
                a.split.as_deref(),
                &a.out,
                cfg,
                &a.limits.limits(),
            )
        }
        Command::Dataset(a) => {
            let cfg = rigserve::dataset::DatasetConfig {
                points: a.points,
                augment: a.augment,
                seed: a.seed,
                max_bones: a.max_bones,
                augment_config: Default::default(),
            };
            dataset::run(
                &a.input,
                a.split.as_deref(),
                &a.out,
                cfg,
                &a.limits.limits(),
            )
        }
        Command::Rig(a) => rig::run(a),
        Command::Serve(a) => serve::run(a),
        Command::Bench(c) => bench::run(c),
        Command::Eval(a) => eval::run(a),
        Command::Library(a) => {
            let mut entries = Vec::new();
            for d in &a.dataset {
                let lib = rigserve::eval::retrieval::build_library_filtered(
                    d,
                    &a.split,
                    &a.exclude_license,
                    &a.limits.limits(),
                )?;
                entries.extend(lib.entries.into_iter().filter(|e| {
                    let out = a.exclude.contains(&e.name);
                    if out {
                        eprintln!("library: leaving out {} (--exclude)", e.name);
                    }
                    !out
                }));
            }
            let lib = rigserve::predict::library::Library::new(entries);
            anyhow::ensure!(
                !lib.entries.is_empty(),
                "no rig of split {} could be read",
                a.split
            );
            lib.save(&a.out)
                .with_context(|| format!("writing {}", a.out.display()))?;
            eprintln!("{}: {} rigs", a.out.display(), lib.entries.len());
            Ok(())
        }
    }
}
