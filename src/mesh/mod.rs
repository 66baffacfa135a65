//! Mesh input: every supported format becomes one [`Mesh`] in world space.
//!
//! Inference sees all primitives merged; export needs to write weights back into the
//! primitives they came from, so each merged range remembers its source in a [`Part`].

mod conform;
mod draco;
mod error;
pub mod gltf;
mod json;
mod meshopt;
mod normalize;
mod obj;
mod plain;
mod ply;
pub mod sample;
pub mod scene;
mod stl;

pub use error::MeshError;
pub use normalize::Normalization;
pub use sample::{sample_surface, SurfaceSamples};

use glam::{Mat4, Vec3};

/// Caps that bound the work and memory any single upload can cost.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub max_bytes: u64,
    pub max_vertices: u64,
    pub max_triangles: u64,
    pub max_nodes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_bytes: 256 << 20,
            max_vertices: 2_000_000,
            max_triangles: 2_000_000,
            max_nodes: 100_000,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Glb,
    Gltf,
    Vrm,
    Obj,
    Ply,
    Stl,
}

/// Where a range of merged vertices came from.
#[derive(Clone, Debug)]
pub struct Part {
    /// The glTF node instancing the mesh (None for OBJ).
    pub node: Option<usize>,
    /// glTF mesh index, or OBJ object/group index.
    pub mesh: usize,
    pub primitive: usize,
    pub name: Option<String>,
    pub first_vertex: u32,
    pub vertex_count: u32,
    pub first_triangle: u32,
    pub triangle_count: u32,
    /// Takes the primitive's stored positions to [`Mesh::positions`]. Identity for
    /// skinned primitives, whose node transform glTF says to ignore.
    pub to_world: Mat4,
    /// The source skin, when the primitive was skinned in the input.
    pub skin: Option<usize>,
}

#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub parts: Vec<Part>,
}

/// A loaded upload: the merged mesh and, for glTF inputs, the document to export into.
#[derive(Debug)]
pub struct Asset {
    pub format: Format,
    pub mesh: Mesh,
    pub document: Option<gltf::Document>,
    /// Per vertex of `mesh`, RGBA in 0..1, from formats that carry colours outside a
    /// glTF document (PLY); written as `COLOR_0`. Empty otherwise.
    pub colors: Vec<[f32; 4]>,
}

/// Guesses the format from the first bytes (and the file name, for OBJ vs. JSON).
pub fn sniff(bytes: &[u8]) -> Option<Format> {
    if gltf::is_glb(bytes) {
        return Some(Format::Glb);
    }
    if ply::is_ply(bytes) {
        return Some(Format::Ply);
    }
    if stl::is_binary(bytes) {
        return Some(Format::Stl);
    }
    let head = &bytes[..bytes.len().min(4096)];
    let text = std::str::from_utf8(head).ok().or_else(|| {
        // A 4 KiB window can cut a UTF-8 sequence; accept the valid prefix.
        std::str::from_utf8(&head[..head.len().saturating_sub(3)]).ok()
    })?;
    let t = text.trim_start_matches('\u{feff}').trim_start();
    if t.starts_with('{') {
        return Some(Format::Gltf);
    }
    if stl::is_ascii(t) {
        return Some(Format::Stl);
    }
    let obj_like = t.lines().any(|l| {
        let l = l.trim_start();
        l.starts_with("v ") || l.starts_with("f ") || l.starts_with("o ") || l.starts_with("vn ")
    });
    let all_text = t
        .lines()
        .all(|l| l.is_empty() || l.starts_with('#') || !l.contains('\0'));
    (obj_like && all_text).then_some(Format::Obj)
}

/// Loads any supported format. Never panics; every failure is a [`MeshError`].
pub fn load(bytes: &[u8], limits: &Limits) -> Result<Asset, MeshError> {
    if bytes.is_empty() {
        return Err(MeshError::Empty);
    }
    if bytes.len() as u64 > limits.max_bytes {
        return Err(MeshError::TooLarge {
            size: bytes.len() as u64,
            cap: limits.max_bytes,
        });
    }
    let format = sniff(bytes).ok_or(MeshError::UnknownFormat)?;
    let mut colors = Vec::new();
    let (format, mesh, document) = match format {
        Format::Obj => (Format::Obj, obj::load(bytes, limits)?, None),
        Format::Stl => (Format::Stl, stl::load(bytes, limits)?, None),
        Format::Ply => {
            let (mesh, c) = ply::load(bytes, limits)?;
            colors = c;
            (Format::Ply, mesh, None)
        }
        Format::Glb | Format::Gltf | Format::Vrm => {
            let doc = if format == Format::Glb {
                gltf::parse_glb(bytes, limits)?
            } else {
                gltf::parse_document(bytes, None, limits)?
            };
            let is_vrm = doc
                .root
                .extensions_used
                .iter()
                .any(|e| e == "VRM" || e == "VRMC_vrm");
            let mesh = scene::build(&doc, limits)?;
            let format = if is_vrm { Format::Vrm } else { format };
            (format, mesh, Some(doc))
        }
    };
    validate_geometry(&mesh)?;
    Ok(Asset {
        format,
        mesh,
        document,
        colors,
    })
}

fn validate_geometry(mesh: &Mesh) -> Result<(), MeshError> {
    if mesh.triangles.is_empty() {
        return Err(MeshError::EmptyScene);
    }
    if mesh.positions.iter().any(|p| !p.is_finite()) {
        return Err(MeshError::NonFinite);
    }
    // Measured in the unit frame, in f32, as the samplers will measure it: relative to
    // the mesh's size, so tiny-but-real models (millimetre units) still pass, and a
    // corner 1e38 out (areas that overflow to infinity in the file's frame and vanish in
    // the unit frame) is refused here rather than failing its job at sampling.
    let norm = Normalization::from_points(&mesh.positions);
    let area: f64 = mesh
        .triangles
        .iter()
        .map(|t| corners_area(t.map(|i| norm.apply(mesh.positions[i as usize]))) as f64)
        .sum();
    // NaN area (from non-finite input) is degenerate too, hence not `area <= 1e-12`.
    if area.is_nan() || area <= 1e-12 {
        return Err(MeshError::Degenerate);
    }
    Ok(())
}

pub(crate) fn triangle_area(mesh: &Mesh, t: &[u32; 3]) -> f32 {
    corners_area(t.map(|i| mesh.positions[i as usize]))
}

fn corners_area([a, b, c]: [Vec3; 3]) -> f32 {
    (b - a).cross(c - a).length() * 0.5
}

/// The key of a position for welding: its bits, with -0.0 and 0.0 the same place.
pub fn position_key(p: Vec3) -> [u32; 3] {
    (p + Vec3::ZERO).to_array().map(f32::to_bits)
}

impl Mesh {
    /// Every triangle split into four at its edge midpoints (shared between neighbours,
    /// so the surface stays closed where it was): the same shape, denser, for measuring
    /// and testing high-poly inputs. Positions and triangles only.
    pub fn subdivided(&self) -> Mesh {
        let mut positions = self.positions.clone();
        let mut mid: std::collections::HashMap<(u32, u32), u32> = Default::default();
        let mut midpoint = |a: u32, b: u32, positions: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                positions.push((positions[a as usize] + positions[b as usize]) * 0.5);
                positions.len() as u32 - 1
            })
        };
        let mut triangles = Vec::with_capacity(self.triangles.len() * 4);
        for &[a, b, c] in &self.triangles {
            let ab = midpoint(a, b, &mut positions);
            let bc = midpoint(b, c, &mut positions);
            let ca = midpoint(c, a, &mut positions);
            triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        Mesh {
            positions,
            triangles,
            ..Mesh::default()
        }
    }

    /// Area-weighted vertex normals, for inputs that lack them.
    pub fn compute_normals(&mut self) {
        let mut n = vec![Vec3::ZERO; self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions[i as usize]);
            let f = (b - a).cross(c - a);
            for &i in t {
                n[i as usize] += f;
            }
        }
        self.normals = n.into_iter().map(|v| v.normalize_or_zero()).collect();
    }

    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        )
    }
}

/// A closed box from `lo` to `hi`, two outward-facing triangles per face (for tests).
#[cfg(test)]
pub(crate) fn box_mesh(lo: Vec3, hi: Vec3) -> Mesh {
    let mut m = Mesh::default();
    for i in 0..8u32 {
        m.positions.push(Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        ));
    }
    // Counter-clockwise seen from outside.
    m.triangles = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    m.compute_normals();
    m
}
