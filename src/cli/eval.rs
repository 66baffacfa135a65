//! `rigserve eval`: one report format, whatever produced the rigs.

use super::rig::{DecodeArgs, ModelArgs, SkinArgs};
use super::LimitArgs;
use anyhow::Context;
use rigserve::infer::BackendConfig;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Folder holding `manifest.tsv` (columns `file`, `category`, optional `split`).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Only the rows of this split (e.g. `dev`).
    #[arg(long)]
    pub split: Option<String>,
    /// Folder of rigged GLBs named like the data set's files, to score.
    #[arg(long, conflicts_with_all = ["baseline", "skeleton_only", "skin_on_gt"])]
    pub pred: Option<PathBuf>,
    /// Score the trivial baseline: each category's medoid training skeleton (from
    /// `--train-split`) stretched onto the mesh's bounding box.
    #[arg(long, conflicts_with_all = ["skeleton_only", "skin_on_gt"])]
    pub baseline: bool,
    #[arg(long, default_value = "train")]
    pub train_split: String,
    /// Score the skeleton of the most similar `--train-split` rig, moved onto each mesh.
    #[arg(long, conflicts_with_all = ["baseline", "skeleton_only", "skin_on_gt"])]
    pub retrieval: bool,
    /// With --retrieval: only stretch the borrowed skeleton onto the box, no warp.
    #[arg(long)]
    pub no_warp: bool,
    /// Run the shipped skeleton model on every mesh and score its skeletons.
    #[arg(long, conflicts_with = "skin_on_gt")]
    pub skeleton_only: bool,
    /// Skin every mesh with rigserve, given the file's own (artist) skeleton, and score
    /// the weights against the artist's.
    #[arg(long)]
    pub skin_on_gt: bool,
    #[command(flatten)]
    pub skin: SkinArgs,
    /// With --skeleton-only: rigs of this split of the data set form the library whose
    /// skeletons join the model's candidates (never the split scored).
    #[arg(long)]
    pub library_split: Option<String>,
    /// Pass the manifest's category to the model as a hint (off by default: users send
    /// none, so the figures that matter are the ones without it).
    #[arg(long)]
    pub category_hint: bool,
    /// With --skeleton-only: turn every mesh and its rig first (a new root rotated by a
    /// multiple of 90°: x90, x-90, z90, …), to score as a Z-up or lying data set.
    #[arg(long, value_parser = parse_rotation)]
    pub rotate: Option<rigserve::predict::orient::Turn>,
    #[command(flatten)]
    pub decode: DecodeArgs,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Where to write the report.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub limits: LimitArgs,
}

pub fn run(a: EvalArgs) -> anyhow::Result<()> {
    let limits = a.limits.limits();
    let split = a.split.as_deref();
    let mut used = None;
    let mut report = if let Some(pred) = &a.pred {
        rigserve::eval::eval_pred(&a.dataset, split, pred, &limits)?
    } else if a.retrieval {
        rigserve::eval::retrieval::eval_retrieval(
            &a.dataset,
            split,
            &a.train_split,
            !a.no_warp,
            &limits,
        )?
    } else if a.baseline {
        rigserve::eval::eval_baseline(&a.dataset, split, &a.train_split, &limits)?
    } else if a.skeleton_only {
        let backend = a.model.backend(BackendConfig {
            max_batch: a.decode.samples.max(1),
            kv_cache: true,
            ragged: true,
            ..BackendConfig::default()
        })?;
        let mut cfg = a.decode.predict_config(None);
        used = Some(a.model.used(a.library_split.is_none(), a.category_hint)?);
        let lib = match &a.library_split {
            Some(ls) => {
                anyhow::ensure!(
                    Some(ls.as_str()) != split,
                    "the library must not hold the split scored"
                );
                let lib = rigserve::eval::retrieval::build_library(&a.dataset, ls, &limits)?;
                eprintln!("skeleton library: {} rigs of split {ls}", lib.entries.len());
                Some(lib)
            }
            None => a.model.load_library()?.map(|l| (*l).clone()),
        };
        // A mesh is never rigged from its own entry: each scored file leaves the library
        // while it is scored (the rest of a split scored against its own library is
        // leave-one-out).
        if let Some(lib) = lib {
            let scored: std::collections::HashSet<String> =
                rigserve::eval::entries_in(&a.dataset, split)?
                    .into_iter()
                    .map(|e| e.file)
                    .collect();
            let own = lib.entries.len() - lib.without(&scored).entries.len();
            if own > 0 {
                eprintln!(
                    "skeleton library: left out {own} entries, each while its own file is scored"
                );
            }
            cfg.library = Some(std::sync::Arc::new(lib));
        }
        rigserve::eval::eval_model_skeleton(
            &a.dataset,
            split,
            &backend,
            &cfg,
            a.category_hint,
            a.rotate,
            &limits,
        )?
    } else if a.skin_on_gt {
        let model = a.skin.load_model(a.model.ort_lib.as_deref())?;
        used = Some(rigserve::eval::Used {
            models: model
                .as_ref()
                .map(|m| rigserve::eval::FileHash::of(m.path()))
                .transpose()?
                .into_iter()
                .collect(),
            ..Default::default()
        });
        eprintln!(
            "skin method: {}",
            model.as_ref().map_or("geometric".to_string(), |m| format!(
                "learned ({})",
                m.path().display()
            ))
        );
        rigserve::eval::skin::eval_skin_on_gt(
            &a.dataset,
            split,
            &a.skin.config(),
            model.as_ref(),
            &limits,
        )?
    } else {
        anyhow::bail!("say what to score: --pred DIR, --baseline, --skeleton-only or --skin-on-gt");
    };
    if let Some(u) = &used {
        for m in &u.models {
            eprintln!("model: {} sha256 {}", m.path, &m.sha256[..16]);
        }
        match &u.library {
            Some(l) => eprintln!("library: {} sha256 {}", l.path, &l.sha256[..16]),
            None if a.library_split.is_some() => {
                eprintln!(
                    "library: split {} of the data set",
                    a.library_split.as_deref().unwrap_or("")
                )
            }
            None => eprintln!("library: none (the model alone)"),
        }
        eprintln!(
            "category hint: {}",
            if u.category_hint { "on" } else { "off" }
        );
    }
    report.used = used;
    std::fs::write(&a.out, serde_json::to_vec_pretty(&report)?)
        .with_context(|| format!("writing {}", a.out.display()))?;
    let o = &report.overall;
    eprintln!(
        "{} models, {:.1}% valid | CD-J2J {:.4} CD-J2B {:.4} CD-B2B {:.4} | skin L1 {:.4} P {:.3} R {:.3} deform {:.4}",
        o.count,
        o.valid_fraction * 100.0,
        o.skeleton.cd_j2j,
        o.skeleton.cd_j2b,
        o.skeleton.cd_b2b,
        o.skin.l1,
        o.skin.precision,
        o.skin.recall,
        o.skin.deformation
    );
    if report.per_artist.len() > 1 {
        for (artist, g) in &report.per_artist {
            eprintln!(
                "  {:<40} {:>3} files, {:>5.1}% valid | CD-J2J {:.4} CD-B2B {:.4}",
                artist,
                g.count,
                g.valid_fraction * 100.0,
                g.skeleton.cd_j2j,
                g.skeleton.cd_b2b
            );
        }
    }
    let best: Vec<f32> = report
        .models
        .iter()
        .filter_map(|m| {
            m.candidates
                .iter()
                .filter_map(|c| c.cd_j2j)
                .reduce(f32::min)
        })
        .collect();
    if !best.is_empty() {
        eprintln!(
            "best candidate of each mesh, had the choice been perfect: CD-J2J {:.4} over {} meshes",
            best.iter().sum::<f32>() / best.len() as f32,
            best.len()
        );
    }
    Ok(())
}

fn parse_rotation(s: &str) -> Result<rigserve::predict::orient::Turn, String> {
    rigserve::predict::orient::Turn::parse_rotation(s).ok_or_else(|| {
        format!("a rotation is an axis and a multiple of 90 degrees (x90, z-90, y180), not {s:?}")
    })
}
