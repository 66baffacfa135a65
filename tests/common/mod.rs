//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The artist-rigged data set beside the checkout, or None (with a message) when a
/// fresh clone has no `../shared`.
pub fn shared_rigs() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/rigs");
    if dir.join("manifest.tsv").is_file() {
        Some(dir)
    } else {
        eprintln!("SKIPPED: ../shared/rigs is absent; the data-set tests need it");
        None
    }
}

pub struct Entry {
    pub file: String,
    pub split: String,
    pub category: String,
}

pub fn manifest(dir: &std::path::Path) -> Vec<Entry> {
    let text = std::fs::read_to_string(dir.join("manifest.tsv")).expect("manifest");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split('\t').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (f, s, c) = (col("file"), col("split"), col("category"));
    lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split('\t').collect();
            Entry {
                file: v[f].into(),
                split: v[s].into(),
                category: v[c].into(),
            }
        })
        .collect()
}
