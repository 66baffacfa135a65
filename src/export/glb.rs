//! [`export_glb`]: a skinned GLB from an uploaded asset and a rig for its merged mesh.

use super::weights::pack_all;
use super::{container, fresh, rewrite, ExportError, ExportOptions};
use crate::mesh::scene::MAX_JOINTS;
use crate::mesh::Asset;
use crate::rig::{Skeleton, SkinWeights};

/// Writes `asset` as a GLB skinned to `skeleton` with `weights`.
///
/// `weights` has one list per merged vertex of `asset.mesh` (bone indices into
/// `skeleton`), and the skeleton is in the mesh's world frame, as inference and
/// [`crate::rig::groundtruth::extract`] produce them. Per vertex the `max_influences`
/// largest weights are kept and normalised so the stored f32 values sum to 1 within
/// half an f32 ulp (3e-8). A vertex with no positive weight is bound with weight 1 to the bone whose
/// head-to-tail segment is nearest, since glTF cannot leave a skinned vertex unweighted.
///
/// Joint `k` of every skin is bone `k`; each joint node is translated only (its rest
/// frame is `T(head)`), so posing bone `k` by a rotation about its head in the glTF
/// world frame is what [`crate::rig::metrics::pose_one_bone`] computes.
///
/// glTF inputs keep everything they had except their old skins (see the `rewrite`
/// module docs for exactly what is replaced); OBJ inputs become a new single-mesh glTF.
/// Re-loading the result with [`crate::mesh::load`] gives the same merged mesh in the
/// same vertex order, and [`crate::rig::groundtruth::extract`] gives back this skeleton
/// (heads) and these weights.
pub fn export_glb(
    asset: &Asset,
    skeleton: &Skeleton,
    weights: &SkinWeights,
    opts: &ExportOptions,
) -> Result<Vec<u8>, ExportError> {
    // The loader's cap, so that rigserve can always read its own output back.
    skeleton.validate(MAX_JOINTS as usize)?;
    let packed = pack_all(&asset.mesh, skeleton, weights, opts.max_influences)?;
    let built = match &asset.document {
        Some(doc) => rewrite::rewrite(doc, &asset.mesh, skeleton, &packed, opts)?,
        None => fresh::build(&asset.mesh, &asset.colors, skeleton, &packed, opts)?,
    };
    container::write_glb(&serde_json::Value::Object(built.root), &built.bin)
}
