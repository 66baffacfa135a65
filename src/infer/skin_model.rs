//! The learned skin model (`skin-v1`, `training/skin/ONNX_CONTRACT.md`): one ONNX session
//! that rescores each vertex's candidate bones ([`crate::rig::skin::features`]).
//!
//! Unlike the skeleton model it needs no decode loop, so it is called directly from the
//! skinning code; the session sits behind a mutex so one loaded model can be shared by
//! every worker (`&SkinModel` is `Sync`).

use super::model::{check_outlets, open_session, Dim, Expect, SessionConfig};
use super::{InferError, Runtime};
use crate::rig::skin::features::{SkinFeatures, BONE_FEATURES, PAIR_FEATURES, VERT_FEATURES};
use ndarray::{ArrayView2, ArrayView3};
use ort::session::Session;
use ort::value::{TensorElementType, TensorRef};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The only skin contract this crate speaks.
pub const SKIN_CONTRACT: &str = "skin-v1";

/// Rows per ONNX Runtime call: bounds the activations (rows × k × d floats) on large
/// meshes, while staying large enough that per-call overhead does not matter.
pub const ROWS_PER_CALL: usize = 4096;

pub struct SkinModel {
    session: Mutex<Session>,
    path: PathBuf,
}

impl std::fmt::Debug for SkinModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SkinModel")
            .field("path", &self.path)
            .finish()
    }
}

impl SkinModel {
    /// The model file under `path`: `path` itself when it is a file, else the first of
    /// `skin.onnx`, `skin.fp16.onnx` (as `training/skin/export.py` names them) in `path`
    /// or in `path/skin/` (a models root). None when there is none.
    pub fn find(path: &Path) -> Option<PathBuf> {
        if path.is_file() {
            return Some(path.to_path_buf());
        }
        [path.to_path_buf(), path.join("skin")]
            .iter()
            .flat_map(|d| ["skin.onnx", "skin.fp16.onnx"].map(|n| d.join(n)))
            .find(|p| p.is_file())
    }

    /// Loads the model found under `path` ([`SkinModel::find`]); `Ok(None)` when there is
    /// none, so callers fall back to geometric weights.
    pub fn load_if_present(
        rt: &Runtime,
        path: &Path,
        cfg: &SessionConfig,
    ) -> Result<Option<Self>, InferError> {
        Self::find(path)
            .map(|file| Self::load(rt, &file, cfg))
            .transpose()
    }

    /// Opens the file and checks its metadata and inputs against the contract.
    pub fn load(rt: &Runtime, path: &Path, cfg: &SessionConfig) -> Result<Self, InferError> {
        let session = open_session(rt, path, cfg)?;
        let bad = |problem: String| InferError::Contract {
            path: path.to_path_buf(),
            problem,
        };
        let contract = session
            .metadata()
            .map_err(|e| bad(format!("no metadata: {e}")))?
            .custom("rigserve.contract");
        match contract {
            Some(c) if c == SKIN_CONTRACT => {}
            other => {
                return Err(bad(format!(
                    "rigserve.contract is {other:?}, expected {SKIN_CONTRACT:?}"
                )))
            }
        }
        use Dim::*;
        use TensorElementType::{Float32, Int64};
        check_outlets(
            path,
            "inputs",
            session.inputs(),
            &[
                Expect {
                    name: "vert",
                    ty: Float32,
                    dims: &[Dynamic, Is(VERT_FEATURES)],
                },
                Expect {
                    name: "bone",
                    ty: Float32,
                    dims: &[Dynamic, Is(BONE_FEATURES)],
                },
                Expect {
                    name: "cand",
                    ty: Int64,
                    dims: &[Dynamic, Dynamic],
                },
                Expect {
                    name: "pair",
                    ty: Float32,
                    dims: &[Dynamic, Dynamic, Is(PAIR_FEATURES)],
                },
            ],
        )?;
        check_outlets(
            path,
            "outputs",
            session.outputs(),
            &[Expect {
                name: "weights",
                ty: Float32,
                dims: &[Dynamic, Dynamic],
            }],
        )?;
        Ok(SkinModel {
            session: Mutex::new(session),
            path: path.to_path_buf(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Weights over each row's candidates (rows × k, row-major), in chunks of
    /// [`ROWS_PER_CALL`] rows. Every chunk sees the whole skeleton.
    pub fn weights(&self, f: &SkinFeatures) -> Result<Vec<f32>, InferError> {
        let (rows, k, bones) = (f.rows.len(), f.k, f.bones());
        let sizes_ok = k > 0
            && bones > 0
            && f.vert.len() == rows * VERT_FEATURES
            && f.cand.len() == rows * k
            && f.pair.len() == rows * k * PAIR_FEATURES
            && f.bone.len() == bones * BONE_FEATURES;
        if !sizes_ok {
            return Err(InferError::InvalidRequest(format!(
                "skin features of inconsistent sizes: {rows} rows, k {k}, {bones} bones"
            )));
        }
        if let Some(&c) = f.cand.iter().find(|&&c| c < -1 || c >= bones as i64) {
            return Err(InferError::InvalidRequest(format!(
                "candidate bone {c} outside 0..{bones}"
            )));
        }
        let input = |e: ort::Error| InferError::run("skin input", e);
        let bone = ArrayView2::from_shape((bones, BONE_FEATURES), &f.bone)
            .map_err(|e| InferError::InvalidRequest(e.to_string()))?;
        let mut session = self.session.lock().unwrap_or_else(|p| p.into_inner());
        let mut out = Vec::with_capacity(rows * k);
        for lo in (0..rows).step_by(ROWS_PER_CALL) {
            let n = (rows - lo).min(ROWS_PER_CALL);
            let shape = |e: ndarray::ShapeError| InferError::InvalidRequest(e.to_string());
            let vert = ArrayView2::from_shape(
                (n, VERT_FEATURES),
                &f.vert[lo * VERT_FEATURES..(lo + n) * VERT_FEATURES],
            )
            .map_err(shape)?;
            let cand =
                ArrayView2::from_shape((n, k), &f.cand[lo * k..(lo + n) * k]).map_err(shape)?;
            let pair = ArrayView3::from_shape(
                (n, k, PAIR_FEATURES),
                &f.pair[lo * k * PAIR_FEATURES..(lo + n) * k * PAIR_FEATURES],
            )
            .map_err(shape)?;
            let result = session
                .run(ort::inputs![
                    "vert" => TensorRef::from_array_view(vert).map_err(input)?,
                    "bone" => TensorRef::from_array_view(bone).map_err(input)?,
                    "cand" => TensorRef::from_array_view(cand).map_err(input)?,
                    "pair" => TensorRef::from_array_view(pair).map_err(input)?,
                ])
                .map_err(|e| InferError::run("skin", e))?;
            let w = result["weights"]
                .try_extract_array::<f32>()
                .map_err(|e| InferError::run("skin output", e))?;
            if w.shape() != [n, k] {
                return Err(InferError::OutputShape {
                    name: "weights".into(),
                    got: w.shape().to_vec(),
                    expected: format!("[{n}, {k}]"),
                });
            }
            out.extend(w.iter().copied());
        }
        Ok(out)
    }
}

impl crate::rig::skin::CandidateScorer for SkinModel {
    fn scores(&self, f: &SkinFeatures) -> Result<Vec<f32>, (&'static str, String)> {
        self.weights(f).map_err(|e| (e.code(), e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_model_can_be_shared_by_worker_threads() {
        fn shared<T: Send + Sync>() {}
        shared::<SkinModel>();
    }

    #[test]
    fn find_prefers_the_given_file_then_fp32_then_fp16_then_a_models_root() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        assert_eq!(SkinModel::find(root), None);
        std::fs::create_dir(root.join("skin")).unwrap();
        std::fs::write(root.join("skin/skin.fp16.onnx"), b"x").unwrap();
        assert_eq!(
            SkinModel::find(root),
            Some(root.join("skin/skin.fp16.onnx"))
        );
        std::fs::write(root.join("skin/skin.onnx"), b"x").unwrap();
        assert_eq!(SkinModel::find(root), Some(root.join("skin/skin.onnx")));
        assert_eq!(
            SkinModel::find(&root.join("skin/skin.fp16.onnx")),
            Some(root.join("skin/skin.fp16.onnx"))
        );
    }
}
