//! The Mixamo-compatible humanoid template: 22 body bones and a 15-bone hand per side.
//!
//! A skeleton whose first bones follow the template can be tokenized without branch tokens
//! (the template supplies order and parents), and its bones carry names that retargeting
//! tools already understand. [`match_mixamo`] recognises Mixamo-named rigs and reorders
//! them into that layout.
//!
//! Layout of a matched skeleton:
//! - bones `0..22`: the body, in [`BODY_NAMES`] order, parents from [`BODY_PARENTS`];
//! - then zero, one or two hands of 15 bones each (left before right), in [`FINGERS`] order,
//!   three segments per finger; segment 1 hangs off the side's `Hand`, the others off the
//!   previous segment;
//! - then every other bone of the input, in its original order.

use super::skeleton::{Bone, Skeleton, Template};

/// Number of bones in the body template.
pub const BODY_BONES: usize = 22;
/// Number of bones in one hand template.
pub const HAND_BONES: usize = 15;
/// Prefix of every template bone name rigserve writes.
pub const PREFIX: &str = "mixamorig:";

/// Body bone names (without prefix), in template order.
pub const BODY_NAMES: [&str; BODY_BONES] = [
    "Hips",
    "Spine",
    "Spine1",
    "Spine2",
    "Neck",
    "Head",
    "LeftShoulder",
    "LeftArm",
    "LeftForeArm",
    "LeftHand",
    "RightShoulder",
    "RightArm",
    "RightForeArm",
    "RightHand",
    "LeftUpLeg",
    "LeftLeg",
    "LeftFoot",
    "LeftToeBase",
    "RightUpLeg",
    "RightLeg",
    "RightFoot",
    "RightToeBase",
];

/// Parent of each body bone, as an index into [`BODY_NAMES`].
pub const BODY_PARENTS: [Option<usize>; BODY_BONES] = [
    None,     // Hips
    Some(0),  // Spine
    Some(1),  // Spine1
    Some(2),  // Spine2
    Some(3),  // Neck
    Some(4),  // Head
    Some(3),  // LeftShoulder
    Some(6),  // LeftArm
    Some(7),  // LeftForeArm
    Some(8),  // LeftHand
    Some(3),  // RightShoulder
    Some(10), // RightArm
    Some(11), // RightForeArm
    Some(12), // RightHand
    Some(0),  // LeftUpLeg
    Some(14), // LeftLeg
    Some(15), // LeftFoot
    Some(16), // LeftToeBase
    Some(0),  // RightUpLeg
    Some(18), // RightLeg
    Some(19), // RightFoot
    Some(20), // RightToeBase
];

/// Index of `LeftHand` in the body template.
pub const LEFT_HAND: usize = 9;
/// Index of `RightHand` in the body template.
pub const RIGHT_HAND: usize = 13;

/// Finger names in hand-template order; each finger has segments 1, 2, 3.
pub const FINGERS: [&str; 5] = ["Thumb", "Index", "Middle", "Ring", "Pinky"];

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Side {
    Left,
    Right,
}

impl Side {
    pub const BOTH: [Side; 2] = [Side::Left, Side::Right];

    /// Index of this side's `Hand` bone in the body template.
    pub fn hand_index(self) -> usize {
        match self {
            Side::Left => LEFT_HAND,
            Side::Right => RIGHT_HAND,
        }
    }

    pub fn other(self) -> Side {
        match self {
            Side::Left => Side::Right,
            Side::Right => Side::Left,
        }
    }

    fn word(self) -> &'static str {
        match self {
            Side::Left => "Left",
            Side::Right => "Right",
        }
    }
}

/// Full (prefixed) name of body bone `k`.
pub fn body_name(k: usize) -> String {
    format!("{PREFIX}{}", BODY_NAMES[k])
}

/// Unprefixed name of hand bone `k` (0..15) of `side`, e.g. `LeftHandIndex2`.
fn hand_base_name(side: Side, k: usize) -> String {
    format!("{}Hand{}{}", side.word(), FINGERS[k / 3], k % 3 + 1)
}

/// Full (prefixed) name of hand bone `k` (0..15) of `side`, e.g. `mixamorig:LeftHandIndex2`.
pub fn hand_bone_name(side: Side, k: usize) -> String {
    format!("{PREFIX}{}", hand_base_name(side, k))
}

/// Parent of hand bone `k` inside its block: `None` for a finger's first segment (it hangs
/// off the side's `Hand`), otherwise the previous segment's position in the block.
pub fn hand_parent(k: usize) -> Option<usize> {
    if k.is_multiple_of(3) {
        None
    } else {
        Some(k - 1)
    }
}

/// Lower-cases a bone name and strips a Mixamo namespace (`mixamorig:`, `mixamorig1:`,
/// `mixamorig_`, …), so names from different exporters compare equal.
pub fn normalize_name(name: &str) -> String {
    let lower = name.trim().to_ascii_lowercase();
    match lower.strip_prefix("mixamorig") {
        Some(rest) => {
            let rest = rest.trim_start_matches(|c: char| c.is_ascii_digit());
            rest.strip_prefix([':', '_']).unwrap_or(rest).to_string()
        }
        None => lower,
    }
}

/// True when the first 22 bones have the body template's parents: the structural promise
/// that `template == Some(MixamoBody)` makes.
pub fn body_matches(skel: &Skeleton) -> bool {
    skel.bones.len() >= BODY_BONES
        && skel.bones[..BODY_BONES]
            .iter()
            .zip(BODY_PARENTS)
            .all(|(b, p)| b.parent == p)
}

/// The side of the hand block starting at bone `offset`, if bones `offset..offset + 15` are
/// structurally a hand: five three-segment chains hanging off one of the body's `Hand`s.
/// Names are not consulted, so the test survives renaming.
pub fn hand_block_at(skel: &Skeleton, offset: usize) -> Option<Side> {
    let block = skel.bones.get(offset..offset + HAND_BONES)?;
    let side = match block[0].parent {
        Some(LEFT_HAND) => Side::Left,
        Some(RIGHT_HAND) => Side::Right,
        _ => return None,
    };
    let ok = block.iter().enumerate().all(|(k, b)| {
        b.parent
            == Some(match hand_parent(k) {
                None => side.hand_index(),
                Some(rel) => offset + rel,
            })
    });
    ok.then_some(side)
}

/// Recognises a Mixamo-named rig and reorders it into the template layout described in the
/// module docs, with `template = Some(MixamoBody)`.
///
/// Names match case-insensitively, with or without a `mixamorig:`-style namespace. Returns
/// `None` when any body bone is missing, when two bones claim the same body name (two rigs
/// merged into one file cannot be told apart), or when the input is not parents-first.
/// A hand becomes a template block only when all 15 of its bones are present, each exactly
/// once; otherwise its fingers stay as ordinary bones.
///
/// The template fixes the parents of template bones. Every other bone is kept, after the
/// template bones and in its original order, under its original parent; so a bone that sat
/// between two template bones (a `Spine3` between `Spine2` and `Neck`) becomes a side branch
/// of its template ancestor, and a bone above `Hips` (an armature root) becomes a root of
/// its own.
pub fn match_mixamo(skel: &Skeleton) -> Option<Skeleton> {
    let n = skel.bones.len();
    if skel
        .bones
        .iter()
        .enumerate()
        .any(|(i, b)| b.parent.is_some_and(|p| p >= i))
    {
        return None;
    }
    let keys: Vec<String> = skel.bones.iter().map(|b| normalize_name(&b.name)).collect();
    // The bone holding a name, when exactly one does.
    let unique = |base: &str| -> Option<usize> {
        let want = base.to_ascii_lowercase();
        let mut hits = keys.iter().enumerate().filter(|(_, k)| **k == want);
        let first = hits.next()?.0;
        hits.next().is_none().then_some(first)
    };

    let mut order = Vec::with_capacity(n);
    for name in BODY_NAMES {
        order.push(unique(name)?);
    }
    let mut hands = Vec::new();
    for side in Side::BOTH {
        let block: Option<Vec<usize>> = (0..HAND_BONES)
            .map(|k| unique(&hand_base_name(side, k)))
            .collect();
        if let Some(block) = block {
            hands.push((side, order.len()));
            order.extend(block);
        }
    }
    let template_len = order.len();
    let mut new_index = vec![usize::MAX; n];
    for (new, &old) in order.iter().enumerate() {
        new_index[old] = new;
    }
    for (old, slot) in new_index.iter_mut().enumerate() {
        if *slot == usize::MAX {
            *slot = order.len();
            order.push(old);
        }
    }

    let mut bones: Vec<Bone> = Vec::with_capacity(n);
    for (new, &old) in order.iter().enumerate() {
        let src = &skel.bones[old];
        let (name, parent) = if new < BODY_BONES {
            (body_name(new), BODY_PARENTS[new])
        } else if new < template_len {
            let &(side, start) = hands
                .iter()
                .rev()
                .find(|(_, start)| *start <= new)
                .expect("hand blocks cover the template range past the body");
            let k = new - start;
            let parent = match hand_parent(k) {
                None => side.hand_index(),
                Some(rel) => start + rel,
            };
            (hand_bone_name(side, k), Some(parent))
        } else {
            // Extras keep their parent; it is either a template bone or an extra with a smaller
            // original index, so it is placed before this bone either way.
            (src.name.clone(), src.parent.map(|p| new_index[p]))
        };
        bones.push(Bone {
            name,
            parent,
            head: src.head,
            tail: src.tail,
            spring: src.spring,
        });
    }
    Some(Skeleton {
        bones,
        template: Some(Template::MixamoBody),
        category: skel.category.clone(),
    })
}

/// A synthetic T-posed Mixamo rig inside [-1, 1] for tests, with plain names, hands on the
/// requested sides, and extras: `HeadTop_End` above `Head`, a `Spine3` between `Spine2` and
/// `Neck`, and a three-bone tail off `Hips`. Bones are deliberately not in template order.
#[cfg(test)]
pub(crate) fn synthetic_mixamo(left_hand: bool, right_hand: bool) -> Skeleton {
    use glam::Vec3;
    let mut bones: Vec<Bone> = Vec::new();
    let add = |bones: &mut Vec<Bone>, name: &str, parent: Option<&str>, p: [f32; 3]| {
        let parent = parent.map(|pn| {
            bones
                .iter()
                .position(|b| b.name == pn)
                .expect("parent added first")
        });
        bones.push(Bone {
            name: name.to_string(),
            parent,
            head: Vec3::from(p),
            tail: Vec3::from(p) + Vec3::Y * 0.01,
            spring: false,
        });
    };
    add(&mut bones, "mixamorig:Hips", None, [0.0, 0.0, 0.0]);
    for (side, sx) in [("Left", 1.0f32), ("Right", -1.0)] {
        let up = format!("{side}UpLeg");
        let leg = format!("{side}Leg");
        let foot = format!("{side}Foot");
        add(
            &mut bones,
            &up,
            Some("mixamorig:Hips"),
            [0.1 * sx, -0.05, 0.0],
        );
        add(&mut bones, &leg, Some(&up), [0.1 * sx, -0.45, 0.01]);
        add(&mut bones, &foot, Some(&leg), [0.1 * sx, -0.85, 0.0]);
        add(
            &mut bones,
            &format!("mixamorig:{side}ToeBase"),
            Some(&foot),
            [0.1 * sx, -0.9, 0.1],
        );
    }
    add(&mut bones, "Spine", Some("mixamorig:Hips"), [0.0, 0.1, 0.0]);
    add(&mut bones, "Spine1", Some("Spine"), [0.0, 0.2, 0.0]);
    add(
        &mut bones,
        "MIXAMORIG1:Spine2",
        Some("Spine1"),
        [0.0, 0.3, 0.0],
    );
    add(
        &mut bones,
        "Spine3",
        Some("MIXAMORIG1:Spine2"),
        [0.0, 0.36, 0.0],
    );
    add(
        &mut bones,
        "mixamorig_Neck",
        Some("Spine3"),
        [0.0, 0.45, 0.0],
    );
    add(
        &mut bones,
        "Head",
        Some("mixamorig_Neck"),
        [0.0, 0.55, 0.02],
    );
    add(&mut bones, "HeadTop_End", Some("Head"), [0.0, 0.75, 0.02]);
    for (side, sx, hand_wanted) in [("Left", 1.0f32, left_hand), ("Right", -1.0, right_hand)] {
        let shoulder = format!("{side}Shoulder");
        let arm = format!("{side}Arm");
        let fore = format!("{side}ForeArm");
        let hand = format!("{side}Hand");
        add(
            &mut bones,
            &shoulder,
            Some("MIXAMORIG1:Spine2"),
            [0.05 * sx, 0.4, 0.0],
        );
        add(&mut bones, &arm, Some(&shoulder), [0.15 * sx, 0.4, 0.0]);
        add(&mut bones, &fore, Some(&arm), [0.35 * sx, 0.41, -0.01]);
        add(&mut bones, &hand, Some(&fore), [0.55 * sx, 0.4, 0.0]);
        // Without the hand template, still give the hand one finger (an extra chain).
        let fingers: &[&str] = if hand_wanted {
            &FINGERS
        } else {
            &FINGERS[1..2]
        };
        for (f, finger) in fingers.iter().enumerate() {
            let mut parent = hand.clone();
            for seg in 1..=3 {
                let name = format!("{side}Hand{finger}{seg}");
                let z = (f as f32 - 2.0) * 0.025;
                let y = 0.4 - if f == 0 { 0.03 } else { 0.0 };
                add(
                    &mut bones,
                    &name,
                    Some(&parent),
                    [(0.58 + 0.03 * seg as f32) * sx, y, z],
                );
                parent = name;
            }
        }
    }
    for (k, y) in [(1, -0.08f32), (2, -0.12), (3, -0.16)] {
        let parent = if k == 1 {
            "mixamorig:Hips".to_string()
        } else {
            format!("Tail{}", k - 1)
        };
        add(
            &mut bones,
            &format!("Tail{k}"),
            Some(&parent),
            [0.0, y, -0.1 * k as f32],
        );
    }
    Skeleton {
        bones,
        template: None,
        category: Some("humanoid".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn template_tables_are_parents_first_and_named_consistently() {
        for (i, p) in BODY_PARENTS.iter().enumerate() {
            assert!(p.map_or(i == 0, |p| p < i), "body bone {i}");
        }
        assert_eq!(BODY_NAMES[LEFT_HAND], "LeftHand");
        assert_eq!(BODY_NAMES[RIGHT_HAND], "RightHand");
        assert_eq!(body_name(0), "mixamorig:Hips");
        assert_eq!(hand_bone_name(Side::Right, 14), "mixamorig:RightHandPinky3");
        assert_eq!(hand_bone_name(Side::Left, 3), "mixamorig:LeftHandIndex1");
        assert_eq!(hand_parent(3), None);
        assert_eq!(hand_parent(4), Some(3));
    }

    #[test]
    fn names_normalize_across_namespaces() {
        for n in [
            "mixamorig:Hips",
            "mixamorig1:hips",
            "MIXAMORIG_Hips",
            " Hips",
            "mixamorig12:HIPS",
        ] {
            assert_eq!(normalize_name(n), "hips", "{n}");
        }
        assert_eq!(normalize_name("Spine1"), "spine1");
    }

    #[test]
    fn match_reorders_into_template_layout() {
        let src = synthetic_mixamo(true, true);
        let m = match_mixamo(&src).expect("matches");
        m.validate(usize::MAX).unwrap();
        assert_eq!(m.template, Some(Template::MixamoBody));
        assert_eq!(m.category.as_deref(), Some("humanoid"));
        assert_eq!(m.len(), src.len());
        assert!(body_matches(&m));
        for (k, b) in m.bones.iter().enumerate().take(BODY_BONES) {
            assert_eq!(b.name, body_name(k));
            let orig = src
                .bones
                .iter()
                .find(|o| normalize_name(&o.name) == BODY_NAMES[k].to_ascii_lowercase());
            assert_eq!(b.head, orig.unwrap().head);
        }
        assert_eq!(hand_block_at(&m, BODY_BONES), Some(Side::Left));
        assert_eq!(
            hand_block_at(&m, BODY_BONES + HAND_BONES),
            Some(Side::Right)
        );
        assert_eq!(m.bones[BODY_BONES].name, "mixamorig:LeftHandThumb1");
        assert_eq!(
            m.bones[BODY_BONES + HAND_BONES + 14].name,
            "mixamorig:RightHandPinky3"
        );
        // Extras follow, in original order, under their original parents.
        let extras: Vec<&str> = m.bones[BODY_BONES + 2 * HAND_BONES..]
            .iter()
            .map(|b| b.name.as_str())
            .collect();
        assert_eq!(extras, ["Spine3", "HeadTop_End", "Tail1", "Tail2", "Tail3"]);
        let spine3 = m.index_of("Spine3").unwrap();
        assert_eq!(m.bones[spine3].parent, Some(3));
        let top = m.index_of("HeadTop_End").unwrap();
        assert_eq!(m.bones[top].parent, Some(5));
        // The template, not the input, decides Neck's parent.
        assert_eq!(m.bones[4].parent, Some(3));
        let t2 = m.index_of("Tail2").unwrap();
        assert_eq!(m.bones[t2].parent, m.index_of("Tail1"));
    }

    #[test]
    fn incomplete_hands_stay_ordinary_bones() {
        let src = synthetic_mixamo(false, true);
        let m = match_mixamo(&src).unwrap();
        m.validate(usize::MAX).unwrap();
        assert_eq!(hand_block_at(&m, BODY_BONES), Some(Side::Right));
        assert_eq!(hand_block_at(&m, BODY_BONES + HAND_BONES), None);
        let idx = m
            .index_of("LeftHandIndex1")
            .expect("kept under its own name");
        assert_eq!(m.bones[idx].parent, Some(LEFT_HAND));
        let idx2 = m.index_of("LeftHandIndex2").unwrap();
        assert_eq!(m.bones[idx2].parent, Some(idx));
    }

    #[test]
    fn missing_or_ambiguous_body_bones_do_not_match() {
        let mut src = synthetic_mixamo(true, true);
        let i = src.index_of("RightFoot").unwrap();
        src.bones[i].name = "RightFootX".into();
        assert!(match_mixamo(&src).is_none());

        let mut src = synthetic_mixamo(false, false);
        let i = src.index_of("HeadTop_End").unwrap();
        src.bones[i].name = "mixamorig1:Head".into();
        assert!(match_mixamo(&src).is_none());

        let mut src = synthetic_mixamo(false, false);
        src.bones[3].parent = Some(7);
        assert!(match_mixamo(&src).is_none());
        assert!(match_mixamo(&Skeleton::default()).is_none());
    }

    #[test]
    fn root_above_hips_becomes_its_own_root() {
        let mut src = synthetic_mixamo(false, false);
        for b in &mut src.bones {
            b.parent = Some(b.parent.map_or(0, |p| p + 1));
        }
        src.bones.insert(
            0,
            Bone {
                name: "Armature".into(),
                parent: None,
                head: glam::Vec3::ZERO,
                tail: glam::Vec3::Y,
                spring: false,
            },
        );
        let m = match_mixamo(&src).unwrap();
        m.validate(usize::MAX).unwrap();
        assert_eq!(m.bones[0].parent, None);
        let a = m.index_of("Armature").unwrap();
        assert!(a >= BODY_BONES);
        assert_eq!(m.bones[a].parent, None);
    }
}
