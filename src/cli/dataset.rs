use rigserve::dataset::{build, DatasetConfig};
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
    eprintln!(
        "{} files -> {} items in {}",
        summary.files,
        summary.items,
        out.display()
    );
    for (f, why) in &summary.skipped {
        eprintln!("skipped {f}: {why}");
    }
    Ok(())
}
