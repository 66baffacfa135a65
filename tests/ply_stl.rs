//! PLY (ASCII, binary of both byte orders, with and without vertex colours) and STL
//! (binary and ASCII) written from the test figure: they load as the same surface, rig
//! with the shipped models, and the GLB passes the Khronos validator with the colours kept
//! as `COLOR_0`. Broken ones get typed errors.
mod common;
#[allow(dead_code)]
#[path = "api/helpers.rs"]
mod helpers;

use rigserve::mesh::{load, Format, Limits, Mesh};

fn colour(i: usize) -> [u8; 3] {
    [(i * 37 % 256) as u8, (i * 91 % 256) as u8, 200]
}

fn ply(m: &Mesh, format: &str, coloured: bool) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat {format} 1.0\ncomment from rigserve's tests\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n",
        m.positions.len()
    );
    if coloured {
        out += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    out += &format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        m.triangles.len()
    );
    let mut bytes = out.into_bytes();
    let big = format == "binary_big_endian";
    let f32b = |v: f32| {
        if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let i32b = |v: i32| {
        if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    for (i, p) in m.positions.iter().enumerate() {
        if format == "ascii" {
            let mut line = format!("{} {} {}", p.x, p.y, p.z);
            if coloured {
                let c = colour(i);
                line += &format!(" {} {} {}", c[0], c[1], c[2]);
            }
            bytes.extend(format!("{line}\n").bytes());
        } else {
            for v in p.to_array() {
                bytes.extend(f32b(v));
            }
            if coloured {
                bytes.extend(colour(i));
            }
        }
    }
    for t in &m.triangles {
        if format == "ascii" {
            bytes.extend(format!("3 {} {} {}\n", t[0], t[1], t[2]).bytes());
        } else {
            bytes.push(3);
            for &i in t {
                bytes.extend(i32b(i as i32));
            }
        }
    }
    bytes
}

fn stl_binary(m: &Mesh) -> Vec<u8> {
    let mut b = b"solid but binary: the header is free text".to_vec();
    b.resize(80, b' ');
    b.extend((m.triangles.len() as u32).to_le_bytes());
    for t in &m.triangles {
        b.extend([0u8; 12]);
        for &i in t {
            for v in m.positions[i as usize].to_array() {
                b.extend(v.to_le_bytes());
            }
        }
        b.extend([0u8; 2]);
    }
    b
}

fn stl_ascii(m: &Mesh) -> Vec<u8> {
    let mut s = String::from("solid figure\n");
    for t in &m.triangles {
        s += "  facet normal 0 0 0\n    outer loop\n";
        for &i in t {
            let p = m.positions[i as usize];
            s += &format!("      vertex {} {} {}\n", p.x, p.y, p.z);
        }
        s += "    endloop\n  endfacet\n";
    }
    s += "endsolid figure\n";
    s.into_bytes()
}

fn surface(m: &Mesh) -> f32 {
    m.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| m.positions[i as usize]);
            (b - a).cross(c - a).length() / 2.0
        })
        .sum()
}

#[test]
fn ply_and_stl_load_as_the_same_surface() {
    let fig = helpers::figure_mesh();
    let cases: Vec<(&str, Vec<u8>, Format, bool)> = vec![
        ("ascii", ply(&fig, "ascii", false), Format::Ply, false),
        (
            "ascii coloured",
            ply(&fig, "ascii", true),
            Format::Ply,
            true,
        ),
        (
            "little",
            ply(&fig, "binary_little_endian", true),
            Format::Ply,
            true,
        ),
        (
            "big",
            ply(&fig, "binary_big_endian", true),
            Format::Ply,
            true,
        ),
        ("stl binary", stl_binary(&fig), Format::Stl, false),
        ("stl ascii", stl_ascii(&fig), Format::Stl, false),
    ];
    for (name, bytes, format, coloured) in cases {
        let a = load(&bytes, &Limits::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(a.format, format, "{name}");
        // STL is welded back to shared corners: the same vertex and triangle counts.
        assert_eq!(a.mesh.positions.len(), fig.positions.len(), "{name}");
        assert_eq!(a.mesh.triangles.len(), fig.triangles.len(), "{name}");
        assert!(
            (surface(&a.mesh) - surface(&fig)).abs() < 1e-4 * surface(&fig),
            "{name}"
        );
        if coloured {
            assert_eq!(a.colors.len(), a.mesh.positions.len(), "{name}");
            // Vertex i of the file is found at its position; its colour came along.
            for (i, p) in fig.positions.iter().enumerate().step_by(7) {
                let k = a.mesh.positions.iter().position(|q| q == p).unwrap();
                let want = colour(i).map(|c| c as f32 / 255.0);
                assert_eq!(&a.colors[k][..3], &want[..], "{name} vertex {i}");
                assert_eq!(a.colors[k][3], 1.0);
            }
        } else {
            assert!(a.colors.is_empty(), "{name}");
        }
    }
}

#[test]
fn broken_ply_and_stl_are_typed_errors() {
    let fig = helpers::figure_mesh();
    let good = ply(&fig, "binary_little_endian", false);
    let header_end = good.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    // The last face of an ASCII PLY pointing past the vertices.
    let ascii = String::from_utf8(ply(&fig, "ascii", false)).unwrap();
    let last = ascii.trim_end().rfind('\n').unwrap() + 1;
    let text = format!("{}3 0 1 99999\n", &ascii[..last]);
    let huge = String::from_utf8_lossy(&good[..header_end])
        .replace(
            &format!("element vertex {}", fig.positions.len()),
            "element vertex 4000000000",
        )
        .into_bytes();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("no end_header", b"ply\nformat ascii 1.0\nelement vertex 3\n".to_vec(), "ply_invalid"),
        ("bad format", b"ply\nformat utf16 1.0\nend_header\n".to_vec(), "ply_invalid"),
        ("truncated", good[..good.len() - 7].to_vec(), "ply_invalid"),
        ("index out of range", text.clone().into_bytes(), "index_out_of_range"),
        ("vertex count over the cap", huge, "too_many_vertices"),
        (
            "no faces",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n".to_vec(),
            "empty_scene",
        ),
        ("ascii stl cut in a facet", b"solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n".to_vec(), "stl_invalid"),
        ("stl nan", b"solid x\nfacet\nvertex nan 0 0\nvertex 1 0 0\nvertex 0 1 0\n".to_vec(), "non_finite"),
    ];
    for (name, bytes, code) in cases {
        let e = load(&bytes, &Limits::default())
            .err()
            .unwrap_or_else(|| panic!("{name} loaded"));
        assert_eq!(e.code(), code, "{name}: {e}");
    }
    // The same file with an index in range loads.
    assert!(load(text.replace("99999", "2").as_bytes(), &Limits::default()).is_ok());
}

#[test]
fn a_coloured_ply_and_an_stl_rig_into_valid_glbs() {
    if !common::ort_ready() {
        return;
    }
    let fig = helpers::figure_mesh();
    let tmp = tempfile::tempdir().unwrap();
    let mut outs = Vec::new();
    for (name, bytes) in [
        ("figure.ply", ply(&fig, "binary_little_endian", true)),
        ("figure.stl", stl_binary(&fig)),
    ] {
        let input = tmp.path().join(name);
        std::fs::write(&input, bytes).unwrap();
        let out = tmp.path().join(format!("{name}.glb"));
        common::rig(
            &input,
            &["--out", out.to_str().unwrap(), "--category", "humanoid"],
        );
        let back = load(&std::fs::read(&out).unwrap(), &Limits::default()).unwrap();
        assert_eq!(back.mesh.positions.len(), fig.positions.len(), "{name}");
        let doc = back.document.as_ref().unwrap();
        let attrs = &doc.root.meshes[0].primitives[0].attributes;
        assert_eq!(
            attrs.contains_key("COLOR_0"),
            name.ends_with(".ply"),
            "{name}"
        );
        assert!(attrs.contains_key("JOINTS_0") && attrs.contains_key("WEIGHTS_0"));
        outs.push(out);
    }
    common::assert_valid(&outs);
}
