use anyhow::Context;
use rigserve::mesh::Limits;
use std::path::{Path, PathBuf};

/// What produces the rigs being scored.
pub enum Source {
    /// Rigged files already written by some tool.
    Pred(PathBuf),
    /// The category-medoid baseline from this training split.
    Baseline(String),
    /// rigserve's shipped models.
    Model,
}

pub fn run(
    dataset: &Path,
    split: Option<&str>,
    source: Source,
    out: &Path,
    limits: &Limits,
) -> anyhow::Result<()> {
    let report = match source {
        Source::Pred(pred) => rigserve::eval::eval_pred(dataset, split, &pred, limits)?,
        Source::Baseline(train) => rigserve::eval::eval_baseline(dataset, split, &train, limits)?,
        Source::Model => {
            anyhow::bail!(
                "model-driven evaluation needs the shipped models; use --pred DIR or --baseline"
            )
        }
    };
    std::fs::write(out, serde_json::to_vec_pretty(&report)?)
        .with_context(|| format!("writing {}", out.display()))?;
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
    Ok(())
}
