//! Refuses skeletons and meshes that cannot be skinned, before any work is done.

use super::{SkinConfig, SkinError};
use crate::mesh::Mesh;
use crate::rig::Skeleton;
use glam::Vec3;

/// Checks the skeleton's own invariants ([`Skeleton::validate`]), the mesh, and that the
/// skeleton sits on the mesh: a rig in other units or another frame puts most joints far
/// outside the mesh's box, and skinning it would bind everything to whichever bone
/// happens to be nearest.
pub fn check(mesh: &Mesh, skeleton: &Skeleton, cfg: &SkinConfig) -> Result<(), SkinError> {
    cfg.check()?;
    skeleton.validate(cfg.max_bones)?;
    mesh_alone(mesh)?;
    sits_on(mesh.bounds(), skeleton, cfg)
}

/// The settings and the mesh alone (what voxelizing needs of them).
pub fn check_mesh(mesh: &Mesh, cfg: &SkinConfig) -> Result<(), SkinError> {
    cfg.check()?;
    mesh_alone(mesh)
}

/// The skeleton, and that it sits on the (checked) mesh whose bounding box is `bounds`.
pub fn check_skeleton(
    bounds: (Vec3, Vec3),
    skeleton: &Skeleton,
    cfg: &SkinConfig,
) -> Result<(), SkinError> {
    skeleton.validate(cfg.max_bones)?;
    sits_on(bounds, skeleton, cfg)
}

fn mesh_alone(mesh: &Mesh) -> Result<(), SkinError> {
    if mesh.positions.is_empty() || mesh.triangles.is_empty() {
        return Err(SkinError::EmptyMesh);
    }
    if mesh.positions.iter().any(|p| !p.is_finite()) {
        return Err(SkinError::NonFiniteMesh);
    }
    let n = mesh.positions.len() as u32;
    if let Some(t) = mesh
        .triangles
        .iter()
        .position(|t| t.iter().any(|&i| i >= n))
    {
        return Err(SkinError::BadTriangle(t));
    }
    Ok(())
}

fn sits_on(bounds: (Vec3, Vec3), skeleton: &Skeleton, cfg: &SkinConfig) -> Result<(), SkinError> {
    let (lo, hi) = bounds;
    Ok(crate::rig::placement::check(
        skeleton,
        lo,
        hi,
        cfg.outside_margin,
    )?)
}
