//! Loading the ONNX Runtime shared library (the `ort` crate's `load-dynamic` mode).
//!
//! ONNX Runtime allows one environment per process and `ort` loads the library once, so
//! both live in a process-wide [`Runtime`]: the first successful [`Runtime::init`] fixes
//! the library, and later calls hand out the same environment.

use super::InferError;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// File name of the library `scripts/setup.sh` unpacks.
pub const ORT_LIB_NAME: &str = "libonnxruntime.so.1.31.1";
/// Where `scripts/setup.sh` puts it, relative to the repository root.
pub const ORT_LIB_DEFAULT: &str = ".onnxruntime/libonnxruntime.so.1.31.1";
/// Environment variable naming the library (the CLI's `--ort-lib` reads it too).
pub const ORT_LIB_ENV: &str = "RIGSERVE_ORT_LIB";

/// A loaded ONNX Runtime and its (single) environment. Cheap to clone.
#[derive(Clone, Debug)]
pub struct Runtime {
    env: ort::environment::Environment,
    library: PathBuf,
}

static RUNTIME: Mutex<Option<Runtime>> = Mutex::new(None);

impl Runtime {
    /// Loads the library (`explicit`, else [`ORT_LIB_ENV`], else the default locations; see
    /// [`resolve_library`]) once per process. A later call naming a different file fails
    /// with [`InferError::LibraryConflict`] rather than silently using the first one.
    pub fn init(explicit: Option<&Path>) -> Result<Runtime, InferError> {
        let mut slot = RUNTIME.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(rt) = slot.as_ref() {
            if let Some(want) = explicit {
                let want = absolute(want);
                if !same_file(&want, &rt.library) {
                    return Err(InferError::LibraryConflict {
                        loaded: rt.library.clone(),
                        requested: want,
                    });
                }
            }
            return Ok(rt.clone());
        }
        let library = resolve_library(explicit)?;
        let builder = ort::init_from(&library).map_err(|e| InferError::LibraryLoad {
            path: library.clone(),
            message: e.to_string(),
        })?;
        let env = builder
            .with_name("rigserve")
            .build()
            .map_err(|e| InferError::Environment(e.to_string()))?;
        let rt = Runtime { env, library };
        *slot = Some(rt.clone());
        Ok(rt)
    }

    pub fn library(&self) -> &Path {
        &self.library
    }

    pub(crate) fn env(&self) -> &ort::environment::Environment {
        &self.env
    }
}

/// The library file to load: `explicit`, else `$RIGSERVE_ORT_LIB`, else
/// [`ORT_LIB_DEFAULT`] under the current directory, then beside the executable (and its
/// parents up to three levels, which covers `target/release/` in a checkout). The first
/// candidate that exists wins; an explicit path is never second-guessed.
pub fn resolve_library(explicit: Option<&Path>) -> Result<PathBuf, InferError> {
    let mut tried = Vec::new();
    let named = explicit.map(Path::to_path_buf).or_else(|| {
        std::env::var_os(ORT_LIB_ENV)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    });
    if let Some(p) = named {
        let p = absolute(&p);
        if p.is_file() {
            return Ok(p);
        }
        return Err(InferError::LibraryNotFound { tried: vec![p] });
    }
    if let Ok(cwd) = std::env::current_dir() {
        tried.push(cwd.join(ORT_LIB_DEFAULT));
    }
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        tried.push(dir.join(ORT_LIB_NAME));
        let mut d = Some(dir.as_path());
        for _ in 0..4 {
            let Some(cur) = d else { break };
            tried.push(cur.join(ORT_LIB_DEFAULT));
            d = cur.parent();
        }
    }
    tried.dedup();
    match tried.iter().find(|p| p.is_file()) {
        Some(p) => Ok(p.clone()),
        None => Err(InferError::LibraryNotFound { tried }),
    }
}

fn absolute(p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir()
            .map(|d| d.join(p))
            .unwrap_or_else(|_| p.to_path_buf())
    }
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}
