//! The bone tree: the skeleton as JSON (schema: `proto/bone_tree.schema.json`).
//!
//! glTF joints carry only a transform, so a skinned GLB alone loses what rigserve knows
//! about each bone: its tail, whether it is part of a spring chain, the template and the
//! category. The bone tree keeps all of it, in the output GLB's world frame (glTF Y-up,
//! the frame of [`crate::mesh::Mesh::positions`]), and round-trips through
//! [`parse_bone_tree`] to the same [`Skeleton`].

use crate::mesh::scene::MAX_JOINTS;
use crate::rig::skeleton::SkeletonError;
use crate::rig::{Bone, Skeleton, Template};
use glam::Vec3;
use serde_json::{json, Map, Value};

pub const BONE_TREE_VERSION: u64 = 1;
/// The only frame version 1 knows: glTF's right-handed Y-up world, in the file's units.
pub const BONE_TREE_FRAME: &str = "gltf_y_up_world";

#[derive(Debug, thiserror::Error)]
pub enum BoneTreeError {
    #[error("bone tree: {0}")]
    Malformed(String),
    #[error("bone tree version {0} is not supported (only {BONE_TREE_VERSION})")]
    Version(String),
    #[error("bone tree frame {0:?} is not supported (only {BONE_TREE_FRAME:?})")]
    Frame(String),
    #[error("bone tree: {0}")]
    Skeleton(#[from] SkeletonError),
}

impl BoneTreeError {
    pub fn code(&self) -> &'static str {
        match self {
            BoneTreeError::Malformed(_) => "bone_tree_malformed",
            BoneTreeError::Version(_) => "bone_tree_unsupported_version",
            BoneTreeError::Frame(_) => "bone_tree_unsupported_frame",
            BoneTreeError::Skeleton(_) => "bone_tree_invalid_skeleton",
        }
    }
}

fn vec3(v: Vec3) -> Value {
    json!([v.x, v.y, v.z])
}

/// The bone tree JSON of a skeleton. Bones keep their order, so `parent` indices (and
/// the glTF joint order of an export, which follows it) stay valid.
pub fn bone_tree(skel: &Skeleton) -> Value {
    let bones: Vec<Value> = skel
        .bones
        .iter()
        .map(|b| {
            let parent_name = b
                .parent
                .and_then(|p| skel.bones.get(p))
                .map(|p| Value::from(p.name.clone()))
                .unwrap_or(Value::Null);
            json!({
                "name": b.name,
                "parent": b.parent,
                "parent_name": parent_name,
                "head": vec3(b.head),
                "tail": vec3(b.tail),
                "spring": b.spring,
            })
        })
        .collect();
    json!({
        "version": BONE_TREE_VERSION,
        "frame": BONE_TREE_FRAME,
        "template": skel.template,
        "category": skel.category,
        "bones": bones,
    })
}

fn bad(msg: impl Into<String>) -> BoneTreeError {
    BoneTreeError::Malformed(msg.into())
}

fn field<'a>(obj: &'a Map<String, Value>, key: &str, at: &str) -> Result<&'a Value, BoneTreeError> {
    obj.get(key)
        .ok_or_else(|| bad(format!("{at} has no {key:?}")))
}

fn parse_vec3(v: &Value, at: &str) -> Result<Vec3, BoneTreeError> {
    let arr = v
        .as_array()
        .filter(|a| a.len() == 3)
        .ok_or_else(|| bad(format!("{at} is not an array of three numbers")))?;
    let mut out = [0f32; 3];
    for (o, x) in out.iter_mut().zip(arr) {
        *o = x
            .as_f64()
            .ok_or_else(|| bad(format!("{at} holds a non-number")))? as f32;
    }
    Ok(Vec3::from(out))
}

/// Reads a bone tree back into a skeleton and checks it with [`Skeleton::validate`].
/// `spring` and `parent_name` may be omitted; a `parent_name` that is given must name
/// the bone at `parent`, so a hand-edited tree cannot silently disagree with itself.
pub fn parse_bone_tree(value: &Value) -> Result<Skeleton, BoneTreeError> {
    let root = value
        .as_object()
        .ok_or_else(|| bad("the top level is not an object"))?;
    let version = field(root, "version", "the tree")?;
    if version.as_u64() != Some(BONE_TREE_VERSION) {
        return Err(BoneTreeError::Version(version.to_string()));
    }
    match field(root, "frame", "the tree")?.as_str() {
        Some(BONE_TREE_FRAME) => {}
        other => return Err(BoneTreeError::Frame(format!("{other:?}"))),
    }
    let template: Option<Template> = match root.get("template") {
        None | Some(Value::Null) => None,
        Some(t) => Some(
            serde_json::from_value(t.clone()).map_err(|_| bad(format!("unknown template {t}")))?,
        ),
    };
    let category = match root.get("category") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(s.clone()),
        Some(other) => return Err(bad(format!("category {other} is not a string"))),
    };
    let list = field(root, "bones", "the tree")?
        .as_array()
        .ok_or_else(|| bad("\"bones\" is not an array"))?;
    // Checked before the loop so a huge list is refused without building it.
    if list.len() > MAX_JOINTS as usize {
        return Err(SkeletonError::TooManyBones(list.len(), MAX_JOINTS as usize).into());
    }
    let mut bones = Vec::with_capacity(list.len());
    for (i, b) in list.iter().enumerate() {
        let at = format!("bone {i}");
        let obj = b
            .as_object()
            .ok_or_else(|| bad(format!("{at} is not an object")))?;
        let name = field(obj, "name", &at)?
            .as_str()
            .ok_or_else(|| bad(format!("{at}: name is not a string")))?
            .to_string();
        let parent = match field(obj, "parent", &at)? {
            Value::Null => None,
            p => Some(
                p.as_u64()
                    .ok_or_else(|| bad(format!("{at}: parent is not null or an index")))?
                    as usize,
            ),
        };
        let head = parse_vec3(field(obj, "head", &at)?, &format!("{at}: head"))?;
        let tail = parse_vec3(field(obj, "tail", &at)?, &format!("{at}: tail"))?;
        let spring = match obj.get("spring") {
            None => false,
            Some(s) => s
                .as_bool()
                .ok_or_else(|| bad(format!("{at}: spring is not a boolean")))?,
        };
        bones.push((
            Bone {
                name,
                parent,
                head,
                tail,
                spring,
            },
            obj.get("parent_name"),
        ));
    }
    let skel = Skeleton {
        bones: bones.iter().map(|(b, _)| b.clone()).collect(),
        template,
        category,
    };
    skel.validate(MAX_JOINTS as usize)?;
    for (i, (b, parent_name)) in bones.iter().enumerate() {
        let expected = b.parent.map(|p| skel.bones[p].name.as_str());
        let ok = match parent_name {
            None => true,
            Some(Value::Null) => expected.is_none(),
            Some(Value::String(s)) => expected == Some(s.as_str()),
            Some(_) => false,
        };
        if !ok {
            return Err(bad(format!(
                "bone {i}: parent_name {} does not name its parent {expected:?}",
                parent_name.cloned().unwrap_or(Value::Null)
            )));
        }
    }
    Ok(skel)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn skel() -> Skeleton {
        let mut s = Skeleton {
            bones: vec![
                Bone {
                    name: "hips".into(),
                    parent: None,
                    head: Vec3::new(0.0, 1.0, 0.0),
                    tail: Vec3::new(0.0, 1.2, 0.0),
                    spring: false,
                },
                Bone {
                    name: "tail.001".into(),
                    parent: Some(0),
                    head: Vec3::new(0.0, 0.9, -0.1),
                    tail: Vec3::new(0.0, 0.7, -0.4),
                    spring: true,
                },
            ],
            template: Some(Template::MixamoBody),
            category: Some("humanoid".into()),
        };
        s.bones[0].head.x = 0.1;
        s
    }

    #[test]
    fn round_trips_exactly() {
        let s = skel();
        let v = bone_tree(&s);
        assert_eq!(v["template"], "mixamo_body");
        assert_eq!(v["bones"][1]["parent_name"], "hips");
        assert_eq!(parse_bone_tree(&v).unwrap(), s);
        let text = serde_json::to_string(&v).unwrap();
        let back: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(parse_bone_tree(&back).unwrap(), s);
    }

    #[test]
    fn rejects_inconsistent_trees() {
        let mut v = bone_tree(&skel());
        v["bones"][1]["parent_name"] = "nope".into();
        assert_eq!(
            parse_bone_tree(&v).unwrap_err().code(),
            "bone_tree_malformed"
        );
        let mut v = bone_tree(&skel());
        v["bones"][0]["parent"] = 1.into();
        assert_eq!(
            parse_bone_tree(&v).unwrap_err().code(),
            "bone_tree_invalid_skeleton"
        );
        let mut v = bone_tree(&skel());
        v["version"] = 2.into();
        assert_eq!(
            parse_bone_tree(&v).unwrap_err().code(),
            "bone_tree_unsupported_version"
        );
        let mut v = bone_tree(&skel());
        v["frame"] = "blender_z_up".into();
        assert_eq!(
            parse_bone_tree(&v).unwrap_err().code(),
            "bone_tree_unsupported_frame"
        );
        let mut v = bone_tree(&skel());
        v["bones"][1]["head"] = json!([0.0, 1.0]);
        assert_eq!(
            parse_bone_tree(&v).unwrap_err().code(),
            "bone_tree_malformed"
        );
    }
}
