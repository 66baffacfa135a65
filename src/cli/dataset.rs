use rigserve::dataset::skin::{build_skin, SkinDatasetConfig};
use rigserve::dataset::{build, DatasetConfig, DatasetSummary};
use rigserve::mesh::Limits;
use std::path::Path;

pub fn run(
    dir: &Path,
    split: Option<&str>,
    out: &Path,
    cfg: DatasetConfig,
    limits: &Limits,
) -> anyhow::Result<()> {
    let entries = rigserve::eval::entries_in(dir, split)?;
    let summary = build(dir, &entries, out, &cfg, limits)?;
    report(&summary, out);
    Ok(())
}

pub fn run_skin(
    dir: &Path,
    split: Option<&str>,
    out: &Path,
    cfg: SkinDatasetConfig,
    limits: &Limits,
) -> anyhow::Result<()> {
    let entries = rigserve::eval::entries_in(dir, split)?;
    let summary = build_skin(dir, &entries, out, &cfg, limits)?;
    report(&summary, out);
    Ok(())
}

fn report(summary: &DatasetSummary, out: &Path) {
    eprintln!(
        "{} files -> {} items in {}",
        summary.files,
        summary.items,
        out.display()
    );
    for (f, why) in &summary.skipped {
        eprintln!("skipped {f}: {why}");
    }
}
