//! What skinning needs of the mesh alone: its parts and their voxels, the solid volume,
//! and each vertex's stencil cells. None of it depends on the skeleton, so a job builds
//! it while its skeleton is still being decoded ([`prepare`]): the worker would
//! otherwise sit waiting on the inference thread, and under load that wait is where one
//! of the two cores went idle (README, "The Zen 4 again").

use super::components::{self, Components};
use super::geodesic::{Stencils, Volume};
use super::voxel::{self, Grid, Region};
use super::{ms, validate, CandidateScorer, SkinConfig, SkinError, SkinTimings, Welded};
use crate::mesh::{Mesh, Normalization};
use crate::rig::{Skeleton, SkinWeights};
use glam::Vec3;
use std::time::Instant;

/// The voxel side of one mesh, as [`super::candidates_timed`] reads it.
pub struct Voxels {
    pub(super) parts: Components,
    /// Each part's own solid cells, in its region of the grid.
    pub(super) part_solids: Vec<(Region, Vec<bool>)>,
    /// The whole mesh's solid cells.
    pub(super) volume: Volume,
    /// Every vertex's stencil cells in `volume`.
    pub(super) stencils: Stencils,
    /// Time taken to build all of the above.
    pub(super) ms: f64,
}

impl Voxels {
    /// The mesh must have passed [`validate::check_mesh`] (finite positions, triangles
    /// naming its vertices).
    pub(super) fn new(mesh: &Mesh, cfg: &SkinConfig) -> Voxels {
        let t0 = Instant::now();
        let pos = &mesh.positions;
        let (lo, hi) = mesh.bounds();
        let grid = Grid::around(lo, hi, cfg.resolution);
        let whole = Region::whole(&grid);
        let parts = components::components(pos, &mesh.triangles);
        // Each triangle is rasterized once, for its part: every part covers its triangles'
        // cells, so the parts' surfaces together are the whole mesh's surface.
        let mut surface = vec![false; whole.len()];
        let part_solids: Vec<(Region, Vec<bool>)> = parts
            .triangles
            .iter()
            .map(|tris| {
                let (plo, phi) = tris.iter().flat_map(|&t| mesh.triangles[t]).fold(
                    (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
                    |(a, b), i| (a.min(pos[i as usize]), b.max(pos[i as usize])),
                );
                let region = Region::around(&grid, plo, phi, 2);
                let s = voxel::surface(pos, &mesh.triangles, tris.iter().copied(), &grid, &region);
                voxel::merge_into(&mut surface, &grid, &region, &s);
                let solid = voxel::fill(&s, &region);
                (region, solid)
            })
            .collect();
        let volume = Volume::new(grid, voxel::fill(&surface, &whole));
        let stencils = Stencils::new(&volume, pos);
        Voxels {
            parts,
            part_solids,
            volume,
            stencils,
            ms: ms(t0),
        }
    }
}

/// The frame skinning runs in: the mesh's units scaled by the power of two that brings its
/// longest half-side into [0.7, 1.4], not moved. Weights do not depend on the units, but in
/// a file's own units a mesh 1e30 long squared its distances past `f32` (every vertex went
/// to bone 0) and one 1e-7 long fell under the voxelizer's resolution (at 1e-10 nearly all
/// went to bone 0). A power of two, and no shift, so that every product, sum and square
/// root is the one the mesh's own units give, scaled exactly: a mesh already about a unit
/// across (most files, in metres) skins bit for bit as before.
pub fn skin_frame(positions: &[Vec3]) -> Normalization {
    let half = Normalization::from_points(positions).half_extent;
    let k = half.log2().round().clamp(-126.0, 126.0) as i32;
    Normalization {
        center: Vec3::ZERO,
        half_extent: 2f32.powi(k),
    }
}

/// Moves `mesh` into its [`skin_frame`] and returns that frame, for the skeleton to follow.
pub fn into_skin_frame(mesh: &mut Mesh) -> Normalization {
    let norm = skin_frame(&mesh.positions);
    for p in &mut mesh.positions {
        *p = norm.apply(*p);
    }
    norm
}

/// A mesh made ready for skinning by any skeleton: welded ([`Welded`]), scaled into its
/// [`skin_frame`] and voxelized; the skeleton follows the mesh there.
pub struct Prepared {
    /// Welded, its positions in the skin frame.
    welded: Welded,
    voxels: Voxels,
    norm: Normalization,
    /// The mesh's bounding box in its own frame, where skeletons are checked.
    bounds: (Vec3, Vec3),
}

/// Checks what can be checked of the mesh and the settings without a skeleton, then
/// welds and voxelizes the mesh. [`Prepared::skin_timed`] finishes the job.
pub fn prepare(mesh: &Mesh, cfg: &SkinConfig) -> Result<Prepared, SkinError> {
    validate::check_mesh(mesh, cfg)?;
    Ok(Prepared::checked(mesh, cfg))
}

impl Prepared {
    /// [`prepare`] of a mesh and settings the caller has checked.
    pub(super) fn checked(mesh: &Mesh, cfg: &SkinConfig) -> Prepared {
        // Welded in the file's frame, where copies of a vertex have equal bits.
        let mut welded = Welded::new(mesh);
        // The mesh's own box, not the coarse copy's (cluster means sit a little inside).
        let bounds = welded.mesh.bounds();
        if cfg.max_vertices > 0 {
            welded = welded.coarsened(cfg.max_vertices);
        }
        let norm = into_skin_frame(&mut welded.mesh);
        let voxels = Voxels::new(&welded.mesh, cfg);
        Prepared {
            welded,
            voxels,
            norm,
            bounds,
        }
    }

    /// [`super::skin_with_timed`] of the mesh this was prepared from, with the same
    /// `cfg`: the same weights, without voxelizing again.
    pub fn skin_timed(
        &self,
        skeleton: &Skeleton,
        cfg: &SkinConfig,
        model: Option<&dyn CandidateScorer>,
    ) -> Result<(SkinWeights, SkinTimings), SkinError> {
        validate::check_skeleton(self.bounds, skeleton, cfg)?;
        self.skin_checked(skeleton, cfg, model)
    }

    /// [`Prepared::skin_timed`] of a skeleton the caller has checked.
    pub(super) fn skin_checked(
        &self,
        skeleton: &Skeleton,
        cfg: &SkinConfig,
        model: Option<&dyn CandidateScorer>,
    ) -> Result<(SkinWeights, SkinTimings), SkinError> {
        let mesh = &self.welded.mesh;
        let mut unit = skeleton.clone();
        unit.map_points(|p| self.norm.apply(p));
        let (w, times) = match model {
            Some(m) => super::learned::skin_learned_in(mesh, &self.voxels, &unit, cfg, m)?,
            None => super::geometric_in(mesh, &self.voxels, &unit, cfg)?,
        };
        Ok((self.welded.spread(&w, cfg.max_influences), times))
    }

    /// [`Prepared::skin_timed`] without the timings.
    pub fn skin(
        &self,
        skeleton: &Skeleton,
        cfg: &SkinConfig,
        model: Option<&dyn CandidateScorer>,
    ) -> Result<SkinWeights, SkinError> {
        self.skin_timed(skeleton, cfg, model).map(|(w, _)| w)
    }
}
