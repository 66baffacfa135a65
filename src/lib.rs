//! rigserve: predicts skeletons and skin weights for bare 3D meshes.
//!
//! Data flows `mesh` → `rig` → `export`; a module never reaches back up that chain.
//! `eval` sits beside them as a consumer of all three.
pub mod dataset;
pub mod eval;
pub mod export;
pub mod mesh;
pub mod rig;
