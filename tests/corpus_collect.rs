//! The real-rig corpus collector (`python3 -m training.corpus.collect`) rebuilds two rows
//! of `training/corpus/manifest.tsv` from their git mirrors into GLBs that carry a skin.
//! Skips (with a message) where the mirrors under /work/.mirror (or $CORPUS_MIRRORS) or
//! python3 are absent, as on a fresh clone.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Rows chosen for being small and of two formats (.b3d through assimp, .glb copied).
const ROWS: [(&str, &str); 2] = [
    ("TheTermos/wildlife", "models/wolf.b3d"),
    (
        "lemonhall/openagentic-sdk-gdscript",
        "assets/kenney/mini-characters-1/character-female-a.glb",
    ),
];

fn mirrors() -> PathBuf {
    std::env::var_os("CORPUS_MIRRORS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/work/.mirror"))
}

/// Joint count of the first skin in a GLB, read from its JSON chunk (std only: the
/// entries of the first `"joints":[...]` array after `"skins"`; the collector writes
/// compact JSON). None when the file has no skin.
fn first_skin_joints(glb: &[u8]) -> Option<usize> {
    assert!(glb.len() > 20 && &glb[..4] == b"glTF", "not a GLB");
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json = std::str::from_utf8(&glb[20..20 + len]).expect("JSON chunk is UTF-8");
    let rest = &json[json.find("\"skins\"")?..];
    let tail = &rest[rest.find("\"joints\":[")? + 10..];
    let end = tail.find(']')?;
    Some(
        tail[..end]
            .split(',')
            .filter(|s| !s.trim().is_empty())
            .count(),
    )
}

#[test]
fn collector_rebuilds_two_rows_with_skins() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mirrors = mirrors();
    let missing: Vec<&str> = ROWS
        .iter()
        .map(|(r, _)| *r)
        .filter(|r| !mirrors.join(r.replace('/', "+")).join("repo").is_dir())
        .collect();
    if !missing.is_empty() {
        eprintln!(
            "SKIPPED: no git mirror under {} for {missing:?}",
            mirrors.display()
        );
        return;
    }
    if Command::new("python3").arg("--version").output().is_err() {
        eprintln!("SKIPPED: python3 is not installed");
        return;
    }
    let text =
        std::fs::read_to_string(root.join("training/corpus/manifest.tsv")).expect("manifest");
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    assert!(
        header.starts_with("repo\tcommit\tpath\tlicence\tartist\tcategory"),
        "{header}"
    );
    let rows: Vec<&str> = lines
        .filter(|l| {
            let v: Vec<&str> = l.split('\t').collect();
            ROWS.iter()
                .any(|(r, p)| v.first() == Some(r) && v.get(2) == Some(p))
        })
        .collect();
    assert_eq!(
        rows.len(),
        2,
        "both test rows are in training/corpus/manifest.tsv"
    );

    let tmp = std::env::temp_dir().join(format!("rigserve_corpus_collect_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).unwrap();
    let small = tmp.join("manifest.tsv");
    std::fs::write(&small, format!("{header}\n{}\n", rows.join("\n"))).unwrap();
    let out = tmp.join("out");
    let status = Command::new("python3")
        .current_dir(root)
        .args(["-m", "training.corpus.collect", "--manifest"])
        .arg(&small)
        .arg("--mirrors")
        .arg(&mirrors)
        .arg("--out")
        .arg(&out)
        .status()
        .expect("python3 runs");
    assert!(status.success(), "collector exit status {status}");

    let built = std::fs::read_to_string(out.join("manifest.tsv")).expect("output manifest.tsv");
    let mut bl = built.lines();
    let bh: Vec<&str> = bl.next().unwrap().split('\t').collect();
    let col = |n: &str| {
        bh.iter()
            .position(|h| *h == n)
            .unwrap_or_else(|| panic!("column {n}"))
    };
    let (f, j, s) = (col("file"), col("joints"), col("split"));
    let built_rows: Vec<Vec<&str>> = bl
        .filter(|l| !l.is_empty())
        .map(|l| l.split('\t').collect())
        .collect();
    assert_eq!(
        built_rows.len(),
        2,
        "both rows built (see {})",
        out.join("DROPPED.tsv").display()
    );
    for v in &built_rows {
        assert_eq!(v[s], "train");
        let joints: usize = v[j].parse().unwrap();
        assert!(joints >= 2, "{}: {joints} joints", v[f]);
        let bytes = std::fs::read(out.join(v[f])).unwrap_or_else(|e| panic!("{}: {e}", v[f]));
        let skin = first_skin_joints(&bytes);
        assert!(
            skin.is_some_and(|n| n >= 2),
            "{}: first skin joints {skin:?}",
            v[f]
        );
    }
    assert!(out.join("ARTISTS.tsv").is_file());
    let _ = std::fs::remove_dir_all(&tmp);
}
