//! Training-time variations of a rigged mesh, as in TokenRig: pose, rotation, stretch and
//! pruned skeletons. They live here, in Rust, so training sees exactly what the loader
//! and tokenizer of the server produce.

use crate::mesh::sample::SplitMix64;
use crate::rig::metrics::{lbs, random_pose};
use crate::rig::{Skeleton, SkinWeights};
use glam::{Mat4, Quat, Vec3};

#[derive(Clone, Debug)]
pub struct AugmentConfig {
    /// Largest rotation of any one bone for pose perturbation, in degrees.
    pub pose_deg: f32,
    /// Largest turn about the vertical axis, in degrees.
    pub yaw_deg: f32,
    /// Largest tilt away from vertical, in degrees (small: "up" carries meaning).
    pub tilt_deg: f32,
    /// Per-axis scale drawn from [1/s, s].
    pub stretch: f32,
    /// Chance of dropping one leaf chain of the skeleton.
    pub drop_chain: f32,
}

impl Default for AugmentConfig {
    fn default() -> Self {
        AugmentConfig {
            pose_deg: 20.0,
            yaw_deg: 30.0,
            tilt_deg: 8.0,
            stretch: 1.25,
            drop_chain: 0.15,
        }
    }
}

fn uniform(rng: &mut SplitMix64, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * rng.next_f64() as f32
}

/// Poses, rotates and stretches the mesh and its skeleton together; may drop a leaf chain.
/// Vertices without weights (unskinned accessories) stay where they are under the pose.
pub fn augment(
    positions: &[Vec3],
    skel: &Skeleton,
    weights: &SkinWeights,
    cfg: &AugmentConfig,
    seed: u64,
) -> (Vec<Vec3>, Skeleton) {
    let mut rng = SplitMix64(seed ^ 0xA5A5_5A5A_0F0F_F0F0);
    let pose = random_pose(skel, rng.next_u64(), cfg.pose_deg);
    let mut pos = lbs(positions, weights, &pose);
    let mut out = skel.clone();
    for (b, m) in out.bones.iter_mut().zip(&pose) {
        b.head = m.transform_point3(b.head);
        b.tail = m.transform_point3(b.tail);
    }
    let yaw = Quat::from_rotation_y(uniform(&mut rng, -cfg.yaw_deg, cfg.yaw_deg).to_radians());
    let tilt_axis = Vec3::new(
        uniform(&mut rng, -1.0, 1.0),
        0.0,
        uniform(&mut rng, -1.0, 1.0),
    )
    .normalize_or_zero();
    let tilt = if tilt_axis == Vec3::ZERO {
        Quat::IDENTITY
    } else {
        Quat::from_axis_angle(tilt_axis, uniform(&mut rng, 0.0, cfg.tilt_deg).to_radians())
    };
    let s = cfg.stretch.max(1.0).ln();
    let scale = Vec3::new(
        uniform(&mut rng, -s, s).exp(),
        uniform(&mut rng, -s, s).exp(),
        uniform(&mut rng, -s, s).exp(),
    );
    let m = Mat4::from_quat(tilt * yaw) * Mat4::from_scale(scale);
    pos.iter_mut().for_each(|p| *p = m.transform_point3(*p));
    out.map_points(|p| m.transform_point3(p));
    if (rng.next_f64() as f32) < cfg.drop_chain {
        out = drop_leaf_chain(&out, &mut rng);
    }
    (pos, out)
}

/// Removes one random leaf chain (a leaf and its single-child ancestors up to a branch),
/// never the whole skeleton nor a template bone.
fn drop_leaf_chain(skel: &Skeleton, rng: &mut SplitMix64) -> Skeleton {
    let children = skel.children();
    let protected = match skel.template {
        Some(_) => crate::rig::template::BODY_BONES,
        None => 0,
    };
    let leaves: Vec<usize> = (protected..skel.len())
        .filter(|&i| children[i].is_empty())
        .collect();
    if leaves.is_empty() || skel.len() < 4 {
        return skel.clone();
    }
    let leaf = leaves[(rng.next_u64() % leaves.len() as u64) as usize];
    let mut drop = vec![false; skel.len()];
    let mut cur = leaf;
    loop {
        drop[cur] = true;
        match skel.bones[cur].parent {
            Some(p)
                if p >= protected && children[p].len() == 1 && skel.bones[p].parent.is_some() =>
            {
                cur = p
            }
            _ => break,
        }
    }
    if drop.iter().filter(|d| !**d).count() < 2 {
        return skel.clone();
    }
    let mut remap = vec![usize::MAX; skel.len()];
    let mut out = Skeleton {
        bones: Vec::new(),
        template: skel.template,
        category: skel.category.clone(),
    };
    for (i, b) in skel.bones.iter().enumerate() {
        if drop[i] {
            continue;
        }
        remap[i] = out.bones.len();
        let mut nb = b.clone();
        nb.parent = b.parent.map(|p| remap[p]);
        out.bones.push(nb);
    }
    out.infer_tails();
    out
}
