//! rigserve: predicts skeletons and skin weights for bare 3D meshes.
//!
//! Data flows `mesh` → `rig` → `export`; a module never reaches back up that chain.
//! `eval` sits beside them as a consumer of all three. `infer` runs the skeleton model
//! (ONNX Runtime) under `rig`'s token grammar, and `predict` drives it from a mesh.
pub mod api;
pub mod app;
pub mod dataset;
pub mod eval;
pub mod export;
pub mod infer;
pub mod jobs;
pub mod mesh;
pub mod predict;
pub mod rig;
