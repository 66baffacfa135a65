//! Whether a skeleton someone hands us sits on the mesh it is meant for. A rig in other
//! units or another frame puts most joints far outside the mesh's box; a single joint a
//! hundred mesh sizes away is a typo or garbage (1e30), never a bone anyone animates.
//! Skinning refuses both, and so do bones to keep, which must sit on the mesh the model
//! continues from; the service checks both at upload, with the same rule.

use super::Skeleton;
use glam::Vec3;

/// Beyond the box by this many of its longest side, any one joint or tail is refused.
/// Artists' rigs reach at most 2.3 sides out (a tail of a mech in ../shared/rigs: IK
/// targets and helper bones stand beside the body, not a hundred bodies away).
pub const FAR_SIDES: f32 = 100.0;
/// A joint farther than this fraction of the box's longest side beyond it is outside.
pub const OUTSIDE_MARGIN: f32 = 0.25;

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Misplaced {
    #[error("{outside} of {bones} joints lie far outside the mesh's bounding box; is the skeleton in the mesh's frame and units?")]
    Outside { outside: usize, bones: usize },
    #[error("bone {name:?} reaches {sides:.3e} times the mesh's size beyond its bounding box")]
    Far { name: String, sides: f32 },
}

/// Checks `skel` against the box `lo..hi`: a joint farther than `margin` × the box's
/// longest side beyond it counts as outside, and more than half outside is refused (first,
/// as the likelier mistake: units or frame); then any head or tail more than
/// [`FAR_SIDES`] sides beyond it is refused on its own.
pub fn check(skel: &Skeleton, lo: Vec3, hi: Vec3, margin: f32) -> Result<(), Misplaced> {
    let side = (hi - lo).max_element().max(f32::MIN_POSITIVE);
    // How far beyond the box, in longest sides (0 inside); f64 so 3e38 - (-3e38) stays finite.
    let beyond = |p: Vec3| -> f64 {
        let (p, lo, hi) = (p.as_dvec3(), lo.as_dvec3(), hi.as_dvec3());
        (lo - p).max(p - hi).max_element().max(0.0) / side as f64
    };
    let outside = skel
        .bones
        .iter()
        .filter(|b| beyond(b.head) > margin as f64)
        .count();
    if outside * 2 > skel.len() {
        return Err(Misplaced::Outside {
            outside,
            bones: skel.len(),
        });
    }
    for b in &skel.bones {
        let sides = beyond(b.head).max(beyond(b.tail));
        if sides > FAR_SIDES as f64 {
            return Err(Misplaced::Far {
                name: b.name.clone(),
                sides: sides as f32,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::Bone;

    fn skel(heads: &[Vec3]) -> Skeleton {
        Skeleton {
            bones: heads
                .iter()
                .enumerate()
                .map(|(i, &h)| Bone::new(format!("b{i}"), i.checked_sub(1), h, h + Vec3::Y * 0.1))
                .collect(),
            ..Skeleton::default()
        }
    }

    #[test]
    fn one_stray_joint_passes_a_majority_or_a_far_one_does_not() {
        let (lo, hi) = (Vec3::ZERO, Vec3::new(1.0, 2.0, 0.5));
        let inside = Vec3::new(0.5, 1.0, 0.25);
        // Beside the body, as helper bones stand: fine.
        assert_eq!(
            check(
                &skel(&[inside, inside, Vec3::new(3.0, 1.0, 0.2)]),
                lo,
                hi,
                0.25
            ),
            Ok(())
        );
        // Two of three a metre out: the rig is elsewhere.
        let out = Vec3::new(4.0, 1.0, 0.2);
        assert_eq!(
            check(&skel(&[inside, out, out]), lo, hi, 0.25),
            Err(Misplaced::Outside {
                outside: 2,
                bones: 3
            })
        );
        // One joint at 1e30 (and one at f32's end, whose distance overflows f32).
        for far in [Vec3::new(1e30, 0.0, 0.0), Vec3::new(-3.4e38, 3.4e38, 0.0)] {
            let err = check(&skel(&[inside, inside, far]), lo, hi, 0.25).unwrap_err();
            assert!(
                matches!(&err, Misplaced::Far { name, .. } if name == "b2"),
                "{err:?}"
            );
        }
        // A tail alone can be garbage too.
        let mut s = skel(&[inside, inside]);
        s.bones[1].tail = Vec3::new(0.0, 500.0, 0.0);
        assert!(matches!(
            check(&s, lo, hi, 0.25),
            Err(Misplaced::Far { .. })
        ));
    }
}
