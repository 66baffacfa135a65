//! Appends rigserve's objects (joint nodes, skins, vertex attributes) to a glTF JSON root
//! whose single buffer is the GLB BIN chunk being built.

use super::weights::Packed;
use super::ExportError;
use crate::rig::Skeleton;
use glam::{DMat4, Mat4};
use serde_json::{json, Map, Value};

pub(crate) const FLOAT: u32 = 5126;
pub(crate) const UNSIGNED_BYTE: u32 = 5121;
pub(crate) const UNSIGNED_SHORT: u32 = 5123;
pub(crate) const UNSIGNED_INT: u32 = 5125;
pub(crate) const ARRAY_BUFFER: u32 = 34962;
pub(crate) const ELEMENT_ARRAY_BUFFER: u32 = 34963;

pub(crate) struct Builder {
    pub root: Map<String, Value>,
    pub bin: Vec<u8>,
}

/// Where the joints went: the node of every bone (in bone order) and the nodes a scene
/// must list so that all of them are reachable.
pub(crate) struct JointNodes {
    pub nodes: Vec<usize>,
    pub scene_roots: Vec<usize>,
}

impl Builder {
    pub fn new(root: Map<String, Value>, bin: Vec<u8>) -> Self {
        Builder { root, bin }
    }

    /// The top-level array `key`, created when absent.
    pub fn array(&mut self, key: &str) -> Result<&mut Vec<Value>, ExportError> {
        self.root
            .entry(key)
            .or_insert_with(|| Value::Array(Vec::new()))
            .as_array_mut()
            .ok_or_else(|| ExportError::Document(format!("{key:?} is not an array")))
    }

    pub fn push(&mut self, key: &str, value: Value) -> Result<usize, ExportError> {
        let a = self.array(key)?;
        a.push(value);
        Ok(a.len() - 1)
    }

    /// Appends bytes as a new bufferView. Offsets are 4-byte aligned, which every
    /// component type and the vertex-attribute rule (§3.6.2.4) need.
    pub fn push_view(&mut self, bytes: &[u8], target: Option<u32>) -> Result<usize, ExportError> {
        // GLB lengths are u32: refuse before allocating rather than after (many frames
        // times many joints is the one way a small input asks for a huge output).
        let end = self.bin.len() as u64 + 3 + bytes.len() as u64;
        if end > u32::MAX as u64 {
            return Err(ExportError::TooLarge(end));
        }
        self.bin.resize(self.bin.len().next_multiple_of(4), 0);
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut view = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
        if let Some(t) = target {
            view["target"] = t.into();
        }
        self.push("bufferViews", view)
    }

    pub fn push_accessor(
        &mut self,
        bytes: &[u8],
        target: Option<u32>,
        component_type: u32,
        count: usize,
        kind: &str,
    ) -> Result<usize, ExportError> {
        let view = self.push_view(bytes, target)?;
        self.push(
            "accessors",
            json!({"bufferView": view, "componentType": component_type, "count": count, "type": kind}),
        )
    }

    /// `JOINTS_0` (bytes when the joints fit, else shorts) and `WEIGHTS_0` (floats) for
    /// a run of vertices.
    pub fn push_skin_attributes(
        &mut self,
        packed: &[Packed],
        joint_count: usize,
    ) -> Result<(usize, usize), ExportError> {
        let (joint_bytes, joint_type) = if joint_count <= 256 {
            let b: Vec<u8> = packed
                .iter()
                .flat_map(|p| p.joints.map(|j| j as u8))
                .collect();
            (b, UNSIGNED_BYTE)
        } else {
            let b: Vec<u8> = packed
                .iter()
                .flat_map(|p| p.joints)
                .flat_map(u16::to_le_bytes)
                .collect();
            (b, UNSIGNED_SHORT)
        };
        let weight_bytes: Vec<u8> = packed
            .iter()
            .flat_map(|p| p.weights)
            .flat_map(f32::to_le_bytes)
            .collect();
        let j = self.push_accessor(
            &joint_bytes,
            Some(ARRAY_BUFFER),
            joint_type,
            packed.len(),
            "VEC4",
        )?;
        let w = self.push_accessor(
            &weight_bytes,
            Some(ARRAY_BUFFER),
            FLOAT,
            packed.len(),
            "VEC4",
        )?;
        Ok((j, w))
    }

    /// One node per bone, parented like the bones, translated only: a joint's rest frame
    /// is then a pure translation to its head, the convention the metrics' skinning
    /// matrices and the bone tree share.
    pub fn push_joint_nodes(&mut self, skel: &Skeleton) -> Result<JointNodes, ExportError> {
        let base = self.array("nodes")?.len();
        let children = skel.children();
        for (i, b) in skel.bones.iter().enumerate() {
            let offset = match b.parent {
                Some(p) => b.head - skel.bones[p].head,
                None => b.head,
            };
            let mut node = json!({"name": b.name, "translation": [offset.x, offset.y, offset.z]});
            if !children[i].is_empty() {
                node["children"] = children[i].iter().map(|&c| base + c).collect();
            }
            self.push("nodes", node)?;
        }
        let nodes: Vec<usize> = (base..base + skel.len()).collect();
        let roots: Vec<usize> = skel.roots().map(|r| base + r).collect();
        // The validator requires a skin's joints to share one root (SKIN_NO_COMMON_ROOT);
        // a forest gets a plain parent node, which no skin lists, so readers still see
        // the skeleton's own roots as root bones.
        let scene_roots = if roots.len() > 1 {
            let holder = self.push(
                "nodes",
                json!({"name": "rigserve_skeleton", "children": roots}),
            )?;
            vec![holder]
        } else {
            roots
        };
        Ok(JointNodes { nodes, scene_roots })
    }

    /// A skin over all joints for vertices whose stored positions `to_world` maps to the
    /// scene. With joint world matrices `T(head)`, `jointWorld · inverseBind = to_world`,
    /// so the rest pose renders every vertex where the input had it.
    pub fn push_skin(
        &mut self,
        skel: &Skeleton,
        joints: &JointNodes,
        to_world: &Mat4,
    ) -> Result<usize, ExportError> {
        let tw = to_world.as_dmat4();
        let mut bytes = Vec::with_capacity(skel.len() * 64);
        for b in &skel.bones {
            // In f64 so the bind matrix does not add rounding of its own on top of the
            // stored positions' frame.
            let ibm = affine((DMat4::from_translation(-b.head.as_dvec3()) * tw).as_mat4());
            bytes.extend(ibm.to_cols_array().iter().flat_map(|c| c.to_le_bytes()));
        }
        let ibm = self.push_accessor(&bytes, None, FLOAT, skel.len(), "MAT4")?;
        let mut skin =
            json!({"name": "rigserve", "inverseBindMatrices": ibm, "joints": joints.nodes});
        if let [root] = joints.scene_roots[..] {
            skin["skeleton"] = root.into();
        }
        self.push("skins", skin)
    }

    pub fn set_buffer(&mut self) {
        self.bin.resize(self.bin.len().next_multiple_of(4), 0);
        self.root
            .insert("buffers".into(), json!([{"byteLength": self.bin.len()}]));
    }
}

pub(crate) use crate::mesh::scene::affine;
