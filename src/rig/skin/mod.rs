//! Geometric skinning: skin weights for any skeleton on any mesh, from distances measured
//! inside the mesh's volume.
//!
//! 1. [`voxel`]: the mesh becomes solid cells (surface plus enclosed interior).
//! 2. [`geodesic`]: each bone's distance field through those cells, so weights do not
//!    jump gaps (leg to leg, arm to torso) the way straight-line distance does.
//! 3. [`weights`]: each vertex blends its nearest bones, at most four, summing to 1.
//!
//! Separate parts of the mesh ([`components`]) keep to their own bones. A part that a
//! bone passes through takes only the bones passing through it (a robot's segmented
//! limbs stay rigid). A part no bone passes through but that touches the body (clothes,
//! eyes, a hat resting on the head) takes what the distances say. A part that floats free
//! of every bone's volume (a hat above the head, a sword held loose) is bound rigidly to
//! the single bone nearest to it on average, as an artist parents a prop.
//!
//! This is also the distance feature and the fallback of the learned skin model:
//! [`candidates_timed`] gives each vertex its nearest allowed bones, [`features`] what the
//! model reads, and [`skin_with`] lets the model choose among those bones when one is
//! loaded (a [`CandidateScorer`]: `infer::SkinModel` runs `models/skin/`).
//!
//! Welding, step 1 and each vertex's stencil cells need only the mesh: [`prepare`] runs
//! them before the skeleton is known, and [`Prepared::skin_timed`] does the rest.

mod components;
pub mod features;
mod geodesic;
mod learned;
mod prepare;
mod validate;
mod voxel;
mod weights;
mod weld;

use crate::mesh::Mesh;
use crate::rig::metrics::Segment;
use crate::rig::skeleton::SkeletonError;
use crate::rig::{Skeleton, SkinWeights};
use geodesic::{Nearest, Ring, Stamp, Stencils};
use glam::Vec3;
pub use learned::from_scores;
use prepare::Voxels;
pub use prepare::{into_skin_frame, prepare, skin_frame, Prepared};
use serde::Serialize;
use std::time::Instant;
pub use weld::Welded;

/// Candidate bones per vertex the learned model chooses among: more than the four kept
/// influences, so it can pass over bones artists leave unweighted.
pub const LEARNED_CANDIDATES: usize = 8;

/// The most cells along the longest side, so memory stays bounded (~7 MB of flags).
pub const MAX_RESOLUTION: usize = 192;

/// Knobs of [`skin`]. The defaults were tuned on the data set's `train` split.
#[derive(Clone, Debug)]
pub struct SkinConfig {
    /// Cells along the mesh's longest side (8 to [`MAX_RESOLUTION`]). Gaps narrower than
    /// a cell are not seen.
    pub resolution: usize,
    /// Influences per vertex, 1 to 4.
    pub max_influences: usize,
    /// Exponent of the inverse-distance falloff: larger is crisper.
    pub falloff: f32,
    /// Added to every distance, in cells, so vertices on a bone still blend near joints.
    pub softness: f32,
    /// Influences below this (after normalizing) are dropped.
    pub min_weight: f32,
    /// The most bones a skeleton may have.
    pub max_bones: usize,
    /// A joint is outside the mesh when it is farther than this fraction of the mesh's
    /// longest side beyond its bounding box; more than half the joints outside is refused.
    pub outside_margin: f32,
    /// Meshes with more distinct positions are skinned on a coarser copy of at most this
    /// many (grid clusters, [`Welded::coarsened`]) and every vertex takes its cluster's
    /// weights: generated meshes of a million vertices skin in the time of this many.
    /// 0: always at full resolution.
    pub max_vertices: usize,
}

/// Above every rig of `../shared/rigs` and `rigs_xdev` (their figures are at full
/// resolution), and where the learned model's time still fits the service's budget.
pub const DEFAULT_MAX_SKIN_VERTICES: usize = 40_000;

impl Default for SkinConfig {
    fn default() -> Self {
        SkinConfig {
            // 64 scores as 96 did on the dev split (learned: L1 0.4569 against 0.4549,
            // precision 0.769 / 0.773, recall 0.829 / 0.817, deformation 0.0109 / 0.0108)
            // at about half the time: the cells, and so the fields, are 3.4× fewer.
            resolution: 64,
            max_influences: 4,
            falloff: 10.0,
            softness: 0.5,
            min_weight: 0.05,
            max_bones: crate::mesh::scene::MAX_JOINTS as usize,
            outside_margin: crate::rig::placement::OUTSIDE_MARGIN,
            max_vertices: DEFAULT_MAX_SKIN_VERTICES,
        }
    }
}

impl SkinConfig {
    fn check(&self) -> Result<(), SkinError> {
        let ok = (8..=MAX_RESOLUTION).contains(&self.resolution)
            && (1..=4).contains(&self.max_influences)
            && self.falloff.is_finite()
            && self.falloff > 0.0
            && self.softness.is_finite()
            && self.softness >= 0.0
            && (0.0..0.5).contains(&self.min_weight)
            && self.outside_margin.is_finite()
            && self.outside_margin >= 0.0
            && (self.max_vertices == 0 || self.max_vertices >= 100);
        if ok {
            Ok(())
        } else {
            Err(SkinError::BadConfig(format!("{self:?}")))
        }
    }
}

/// Why skinning was refused. Each variant has a stable [`code`](SkinError::code).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SkinError {
    /// Codes `skeleton_empty`, `skeleton_too_many_bones`, `skeleton_not_a_tree` (a cycle
    /// or a parent index out of order), `skeleton_non_finite`, `skeleton_duplicate_name`.
    #[error("the skeleton is invalid: {0}")]
    Skeleton(#[from] SkeletonError),
    #[error(transparent)]
    OutsideMesh(#[from] crate::rig::placement::Misplaced),
    #[error("the mesh has no triangles to skin")]
    EmptyMesh,
    #[error("the mesh has a NaN or infinite vertex position")]
    NonFiniteMesh,
    #[error("triangle {0} names a vertex the mesh does not have")]
    BadTriangle(usize),
    #[error("invalid skinning configuration: {0}")]
    BadConfig(String),
    /// The learned model failed; `code` is the inference layer's
    /// ([`crate::infer::InferError::code`]).
    #[error("the skin model failed: {message}")]
    Model { code: &'static str, message: String },
}

impl SkinError {
    pub fn code(&self) -> &'static str {
        match self {
            SkinError::Skeleton(e) => e.code(),
            SkinError::OutsideMesh(_) => "skeleton_outside_mesh",
            SkinError::EmptyMesh => "skin_empty_mesh",
            SkinError::NonFiniteMesh => "skin_non_finite_mesh",
            SkinError::BadTriangle(_) => "skin_bad_triangle",
            SkinError::BadConfig(_) => "skin_bad_config",
            SkinError::Model { code, .. } => code,
        }
    }
}

/// Where the time of one [`skin_timed`] call went, in milliseconds.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct SkinTimings {
    pub voxelize_ms: f64,
    pub geodesic_ms: f64,
    pub weights_ms: f64,
    /// Features and the learned model (zero for geometric weights).
    pub model_ms: f64,
    pub solid_cells: usize,
    pub parts: usize,
}

/// Skin weights for every vertex of `mesh`, bound to `skeleton` (bones in the mesh's
/// frame, as [`crate::mesh::load`] and [`crate::rig::groundtruth::extract`] give them).
///
/// Every vertex gets 1 to `cfg.max_influences` (bone index, weight) pairs with positive
/// weights summing to 1; none is left unweighted. The skeleton is checked first: see
/// [`SkinError`] for what is refused. Deterministic: equal inputs give equal weights.
pub fn skin(mesh: &Mesh, skeleton: &Skeleton, cfg: &SkinConfig) -> Result<SkinWeights, SkinError> {
    skin_timed(mesh, skeleton, cfg).map(|(w, _)| w)
}

/// What the learned skin model is to this module: it scores each vertex's candidate
/// bones from their features. Implemented by `infer::SkinModel`; a trait so that `rig`
/// does not depend on the inference layer that depends on it.
pub use features::SkinFeatures;

pub trait CandidateScorer: Send + Sync {
    /// One score per row of `f` (per vertex, per candidate); on failure a stable code
    /// and a message.
    fn scores(&self, f: &SkinFeatures) -> Result<Vec<f32>, (&'static str, String)>;
}

/// [`skin`] with the learned model when one is given (see [`CandidateScorer`]), the geometric
/// weights otherwise. Same guarantees as [`skin`]; the model only chooses among each
/// vertex's nearest allowed bones, so the per-part rules still hold.
pub fn skin_with(
    mesh: &Mesh,
    skeleton: &Skeleton,
    cfg: &SkinConfig,
    model: Option<&dyn CandidateScorer>,
) -> Result<SkinWeights, SkinError> {
    skin_with_timed(mesh, skeleton, cfg, model).map(|(w, _)| w)
}

/// [`skin_with`], also reporting where the time went. Vertices at the same position
/// (glTF's seams) are skinned once and get the same weights ([`weld`]).
pub fn skin_with_timed(
    mesh: &Mesh,
    skeleton: &Skeleton,
    cfg: &SkinConfig,
    model: Option<&dyn CandidateScorer>,
) -> Result<(SkinWeights, SkinTimings), SkinError> {
    // Checked here in full first, so a call refuses what it always did, in that order.
    validate::check(mesh, skeleton, cfg)?;
    Prepared::checked(mesh, cfg).skin_checked(skeleton, cfg, model)
}

/// How a part of the mesh chooses its bones.
enum Binding {
    /// Only these bones (they pass through the part).
    Bones(Vec<bool>),
    /// Whatever bones reach it through the volume.
    Reachable,
    /// This bone alone.
    Rigid(u32),
}

/// [`skin`], also reporting where the time went.
pub fn skin_timed(
    mesh: &Mesh,
    skeleton: &Skeleton,
    cfg: &SkinConfig,
) -> Result<(SkinWeights, SkinTimings), SkinError> {
    skin_with_timed(mesh, skeleton, cfg, None)
}

/// Geometric weights of every vertex of `mesh` as it is (no welding), `voxels` being
/// the mesh's.
fn geometric_in(
    mesh: &Mesh,
    voxels: &Voxels,
    skeleton: &Skeleton,
    cfg: &SkinConfig,
) -> Result<(SkinWeights, SkinTimings), SkinError> {
    // Two spare candidates beyond the kept influences: enough for the inverse-distance
    // blend, whose weights depend only on the nearest `max_influences`.
    let (cands, mut times) = candidates_in(mesh, voxels, skeleton, cfg, cfg.max_influences + 2)?;
    let t2 = Instant::now();
    let out = cands.geometric(cfg);
    times.weights_ms = ms(t2);
    Ok((out, times))
}

/// The bones a vertex may take, decided by the per-part rules of the module docs.
#[derive(Clone, Debug, PartialEq)]
pub enum VertexBones {
    /// The part floats free: this bone alone, weight 1.
    Rigid(u32),
    /// The nearest allowed bones `(bone, distance in mesh units)`, nearest first;
    /// geodesic through the volume, or straight-line when the volume does not reach
    /// the vertex (`geodesic` false). Never empty: a part may always use at least one
    /// bone, and a vertex outside every part may use them all.
    Near {
        bones: Vec<(u32, f32)>,
        geodesic: bool,
    },
}

/// Each vertex's candidate bones: what geometric weights blend and what the learned
/// model rescores.
#[derive(Clone, Debug)]
pub struct Candidates {
    pub per_vertex: Vec<VertexBones>,
    /// Voxel size, in mesh units.
    pub cell: f32,
}

impl Candidates {
    /// Inverse-distance weights (`weights::from_distances`) over the candidates.
    pub fn geometric(&self, cfg: &SkinConfig) -> SkinWeights {
        let mut out = SkinWeights {
            per_vertex: self
                .per_vertex
                .iter()
                .map(|v| match v {
                    VertexBones::Rigid(b) => vec![(*b, 1.0)],
                    VertexBones::Near { bones, .. } => {
                        weights::from_distances(bones, cfg, self.cell)
                    }
                })
                .collect(),
        };
        out.normalize();
        out
    }
}

/// The `k` nearest allowed bones of every vertex (see [`Candidates`]), checked and
/// timed like [`skin_timed`] (`weights_ms` is left at zero).
pub fn candidates_timed(
    mesh: &Mesh,
    skeleton: &Skeleton,
    cfg: &SkinConfig,
    k: usize,
) -> Result<(Candidates, SkinTimings), SkinError> {
    validate::check(mesh, skeleton, cfg)?;
    candidates_in(mesh, &Voxels::new(mesh, cfg), skeleton, cfg, k)
}

/// [`candidates_timed`] with the mesh already checked and voxelized, `voxels` being the
/// mesh's; the skeleton is checked by the caller.
fn candidates_in(
    mesh: &Mesh,
    voxels: &Voxels,
    skeleton: &Skeleton,
    cfg: &SkinConfig,
    k: usize,
) -> Result<(Candidates, SkinTimings), SkinError> {
    let k = k.max(cfg.max_influences).max(1);
    let pos = &mesh.positions;
    let Voxels {
        parts,
        part_solids,
        volume,
        stencils,
        ..
    } = voxels;
    let mut times = SkinTimings {
        voxelize_ms: voxels.ms,
        solid_cells: volume.cells.len(),
        parts: parts.triangles.len(),
        ..SkinTimings::default()
    };

    let t1 = Instant::now();
    let segs: Vec<Segment> = skeleton
        .bones
        .iter()
        .map(|b| Segment {
            a: b.head,
            b: b.tail,
        })
        .collect();
    let mut stamp = Stamp::new(volume.solid().len());
    let on_bone: Vec<Vec<(u32, f32)>> = segs
        .iter()
        .map(|s| volume.cells_on(s, &mut stamp))
        .collect();
    let seeds: Vec<Vec<(u32, u32)>> = segs
        .iter()
        .zip(&on_bone)
        .map(|(s, on)| volume.seeds(s, on))
        .collect();
    let mut seeded_blob = vec![false; volume.cells.len().max(1)];
    for &(c, _) in seeds.iter().flatten() {
        if let Some(b) = seeded_blob.get_mut(volume.blob[c as usize] as usize) {
            *b = true;
        }
    }
    let bindings: Vec<Binding> = part_solids
        .iter()
        .enumerate()
        .map(|(p, (region, s))| {
            let through: Vec<bool> = on_bone
                .iter()
                .map(|cells| {
                    cells.iter().any(|&(c, _)| {
                        region
                            .local(volume.grid.coords(c as usize))
                            .is_some_and(|l| s[l])
                    })
                })
                .collect();
            if through.iter().any(|&t| t) {
                return Binding::Bones(through);
            }
            let first = mesh.triangles[parts.triangles[p][0]][0] as usize;
            let blob = Stencils::new(volume, &pos[first..=first])
                .cells
                .first()
                .map(|&(c, _)| volume.blob[c as usize]);
            match blob.and_then(|b| seeded_blob.get(b as usize)) {
                Some(true) => Binding::Reachable,
                _ => Binding::Rigid(nearest_on_average(
                    pos,
                    &mesh.triangles,
                    &parts.triangles[p],
                    &segs,
                )),
            }
        })
        .collect();

    let mut nearest: Vec<Vec<(u32, f32)>> = vec![Vec::new(); pos.len()];
    let (mut dist, mut ring) = (Vec::new(), Ring::default());
    // A bone's field need only cover where it is among the k nearest of the bones that
    // every vertex may take: where k of those are nearer, no vertex can want it. Bones
    // some part may not take never bound the others (that part might need the bone
    // they outrank).
    let everywhere: Vec<bool> = (0..segs.len())
        .map(|b| {
            bindings.iter().all(|p| match p {
                Binding::Bones(ok) => ok[b],
                Binding::Reachable | Binding::Rigid(_) => true,
            })
        })
        .collect();
    let mut pruning =
        (everywhere.iter().filter(|&&e| e).count() >= k).then(|| Nearest::new(volume, k));
    // Bones every vertex may take first: only they bound the others.
    let order = (0..segs.len())
        .filter(|&b| everywhere[b])
        .chain((0..segs.len()).filter(|&b| !everywhere[b]));
    for b in order {
        let bounds = pruning.as_mut().map(|n| (n, everywhere[b]));
        volume.field(&seeds[b], &mut dist, &mut ring, bounds);
        for (v, cands) in nearest.iter_mut().enumerate() {
            let allowed = match parts.of_vertex[v].map(|p| &bindings[p as usize]) {
                Some(Binding::Bones(ok)) => ok[b],
                Some(Binding::Reachable) => true,
                _ => false,
            };
            if allowed {
                if let Some(d) = stencils.distance(volume, v, &dist) {
                    insert_nearest(cands, (b as u32, d), k);
                }
            }
        }
    }

    let per_vertex = nearest
        .into_iter()
        .enumerate()
        .map(|(v, mut cands)| {
            let binding = parts.of_vertex[v].map(|p| &bindings[p as usize]);
            if let Some(Binding::Rigid(b)) = binding {
                return VertexBones::Rigid(*b);
            }
            let geodesic = !cands.is_empty();
            if !geodesic {
                // Not reached through the volume: straight-line distance to the bones the
                // part may use.
                for (b, s) in segs.iter().enumerate() {
                    if !matches!(binding, Some(Binding::Bones(ok)) if !ok[b]) {
                        insert_nearest(&mut cands, (b as u32, s.distance(pos[v])), k);
                    }
                }
            }
            VertexBones::Near {
                bones: cands,
                geodesic,
            }
        })
        .collect();
    times.geodesic_ms = ms(t1);
    Ok((
        Candidates {
            per_vertex,
            cell: volume.grid.cell,
        },
        times,
    ))
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Keeps `list` as the `k` nearest, sorted nearest first; equal distances by bone index,
/// so the result does not depend on the order bones are offered in.
fn insert_nearest(list: &mut Vec<(u32, f32)>, item: (u32, f32), k: usize) {
    let before = |x: &(u32, f32)| x.1 < item.1 || (x.1 == item.1 && x.0 < item.0);
    if list.len() == k && list.last().is_some_and(before) {
        return;
    }
    let at = list.partition_point(before);
    list.insert(at, item);
    list.truncate(k);
}

/// The bone whose segment is nearest to the part's vertices on average.
fn nearest_on_average(
    pos: &[Vec3],
    triangles: &[[u32; 3]],
    tris: &[usize],
    segs: &[Segment],
) -> u32 {
    let mut verts: Vec<u32> = tris.iter().flat_map(|&t| triangles[t]).collect();
    verts.sort_unstable();
    verts.dedup();
    // A few hundred vertices spread over the part decide as well as all of them.
    let step = (verts.len() / 256).max(1);
    let sample: Vec<Vec3> = verts
        .iter()
        .step_by(step)
        .map(|&v| pos[v as usize])
        .collect();
    (0..segs.len())
        .map(|b| {
            let mean =
                sample.iter().map(|&p| segs[b].distance(p)).sum::<f32>() / sample.len() as f32;
            (b as u32, mean)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0, |x| x.0)
}
