//! Compressed glTF in: Draco, meshopt and quantized copies made by gltf-transform (the
//! tool web pipelines run) from the committed fixtures, read like their source, rigged
//! by the CLI, and exported as files the Khronos validator passes with textures
//! (WebP included) kept; corrupt compressed data is a typed refusal, never a panic.
//!
//! The copies are made at test time into a temporary folder, so the test follows
//! whatever gltf-transform `tools/package.json` pins. It skips, with a message, where
//! node or gltf-transform cannot be had, and skips the rigging where the ONNX Runtime
//! library is missing.

mod common;

use common::{errors_of, manifest, shared_rigs, tools_dir, validate};
use glam::Vec3;
use rigserve::mesh::{load, Asset, Limits};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

const COMPRESSION: [&str; 3] = [
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "KHR_meshopt_compression",
];

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn fixture(name: &str) -> PathBuf {
    repo().join("tests/fixtures/compressed").join(name)
}

/// The gltf-transform CLI from tools/node_modules, installing tools/ once if needed.
fn gltf_transform() -> Option<PathBuf> {
    let bin = tools_dir().join("node_modules/.bin/gltf-transform");
    if !bin.is_file() {
        let _ = Command::new("npm")
            .args([
                "ci",
                "--prefix",
                tools_dir().to_str().unwrap(),
                "--no-audit",
                "--no-fund",
            ])
            .status();
    }
    if bin.is_file() && Command::new("node").arg("--version").output().is_ok() {
        Some(bin)
    } else {
        eprintln!(
            "SKIPPED: gltf-transform is not installed (npm ci --prefix tools) or node is missing"
        );
        None
    }
}

/// Runs `gltf-transform` with `steps` in turn (each one a command, e.g. "draco"),
/// from `input` to `output`.
fn transform(gt: &Path, steps: &[&str], input: &Path, output: &Path) {
    let mut from = input.to_path_buf();
    for (k, step) in steps.iter().enumerate() {
        let to = if k + 1 == steps.len() {
            output.to_path_buf()
        } else {
            output.with_extension(format!("step{k}.glb"))
        };
        let out = Command::new(gt)
            .arg(step)
            .arg(&from)
            .arg(&to)
            .output()
            .expect("gltf-transform");
        assert!(
            out.status.success(),
            "gltf-transform {step} {}: {}",
            from.display(),
            String::from_utf8_lossy(&out.stderr)
        );
        from = to;
    }
}

fn glb_json(bytes: &[u8]) -> (Value, usize) {
    let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json = serde_json::from_slice(&bytes[20..20 + len]).unwrap();
    (json, 20 + len + 8)
}

fn names(v: &Value, key: &str) -> Vec<String> {
    v.get(key)
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
        .filter_map(|e| e.as_str().map(String::from))
        .collect()
}

fn declares_compression(json: &Value) -> bool {
    let text = json.to_string();
    COMPRESSION.iter().any(|c| text.contains(c))
}

fn ort_lib() -> PathBuf {
    std::env::var_os("RIGSERVE_ORT_LIB")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo().join(".onnxruntime/libonnxruntime.so.1.31.1"))
}

fn can_rig() -> bool {
    let ok = ort_lib().is_file();
    if !ok {
        eprintln!(
            "SKIPPED (rigging): no ONNX Runtime at {} (make setup fetches it)",
            ort_lib().display()
        );
    }
    ok
}

/// `rigserve rig IN -o OUT` with the shipped models.
fn rig(input: &Path, output: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_rigserve"))
        .current_dir(repo())
        .env("RIGSERVE_ORT_LIB", ort_lib())
        .arg("rig")
        .arg(input)
        .arg("-o")
        .arg(output)
        .output()
        .expect("rigserve rig")
}

fn rig_ok(input: &Path, output: &Path) {
    let out = rig(input, output);
    assert!(
        out.status.success(),
        "rig {}: {}",
        input.display(),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn load_file(path: &Path) -> Asset {
    load(&std::fs::read(path).unwrap(), &Limits::default())
        .unwrap_or_else(|e| panic!("{}: {e} [{}]", path.display(), e.code()))
}

fn size_of(a: &Asset) -> f32 {
    let (lo, hi) = a.mesh.bounds();
    (hi - lo).length()
}

fn area(a: &Asset) -> f64 {
    a.mesh
        .triangles
        .iter()
        .map(|t| {
            let [p, q, r] = t.map(|i| a.mesh.positions[i as usize]);
            (q - p).cross(r - p).length() as f64 * 0.5
        })
        .sum()
}

/// Largest distance from a vertex of `a` to the nearest vertex of `b`.
fn farthest_vertex(a: &[Vec3], b: &[Vec3]) -> f32 {
    a.iter()
        .map(|p| {
            b.iter()
                .map(|q| p.distance_squared(*q))
                .fold(f32::MAX, f32::min)
        })
        .fold(0.0, f32::max)
        .sqrt()
}

/// The copies each test makes: label, gltf-transform steps, what the output keeps.
const VARIANTS: [(&str, &[&str]); 5] = [
    ("draco", &["draco"]),
    ("meshopt", &["meshopt"]),
    ("quantize", &["quantize"]),
    ("webp_meshopt", &["webp", "meshopt"]),
    ("webp_draco", &["webp", "draco"]),
];

/// Makes every variant of both fixtures in `dir`: (source, copy, label).
fn make_copies(gt: &Path, dir: &Path) -> Vec<(PathBuf, PathBuf, String)> {
    let mut out = Vec::new();
    for src in ["figure.glb", "figure_rigged.glb"] {
        for (label, steps) in VARIANTS {
            let name = format!("{}_{label}.glb", src.trim_end_matches(".glb"));
            let copy = dir.join(&name);
            transform(gt, steps, &fixture(src), &copy);
            out.push((fixture(src), copy, name));
        }
    }
    out
}

#[test]
fn compressed_copies_read_like_their_source() {
    let Some(gt) = gltf_transform() else { return };
    let dir = tempfile::tempdir().unwrap();
    for (src, copy, label) in make_copies(&gt, dir.path()) {
        let input = std::fs::read(&copy).unwrap();
        let (in_json, _) = glb_json(&input);
        let want = if label.contains("draco") {
            "KHR_draco_mesh_compression"
        } else if label.contains("meshopt") {
            "EXT_meshopt_compression"
        } else {
            "KHR_mesh_quantization"
        };
        assert!(
            names(&in_json, "extensionsUsed").iter().any(|e| e == want),
            "{label}: gltf-transform did not write {want}"
        );
        let a = load_file(&src);
        let b = load_file(&copy);
        // The document handed to the export is plain glTF: no compression left.
        let doc = b.document.as_ref().unwrap();
        assert!(
            !declares_compression(&doc.json),
            "{label}: still declares compression"
        );
        let size = size_of(&a);
        // gltf-transform quantizes positions to 14 bits (Draco, meshopt, quantize alike).
        let tol = size * 2e-3;
        let (alo, ahi) = a.mesh.bounds();
        let (blo, bhi) = b.mesh.bounds();
        assert!(
            alo.distance(blo) < tol && ahi.distance(bhi) < tol,
            "{label}: bounds {blo:?}..{bhi:?}, source {alo:?}..{ahi:?}"
        );
        let (fa, fb) = (
            farthest_vertex(&b.mesh.positions, &a.mesh.positions),
            farthest_vertex(&a.mesh.positions, &b.mesh.positions),
        );
        assert!(
            fa < tol && fb < tol,
            "{label}: vertices moved {fa} / {fb} (size {size})"
        );
        let (aa, ab) = (area(&a), area(&b));
        assert!(
            (aa - ab).abs() < aa * 0.01,
            "{label}: area {ab} against {aa}"
        );
        // Draco drops the sphere's degenerate pole triangles and splits seams; the
        // others keep every vertex and triangle.
        let (ta, tb) = (a.mesh.triangles.len(), b.mesh.triangles.len());
        if label.contains("draco") {
            assert!(
                tb <= ta && tb * 100 >= ta * 98,
                "{label}: {tb} triangles of {ta}"
            );
        } else {
            assert_eq!(tb, ta, "{label}: triangles");
            assert_eq!(b.mesh.positions.len(), a.mesh.positions.len(), "{label}");
        }
        // The rigged copies keep their skin (the loader reads it as the input's rig).
        assert_eq!(
            b.mesh.parts.iter().filter(|p| p.skin.is_some()).count(),
            a.mesh.parts.iter().filter(|p| p.skin.is_some()).count(),
            "{label}: skinned parts"
        );
    }
}

#[test]
fn compressed_copies_rig_and_validate_with_their_textures() {
    let Some(gt) = gltf_transform() else { return };
    if !can_rig() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut outputs = Vec::new();
    for (_, copy, label) in make_copies(&gt, dir.path()) {
        let out = dir.path().join(format!("rigged_{label}"));
        rig_ok(&copy, &out);
        let (in_json, _) = glb_json(&std::fs::read(&copy).unwrap());
        let bytes = std::fs::read(&out).unwrap();
        let (json, _) = glb_json(&bytes);
        assert!(
            !declares_compression(&json),
            "{label}: output declares compression"
        );
        // Images, textures and the texture extensions come through as they were.
        assert_eq!(
            json["images"].as_array().map(Vec::len),
            in_json["images"].as_array().map(Vec::len)
        );
        assert_eq!(json["textures"], in_json["textures"], "{label}: textures");
        for (i, img) in json["images"].as_array().unwrap().iter().enumerate() {
            assert_eq!(img["mimeType"], in_json["images"][i]["mimeType"], "{label}");
        }
        let used = names(&json, "extensionsUsed");
        if label.contains("webp") {
            assert_eq!(json["images"][0]["mimeType"], "image/webp", "{label}");
            assert!(
                used.iter().any(|e| e == "EXT_texture_webp"),
                "{label}: {used:?}"
            );
            assert!(names(&json, "extensionsRequired")
                .iter()
                .any(|e| e == "EXT_texture_webp"));
        }
        // Quantized data stays quantized, so the output still declares it.
        let quantized = names(&in_json, "extensionsUsed")
            .iter()
            .any(|e| e == "KHR_mesh_quantization");
        assert_eq!(
            used.iter().any(|e| e == "KHR_mesh_quantization"),
            quantized,
            "{label}: {used:?}"
        );
        outputs.push(out);
    }
    let Some(reports) = validate(&outputs) else {
        return;
    };
    let errors = errors_of(&reports);
    assert!(errors.is_empty(), "validator errors: {errors:#?}");
}

/// Where the compressed bytes of a GLB lie: (start, end) in the file.
fn compressed_ranges(bytes: &[u8]) -> Vec<(usize, usize)> {
    let (json, bin) = glb_json(bytes);
    let views = json["bufferViews"].as_array().unwrap();
    let mut out = Vec::new();
    for v in views {
        if let Some(e) = v.pointer("/extensions/EXT_meshopt_compression") {
            let o = e["byteOffset"].as_u64().unwrap_or(0) as usize;
            out.push((
                bin + o,
                bin + o + e["byteLength"].as_u64().unwrap() as usize,
            ));
        }
    }
    for m in json["meshes"].as_array().unwrap() {
        for p in m["primitives"].as_array().unwrap() {
            if let Some(e) = p.pointer("/extensions/KHR_draco_mesh_compression") {
                let v = &views[e["bufferView"].as_u64().unwrap() as usize];
                let o = v["byteOffset"].as_u64().unwrap_or(0) as usize;
                out.push((
                    bin + o,
                    bin + o + v["byteLength"].as_u64().unwrap() as usize,
                ));
            }
        }
    }
    out.sort();
    out.dedup();
    out
}

#[test]
fn corrupt_compressed_data_is_a_typed_error_never_a_panic() {
    let Some(gt) = gltf_transform() else { return };
    let dir = tempfile::tempdir().unwrap();
    let limits = Limits::default();
    let mut seed: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for kind in ["draco", "meshopt"] {
        let copy = dir.path().join(format!("{kind}.glb"));
        transform(&gt, &[kind], &fixture("figure_rigged.glb"), &copy);
        let bytes = std::fs::read(&copy).unwrap();
        let ranges = compressed_ranges(&bytes);
        assert!(!ranges.is_empty(), "{kind}: no compressed data found");
        // Every stream's header bytes wrecked: each kind refuses with its code.
        let mut headers = bytes.clone();
        for &(s, _) in &ranges {
            for b in &mut headers[s..s + 4] {
                *b ^= 0xff;
            }
        }
        let err = load(&headers, &limits).unwrap_err();
        assert_eq!(err.code(), "compressed_data_invalid", "{kind}: {err}");
        // A stream cut short: its tail zeroed out.
        let mut cut = bytes.clone();
        for &(s, e) in &ranges {
            cut[s + (e - s) / 3..e].fill(0);
        }
        match load(&cut, &limits) {
            Err(e) => assert_eq!(e.code(), "compressed_data_invalid", "{kind}: {e}"),
            Ok(_) => panic!("{kind}: a stream with its tail zeroed loaded"),
        }
        // And the CLI says so with the code, as the API does (a 422 with error_type).
        let bad = dir.path().join(format!("{kind}_bad.glb"));
        std::fs::write(&bad, &headers).unwrap();
        let out = rig(&bad, &dir.path().join("never.glb"));
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains("[compressed_data_invalid]"),
            "{kind}: {stderr}"
        );
        // Random damage anywhere in the compressed bytes: an answer every time (a
        // stream may still decode, to other geometry), and never a panic.
        let mut refused = 0;
        for _ in 0..150 {
            let mut b = bytes.clone();
            let &(s, e) = &ranges[next() as usize % ranges.len()];
            for _ in 0..1 + next() % 8 {
                let at = s + next() as usize % (e - s);
                b[at] ^= 1 + (next() % 255) as u8;
            }
            if let Err(e) = load(&b, &limits) {
                assert!(!e.code().is_empty());
                refused += 1;
            }
        }
        eprintln!("{kind}: 150 random corruptions, {refused} refused, the rest decoded");
    }
}

/// Draco, meshopt and quantized copies of a few dev files (one per kind of rig) rig
/// and validate.
#[test]
fn compressed_copies_of_dev_files_rig_and_validate() {
    let Some(rigs) = shared_rigs() else { return };
    let Some(gt) = gltf_transform() else { return };
    if !can_rig() {
        return;
    }
    let picks = [
        "modular_men__King.glb",
        "animals_pack__Fox.glb",
        "mobs_spider.glb",
    ];
    let dev: Vec<String> = manifest(&rigs)
        .into_iter()
        .filter(|e| e.split == "dev")
        .map(|e| e.file)
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let mut outputs = Vec::new();
    for file in picks.iter().filter(|f| dev.iter().any(|d| d == *f)) {
        for kind in ["draco", "meshopt", "quantize"] {
            let copy = dir.path().join(format!("{kind}_{file}"));
            transform(&gt, &[kind], &rigs.join(file), &copy);
            let source = load_file(&rigs.join(file));
            let asset = load_file(&copy);
            let tol = size_of(&source) * 2e-3;
            let (alo, ahi) = source.mesh.bounds();
            let (blo, bhi) = asset.mesh.bounds();
            assert!(
                alo.distance(blo) < tol && ahi.distance(bhi) < tol,
                "{kind} {file}"
            );
            let out = dir.path().join(format!("rigged_{kind}_{file}"));
            rig_ok(&copy, &out);
            outputs.push(out);
        }
    }
    assert_eq!(
        outputs.len(),
        picks.len() * 3,
        "the picked files are not all in dev"
    );
    let Some(reports) = validate(&outputs) else {
        return;
    };
    let errors = errors_of(&reports);
    assert!(errors.is_empty(), "validator errors: {errors:#?}");
}

/// The 12 VALID avatars of ../shared/rigs_xdev (meshopt, KHR_mesh_quantization,
/// EXT_texture_webp) rig, and the outputs validate with their WebP textures.
#[test]
fn valid_avatars_of_xdev_rig_and_validate() {
    let xdev = repo().join("../shared/rigs_xdev");
    if !xdev.join("manifest.tsv").is_file() {
        eprintln!("SKIPPED: ../shared/rigs_xdev is absent");
        return;
    }
    if !can_rig() {
        return;
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(&xdev)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("valid__") && n.ends_with(".glb"))
        })
        .collect();
    files.sort();
    assert_eq!(files.len(), 12, "valid__ avatars in {}", xdev.display());
    let dir = tempfile::tempdir().unwrap();
    let mut outputs = Vec::new();
    for f in &files {
        let out = dir.path().join(f.file_name().unwrap());
        rig_ok(f, &out);
        let (json, _) = glb_json(&std::fs::read(&out).unwrap());
        assert!(!declares_compression(&json), "{}", f.display());
        assert!(names(&json, "extensionsUsed")
            .iter()
            .any(|e| e == "EXT_texture_webp"));
        assert!(json["images"].as_array().is_some_and(|i| !i.is_empty()));
        outputs.push(out);
    }
    let Some(reports) = validate(&outputs) else {
        return;
    };
    let errors = errors_of(&reports);
    assert!(errors.is_empty(), "validator errors: {errors:#?}");
}
