use anyhow::Context;
use rigserve::mesh::Limits;
use std::path::Path;

pub fn run(
    dataset: &Path,
    split: Option<&str>,
    pred: Option<&Path>,
    out: &Path,
    limits: &Limits,
) -> anyhow::Result<()> {
    let Some(pred) = pred else {
        anyhow::bail!(
            "eval needs --pred DIR until the shipped models land (model-driven evaluation)"
        );
    };
    let report = rigserve::eval::eval_pred(dataset, split, pred, limits)?;
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
