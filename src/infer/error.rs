use std::path::PathBuf;

/// Everything the inference layer can fail with. Start-up failures (library, model files,
/// contract) are distinct variants so a server can refuse to start with a precise message;
/// per-request failures carry what the caller sent wrong.
///
/// `Clone` because one failed batch call is reported to every request in the batch.
#[derive(Debug, Clone, thiserror::Error)]
pub enum InferError {
    #[error("ONNX Runtime library not found (tried {})", display_paths(.tried))]
    LibraryNotFound { tried: Vec<PathBuf> },
    #[error("ONNX Runtime library {path} could not be loaded: {message}")]
    LibraryLoad { path: PathBuf, message: String },
    #[error("ONNX Runtime is already loaded from {loaded}; cannot switch to {requested} in the same process")]
    LibraryConflict { loaded: PathBuf, requested: PathBuf },
    #[error("ONNX Runtime environment: {0}")]
    Environment(String),
    #[error("model file {0} not found")]
    ModelNotFound(PathBuf),
    #[error("model file {path} could not be loaded: {message}")]
    ModelLoad { path: PathBuf, message: String },
    #[error("model {path} breaks its rigserve contract (skeleton-v2 or skin-v1): {problem}")]
    Contract { path: PathBuf, problem: String },
    #[error("invalid request: {0}")]
    InvalidRequest(String),
    #[error("ONNX Runtime failed in {op}: {message}")]
    Run { op: &'static str, message: String },
    #[error("model output {name} has shape {got:?}, expected {expected}")]
    OutputShape {
        name: String,
        got: Vec<usize>,
        expected: String,
    },
    #[error("no token is allowed at step {step}: every allowed token has a non-finite logit or lies outside the model's vocabulary")]
    NoAllowedToken { step: usize },
    #[error("the inference backend has shut down")]
    BackendGone,
    #[error("the request was canceled")]
    Canceled,
}

impl InferError {
    /// Stable machine-readable code, for API error bodies and logs.
    pub fn code(&self) -> &'static str {
        match self {
            InferError::LibraryNotFound { .. } => "ort_library_not_found",
            InferError::LibraryLoad { .. } => "ort_library_load_failed",
            InferError::LibraryConflict { .. } => "ort_library_conflict",
            InferError::Environment(_) => "ort_environment_failed",
            InferError::ModelNotFound(_) => "model_not_found",
            InferError::ModelLoad { .. } => "model_load_failed",
            InferError::Contract { .. } => "model_contract_mismatch",
            InferError::InvalidRequest(_) => "invalid_request",
            InferError::Run { .. } => "inference_failed",
            InferError::OutputShape { .. } => "model_output_shape",
            InferError::NoAllowedToken { .. } => "no_allowed_token",
            InferError::BackendGone => "backend_gone",
            InferError::Canceled => "canceled",
        }
    }

    /// Whether the failure happened while starting up (library, files, contract), as
    /// opposed to while serving a request.
    pub fn is_startup(&self) -> bool {
        matches!(
            self,
            InferError::LibraryNotFound { .. }
                | InferError::LibraryLoad { .. }
                | InferError::LibraryConflict { .. }
                | InferError::Environment(_)
                | InferError::ModelNotFound(_)
                | InferError::ModelLoad { .. }
                | InferError::Contract { .. }
        )
    }

    pub(crate) fn run(op: &'static str, e: impl std::fmt::Display) -> Self {
        InferError::Run {
            op,
            message: e.to_string(),
        }
    }
}

fn display_paths(p: &[PathBuf]) -> String {
    p.iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}
