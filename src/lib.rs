//! rigserve: predicts skeletons and skin weights for bare 3D meshes.
//!
//! Data flows `mesh` → `rig` → `export`; a module never reaches back up that chain.
pub mod mesh;
pub mod rig;
