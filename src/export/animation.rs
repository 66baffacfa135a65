//! `animation=preview`: a short looping clip baked into the GLB, so that any glTF viewer
//! shows the rig moving without a retargeting step.
//!
//! The clip is one rotation channel per moving joint node. Joint nodes are translated
//! only (their rest frame is `T(head)`), so a node rotation `R` turns the bone about its
//! head exactly as [`crate::rig::metrics::skinning_matrices`] does with the same local
//! rotations: [`preview_pose`] is the single source of truth for both, which is what lets
//! tests compare a viewer's deformation with rigserve's own skinning at any key time.

use super::builder::{Builder, JointNodes, FLOAT};
use super::ExportError;
use crate::rig::skeleton::Template;
use crate::rig::template::{body_matches, normalize_name};
use crate::rig::Skeleton;
use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::f32::consts::TAU;

/// Whether the export carries a test motion.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Animation {
    #[default]
    None,
    /// [`PREVIEW_CLIP`]: a walk with a wave for Mixamo-like humanoids, a sway otherwise.
    Preview,
}

impl Animation {
    pub fn as_str(self) -> &'static str {
        match self {
            Animation::None => "none",
            Animation::Preview => "preview",
        }
    }

    pub fn parse(s: &str) -> Option<Animation> {
        [Animation::None, Animation::Preview]
            .into_iter()
            .find(|a| a.as_str() == s)
    }
}

/// Name of the clip in `animations[]`.
pub const PREVIEW_CLIP: &str = "rigserve_preview";
/// Length of one loop.
pub const PREVIEW_SECONDS: f32 = 2.0;
/// Keyframes per second. Times are `k / PREVIEW_FPS`, exact in f32 at whole and half
/// seconds, so a test can sample the clip exactly on a key.
pub const PREVIEW_FPS: f32 = 20.0;

/// Key times of the clip: the last key repeats the first pose, so the loop is seamless.
pub fn preview_times() -> Vec<f32> {
    let frames = (PREVIEW_SECONDS * PREVIEW_FPS).round() as usize;
    (0..=frames).map(|k| k as f32 / PREVIEW_FPS).collect()
}

/// Whether the preview treats `skel` as a humanoid (Mixamo body names and parents).
pub fn is_humanoid(skel: &Skeleton) -> bool {
    skel.template == Some(Template::MixamoBody) || body_matches(skel)
}

/// Every bone's rotation about its own head at time `t` of the clip, in the parent's
/// posed frame (the local rotations of [`crate::rig::metrics::skinning_matrices`] and the
/// joint nodes' `rotation`).
pub fn preview_pose(skel: &Skeleton, t: f32) -> Vec<Quat> {
    let phase = TAU * t / PREVIEW_SECONDS;
    let pose = if is_humanoid(skel) {
        humanoid_pose(skel, phase)
    } else {
        sway_pose(skel, phase)
    };
    // Rounding in products of rotations drifts off unit length; glTF wants unit
    // quaternions, and both readers must see the same ones.
    pose.into_iter().map(Quat::normalize).collect()
}

fn direction(skel: &Skeleton, i: usize) -> Vec3 {
    let b = &skel.bones[i];
    (b.tail - b.head).normalize_or(Vec3::Y)
}

/// An axis that turns bone `i` towards `towards` (any perpendicular one when the bone
/// already points that way).
fn turn_axis(skel: &Skeleton, i: usize, towards: Vec3) -> Vec3 {
    let d = direction(skel, i);
    let a = d.cross(towards);
    if a.length_squared() > 1e-6 {
        a.normalize()
    } else {
        d.any_orthonormal_vector()
    }
}

/// Every joint rocks about an axis across its bone, each level of the tree a little
/// behind its parent, so chains bend like a wave travelling outwards; roots turn gently
/// about the vertical.
fn sway_pose(skel: &Skeleton, phase: f32) -> Vec<Quat> {
    let mut depth = vec![0usize; skel.len()];
    let mut out = Vec::with_capacity(skel.len());
    for (i, b) in skel.bones.iter().enumerate() {
        match b.parent {
            None => out.push(Quat::from_rotation_y(8f32.to_radians() * phase.sin())),
            Some(p) => {
                depth[i] = depth[p] + 1;
                let axis = turn_axis(skel, i, Vec3::Y);
                let angle = 12f32.to_radians() * (phase - 0.7 * depth[i] as f32).sin();
                out.push(Quat::from_axis_angle(axis, angle));
            }
        }
    }
    out
}

/// A walk cycle (legs and the left arm swing, knees bend) while the right arm waves.
/// Axes come from the bones themselves, so the motion reads the same whichever side the
/// character's left is on; the swing axis is X, the humanoid's usual left–right axis.
fn humanoid_pose(skel: &Skeleton, phase: f32) -> Vec<Quat> {
    let mut out = vec![Quat::IDENTITY; skel.len()];
    let find = |name: &str| {
        skel.bones
            .iter()
            .position(|b| normalize_name(&b.name) == name)
    };
    let (s, deg) = (phase.sin(), |d: f32| d.to_radians());
    let mut set = |name: &str, f: &dyn Fn(usize) -> Quat| {
        if let Some(i) = find(name) {
            out[i] = f(i);
        }
    };
    set("leftupleg", &|_| Quat::from_rotation_x(deg(25.0) * s));
    set("rightupleg", &|_| Quat::from_rotation_x(-deg(25.0) * s));
    // Positive turns about +X move a downward shin backwards for a character facing +Z
    // (glTF's front); half-cosine ramps keep the knee from over-extending.
    set("leftleg", &|_| {
        Quat::from_rotation_x(deg(30.0) * (1.0 - s) / 2.0)
    });
    set("rightleg", &|_| {
        Quat::from_rotation_x(deg(30.0) * (1.0 + s) / 2.0)
    });
    set("spine", &|_| Quat::from_rotation_y(deg(6.0) * s));
    set("head", &|_| {
        Quat::from_rotation_x(deg(5.0) * (2.0 * phase).sin())
    });
    set("leftarm", &|i| {
        let down = Quat::from_axis_angle(turn_axis(skel, i, Vec3::NEG_Y), deg(60.0));
        Quat::from_rotation_x(-deg(20.0) * s) * down
    });
    set("rightarm", &|i| {
        Quat::from_axis_angle(turn_axis(skel, i, Vec3::Y), deg(70.0))
    });
    set("rightforearm", &|i| {
        let axis = turn_axis(skel, i, Vec3::Y);
        Quat::from_axis_angle(axis, deg(20.0) + deg(30.0) * (2.0 * phase).sin())
    });
    out
}

/// Appends [`PREVIEW_CLIP`] to the document: one sampler and one rotation channel per
/// joint that moves during the clip, all sharing one time accessor.
pub(crate) fn push_preview(
    b: &mut Builder,
    skel: &Skeleton,
    joints: &JointNodes,
) -> Result<(), ExportError> {
    let times = preview_times();
    let poses: Vec<Vec<Quat>> = times.iter().map(|&t| preview_pose(skel, t)).collect();
    let time_bytes: Vec<u8> = times.iter().flat_map(|t| t.to_le_bytes()).collect();
    let input = b.push_accessor(&time_bytes, None, FLOAT, times.len(), "SCALAR")?;
    // Animation inputs must declare their range (ANIMATION_SAMPLER_INPUT_ACCESSOR...).
    let last = times[times.len() - 1];
    let acc = &mut b.array("accessors")?[input];
    acc["min"] = json!([0.0]);
    acc["max"] = json!([last]);

    let (mut samplers, mut channels) = (Vec::new(), Vec::new());
    for (bone, &node) in joints.nodes.iter().enumerate() {
        let track: Vec<Quat> = poses.iter().map(|p| p[bone]).collect();
        if track.iter().all(|q| q.abs_diff_eq(Quat::IDENTITY, 1e-7)) {
            continue;
        }
        let bytes: Vec<u8> = track
            .iter()
            .flat_map(|q| q.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        let output = b.push_accessor(&bytes, None, FLOAT, track.len(), "VEC4")?;
        channels
            .push(json!({"sampler": samplers.len(), "target": {"node": node, "path": "rotation"}}));
        samplers.push(json!({"input": input, "output": output, "interpolation": "LINEAR"}));
    }
    if channels.is_empty() {
        return Ok(());
    }
    b.push(
        "animations",
        json!({"name": PREVIEW_CLIP, "channels": channels, "samplers": samplers}),
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::skeleton::Bone;

    fn chain() -> Skeleton {
        Skeleton {
            bones: vec![
                Bone::new("a", None, Vec3::ZERO, Vec3::Y),
                Bone::new("b", Some(0), Vec3::Y, Vec3::new(0.0, 2.0, 0.0)),
                Bone::new(
                    "c",
                    Some(1),
                    Vec3::new(0.0, 2.0, 0.0),
                    Vec3::new(1.0, 2.0, 0.0),
                ),
            ],
            ..Default::default()
        }
    }

    #[test]
    fn the_clip_loops_and_moves_every_bone_of_a_generic_rig() {
        let skel = chain();
        let times = preview_times();
        assert_eq!((times[0], *times.last().unwrap()), (0.0, PREVIEW_SECONDS));
        assert_eq!(times[10], 0.5);
        let first = preview_pose(&skel, 0.0);
        let end = preview_pose(&skel, PREVIEW_SECONDS);
        for (a, b) in first.iter().zip(&end) {
            assert!(a.abs_diff_eq(*b, 1e-5), "{a} vs {b}");
        }
        let mid = preview_pose(&skel, 0.5);
        for q in &mid {
            assert!((q.length() - 1.0).abs() < 1e-6);
            assert!(q.angle_between(Quat::IDENTITY) > 1e-3, "{q}");
        }
        assert!(!is_humanoid(&skel));
    }

    /// The body template with made-up T-pose positions: what the humanoid branch reads.
    fn body() -> Skeleton {
        use crate::rig::template::{body_name, BODY_BONES, BODY_PARENTS};
        let bones = (0..BODY_BONES)
            .map(|k| {
                let name = body_name(k);
                let side = if name.contains("Left") { 1.0 } else { -1.0 };
                let head = if name.contains("Arm") || name.contains("Hand") {
                    Vec3::new(side * (0.2 + 0.2 * k as f32 / 22.0), 1.4, 0.0)
                } else {
                    Vec3::new(0.0, 1.0 + k as f32 * 0.01, 0.0)
                };
                let tail = if name.contains("Arm") || name.contains("Hand") {
                    head + Vec3::new(side * 0.2, 0.0, 0.0)
                } else {
                    head + Vec3::new(0.0, -0.3, 0.0)
                };
                Bone::new(name, BODY_PARENTS[k], head, tail)
            })
            .collect();
        Skeleton {
            bones,
            ..Default::default()
        }
    }

    #[test]
    fn humanoids_walk_and_wave() {
        let skel = body();
        assert!(is_humanoid(&skel));
        let at = |name: &str| {
            skel.bones
                .iter()
                .position(|b| b.name.ends_with(name))
                .unwrap()
        };
        let (right_arm, left_leg, right_leg) =
            (at(":RightArm"), at(":LeftUpLeg"), at(":RightUpLeg"));
        for t in [0.25, 0.5, 1.5] {
            let pose = preview_pose(&skel, t);
            // The waving arm is up the whole time; the legs swing in opposite phase.
            let up = pose[right_arm] * (skel.bones[right_arm].tail - skel.bones[right_arm].head);
            assert!(up.y > 0.15, "t={t}: the right arm points {up}");
            let (l, r) = (
                pose[left_leg].to_axis_angle(),
                pose[right_leg].to_axis_angle(),
            );
            assert!(
                (l.0 * l.1).abs_diff_eq(-(r.0 * r.1), 1e-5),
                "t={t}: {l:?} {r:?}"
            );
        }
    }

    #[test]
    fn names_parse() {
        assert_eq!(Animation::parse("preview"), Some(Animation::Preview));
        assert_eq!(Animation::parse("none"), Some(Animation::None));
        assert_eq!(Animation::parse("walk"), None);
    }
}
